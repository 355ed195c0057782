"""sensor_msgs/PointCloud2 <-> numpy structured arrays, with no Python loop over points.

Input contract (``tracks``): one cloud per camera frame, one point per tracked feature, fields
``track_id`` (UINT32), ``u`` and ``v`` (FLOAT32, pixels). Other fields are ignored; any field
order, ``point_step``, ``row_step``, organised layout (``height > 1``) and endianness that the
message declares is honoured. Output (``points``): fields ``x, y, z`` (FLOAT32) and
``track_id`` (UINT32), ``point_step`` 16.

Decoding works on anything shaped like a PointCloud2 (rclpy messages, rosbags dataclasses,
``types.SimpleNamespace``): only ``encode_*`` imports ``sensor_msgs``.
"""
from dataclasses import dataclass

import numpy as np

# PointField datatypes (sensor_msgs/msg/PointField.msg)
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
DATATYPE_TO_DTYPE = {
    INT8: np.dtype('i1'), UINT8: np.dtype('u1'), INT16: np.dtype('i2'), UINT16: np.dtype('u2'),
    INT32: np.dtype('i4'), UINT32: np.dtype('u4'), FLOAT32: np.dtype('f4'),
    FLOAT64: np.dtype('f8'),
}
DTYPE_TO_DATATYPE = {dt: code for code, dt in DATATYPE_TO_DTYPE.items()}

TRACK_FIELDS = {'track_id': (UINT32,), 'u': (FLOAT32, FLOAT64), 'v': (FLOAT32, FLOAT64)}
POINTS_DTYPE = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('track_id', '<u4')])
MAX_POINTS = 5_000_000          # a frame larger than this is refused, not allocated


class CloudError(ValueError):
    """A cloud that cannot be decoded; the message says why."""


@dataclass(frozen=True)
class Tracks:
    """One decoded frame: ``ids: (P,) uint32`` (unique) and ``uv: (P, 2) float64`` pixels."""

    ids: np.ndarray
    uv: np.ndarray


def _field_dtype(field, byteorder):
    code = _uint(field, 'datatype', 8)
    if code not in DATATYPE_TO_DTYPE:
        raise CloudError(f'field {field.name!r} has unknown datatype {code}')
    count = _uint(field, 'count') if hasattr(field, 'count') else 1
    if count != 1:
        raise CloudError(f'field {field.name!r} has count {field.count}; only 1 is supported')
    return DATATYPE_TO_DTYPE[code].newbyteorder(byteorder)


def _uint(msg_part, name, bits=32):
    """``msg_part.name`` as an int in ``0 .. 2**bits - 1`` (the PointCloud2 field types)."""
    value = getattr(msg_part, name)
    try:
        value = int(value)
    except (TypeError, ValueError, OverflowError):
        raise CloudError(f'{name} {value!r} is not an integer') from None
    if not 0 <= value < 2 ** bits:
        raise CloudError(f'{name} {value} outside the uint{bits} range')
    return value


def _bytes_of(data):
    """``data`` (bytes-like, uint8 array or sequence of ints 0..255) as a uint8 array."""
    try:
        if isinstance(data, (bytes, bytearray, memoryview)):
            return np.frombuffer(data, dtype=np.uint8)
        raw = np.asarray(data)
        if raw.dtype != np.uint8:
            raw = np.asarray(data, dtype=np.int64)
            if raw.size and (raw.min() < 0 or raw.max() > 255):
                raise ValueError('values outside 0..255')
            raw = raw.astype(np.uint8)
        return raw.reshape(-1)
    except (TypeError, ValueError, OverflowError) as exc:
        raise CloudError(f'data is not a byte buffer ({type(data).__name__}: {exc})') from None


def structured_view(msg, wanted):
    """Zero-copy structured view of the ``wanted`` fields of a cloud: ``(height*width,)``.

    ``wanted`` maps field name -> allowed datatype codes. Raises CloudError on a missing field,
    a wrong datatype, fields outside ``point_step``, integers outside their ROS types, or
    ``data`` shorter than the declared layout (checked before anything of the declared size is
    allocated).
    """
    byteorder = '>' if bool(msg.is_bigendian) else '<'
    fields = {f.name: f for f in msg.fields}
    names, formats, offsets = [], [], []
    point_step = _uint(msg, 'point_step')
    for name, allowed in wanted.items():
        if name not in fields:
            raise CloudError(f'missing field {name!r} (has {sorted(map(str, fields))})')
        f = fields[name]
        if _uint(f, 'datatype', 8) not in allowed:
            raise CloudError(f'field {name!r} has datatype {int(f.datatype)}; '
                             f'expected one of {list(allowed)}')
        dt = _field_dtype(f, byteorder)
        if _uint(f, 'offset') + dt.itemsize > point_step:
            raise CloudError(f'field {name!r} at offset {f.offset} does not fit point_step '
                             f'{point_step}')
        names.append(name)
        formats.append(dt)
        offsets.append(int(f.offset))
    height, width = _uint(msg, 'height'), _uint(msg, 'width')
    if height * width > MAX_POINTS:
        raise CloudError(f'cloud size {height}x{width} outside 0..{MAX_POINTS} points')
    n = height * width
    if n == 0:
        return np.zeros(0, dtype=np.dtype({'names': names, 'formats': formats,
                                           'offsets': offsets}))
    row_step = _uint(msg, 'row_step')
    if row_step < point_step * width:
        raise CloudError(f'row_step {row_step} < point_step {point_step} x width {width}')
    raw = _bytes_of(msg.data)
    need = row_step * (height - 1) + point_step * width
    if raw.size < need:
        raise CloudError(f'data has {raw.size} bytes; layout needs {need}')
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                      'itemsize': point_step})
    if row_step == point_step * width:
        return np.frombuffer(raw, dtype=dtype, count=n)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(height, point_step * width),
                                           strides=(row_step, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(n)


def strictly_increasing(ids):
    """True if ``ids: (P,)`` is sorted with no repeats (then neither a sort nor a duplicate
    check is needed)."""
    return bool(ids.size < 2 or (ids[1:] > ids[:-1]).all())


def decode_tracks(msg):
    """Decode a ``tracks`` cloud into :class:`Tracks`.

    Points with non-finite u or v are dropped; a track id that occurs more than once makes the
    frame ambiguous and raises CloudError (which id, how many). An empty cloud decodes to empty
    arrays.
    """
    view = structured_view(msg, TRACK_FIELDS)
    ids = view['track_id'].astype(np.uint32)
    with np.errstate(invalid='ignore'):              # signalling NaNs in float32 data
        uv = np.stack([view['u'].astype(np.float64), view['v'].astype(np.float64)], axis=1)
    finite = np.isfinite(uv).all(axis=1)
    if not finite.all():
        ids, uv = ids[finite], uv[finite]
    if strictly_increasing(ids):                     # the usual tracker output: no sort needed
        return Tracks(ids=ids, uv=uv)
    unique, counts = np.unique(ids, return_counts=True)
    if unique.size != ids.size:
        dup = unique[counts > 1]
        raise CloudError(f'{dup.size} duplicate track ids (first: {int(dup[0])})')
    return Tracks(ids=ids, uv=uv)


def tracks_array(ids, uv):
    """Structured ``(P,)`` array with fields track_id, u, v for ``ids: (P,)``, ``uv: (P, 2)``."""
    arr = np.empty(len(ids), dtype=[('track_id', '<u4'), ('u', '<f4'), ('v', '<f4')])
    arr['track_id'] = ids
    arr['u'] = uv[:, 0]
    arr['v'] = uv[:, 1]
    return arr


def points_array(xyz, ids):
    """Structured ``(P,)`` array (x, y, z, track_id) for ``xyz: (P, 3)`` and ``ids: (P,)``."""
    arr = np.empty(len(ids), dtype=POINTS_DTYPE)
    arr['x'], arr['y'], arr['z'] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    arr['track_id'] = ids
    return arr


def cloud_layout(arr, point_field):
    """PointCloud2 keyword arguments (all but ``header``) for structured ``arr: (P,)``:
    unordered (height 1), little-endian, one PointField per dtype field made by
    ``point_field(name=, offset=, datatype=, count=)`` (rclpy's or rosbags' class), ``data``
    the array's bytes, ``is_dense`` True when every float is finite."""
    arr = np.ascontiguousarray(arr)
    fields = [point_field(name=name, offset=arr.dtype.fields[name][1],
                          datatype=DTYPE_TO_DATATYPE[arr.dtype.fields[name][0].newbyteorder('=')],
                          count=1)
              for name in arr.dtype.names]
    finite = all(np.isfinite(arr[n]).all() for n in arr.dtype.names
                 if arr.dtype.fields[n][0].kind == 'f')
    return dict(height=1, width=arr.size, fields=fields, is_bigendian=False,
                point_step=arr.dtype.itemsize, row_step=arr.dtype.itemsize * arr.size,
                data=arr.view(np.uint8).reshape(-1), is_dense=bool(finite))


def to_pointcloud2(arr, header):
    """sensor_msgs/PointCloud2 (see :func:`cloud_layout`) holding structured ``arr: (P,)``."""
    # imported here: sensor_msgs comes with ROS 2 (the optional extra); decoding needs none
    from sensor_msgs.msg import PointCloud2, PointField

    layout = cloud_layout(arr, PointField)
    layout['data'] = layout['data'].tobytes()
    return PointCloud2(header=header, **layout)


def encode_tracks(ids, uv, header):
    """``tracks`` cloud (the input contract) for ``ids: (P,)``, ``uv: (P, 2)`` pixels."""
    return to_pointcloud2(tracks_array(ids, uv), header)


def encode_points(xyz, ids, header):
    """``points`` cloud (x, y, z, track_id) for ``xyz: (P, 3)`` and ``ids: (P,)``."""
    return to_pointcloud2(points_array(xyz, ids), header)


def decode_points(msg):
    """Decode a ``points`` cloud into ``(ids: (P,) uint32, xyz: (P, 3) float64)``."""
    f = (FLOAT32, FLOAT64)
    view = structured_view(msg, {'x': f, 'y': f, 'z': f, 'track_id': (UINT32,)})
    xyz = np.stack([view[c].astype(np.float64) for c in 'xyz'], axis=1)
    return view['track_id'].astype(np.uint32), xyz
