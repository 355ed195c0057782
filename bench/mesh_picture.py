"""A headless picture of the node's ``mesh`` marker (RViz cannot run here): the node as shipped
(GrassmannNRSfM, context_frames 0 to keep it short) with ``publish_mesh:=true`` is fed a
synthetic bending sheet over DDS; the newest Marker it publishes is drawn with matplotlib
(:func:`grass_nrsfm_ros.render.mesh_figure`, the marker's own triangles and colours).

    python -m bench.mesh_picture [-o docs/mesh.png] [--points 1500] [--frames 40]
"""
import argparse
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

from bench.load import clouds, DEFAULT_LAUNCH, isolated_env

REPO = Path(__file__).resolve().parents[1]


def newest_marker(points, frames, tmp):
    """The last Marker on ``mesh`` after ``frames`` frames of ``points`` tracks at 30 Hz."""
    sys.path.insert(0, str(REPO / 'test'))
    import rosutil
    from visualization_msgs.msg import Marker

    env = isolated_env(tmp)
    args = ['-p', 'publish_mesh:=true', '-p', 'context_frames:=0', '-p', 'window_size:=20',
            '-p', 'window_stride:=10']
    messages = clouds(points, n_frames=frames)
    with rosutil.node_with_feeder(env, Path(tmp) / 'node.log', args, launch=DEFAULT_LAUNCH,
                                  keep_points=False, connect_timeout=60) as (proc, feeder):
        markers = []
        feeder.node.create_subscription(Marker, 'mesh', markers.append, 10)
        time.sleep(1.0)                                  # the node's writer matches our reader
        start = time.monotonic()
        for k, msg in enumerate(messages):
            time.sleep(max(0.0, start + k / 30 - time.monotonic()))
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), 10 ** 9)
            feeder.pub.publish(msg)
        counts = feeder.accounted(frames, timeout=180)
        assert counts is not None and feeder.wait_for(lambda: markers, 10), \
            (Path(tmp) / 'node.log').read_text()
        return markers[-1]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('-o', '--output', default=str(REPO / 'docs' / 'mesh.png'))
    parser.add_argument('--points', type=int, default=1500)
    parser.add_argument('--frames', type=int, default=40)
    args = parser.parse_args(argv)
    from grass_nrsfm_ros.render import mesh_figure, write_png

    with tempfile.TemporaryDirectory(prefix='grass_mesh_') as tmp:
        marker = newest_marker(args.points, args.frames, tmp)
    vertices = np.array([[p.x, p.y, p.z] for p in marker.points])
    colours = np.array([[c.r, c.g, c.b, c.a] for c in marker.colors])
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    write_png(args.output, mesh_figure(
        vertices, colours, f'mesh marker: {len(vertices) // 3} triangles on {args.points} '
        'tracks\n(bending sheet, newest frame, coloured by depth)'))
    print(f'{args.output}: {len(vertices) // 3} triangles')
    return 0


if __name__ == '__main__':
    sys.exit(main())
