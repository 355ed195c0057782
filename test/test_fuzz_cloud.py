"""Fuzzing the input contract: hostile ``tracks`` clouds against cloud.decode_tracks and the
node's callback.

Every example starts from a valid cloud (random field order, padding, organised layout,
endianness, float32/float64 u, v) and breaks it in a few random ways: fields renamed, dropped,
duplicated or given other datatypes, counts and offsets; point_step / row_step / height / width
changed (sizes up to millions of points claimed over a short ``data``); data cut or padded;
NaN/Inf, huge and negative coordinates; repeated ids. The decoder must either return
consistent Tracks or raise CloudError with a specific message; nothing else may escape, and
its peak allocation (tracemalloc) is bounded by a multiple of the bytes actually given.

Both real ``sensor_msgs/PointCloud2`` messages (field types enforced by rclpy) and duck-typed
ones (``SimpleNamespace``: any integer, negative or beyond 64 bits) are tried.

What was tried and rejected is recorded as the test-suite property ``reliability_fuzz`` (JSON);
``python -m bench.reliability`` collects it into bench/results/reliability.json. The tests
write no file.
"""
from collections import Counter
import json
import os
import tracemalloc
from types import SimpleNamespace

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

from doubles import RigidALS
from grass_nrsfm_ros import cloud

EXAMPLES = 300
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
MEMORY_FACTOR = 40          # peak bytes allocated per byte of data given (measured max ~21)
MEMORY_SLACK = 256 * 1024   # fixed overhead (dtype objects, exception text, small arrays)
REASON_WORDS = ('field', 'data', 'row_step', 'point_step', 'size', 'duplicate', 'datatype',
                'offset', 'count', 'height', 'width', 'bytes')

NAMES = ('track_id', 'u', 'v', 'x', 'score', 'U', 'track_id ', '')
MUTATIONS = ('drop_field', 'rename_field', 'duplicate_field', 'datatype', 'count', 'offset',
             'point_step', 'row_step', 'claim_width', 'claim_height', 'swap_hw', 'cut_data',
             'pad_data', 'endianness', 'non_finite', 'huge', 'repeat_ids', 'empty')


@st.composite
def layouts(draw):
    """A valid tracks cloud as a dict of PointCloud2 fields (``fields`` as dicts)."""
    P = draw(st.integers(0, 60))
    height = draw(st.sampled_from([1, 1, 1, 2, 3]))
    width = P // height if height > 1 else P
    n = height * width
    uv_type = draw(st.sampled_from([cloud.FLOAT32, cloud.FLOAT64]))
    bigendian = draw(st.booleans())
    order = draw(st.permutations(['track_id', 'u', 'v', 'pad']))
    sizes = {'track_id': 4, 'u': cloud.DATATYPE_TO_DTYPE[uv_type].itemsize,
             'v': cloud.DATATYPE_TO_DTYPE[uv_type].itemsize,
             'pad': draw(st.sampled_from([0, 1, 4]))}
    offsets, at = {}, 0
    for name in order:
        offsets[name] = at
        at += sizes[name]
    point_step = at + draw(st.sampled_from([0, 0, 3, 8]))
    row_step = point_step * width + draw(st.sampled_from([0, 0, 5]))
    e = '>' if bigendian else '<'
    dtype = np.dtype({'names': ['track_id', 'u', 'v'],
                      'formats': [e + 'u4', e + ('f4' if uv_type == cloud.FLOAT32 else 'f8')] * 1
                      + [e + ('f4' if uv_type == cloud.FLOAT32 else 'f8')],
                      'offsets': [offsets['track_id'], offsets['u'], offsets['v']],
                      'itemsize': point_step})
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    points = np.zeros(n, dtype)
    points['track_id'] = rng.permutation(10 * n + 1)[:n]
    points['u'] = rng.uniform(-100, 2000, n)
    points['v'] = rng.uniform(-100, 2000, n)
    rows = np.zeros((height, row_step), np.uint8)
    if n:
        rows[:, :point_step * width] = points.view(np.uint8).reshape(height, -1)
    fields = [dict(name=name, offset=offsets[name], count=1,
                   datatype=cloud.UINT32 if name == 'track_id' else uv_type)
              for name in order if name != 'pad']
    return dict(height=height, width=width, fields=fields, is_bigendian=bigendian,
                point_step=point_step, row_step=row_step, data=bytearray(rows.tobytes()),
                is_dense=True, uv_type=uv_type)


def mutate(layout, kind, draw, duck):
    """Apply one mutation ``kind`` in place; ``duck``: integers need not fit the ROS types."""
    big = st.integers(-2 ** 70, 2 ** 70) if duck else st.integers(0, 2 ** 32 - 1)
    fields, data = layout['fields'], layout['data']
    pick = draw(st.integers(0, max(len(fields) - 1, 0)))
    if kind == 'drop_field' and fields:
        del fields[pick]
    elif kind == 'rename_field' and fields:
        fields[pick]['name'] = draw(st.sampled_from(NAMES))
    elif kind == 'duplicate_field' and fields:
        fields.append(dict(fields[pick], offset=draw(st.integers(0, 40))))
    elif kind == 'datatype' and fields:
        fields[pick]['datatype'] = draw(st.one_of(st.integers(0, 12), st.integers(0, 255),
                                                  big if duck else st.integers(0, 255)))
    elif kind == 'count' and fields:
        fields[pick]['count'] = draw(st.one_of(st.integers(0, 3), big))
    elif kind == 'offset' and fields:
        fields[pick]['offset'] = draw(st.one_of(st.integers(-4 if duck else 0, 40), big))
    elif kind == 'point_step':
        layout['point_step'] = draw(st.one_of(st.integers(0, 40), big))
    elif kind == 'row_step':
        layout['row_step'] = draw(st.one_of(st.integers(0, 400), big))
    elif kind == 'claim_width':
        layout['width'] = draw(st.one_of(st.integers(0, 5_000_001), st.integers(0, 100), big))
    elif kind == 'claim_height':
        layout['height'] = draw(st.one_of(st.integers(0, 3_000_000), big))
    elif kind == 'swap_hw':
        layout['height'], layout['width'] = layout['width'], layout['height']
    elif kind == 'cut_data':
        del data[draw(st.integers(0, len(data))):]
    elif kind == 'pad_data':
        data.extend(bytes(draw(st.integers(1, 64))))
    elif kind == 'endianness':
        layout['is_bigendian'] = not layout['is_bigendian']
    elif kind in ('non_finite', 'huge', 'repeat_ids') and layout['width'] * layout['height']:
        overwrite(layout, kind, draw)
    elif kind == 'empty':
        layout.update(width=0, data=bytearray())


def overwrite(layout, kind, draw):
    """Write NaN/Inf, huge/negative coordinates or repeated ids into valid data."""
    try:
        view = np.frombuffer(layout['data'], np.uint8)
        e = '>' if layout['is_bigendian'] else '<'
        fields = {f['name']: f for f in layout['fields']}
        f = fields['track_id' if kind == 'repeat_ids' else draw(st.sampled_from(['u', 'v']))]
        size = 4 if f['datatype'] in (cloud.UINT32, cloud.FLOAT32) else 8
        fmt = e + ('u4' if kind == 'repeat_ids' else ('f4' if size == 4 else 'f8'))
        value = {'non_finite': draw(st.sampled_from([np.nan, np.inf, -np.inf])),
                 'huge': draw(st.sampled_from([3e38, -3e38, 1e30, -1e9, 1e300, -1e300])),
                 'repeat_ids': 7}[kind]
        if size == 4 and abs(value) == 1e300:
            value = np.sign(value) * 3e38
        stride = int(layout['point_step'])
        for k in sorted(set(draw(st.lists(st.integers(0, layout['width'] - 1), min_size=1,
                                          max_size=3)))):
            at = int(f['offset']) + k * stride
            view[at:at + size] = np.frombuffer(np.array(value, fmt).tobytes(), np.uint8)
    except (KeyError, ValueError, IndexError, OverflowError, TypeError):
        pass                          # the layout was already broken: nothing to overwrite


@st.composite
def hostile(draw, duck):
    layout = draw(layouts())
    for kind in draw(st.lists(st.sampled_from(MUTATIONS), min_size=0, max_size=3)):
        mutate(layout, kind, draw, duck)
    layout.pop('uv_type')
    layout['data'] = bytes(layout['data'])
    if duck:
        kind = draw(st.sampled_from(['bytes', 'numpy', 'memoryview', 'bytearray', 'list',
                                     'hostile']))
        data = layout['data']
        hostile_data = draw(st.sampled_from([None, 'x' * len(data), [300] * len(data),
                                             [-1] * len(data), np.ones(len(data)) * 1.5]))
        layout['data'] = {'bytes': data, 'numpy': np.frombuffer(data, np.uint8),
                          'memoryview': memoryview(data), 'bytearray': bytearray(data),
                          'list': list(data), 'hostile': hostile_data}[kind]
        layout['fields'] = [SimpleNamespace(**f) for f in layout['fields']]
        return SimpleNamespace(header=SimpleNamespace(
            stamp=SimpleNamespace(sec=1, nanosec=0), frame_id='cam'), **layout)
    return real_message(layout)


def real_message(layout):
    from sensor_msgs.msg import PointCloud2, PointField
    fields = [PointField(**f) for f in layout['fields']]
    return PointCloud2(**{**layout, 'fields': fields})


def given_size(data):
    """Bytes the caller handed over (a list of ints counts one byte per element)."""
    if isinstance(data, np.ndarray):
        return data.nbytes
    try:
        return len(data)
    except TypeError:
        return 0


def check_decode(msg, figures):
    """Decode ``msg`` under tracemalloc; the contract: Tracks or a specific CloudError."""
    given_bytes = given_size(msg.data)
    figures['tried'] += 1
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        try:
            tracks = cloud.decode_tracks(msg)
        except cloud.CloudError as exc:
            tracks, reason = None, str(exc)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak <= MEMORY_FACTOR * given_bytes + MEMORY_SLACK, (peak, given_bytes)
    if given_bytes >= 512:
        figures['peak_ratio_max'] = max(figures['peak_ratio_max'], round(peak / given_bytes, 1))
    if tracks is None:
        figures['rejected'] += 1
        assert reason and any(word in reason for word in REASON_WORDS), reason
        return None
    figures['decoded'] += 1
    P = tracks.ids.size
    assert tracks.ids.dtype == np.uint32 and tracks.uv.shape == (P, 2)
    assert np.isfinite(tracks.uv).all()
    assert np.unique(tracks.ids).size == P
    assert P <= int(msg.width) * int(msg.height)
    return tracks


@SETTINGS
@given(msg=hostile(duck=False))
def test_decoder_on_hostile_real_messages(msg):
    pytest.importorskip('sensor_msgs')
    check_decode(msg, FIGURES_REAL)


@SETTINGS
@given(msg=hostile(duck=True))
def test_decoder_on_hostile_duck_typed_messages(msg):
    check_decode(msg, FIGURES_DUCK)


FIGURES_REAL, FIGURES_DUCK, FIGURES_NODE = Counter(), Counter(), Counter()


@pytest.fixture(scope='module', autouse=True)
def fuzz_figures(record_testsuite_property):
    """After the module: what the fuzz tests tried, as the suite property ``reliability_fuzz``
    (kept only with ``--junitxml``, as bench/reliability.py runs it)."""
    yield
    summary = {name: dict(figures) for name, figures in (
        ('decode_real_messages', FIGURES_REAL), ('decode_duck_typed', FIGURES_DUCK),
        ('node_callback', FIGURES_NODE)) if figures}
    summary['memory_bound'] = f'peak <= {MEMORY_FACTOR} x data + {MEMORY_SLACK // 1024} KiB'
    record_testsuite_property('reliability_fuzz', json.dumps(summary, sort_keys=True))


def duck(data=b'', fields=None, **header):
    fields = fields or [dict(name='track_id', offset=0), dict(name='u', offset=4),
                        dict(name='v', offset=8)]
    fields = [SimpleNamespace(**{'count': 1, 'datatype': cloud.UINT32 if f['name'] == 'track_id'
                                 else cloud.FLOAT32, **f}) for f in fields]
    layout = dict(height=1, width=0, is_bigendian=False, point_step=12, row_step=0)
    return SimpleNamespace(data=data, fields=fields, **{**layout, **header})


FOUND = {   # what the fuzzing found (each escaped as another exception before the fix)
    'point_step 2**71': (dict(point_step=2 ** 71), 'point_step'),
    'offset 2**70': (dict(point_step=2 ** 71, width=1, row_step=2 ** 71, data=bytes(100),
                          fields=[dict(name='track_id', offset=2 ** 70), dict(name='u', offset=4),
                                  dict(name='v', offset=8)]), 'offset|point_step'),
    'data with 300': (dict(width=1, row_step=12, data=[300] * 12), 'data'),
    'data a str': (dict(width=1, row_step=12, data='x' * 12), 'data'),
    'data None': (dict(width=1, row_step=12, data=None), 'data'),
    'field name None': (dict(fields=[dict(name=None, offset=0), dict(name='u', offset=4),
                                     dict(name='v', offset=8)]), "missing field 'track_id'"),
}


@pytest.mark.parametrize('case', FOUND)
def test_fuzz_findings_are_clear_rejections(case):
    header, reason = FOUND[case]
    with pytest.raises(cloud.CloudError, match=reason):
        cloud.decode_tracks(duck(**header))


def test_real_empty_message_with_huge_point_step_decodes():
    """Found by the fuzzing: it raised ValueError (numpy itemsize) before the fix."""
    PointCloud2 = pytest.importorskip('sensor_msgs.msg').PointCloud2
    msg = real_message(dict(height=1, width=0, point_step=2 ** 32 - 1, row_step=0,
                            is_bigendian=False, is_dense=True, data=b'',
                            fields=[dict(name='track_id', offset=0, datatype=6, count=1),
                                    dict(name='u', offset=4, datatype=7, count=1),
                                    dict(name='v', offset=8, datatype=7, count=1)]))
    assert isinstance(msg, PointCloud2)
    tracks = cloud.decode_tracks(msg)         # an empty cloud: valid, nothing allocated
    assert tracks.ids.size == 0


def test_claimed_millions_of_points_allocate_nothing():
    """width x height claims 4.9 million points over 1 kB of data: refused before allocating."""
    msg = SimpleNamespace(height=7, width=700_000, point_step=12, row_step=12 * 700_000,
                          is_bigendian=False, data=bytes(1024),
                          fields=[SimpleNamespace(name=n, offset=4 * i, datatype=t, count=1)
                                  for i, (n, t) in enumerate([('track_id', cloud.UINT32),
                                                              ('u', cloud.FLOAT32),
                                                              ('v', cloud.FLOAT32)])])
    tracemalloc.start()
    try:
        with pytest.raises(cloud.CloudError, match='data has 1024 bytes; layout needs'):
            cloud.decode_tracks(msg)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 64 * 1024


# -- the node's callback path ------------------------------------------------------------------
@pytest.fixture(scope='module')
def node_in_process():
    """A ReconstructionNode in this process (discovery off), the rigid test solver injected;
    windows of 1000 frames so no solve starts (the callback path only)."""
    rclpy = pytest.importorskip('rclpy')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'OFF'
    from grass_nrsfm_ros.node import ReconstructionNode    # here: it needs rclpy

    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '-p', 'window_size:=1000',
                                      '-p', 'window_stride:=1000', '-p', 'min_tracks:=4',
                                      '--log-level', 'fatal'])
    node = ReconstructionNode(RigidALS, context=context)
    yield node
    node.close()
    node.destroy_node()
    rclpy.shutdown(context=context)


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                 HealthCheck.function_scoped_fixture])
@given(msg=hostile(duck=False), seconds=st.integers(0, 10 ** 6))
def test_node_callback_accepts_or_counts_every_hostile_message(node_in_process, msg, seconds):
    """Each message is either buffered as a frame or counted as dropped; nothing raises."""
    from rclpy.serialization import serialize_message
    node = node_in_process
    msg.header.stamp.sec = 1000 + seconds
    before = (node.counts['messages'], node.counts['dropped_messages'],
              node.pipeline.windowing.stats['frames'])
    node._on_tracks_raw(serialize_message(msg))
    after = (node.counts['messages'], node.counts['dropped_messages'],
             node.pipeline.windowing.stats['frames'])
    assert after[0] == before[0] + 1
    assert (after[1] - before[1]) + (after[2] - before[2]) == 1
    FIGURES_NODE['tried'] += 1
    FIGURES_NODE['rejected'] += after[1] - before[1]
