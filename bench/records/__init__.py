"""Scripts that reproduce decision records' figures which no benchmark suite measures.

``python -m bench.records.rNNNN [--full]`` prints, for record NNNN, e3D per case and setting
(and the geometric mean of each setting's ratio to the first); the default runs a small case
set in minutes, ``--full`` the record's own case set where it is larger. Only the package's
public solver API is used (:class:`~grass_nrsfm_ros.nrsfm.GrassmannNRSfM` parameters, the
synthetic and face generators, the data folder's mocap sets, skipped when missing), so what a
script compares is what the record's Decision section chose between. Shared pieces:
:mod:`.compare`.
"""
