"""Node latency and throughput, plus warm-start savings and streaming accuracy (prints figures).

For 1k, 10k and 30k tracks at window 30 / stride 10: latency from a window closing to its
frames being encoded for publishing (solve + PointCloud2 encoding, in process, no DDS), and the
highest input rate sustained without falling behind (stride frames per window period). Then, on
one sequence: solver iterations and CPU seconds per window under each warm start, and the e3D
of the streamed clouds (``points/refined`` with ``refined_from: first_window``: the sliding
windows) against the whole-sequence solve. The pipeline is the node's, inline (each window
solved as it closes).

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

from bench.streaming import Counting  # noqa: E402
from doubles import bending_sheet  # noqa: E402
from grass_nrsfm_ros import cloud  # noqa: E402
from grass_nrsfm_ros.nrsfm import GrassmannNRSfM  # noqa: E402
from grass_nrsfm_ros.nrsfm.metrics import e3d  # noqa: E402
from grass_nrsfm_ros.params import defaults  # noqa: E402
from grass_nrsfm_ros.pipeline import make_pipeline, reconstruct_live  # noqa: E402


def sliding_pipeline(factory, **options):
    """The node's pipeline (defaults, inline) with ``refined_from: first_window``."""
    return make_pipeline({**defaults(), 'refined_from': 'first_window', **options}, factory)


def latency(tracks, factory, frames=60):
    W, S, ids = bending_sheet(F=frames, P=tracks, noise=0.5)
    pipe = sliding_pipeline(factory)
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
        cpu = time.process_time()
        pipe.add_frame(stamps[f], ids, uv[f])          # inline: a closed window is solved here
        results, updates = pipe.refined()
        if not updates:
            continue
        if header is not None:
            for r in results:
                cloud.encode_points(r.xyz, r.ids, header)
        walls += [time.monotonic() - u.closed_at for u in updates]
        cpus.append(time.process_time() - cpu)
    steady = walls[1:] or walls                 # after the first window: stride new frames
    rate = pipe.windowing.window_stride / statistics.median(steady)
    print(f'{tracks:>6} tracks: window close -> published: first {walls[0]:.3f} s, then median '
          f'{statistics.median(steady):.3f} s (max {max(steady):.3f}); CPU median '
          f'{statistics.median(cpus[1:] or cpus):.3f} s; sustains ~{rate:.1f} frames/s')


def accuracy(factory, frames=90, tracks=1000):
    W, S, ids = bending_sheet(F=frames, P=tracks, noise=0.5)
    order = np.argsort(ids)
    stamps = np.arange(frames)
    frames_in = [(ids, W[2 * f:2 * f + 2].T) for f in range(frames)]
    for warm in ('resume', 'model'):
        counting = Counting(factory)
        _, results, _ = reconstruct_live(sliding_pipeline(counting, warm_start=warm), stamps,
                                         frames_in)
        streamed = np.vstack([r.xyz[np.searchsorted(r.ids, ids[order])].T for r in results])
        later = counting.fits[1:]
        print(f'warm_start {warm:>6}: windows after the first: iterations '
              f'{np.mean([f[0] for f in later]):.1f}, CPU {np.mean([f[1] for f in later]):.3f} '
              f's per window; streaming e3D {e3d(streamed, S[:, order]):.4f}')
    whole = factory().fit(W)
    print(f'whole-sequence solve ({frames} frames): e3D {e3d(whole.S, S):.4f}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--tracks', type=int, nargs='+', default=[1000, 10000, 30000])
    args = parser.parse_args()
    factory = GrassmannNRSfM
    print('solver: GrassmannNRSfM (defaults); window 30, stride 10')
    for tracks in args.tracks:
        latency(tracks, factory)
    accuracy(factory)


if __name__ == '__main__':
    main()
