"""Benchmarks of grass_nrsfm_ros: the paper's experiments, peers side by side, speed and scale.

Run ``python -m bench [--full] [--only SUITE ...] [--smoke]``; results go to
``bench/results/<suite>.json`` (``bench/results/smoke/`` for ``--smoke``) with PNG plots beside
them, and ``python -m bench.table --write docs/results.md`` turns them into the results page.

BLAS threads default to 1 (set before numpy is imported): the solvers run many small
decompositions, and timings on a shared machine are only comparable single-threaded. Export
``OPENBLAS_NUM_THREADS`` (etc.) yourself to override.
"""
import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')
