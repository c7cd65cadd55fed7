"""sensor_msgs/PointCloud2 <-> numpy arrays and :class:`pointforce_ros.types.Surface`.

Reads what realsense-ros publishes (x, y, z FLOAT32 plus a packed ``rgb`` FLOAT32 whose bytes are
0x00RRGGBB, organised or not, NaN where depth is invalid), ``rgba`` UINT32 and optional
``normal_x/y/z``. Any point_step, field order, padding and endianness described by the message's
own fields is honoured; a layout that lacks x, y, z or has a wrong size raises
:class:`~pointforce_ros.errors.InvalidInput` instead of crashing the node.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Surface

_FIELD_DTYPES = {
    PointField.INT8: 'i1', PointField.UINT8: 'u1', PointField.INT16: 'i2',
    PointField.UINT16: 'u2', PointField.INT32: 'i4', PointField.UINT32: 'u4',
    PointField.FLOAT32: 'f4', PointField.FLOAT64: 'f8',
}


@dataclass(frozen=True)
class CloudArrays:
    """A point cloud as arrays.

    Attributes:
        points: (N, 3) float64 metres, or (H, W, 3) when ``organised``; NaN rows kept unless
            the reader was asked to drop them.
        rgb: same leading shape x 3, float64 in [0, 1], or ``None`` without a colour field.
        normals: same leading shape x 3, or ``None`` without normal fields.
        frame_id: the header's frame.
        stamp: header time, seconds.
        organised: whether ``points`` keeps the (H, W) image layout.

    """

    points: np.ndarray
    rgb: Optional[np.ndarray]
    normals: Optional[np.ndarray]
    frame_id: str
    stamp: float
    organised: bool


def _structured_dtype(msg: PointCloud2) -> np.dtype:
    names, formats, offsets = [], [], []
    order = '>' if msg.is_bigendian else '<'
    for f in msg.fields:
        if f.datatype not in _FIELD_DTYPES:
            raise InvalidInput(f'PointCloud2: field {f.name!r} has unknown datatype {f.datatype}')
        if f.count != 1:
            continue  # multi-count fields are not read; they still occupy point_step
        names.append(f.name)
        formats.append(order + _FIELD_DTYPES[f.datatype])
        offsets.append(f.offset)
    try:
        return np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                         'itemsize': msg.point_step})
    except ValueError as exc:
        raise InvalidInput(f'PointCloud2: fields do not fit point_step {msg.point_step}: {exc}')


def unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """Unpack realsense-style ``rgb`` (float32 or uint32 holding 0x00RRGGBB) to (..., 3) [0, 1]."""
    packed = np.asarray(packed)
    if packed.dtype.kind == 'f':
        # reinterpret the float's bits in its own byte order, then convert to native uint32
        packed = packed.view(packed.dtype.str.replace('f', 'u'))
    as_int = packed.astype(np.uint32)
    r = (as_int >> 16) & 0xFF
    g = (as_int >> 8) & 0xFF
    b = as_int & 0xFF
    return np.stack([r, g, b], axis=-1).astype(np.float64) / 255.0


def pack_rgb(rgb: np.ndarray) -> np.ndarray:
    """Pack (..., 3) colours in [0, 1] into float32 ``rgb`` as realsense-ros does."""
    c = np.clip(np.round(np.asarray(rgb, dtype=np.float64) * 255.0), 0, 255).astype(np.uint32)
    return ((c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]).astype(np.uint32).view(np.float32)


def cloud_from_msg(msg: PointCloud2, *, drop_nan: bool = False) -> CloudArrays:
    """Convert a PointCloud2 message to :class:`CloudArrays`.

    Args:
        msg: the message.
        drop_nan: remove points with a non-finite coordinate (and flatten an organised cloud).

    Raises:
        InvalidInput: missing x/y/z fields (or one of a count other than 1), a data length
            that does not match ``row_step * height`` / ``point_step * width``, or an unknown
            field type.

    """
    names = [f.name for f in msg.fields]
    for axis in ('x', 'y', 'z'):
        if axis not in names:
            raise InvalidInput(f'PointCloud2: no {axis!r} field (fields: {names})')
    counts = {f.name: f.count for f in msg.fields}
    for axis in ('x', 'y', 'z'):
        if counts[axis] != 1:
            raise InvalidInput(f'PointCloud2: field {axis!r} has count {counts[axis]}; a '
                               'coordinate needs count 1')
    # colour and normal fields of another count are not read (as any multi-count field)
    names = [name for name in names if counts[name] == 1]
    if msg.point_step <= 0 and msg.width * msg.height > 0:
        raise InvalidInput('PointCloud2: point_step must be positive')
    n_expected = msg.width * msg.height
    if msg.row_step < msg.point_step * msg.width:
        raise InvalidInput(f'PointCloud2: row_step {msg.row_step} < point_step x width '
                           f'({msg.point_step} x {msg.width})')
    data = bytes(msg.data)
    if len(data) != msg.row_step * msg.height:
        raise InvalidInput(f'PointCloud2: data has {len(data)} bytes, expected row_step x height '
                           f'= {msg.row_step * msg.height}')
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    if n_expected == 0:
        empty = np.zeros((0, 3))
        return CloudArrays(empty, None, None, msg.header.frame_id, stamp, False)
    dtype = _structured_dtype(msg)
    rows = []
    for r in range(msg.height):
        start = r * msg.row_step
        rows.append(np.frombuffer(data, dtype=dtype, count=msg.width, offset=start))
    arr = np.concatenate(rows) if len(rows) > 1 else rows[0]
    points = np.stack([arr['x'], arr['y'], arr['z']], axis=-1).astype(np.float64)
    rgb = None
    if 'rgb' in names:
        rgb = unpack_rgb(arr['rgb'])
    elif 'rgba' in names:
        rgb = unpack_rgb(arr['rgba'])
    normals = None
    if all(f'normal_{a}' in names for a in 'xyz'):
        normals = np.stack([arr['normal_x'], arr['normal_y'], arr['normal_z']],
                           axis=-1).astype(np.float64)
    organised = msg.height > 1
    if drop_nan:
        keep = np.all(np.isfinite(points), axis=1)
        points = points[keep]
        rgb = None if rgb is None else rgb[keep]
        normals = None if normals is None else normals[keep]
        organised = False
    elif organised:
        shape = (msg.height, msg.width, 3)
        points = points.reshape(shape)
        rgb = None if rgb is None else rgb.reshape(shape)
        normals = None if normals is None else normals.reshape(shape)
    return CloudArrays(points, rgb, normals, msg.header.frame_id, stamp, organised)


def msg_from_cloud(points: np.ndarray, rgb: Optional[np.ndarray] = None,
                   normals: Optional[np.ndarray] = None, *, frame_id: str = 'base',
                   stamp: float = 0.0) -> PointCloud2:
    """Build a PointCloud2 (x, y, z, [rgb], [normal_x, normal_y, normal_z], all FLOAT32).

    ``points`` may be (N, 3) (unorganised, height 1) or (H, W, 3) (organised); ``rgb`` and
    ``normals`` must have the same leading shape.

    Raises:
        InvalidInput: shapes that disagree.

    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim not in (2, 3) or points.shape[-1] != 3:
        raise InvalidInput(f'points: expected (N, 3) or (H, W, 3), got {points.shape}')
    height, width = (1, points.shape[0]) if points.ndim == 2 else points.shape[:2]
    fields = [('x', 0), ('y', 4), ('z', 8)]
    columns = [points[..., 0], points[..., 1], points[..., 2]]
    offset = 12
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != points.shape:
            raise InvalidInput(f'rgb: shape {rgb.shape} does not match points {points.shape}')
        fields.append(('rgb', offset))
        columns.append(pack_rgb(rgb))
        offset += 4
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != points.shape:
            raise InvalidInput(f'normals: shape {normals.shape} does not match points '
                               f'{points.shape}')
        for i, axis in enumerate('xyz'):
            fields.append((f'normal_{axis}', offset))
            columns.append(normals[..., i])
            offset += 4
    dtype = np.dtype({'names': [f[0] for f in fields], 'formats': ['<f4'] * len(fields),
                      'offsets': [f[1] for f in fields], 'itemsize': offset})
    arr = np.zeros(height * width, dtype=dtype)
    for (name, _), col in zip(fields, columns):
        arr[name] = np.asarray(col).reshape(-1).astype(np.float32)
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec = int(np.floor(stamp))
    msg.header.stamp.nanosec = int(round((stamp - np.floor(stamp)) * 1e9)) % 1_000_000_000
    msg.height = int(height)
    msg.width = int(width)
    msg.fields = [PointField(name=name, offset=off, datatype=PointField.FLOAT32, count=1)
                  for name, off in fields]
    msg.is_bigendian = False
    msg.point_step = offset
    msg.row_step = offset * int(width)
    msg.is_dense = bool(np.all(np.isfinite(points)))
    msg.data = arr.tobytes()
    return msg


def surface_to_msg(surface: Surface, *, stamp: float = 0.0) -> PointCloud2:
    """Build the ``~/surface`` cloud: x, y, z, rgb, normal_x, normal_y, normal_z."""
    return msg_from_cloud(surface.points, surface.colors, surface.normals,
                          frame_id=surface.frame, stamp=stamp)


def surface_from_msg(msg: PointCloud2) -> Surface:
    """Read a ``~/surface`` cloud back into a :class:`Surface`.

    Raises:
        InvalidInput: no normal fields, NaN points or non-unit normals.

    """
    cloud = cloud_from_msg(msg)
    if cloud.normals is None:
        raise InvalidInput('PointCloud2: a surface needs normal_x/normal_y/normal_z fields')
    points = cloud.points.reshape(-1, 3)
    normals = cloud.normals.reshape(-1, 3)
    # float32 transport: renormalise so unit checks hold
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.full_like(normals, np.nan), where=lengths > 0)
    rgb = None if cloud.rgb is None else cloud.rgb.reshape(-1, 3)
    return Surface(points=points, normals=normals, colors=rgb, frame=cloud.frame_id)
