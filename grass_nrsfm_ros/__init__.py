"""grass_nrsfm_ros: dense Grassmannian NRSfM (Kumar et al., CVPR 2018) for ROS 2.

The numerical core lives in :mod:`grass_nrsfm_ros.nrsfm` and imports no ROS; the node, bag and
PointCloud2 modules sit on top of it.
"""
__version__ = '0.1.0'
