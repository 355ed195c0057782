"""Bags: written here, read back by a library that did not write them; crash recovery;
errors. (ROS-free except the tests marked ``ros``.)"""
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as McapRos2Writer
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import get_typestore, Stores
import yaml

from doubles import ChunkPipeline
from grass_nrsfm_ros import bag
from grass_nrsfm_ros.cli import main
from grass_nrsfm_ros.cloud import decode_tracks, encode_points, tracks_array
from grass_nrsfm_ros.commands.reconstruct import reconstruct_bag

REPO = Path(__file__).resolve().parents[1]


def synthetic_W(F=12, P=40, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 640, (2 * F, P)), rng.normal(size=(3 * F, P))


def mcap_messages(mcap_path):
    """``[(topic, log_time, decoded)]`` read with mcap + mcap_ros2 (not rosbags)."""
    with open(mcap_path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(ch.topic, m.log_time, dec)
                for _, ch, m, dec in reader.iter_decoded_messages()]


def test_written_bag_is_read_by_mcap_ros2_with_equal_payloads(tmp_path):
    W, S = synthetic_W()
    stamps = 1_000_000_000 + np.arange(12) * 50_000_000
    counts = bag.tracks_bag_from_arrays(W, stamps, tmp_path / 'b', 'cam', S=S)
    assert counts == {'/tracks': 12, '/ground_truth': 12}
    msgs = mcap_messages(tmp_path / 'b' / 'b_0.mcap')
    tracks = [(t, m) for topic, t, m in msgs if topic == '/tracks']
    assert [t for t, _ in tracks] == stamps.tolist()
    for f, (_, m) in enumerate(tracks):
        assert m.header.frame_id == 'cam'
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == stamps[f]
        got = decode_tracks(m)
        np.testing.assert_array_equal(got.ids, np.arange(40))
        np.testing.assert_array_equal(got.uv, W[2 * f:2 * f + 2].T.astype(np.float32))


def test_clean_close_gives_metadata_and_summary(tmp_path):
    rec = bag.Recorder(tmp_path / 'rec', chunk_size=4096)
    rec.add_topic('/tracks', bag.POINTCLOUD2)
    for i in range(50):
        rec.write('/tracks', bag.cloud_cdr(tracks_array(np.arange(30) + i, np.ones((30, 2))),
                                           i, 'cam'), i * 1000)
    assert rec.close() is None
    assert rec.close() is None                                  # idempotent
    meta = yaml.safe_load((tmp_path / 'rec' / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['message_count'] == 50
    assert info['topics_with_message_count'][0]['message_count'] == 50
    with open(tmp_path / 'rec' / 'rec_0.mcap', 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == 50
    assert summary.statistics.chunk_count > 1                     # 4 KiB chunks
    assert len(summary.chunk_indexes) == summary.statistics.chunk_count
    assert (rec.written, rec.dropped) == (50, 0)
    frames = list(bag.read_tracks(tmp_path / 'rec'))
    assert [int(f.ids[0]) for f in frames] == list(range(50))


def test_bags_written_by_other_libraries_are_read(tmp_path):
    """mcap_ros2 bare .mcap, rosbags sqlite3 rosbag2 and rosbags ROS 1 .bag -> read_tracks."""
    W, _ = synthetic_W(F=5, P=7)
    uv = [W[2 * f:2 * f + 2].T for f in range(5)]
    ids = np.arange(7, dtype=np.uint32) * 3
    raws = [bag.cloud_cdr(tracks_array(ids, uv[f]), 10 + f, 'cam') for f in range(5)]
    ts2 = bag.typestore()
    msgs = [ts2.deserialize_cdr(r, bag.POINTCLOUD2) for r in raws]

    with open(tmp_path / 'bare.mcap', 'wb') as f:
        w = McapRos2Writer(f)
        schema = w.register_msgdef(bag.POINTCLOUD2, bag.message_definition(bag.POINTCLOUD2)[0])
        for k, m in enumerate(msgs):
            as_dict = {'header': {'stamp': {'sec': 0, 'nanosec': 10 + k}, 'frame_id': 'cam'},
                       'height': 1, 'width': 7, 'is_bigendian': False, 'point_step': 12,
                       'row_step': 84, 'is_dense': True, 'data': bytes(m.data),
                       'fields': [{'name': p.name, 'offset': p.offset, 'datatype': p.datatype,
                                   'count': 1} for p in m.fields]}
            w.write_message('/tracks', schema, as_dict, log_time=k, publish_time=k)
        w.finish()

    with Writer2(tmp_path / 'sq', version=8, storage_plugin=StoragePlugin.SQLITE3) as w:
        conn = w.add_connection('/tracks', bag.POINTCLOUD2, typestore=ts2)
        for k, r in enumerate(raws):
            w.write(conn, k, r)

    ts1 = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(tmp_path / 'one.bag') as w:
        conn = w.add_connection('/tracks', bag.POINTCLOUD2, typestore=ts1)
        for k, m in enumerate(msgs):
            H, T = ts1.types['std_msgs/msg/Header'], ts1.types['builtin_interfaces/msg/Time']
            F1 = ts1.types['sensor_msgs/msg/PointField']
            m1 = ts1.types[bag.POINTCLOUD2](
                header=H(seq=k, stamp=T(sec=0, nanosec=10 + k), frame_id='cam'), height=1,
                width=7, fields=[F1(name=p.name, offset=p.offset, datatype=p.datatype, count=1)
                                 for p in m.fields],
                is_bigendian=False, point_step=12, row_step=84, data=m.data, is_dense=True)
            w.write(conn, k + 1, ts1.serialize_ros1(m1, bag.POINTCLOUD2))

    for source in ('bare.mcap', 'sq', 'one.bag'):
        frames = list(bag.read_tracks(tmp_path / source))
        assert [f.stamp_ns for f in frames] == [10, 11, 12, 13, 14], source
        for f, frame in enumerate(frames):
            assert frame.frame_id == 'cam'
            np.testing.assert_array_equal(frame.ids, ids)
            np.testing.assert_array_equal(frame.uv, uv[f].astype(np.float32))


@pytest.mark.ros
def test_recorder_serializes_rclpy_messages(tmp_path):
    pytest.importorskip('rclpy')
    # imported here: rclpy is the optional ROS extra; the rest of this file needs none
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import Header

    rng = np.random.default_rng(3)
    rec = bag.Recorder(tmp_path / 'r')
    rec.add_topic('/points', bag.POINTCLOUD2)
    sent = []
    for i in range(5):
        header = Header(frame_id='camera_optical')
        header.stamp.sec, header.stamp.nanosec = 100 + i, 7
        msg = encode_points(rng.normal(size=(25, 3)), np.arange(25), header)
        sent.append(msg)
        rec.write('/points', msg, (100 + i) * 10**9)
    assert rec.close() is None
    got = mcap_messages(tmp_path / 'r' / 'r_0.mcap')
    assert len(got) == 5
    for msg, (_, t, dec) in zip(sent, got):
        assert bytes(dec.data) == bytes(msg.data) and dec.header.stamp.sec == msg.header.stamp.sec
    frames = list(bag.read_points(tmp_path / 'r'))
    raw = bag.serialize(sent[0])
    assert deserialize_message(raw, PointCloud2) == sent[0]
    assert [f.stamp_ns for f in frames] == [(100 + i) * 10**9 + 7 for i in range(5)]


KILLED_WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from grass_nrsfm_ros import bag
    from grass_nrsfm_ros.cloud import tracks_array
    out, chunk = sys.argv[1], int(sys.argv[2])
    rec = bag.Recorder(out, chunk_size=chunk, flush_period=60.0)
    rec.add_topic('/tracks', bag.POINTCLOUD2)
    i = 0
    while True:
        ids = np.arange(80) + 80 * i
        rec.write('/tracks', bag.cloud_cdr(tracks_array(ids, np.zeros((80, 2))), i, 'c'), i)
        print(i + 1, flush=True)
        i += 1
        time.sleep(0.002)        # a 500 Hz source (a rate, not a wait): the writer keeps up
""")


def test_kill_9_loses_at_most_the_last_chunk_and_recover_rescues_the_rest(tmp_path):
    chunk = 16 * 1024
    msg_len = len(bag.cloud_cdr(tracks_array(np.arange(80), np.zeros((80, 2))), 0, 'c'))
    proc = subprocess.Popen([sys.executable, '-c', KILLED_WRITER, str(tmp_path / 'k'),
                             str(chunk)], stdout=subprocess.PIPE, text=True, cwd=REPO,
                            env={**os.environ, 'PYTHONPATH': str(REPO)})
    reported = 0
    for line in proc.stdout:
        reported = int(line)
        if reported >= 311:
            break
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    for line in proc.stdout:                  # what it printed before it died
        reported = int(line)
    assert not (tmp_path / 'k' / 'metadata.yaml').exists()
    with pytest.raises(bag.CorruptBagError, match='recover'):
        list(bag.read_tracks(tmp_path / 'k'))

    report = bag.recover(tmp_path / 'k')
    assert report.out_path == tmp_path / 'k_recovered'
    assert len(report.stopped) == 1                       # the file had no end
    frames = list(bag.read_tracks(report.out_path))
    got = [int(f.ids[0]) // 80 for f in frames]
    assert got == list(range(len(got)))                   # a prefix, in order, complete
    assert report.messages == len(got)
    lost = reported - len(got)
    per_chunk = chunk // msg_len + 1                      # a chunk closes once it passes chunk
    print(f'kill -9: reported {reported}, recovered {len(got)}, lost {lost}, '
          f'bound {per_chunk + 1}')
    assert 0 <= lost <= per_chunk + 1, (lost, per_chunk)  # +1: a message in the writer's hands


def test_recover_of_a_complete_bag_keeps_every_message(tmp_path):
    W, S = synthetic_W(F=30, P=20)
    bag.tracks_bag_from_arrays(W, np.arange(30), tmp_path / 'c', S=S)
    report = bag.recover(tmp_path / 'c', tmp_path / 'again')
    assert report.counts == {'/tracks': 30, '/ground_truth': 30} and report.stopped == []
    W2, _, _ = bag.read_W(tmp_path / 'again')
    np.testing.assert_array_equal(W2, W.astype(np.float32))


def test_unwritable_path_gives_one_error_and_writes_do_not_raise(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('x')
    errors = []
    rec = bag.Recorder(blocker / 'bag', on_error=errors.append)
    rec.add_topic('/tracks', bag.POINTCLOUD2)
    assert [rec.write('/tracks', b'\0' * 8, i) for i in range(5)] == [False] * 5
    assert rec.close() == rec.error
    assert len(errors) == 1 and errors[0] == rec.error
    assert str(blocker) in rec.error and 'recording' in rec.error
    assert rec.dropped == 5 and rec.written == 0


FULL_DISK_WRITER = textwrap.dedent("""
    import resource, signal, sys, threading, time
    from grass_nrsfm_ros import bag
    from grass_nrsfm_ros.cloud import tracks_array
    import numpy as np
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)          # writes past the limit -> EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))
    errors, failed = [], threading.Event()
    rec = bag.Recorder(sys.argv[1], chunk_size=8192, queue_size=1000,
                       on_error=lambda e: (errors.append(e), failed.set()))
    rec.add_topic('/tracks', bag.POINTCLOUD2)
    raw = bag.cloud_cdr(tracks_array(np.arange(100), np.zeros((100, 2))), 0, 'c')
    for i in range(200):
        rec.write('/tracks', raw, i)
    assert failed.wait(30)
    start = time.process_time()
    time.sleep(2.0)          # a measuring window: the failed recorder must not spin meanwhile
    idle_cpu = time.process_time() - start
    rec.close()
    print(len(errors), rec.written, rec.dropped, idle_cpu, repr(rec.error))
""")


def test_full_disk_gives_one_error_and_the_caller_goes_on(tmp_path):
    out = subprocess.run([sys.executable, '-c', FULL_DISK_WRITER, str(tmp_path / 'full')],
                         capture_output=True, text=True, cwd=REPO, timeout=60,
                         env={**os.environ, 'PYTHONPATH': str(REPO)})
    assert out.returncode == 0, out.stderr
    n_errors, written, dropped, idle_cpu, error = out.stdout.split(maxsplit=4)
    assert n_errors == '1' and 'File too large' in error and 'recover' in error
    # the recorder thread busy-looped after a failure (a whole core: 2.0 s of CPU in 2 s),
    # which starved the node's solves (rigid stand-in 0.1 s -> 7.4 s per window)
    assert float(idle_cpu) < 0.2, idle_cpu
    assert int(written) + int(dropped) == 200 and int(dropped) > 0
    report = bag.recover(tmp_path / 'full')                      # what reached the disk
    assert 0 < report.messages <= int(written)


def test_truncated_and_corrupt_bags_give_clear_errors(tmp_path):
    W, _ = synthetic_W()
    bag.tracks_bag_from_arrays(W, np.arange(12), tmp_path / 'ok')
    mcap = tmp_path / 'ok' / 'ok_0.mcap'
    data = mcap.read_bytes()
    (tmp_path / 'cut.mcap').write_bytes(data[:len(data) // 2])
    with pytest.raises(bag.CorruptBagError, match='cut.mcap.*recover'):
        list(bag.read_tracks(tmp_path / 'cut.mcap'))
    (tmp_path / 'junk.mcap').write_bytes(b'not a bag at all' * 10)
    with pytest.raises(bag.CorruptBagError, match='junk.mcap'):
        list(bag.read_tracks(tmp_path / 'junk.mcap'))
    (tmp_path / 'junk.bag').write_bytes(b'#ROSBAG V2.0\n' + b'\xff' * 50)
    with pytest.raises(bag.CorruptBagError, match='junk.bag'):
        list(bag.read_tracks(tmp_path / 'junk.bag'))
    (tmp_path / 'ok' / 'metadata.yaml').unlink()
    with pytest.raises(bag.CorruptBagError, match='no metadata.yaml.*recover'):
        list(bag.read_tracks(tmp_path / 'ok'))
    with pytest.raises(FileNotFoundError):
        list(bag.read_tracks(tmp_path / 'missing'))


def test_missing_topic_and_wrong_type_are_rejected(tmp_path):
    W, _ = synthetic_W()
    bag.tracks_bag_from_arrays(W, np.arange(12), tmp_path / 'b')
    with pytest.raises(bag.TopicNotFoundError, match=r"no topic '/points' \(topics: /tracks\)"):
        list(bag.read_points(tmp_path / 'b'))
    with bag.BagWriter(tmp_path / 'other') as w:
        w.add_topic('/tracks', 'std_msgs/msg/String')
        w.write('/tracks', bag.typestore().serialize_cdr(
            bag.typestore().types['std_msgs/msg/String'](data='hi'), 'std_msgs/msg/String'), 1)
    with pytest.raises(bag.BagError, match='std_msgs/msg/String'):
        list(bag.read_tracks(tmp_path / 'other'))


def test_writer_refuses_to_overwrite(tmp_path):
    (tmp_path / 'x').mkdir()
    (tmp_path / 'x' / 'keep').write_text('1')
    with pytest.raises(FileExistsError):
        bag.BagWriter(tmp_path / 'x')


def test_convert_round_trip_equals_W(tmp_path, dataset, capsys):
    W, S = dataset('akhter_mocap/yoga.npz')
    np.savez(tmp_path / 'in.npz', W=W, S=S)
    assert main(['convert', str(tmp_path / 'in.npz'), str(tmp_path / 'y'), '--rate', '25',
                 '--start', '100', '--frame-id', 'cam']) == 0
    assert '307 messages on /tracks, 307 messages on /ground_truth' in capsys.readouterr().out
    frames = list(bag.read_tracks(tmp_path / 'y'))
    assert len(frames) == 307 and {f.frame_id for f in frames} == {'cam'}
    assert [f.stamp_ns for f in frames] == [100 * 10**9 + k * 40_000_000 for k in range(307)]
    W2, ids, _ = bag.read_W(tmp_path / 'y')
    np.testing.assert_array_equal(ids, np.arange(41))
    np.testing.assert_array_equal(W2, W)                   # the data are float32 already
    S2, _, _ = bag.read_S(tmp_path / 'y', bag.GROUND_TRUTH_TOPIC)
    np.testing.assert_array_equal(S2, S)


def test_convert_leaves_out_invisible_points_and_recover_cli(tmp_path, capsys):
    W, _ = synthetic_W(F=4, P=6)
    visible = np.ones((4, 6), bool)
    visible[1, [0, 4]] = False
    np.savez(tmp_path / 'in.npz', W=W, visible=visible)
    assert main(['convert', str(tmp_path / 'in.npz'), str(tmp_path / 'v')]) == 0
    frames = list(bag.read_tracks(tmp_path / 'v'))
    np.testing.assert_array_equal(frames[1].ids, [1, 2, 3, 5])
    W2, _, _ = bag.read_W(tmp_path / 'v')
    expected = W.astype(np.float32).astype(np.float64)
    expected[2:4, [0, 4]] = np.nan
    np.testing.assert_array_equal(W2, expected)
    assert main(['recover', str(tmp_path / 'v'), '-o', str(tmp_path / 'r')]) == 0
    assert 'recovered 4 messages from 1 file(s)' in capsys.readouterr().out
    np.savez(tmp_path / 'bad.npz', X=W)
    assert main(['convert', str(tmp_path / 'bad.npz'), str(tmp_path / 'z')]) == 2
    assert 'has no array W' in capsys.readouterr().err


def test_reconstruct_bag_writes_points_for_every_frame_and_copies_inputs(tmp_path):
    W, S = synthetic_W(F=8, P=10)
    visible = np.ones((8, 10), bool)
    visible[5, 2:] = False                                  # frame 5: 2 tracks, refused
    stamps = 10**9 + np.arange(8) * 1000
    bag.tracks_bag_from_arrays(W, stamps, tmp_path / 'in', S=S, visible=visible)
    calls = []
    report = reconstruct_bag(tmp_path / 'in', tmp_path / 'out', ChunkPipeline(),
                             progress=lambda d, t: calls.append((d, t)))
    assert (report.frames_in, report.frames_out, report.windows) == (8, 7, 3)
    assert len(report.refused) == 1 and 'frame 5' in report.refused[0]
    assert report.copied == {'/tracks': 8, '/ground_truth': 8}
    assert calls[-1] == (8, 8) and len(calls) == 8
    points = list(bag.read_points(tmp_path / 'out'))
    assert [p.stamp_ns for p in points] == [s for k, s in enumerate(stamps) if k != 5]
    for p in points:
        f = int(np.flatnonzero(stamps == p.stamp_ns)[0])
        uv = W[2 * f:2 * f + 2].T.astype(np.float32)
        np.testing.assert_allclose(p.xyz[:, :2], uv)
        np.testing.assert_allclose(p.xyz[:, 2], uv.astype(np.float64).sum(axis=1), rtol=1e-6)
    W2, _, _ = bag.read_W(tmp_path / 'out')
    W_in, _, _ = bag.read_W(tmp_path / 'in')
    np.testing.assert_array_equal(W2, W_in)
    assert bag.topics(tmp_path / 'out')['/ground_truth'] == (bag.POINTCLOUD2, 8)
