"""The offline path (``grass-nrsfm reconstruct BAG``) and the live node give the same clouds.

One synthetic sequence is converted to a tracks bag; the bag is reconstructed offline with the
CLI, and the same frames are published to a node process (real GrassmannNRSfM, default window
parameters) slowly enough that no window is skipped. Every frame's cloud must agree.
"""

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from doubles import paced
from grass_nrsfm_ros import bag, cli, cloud
from grass_nrsfm_ros.nrsfm import e3d
from grass_nrsfm_ros.nrsfm.measurement import as_frames
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence

rclpy = pytest.importorskip('rclpy')
from builtin_interfaces.msg import Time  # noqa: E402, I100
from std_msgs.msg import Header  # noqa: E402
from rosutil import node_with_feeder  # noqa: E402, I100

pytestmark = pytest.mark.ros
REAL_SOLVER_LAUNCH = 'import sys; from grass_nrsfm_ros.node import main; sys.exit(main())'
T0 = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000                      # 10 Hz: slow enough that no window is skipped


def clouds_by_stamp(messages):
    out = {}
    for msg in messages:
        ids, xyz = cloud.decode_points(msg)
        out[msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec] = (ids, xyz)
    return out


def feed(feeder, seq, stamps):
    """Publish the sequence's tracks at 10 Hz (a camera's rate, not a wait)."""
    uv = as_frames(seq.W, 2).transpose(0, 2, 1)
    ids = np.arange(seq.n_points, dtype=np.uint32)
    for f, stamp in paced(enumerate(stamps), PERIOD_NS / 1e9):
        header = Header(stamp=Time(sec=int(stamp) // 10 ** 9, nanosec=int(stamp) % 10 ** 9),
                        frame_id='camera')
        feeder.publish(cloud.encode_tracks(ids, uv[f], header))


def assert_same(live, offline, seq, stamps, what):
    assert sorted(live) == list(stamps), what                 # each frame once, all
    scale = np.abs(seq.W).max()
    for stamp in stamps:
        np.testing.assert_array_equal(live[stamp][0], offline[stamp][0])
        np.testing.assert_allclose(live[stamp][1], offline[stamp][1], rtol=0, atol=1e-4 * scale,
                                   err_msg=what)
    S_live = np.concatenate([live[s][1].T for s in stamps])
    S_off = np.concatenate([offline[s][1].T for s in stamps])
    print(f'{what}: max |live - offline| = {np.abs(S_live - S_off).max():.3g}, e3D live '
          f'{e3d(S_live, seq.S):.4f}, offline {e3d(S_off, seq.S):.4f}')
    assert abs(e3d(S_live, seq.S) - e3d(S_off, seq.S)) < 1e-4


@pytest.mark.parametrize('mapping', ['inline', 'process'])
def test_offline_reconstruction_equals_the_live_node(ros_env, tmp_path, mapping):
    """``mapping:=inline`` solves each window before the next frame, as the offline path does:
    ``points`` and ``points/refined`` are the same. In the mapping process the model swaps in
    when its solve ends, so ``points`` depend on timing;
    ``points/refined`` (the windows, none skipped at 10 Hz) are still the same."""
    seq = make_sequence('inflating', n_frames=40, n_points=300, seed=1)
    stamps = T0 + PERIOD_NS * np.arange(seq.n_frames, dtype=np.int64)
    bag.tracks_bag_from_arrays(seq.W, stamps, tmp_path / 'tracks', frame_id='camera')
    with threadpool_limits(1):                       # the node caps BLAS to 1 thread here too
        assert cli.main(['reconstruct', str(tmp_path / 'tracks'), '-o',
                         str(tmp_path / 'offline'), '--quiet']) == 0
    offline = {f.stamp_ns: (f.ids, f.xyz) for f in bag.read_points(tmp_path / 'offline')}
    refined = {f.stamp_ns: (f.ids, f.xyz)
               for f in bag.read_points(tmp_path / 'offline', bag.REFINED_TOPIC)}
    assert sorted(offline) == sorted(refined) == list(stamps)

    log = tmp_path / 'node.log'
    with node_with_feeder(ros_env, log, ['-p', f'mapping:={mapping}'], launch=REAL_SOLVER_LAUNCH,
                          points_depth=seq.n_frames) as (_, feeder):
        feed(feeder, seq, stamps)
        assert feeder.wait_for(lambda: len(feeder.points) >= seq.n_frames
                               and len(feeder.refined) >= seq.n_frames, 120), log.read_text()
        live, live_refined = clouds_by_stamp(feeder.points), clouds_by_stamp(feeder.refined)

    assert_same(live_refined, refined, seq, stamps, f'{mapping}: points/refined')
    if mapping == 'inline':
        assert_same(live, offline, seq, stamps, 'inline: points')
    else:
        assert sorted(live) == list(stamps)
