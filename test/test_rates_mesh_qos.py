"""The pure modules behind the node's diagnostics, mesh and recorded QoS: rates.py (frequency
and stamp delay in diagnostic_updater's shape), mesh.py (Delaunay surface), qos.py (offered
QoS as rosbag2 writes it)."""
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.interfaces import QosDurability, QosHistory, QosReliability
from rosbags.rosbag2.metadata import parse_qos

from grass_nrsfm_ros import mesh, rates
from grass_nrsfm_ros.bag import offered_qos as qos


def test_frequency_over_the_sliding_window_and_its_bounds():
    f = rates.FrequencyStatus(30.0, tolerance=0.1, window_size=5, now=0.0)
    level, message, values = f.status(1.0)
    assert (level, message) == (rates.WARN, 'No events recorded.')
    for t in range(2, 7):                     # 30 events per second for 5 s
        f.tick(30)
        level, message, values = f.status(float(t))
    values = dict(values)
    # the window holds the last 5 updates: t = 1..6 -> 150 events in 5 s
    assert values['Events in window'] == '150' and values['Events since startup'] == '150'
    assert float(values['Duration of window (s)']) == 5.0
    assert float(values['Actual frequency (Hz)']) == 30.0
    assert (level, message) == (rates.OK, 'Desired frequency met')
    assert float(values['Minimum acceptable frequency (Hz)']) == pytest.approx(27.0)
    assert float(values['Maximum acceptable frequency (Hz)']) == pytest.approx(33.0)
    for t in range(7, 12):                     # 20 Hz: below 27
        f.tick(20)
        level, message, _ = f.status(float(t))
    assert (level, message) == (rates.WARN, 'Frequency too low.')
    for t in range(12, 17):
        f.tick(40)
        level, message, _ = f.status(float(t))
    assert (level, message) == (rates.WARN, 'Frequency too high.')
    f.reset(17.0)
    assert dict(f.status(18.0)[2])['Events in window'] == '0'


def test_unchecked_frequency_reports_without_judging():
    f = rates.FrequencyStatus(0.0)
    f.tick(3)
    level, message, values = f.status(1.0)
    assert level == rates.OK and 'not checked' in message
    assert 'Target frequency (Hz)' not in dict(values)


def test_timestamp_delays_since_the_last_update():
    t = rates.TimeStampStatus(min_acceptable=-1.0, max_acceptable=5.0)
    assert t.status()[:2] == (rates.WARN, 'No data since last update.')
    t.tick(stamp=10.0, now=10.5)
    t.tick(stamp=11.0, now=11.2)
    level, message, values = t.status()
    values = dict(values)
    assert (level, message) == (rates.OK, 'Timestamps are reasonable.')
    assert float(values['Earliest timestamp delay']) == pytest.approx(0.2)
    assert float(values['Latest timestamp delay']) == pytest.approx(0.5)
    assert float(values['Newest timestamp delay']) == pytest.approx(0.2)
    t.tick(stamp=1.0, now=20.0)
    assert t.status()[:2] == (rates.WARN, 'Timestamps too late.')
    t.tick(stamp=30.0, now=20.0)
    level, message, values = t.status()
    assert message == 'Timestamps too far in future seen.'
    assert dict(values)['Late diagnostic update count'] == '1'
    assert dict(values)['Zero seen diagnostic update count'] == '1'


def test_delaunay_surface_drops_overlong_triangles():
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), axis=-1).reshape(-1, 2)
    far = np.array([[40.0, 2.5]])                      # one outlier, far to the right
    uv = np.vstack([g, far])
    full = mesh.triangulate(uv, max_edge_factor=np.inf)
    kept = mesh.triangulate(uv)
    assert len(full) > len(kept) == 50                 # a 5 x 5 grid of squares, 2 each
    assert not (kept == len(g)).any()                  # the outlier is in no kept triangle
    assert mesh.triangulate(uv[:2]).shape == (0, 3)
    assert mesh.triangulate(np.c_[np.arange(5.0), np.zeros(5)]).shape == (0, 3)   # collinear


def test_triangle_list_colours_by_depth_and_cache_rebuilds_on_new_ids():
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 1, (40, 2))
    xyz = np.c_[uv, uv[:, 0]]                           # depth grows with x
    cache = mesh.MeshCache()
    ids = np.arange(40)
    tri = cache.triangles_for(ids, uv)
    vertices, colours = mesh.triangle_list(xyz, tri)
    assert vertices.shape == (3 * len(tri), 3) and colours.shape == (3 * len(tri), 4)
    near, far = np.argmin(vertices[:, 2]), np.argmax(vertices[:, 2])
    assert colours[near, :3].sum() < colours[far, :3].sum()           # viridis: near dark
    # the same ids in another order: the same surface, not rebuilt
    perm = rng.permutation(40)
    tri2 = cache.triangles_for(ids[perm], uv[perm])
    assert cache.builds == 1
    np.testing.assert_array_equal(np.sort(ids[perm][tri2], axis=1), np.sort(ids[tri], axis=1))
    cache.triangles_for(ids + 100, uv)
    assert cache.builds == 2


def _profile(**kw):
    name = SimpleNamespace
    dur = SimpleNamespace
    inf = 2 ** 63 - 1
    base = dict(history=name(name='UNKNOWN'), depth=0, reliability=name(name='BEST_EFFORT'),
                durability=name(name='VOLATILE'), deadline=dur(nanoseconds=inf),
                lifespan=dur(nanoseconds=inf), liveliness=name(name='AUTOMATIC'),
                liveliness_lease_duration=dur(nanoseconds=1_500_000_000),
                avoid_ros_namespace_conventions=False)
    return SimpleNamespace(**{**base, **kw})


def test_offered_qos_in_rosbag2_form_read_back_by_rosbags():
    text = qos.offered_qos_yaml([_profile(), _profile(reliability=SimpleNamespace(
        name='RELIABLE'), history=SimpleNamespace(name='KEEP_LAST'), depth=10)])
    (a, b) = qos.offered_qos_list(text)
    assert list(a) == list(qos.KEYS)
    assert a['deadline'] == {'sec': 9223372036, 'nsec': 854775807}      # RMW_DURATION_INFINITE
    assert a['liveliness_lease_duration'] == {'sec': 1, 'nsec': 500_000_000}
    assert (a['history'], a['reliability'], a['durability'], a['liveliness']) == \
        ('unknown', 'best_effort', 'volatile', 'automatic')
    parsed = parse_qos(text)
    assert parsed[0].reliability == QosReliability.BEST_EFFORT
    assert parsed[0].durability == QosDurability.VOLATILE
    assert parsed[1].history == QosHistory.KEEP_LAST and parsed[1].depth == 10
    assert qos.offered_qos_yaml([]) == '' and qos.offered_qos_list('') == []
