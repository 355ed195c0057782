"""The add-ons around Algorithm 1, one module each, in the order :meth:`GrassmannNRSfM.fit`
runs them: (through a pinhole, surface: a sheet or not,) robust (track weights), rotations,
rotation check, thinning, (the ADMM,) refinement, fill, registration, relief.

Each stage module has ``NAME`` (as listed in ``SolverReport.stages``), ``applies(...) -> bool``
(whether it acts on this problem), ``run(...)`` (what it does) and writes its own section of the
:class:`~grass_nrsfm_ros.nrsfm.problem.SolverReport` (its docstring names the fields). A stage
that needs an ADMM solve is handed the solver's shape pass as a function; no stage builds a
solver.
"""
