"""Node latency and throughput, plus warm-start savings and streaming accuracy (prints figures).

For 1k, 10k and 30k tracks at window 30 / stride 10: latency from a window closing to its
frames being encoded for publishing (solve + PointCloud2 encoding, in process, no DDS), and the
highest input rate sustained without falling behind (stride frames per window period). Then, on
one sequence: solver iterations and CPU seconds per window with and without the warm start, and
the e3D of the streamed clouds against the whole-sequence solve.

    OPENBLAS_NUM_THREADS=1 python bench/node_latency.py [--tracks 1000 10000 30000]

Uses GrassmannNRSfM and the bending sheet of test/doubles.py. Timings are noisy on a shared
machine: CPU seconds are printed too.
"""
import argparse
from pathlib import Path
import statistics
import sys
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / 'test')]     # run as a script: the checkout and test/

from doubles import bending_sheet  # noqa: E402
from grass_nrsfm_ros import cloud  # noqa: E402
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM, WarmStart  # noqa: E402
from grass_nrsfm_ros.nrsfm.metrics import e3d  # noqa: E402
from grass_nrsfm_ros.pipeline import reconstruct_sequence, SlidingWindow  # noqa: E402


class Counting:
    """Wraps a factory to record each fit's iterations and CPU seconds."""

    def __init__(self, factory):
        self.factory, self.fits = factory, []

    def __call__(self):
        inner = self.factory()
        fits = self.fits

        class Fit:
            def fit(self, W, init=None):
                start = time.process_time()
                result = inner.fit(W, init=init) if init is not None else inner.fit(W)
                fits.append((getattr(result.report, 'iterations', 0),
                             time.process_time() - start, init is not None))
                return result
        return Fit()


def latency(tracks, factory, warm_cls, frames=60):
    W, S, ids = bending_sheet(F=frames, P=tracks, noise=0.5)
    pipe = SlidingWindow(factory, warm_start_class=warm_cls)
    stamps = np.arange(frames) * 33_000_000
    uv = W.reshape(frames, 2, tracks).transpose(0, 2, 1)
    walls, cpus = [], []
    header = None
    try:        # std_msgs comes with ROS 2 (optional): without it the encoding is not timed
        from std_msgs.msg import Header
        header = Header(frame_id='camera')
    except ImportError:
        pass
    for f in range(frames):
        for window in pipe.add_frame(stamps[f], ids, uv[f]):
            cpu = time.process_time()
            results = pipe.solve(window)
            if header is not None:
                for r in results:
                    cloud.encode_points(r.xyz, r.ids, header)
            walls.append(time.monotonic() - window.closed_at)
            cpus.append(time.process_time() - cpu)
    steady = walls[1:] or walls                 # after the first window: stride new frames
    rate = pipe.window_stride / statistics.median(steady)
    print(f'{tracks:>6} tracks: window close -> published: first {walls[0]:.3f} s, then median '
          f'{statistics.median(steady):.3f} s (max {max(steady):.3f}); CPU median '
          f'{statistics.median(cpus[1:] or cpus):.3f} s; sustains ~{rate:.1f} frames/s')


def accuracy(factory, warm_cls, frames=90, tracks=1000):
    W, S, ids = bending_sheet(F=frames, P=tracks, noise=0.5)
    order = np.argsort(ids)
    stamps = np.arange(frames)
    frames_in = [(ids, W[2 * f:2 * f + 2].T) for f in range(frames)]
    for warm in ('model', 'off', 'full'):
        counting = Counting(factory)
        pipe = SlidingWindow(counting, warm_start=warm, warm_start_class=warm_cls)
        results = reconstruct_sequence(pipe, stamps, frames_in)
        streamed = np.vstack([r.xyz[np.searchsorted(r.ids, ids[order])].T for r in results])
        later = counting.fits[1:]
        print(f'warm_start {warm:>5}: windows after the first: iterations '
              f'{np.mean([f[0] for f in later]):.1f}, CPU {np.mean([f[1] for f in later]):.3f} '
              f's per window; streaming e3D {e3d(streamed, S[:, order]):.4f}')
    whole = factory().fit(W)
    print(f'whole-sequence solve ({frames} frames): e3D {e3d(whole.S, S):.4f}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--tracks', type=int, nargs='+', default=[1000, 10000, 30000])
    args = parser.parse_args()
    factory, warm_cls = GrassmannNRSfM, WarmStart
    print('solver: GrassmannNRSfM (defaults); window 30, stride 10')
    for tracks in args.tracks:
        latency(tracks, factory, warm_cls)
    accuracy(factory, warm_cls)


if __name__ == '__main__':
    main()
