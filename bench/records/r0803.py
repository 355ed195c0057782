"""Record 0803: a window's unseen entries completed once. CPU seconds per window of the mapper
(make_mapper, defaults) on a dense face whose tracks die and are born (bench.track_streams'
stream), with the window's completion handed to the solver (``fit(W, filled=)``, shipped) and
without (the solver completes its tracks again), and the seconds spent in the completion.

    python -m bench.records.r0803 [--frames 60] [--tracks 10000] [--windows 4]
"""
import argparse
import sys
import time

import numpy as np

from bench import common
from bench.track_streams import track_stream
from grass_nrsfm_ros import mapper, params
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, missing, problem
from grass_nrsfm_ros.windowing import Windowing


class CompletesAgain(GrassmannNRSfM):
    """The solver without the ``filled`` keyword: it completes the window's tracks itself."""

    def fit(self, W, init=None, progress=None, beta_max=None, visible=None):
        return super().fit(W, init=init, progress=progress, beta_max=beta_max, visible=visible)


def timed_completion(seconds):
    """``missing.complete`` wrapped to add its CPU seconds to ``seconds[0]``."""
    shipped = missing.complete

    def complete(*args, **kwargs):
        start = time.process_time()
        try:
            return shipped(*args, **kwargs)
        finally:
            seconds[0] += time.process_time() - start
    return complete


def windows(frames):
    config = params.defaults()
    windowing = Windowing(**{k: config[k] for k in params.WINDOW_KEYS})
    return [w for f, (ids, uv) in enumerate(frames)
            for w in windowing.push(windowing.accept(f, ids, uv))]


def run(frames, n_windows, factory):
    """Per window ``(CPU s, completion CPU s, tracks)`` of a fresh mapper."""
    config = params.defaults()
    solver_kwargs = params.solver_kwargs(config)
    the_mapper = mapper.make_mapper(config, solver_factory=lambda: factory(**solver_kwargs))
    out = []
    for window in windows(frames)[:n_windows]:
        spent = [0.0]
        shipped = missing.complete, problem.complete
        missing.complete = problem.complete = timed_completion(spent)
        try:
            start = time.process_time()
            the_mapper.solve(window)
            out.append((time.process_time() - start, spent[0], int(window.ids.size)))
        finally:
            missing.complete, problem.complete = shipped
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=60)
    parser.add_argument('--tracks', type=int, default=10000)
    parser.add_argument('--windows', type=int, default=4)
    args = parser.parse_args(argv)
    W, _ = common.dense_face(args.frames, args.tracks)
    frames, _ = track_stream(W, np.random.default_rng(0))
    for name, factory in (('once (filled handed over)', GrassmannNRSfM),
                          ('twice (the solver completes again)', CompletesAgain)):
        rows = run(frames, args.windows, factory)
        cells = [f'{cpu:.2f} s (completion {fill:.2f} s, {n} tracks)' for cpu, fill, n in rows]
        print(f'{name}: ' + '; '.join(cells) + f'; total {sum(r[0] for r in rows):.2f} s',
              flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
