"""PointCloud2 <-> structured numpy arrays, standing in for sensor_msgs_py (not in the pip wheels).

A cloud is a table: one point per row, one ``PointField`` per column.  The
contour topics use fields ``x, y, tx, ty`` (float32) and ``contour`` (uint32),
see :data:`CONTOUR_DTYPE`.  Clouds written here are little endian, unorganized
(height 1) and tightly packed; clouds read may have any layout ROS allows
(padding, row padding, big endian, ``count > 1``).
"""

from __future__ import annotations

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from memo_ros.core.vision.contours import CONTOUR_DTYPE  # noqa: F401 - DESIGN.md's contour table, re-exported

# PointField datatype -> numpy type code (without byte order)
FIELD_TYPES = {
    PointField.INT8: 'i1',
    PointField.UINT8: 'u1',
    PointField.INT16: 'i2',
    PointField.UINT16: 'u2',
    PointField.INT32: 'i4',
    PointField.UINT32: 'u4',
    PointField.FLOAT32: 'f4',
    PointField.FLOAT64: 'f8',
}
NUMPY_TO_FIELD = {
    np.dtype(code).newbyteorder('<'): datatype for datatype, code in FIELD_TYPES.items()
}


def dtype_from_fields(fields, point_step: int, big_endian: bool = False) -> np.dtype:
    """Return the structured dtype of one point.

    The point is described by ``fields`` (a PointField list) and ``point_step``.
    """
    order = '>' if big_endian else '<'
    names, formats, offsets = [], [], []
    for field in fields:
        code = FIELD_TYPES.get(field.datatype)
        if code is None:
            raise ValueError(f'PointField {field.name!r} has unknown datatype {field.datatype}')
        if field.name in names:
            raise ValueError(f'PointField {field.name!r} appears twice')
        count = max(int(field.count), 1)
        base = np.dtype(order + code)
        end = int(field.offset) + base.itemsize * count
        if end > point_step:
            raise ValueError(
                f'PointField {field.name!r} ends at byte {end}, beyond point_step {point_step}'
            )
        names.append(field.name)
        formats.append(base if count == 1 else (base, (count,)))
        offsets.append(int(field.offset))
    return np.dtype(
        {'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': int(point_step)}
    )


def pointcloud_to_array(msg) -> np.ndarray:
    """All points of ``msg`` as a 1-D structured array (row-major over height x width).

    Copied out of the message.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    dtype = dtype_from_fields(msg.fields, point_step, bool(msg.is_bigendian))
    if height * width == 0:
        return np.zeros(0, dtype)
    if row_step < width * point_step:
        raise ValueError(
            f'row_step {row_step} is smaller than width * point_step = {width * point_step}'
        )
    data = np.frombuffer(memoryview(msg.data).cast('B'), np.uint8)
    if data.size < (height - 1) * row_step + width * point_step:
        raise ValueError(
            f'PointCloud2 data has {data.size} bytes, too few for {height} x {width} points'
        )
    rows = np.lib.stride_tricks.as_strided(
        data, shape=(height, width * point_step), strides=(row_step, 1)
    )
    packed = np.ascontiguousarray(rows).reshape(-1)
    return packed.view(dtype).copy()


def fields_from_dtype(dtype: np.dtype) -> list[PointField]:
    """PointFields describing a structured dtype of numeric fields, scalars or fixed 1-D arrays."""
    if dtype.names is None:
        raise ValueError('a point cloud needs a structured dtype (named fields)')
    fields = []
    for name in dtype.names:
        field_dtype, offset = dtype.fields[name][:2]
        base, shape = (
            (field_dtype.base, field_dtype.shape) if field_dtype.subdtype else (field_dtype, ())
        )
        if len(shape) > 1:
            raise ValueError(
                f'field {name!r} has shape {shape}; only scalars and 1-D sub-arrays fit a '
                'PointField'
            )
        datatype = NUMPY_TO_FIELD.get(base.newbyteorder('<'))
        if datatype is None:
            raise ValueError(
                f'field {name!r} has type {base}, which no PointField datatype represents'
            )
        count = int(shape[0]) if shape else 1
        fields.append(PointField(name=name, offset=int(offset), datatype=datatype, count=count))
    return fields


def _little_endian(dtype: np.dtype) -> np.dtype:
    """``dtype`` with every field little endian, same names, offsets and itemsize."""
    formats = []
    for name in dtype.names:
        field_dtype = dtype.fields[name][0]
        if field_dtype.subdtype:
            formats.append((field_dtype.base.newbyteorder('<'), field_dtype.shape))
        else:
            formats.append(field_dtype.newbyteorder('<'))
    offsets = [dtype.fields[name][1] for name in dtype.names]
    return np.dtype(
        {
            'names': list(dtype.names),
            'formats': formats,
            'offsets': offsets,
            'itemsize': dtype.itemsize,
        }
    )


def _is_dense(array: np.ndarray) -> bool:
    """Return True when no floating-point field holds NaN or infinity (no invalid points)."""
    for name in array.dtype.names:
        values = array[name]
        if values.dtype.base.kind == 'f' and not np.isfinite(values).all():
            return False
    return True


def array_to_pointcloud(array: np.ndarray, header: Header | None = None) -> PointCloud2:
    """Return an unorganized (height 1) little-endian PointCloud2 of a structured array's rows."""
    array = np.asarray(array).reshape(-1)
    fields = fields_from_dtype(array.dtype)
    packed = np.ascontiguousarray(array.astype(_little_endian(array.dtype), copy=False))
    msg = PointCloud2()
    if header is not None:
        msg.header = header
    msg.height = 1
    msg.width = int(packed.size)
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = int(packed.dtype.itemsize)
    msg.row_step = msg.point_step * msg.width
    msg.data = packed.view(np.uint8).tobytes()
    msg.is_dense = _is_dense(packed)
    return msg


def table_columns(array: np.ndarray) -> tuple[list[str], list[np.ndarray]]:
    """Column names and 1-D columns of a structured array.

    a sub-array field ``n`` becomes ``n[0]``, ``n[1]``...
    """
    names, columns = [], []
    for name in array.dtype.names:
        values = array[name]
        if values.ndim == 1:
            names.append(name)
            columns.append(values)
        else:
            for index in range(values.shape[1]):
                names.append(f'{name}[{index}]')
                columns.append(values[:, index])
    return names, columns


def contour_cloud_to_table(msg, max_points: int) -> np.ndarray:
    """Return a contour cloud's table (``x, y, tx, ty`` float32, ``contour`` uint32 when present).

    Its size is checked before anything is allocated, and its fields' declared types must be
    those of DESIGN.md's contour table: a cloud that declares ``x`` as uint8 is refused, not
    reinterpreted. ValueError says why a cloud is refused.
    """
    points = int(msg.height) * int(msg.width)
    if points > max_points:
        raise ValueError(f'{points} points, more than max_contour_points {max_points}')
    declared = {f.name: int(f.datatype) for f in msg.fields}
    wrong = [
        name
        for name in ('x', 'y', 'tx', 'ty')
        if name in declared and declared[name] != PointField.FLOAT32
    ]
    if 'contour' in declared and declared['contour'] != PointField.UINT32:
        wrong.append('contour')
    if wrong:
        raise ValueError(f"field(s) {', '.join(wrong)} not of the contour table's type")
    table = pointcloud_to_array(msg)
    missing = [f for f in ('x', 'y', 'tx', 'ty') if f not in (table.dtype.names or ())]
    if missing:
        raise ValueError(f'no field {", ".join(missing)}')
    return table
