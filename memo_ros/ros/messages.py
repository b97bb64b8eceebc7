"""Generic rclpy message helpers.

Import a type by name, and render any message as YAML, a dict or flat CSV columns.

They walk ``get_fields_and_field_types()`` and stand in for ``rosidl_runtime_py`` (not in the pip
wheels).  The YAML looks like ``ros2 topic echo``'s, with short numeric arrays inline, long ones
(image and cloud ``data``) abbreviated, and a PointCloud2 additionally decoded into a table of its
points.
"""

from __future__ import annotations

import array
import importlib
import math
import re

import numpy as np
from sensor_msgs.msg import PointCloud2
import yaml

from memo_ros.ros.pointcloud import pointcloud_to_array, table_columns

NUMERIC_TYPES = frozenset(
    (
        'boolean',
        'octet',
        'char',
        'byte',
        'float',
        'double',
        'long double',
        'int8',
        'uint8',
        'int16',
        'uint16',
        'int32',
        'uint32',
        'int64',
        'uint64',
    )
)
DEFAULT_TRUNCATE = 64
PREVIEW_VALUES = 8


class MessageTypeError(ValueError):
    """A message type name that is malformed or not installed."""


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (rclpy or rosbags) to integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def import_message_type(type_name: str) -> type:
    """Return the rclpy message class for 'pkg/msg/Name' (also 'pkg/Name').

    With a clear error when unavailable.
    """
    parts = type_name.strip().split('/')
    if len(parts) == 2:
        parts.insert(1, 'msg')
    if len(parts) != 3 or parts[1] != 'msg' or not all(p.isidentifier() for p in parts):
        raise MessageTypeError(f'malformed message type {type_name!r} (expected pkg/msg/Name)')
    package, kind, name = parts
    try:
        module = importlib.import_module(f'{package}.{kind}')
    except ImportError:
        raise MessageTypeError(
            f'unknown message type {type_name!r}: no message package {package!r} is installed'
        ) from None
    cls = getattr(module, name, None)
    if cls is None or not hasattr(cls, 'get_fields_and_field_types'):
        raise MessageTypeError(
            f'unknown message type {type_name!r}: package {package!r} has no message {name!r}'
        )
    return cls


def is_message(value) -> bool:
    """Return True for an rclpy (or any rosidl-generated) message instance."""
    return hasattr(value, 'get_fields_and_field_types') and not isinstance(value, type)


def element_type(field_type: str) -> str:
    """Return the element type of an array field type.

    'sequence<double, 4>' or 'double[9]' -> 'double'.
    """
    match = re.fullmatch(r'sequence<([^,>]+)(?:,\s*\d+)?>', field_type)
    if match:
        return match.group(1)
    return re.sub(r'\[\d*\]$', '', field_type)


def is_array_type(field_type: str) -> bool:
    """Return True for sequence and fixed-size array field types."""
    return field_type.startswith('sequence<') or field_type.endswith(']')


def _plain_scalar(value, field_type: str):
    """Return a Python scalar (octets and numpy scalars become int/float)."""
    if isinstance(value, bytes):
        return value[0] if len(value) == 1 else list(value)
    if isinstance(value, np.generic):
        return value.item()
    return value


def _plain_array(value, field_type: str) -> list:
    """Return an array field as a list of plain values (or of dicts for nested messages)."""
    if isinstance(value, (np.ndarray, array.array)):
        return value.tolist()
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    element = element_type(field_type)
    return [message_to_dict(v) if is_message(v) else _plain_scalar(v, element) for v in value]


def message_to_dict(msg) -> dict:
    """Return a message as nested dicts and lists of plain Python values, in field order."""
    out = {}
    for name, field_type in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if is_message(value):
            out[name] = message_to_dict(value)
        elif is_array_type(field_type):
            out[name] = _plain_array(value, field_type)
        else:
            out[name] = _plain_scalar(value, field_type)
    return out


def yaml_scalar(value) -> str:
    """One YAML scalar on one line, quoted only when YAML needs it (floats as ros2 prints them)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        if math.isnan(value):
            return '.nan'
        if math.isinf(value):
            return '.inf' if value > 0 else '-.inf'
        return repr(value)
    if isinstance(value, int):
        return str(value)
    style = '"' if any(c in str(value) for c in '\n\r\t') else None
    text = yaml.safe_dump(str(value), default_style=style, width=float('inf'), allow_unicode=True)
    return text[:-5] if text.endswith('\n...\n') else text.rstrip('\n')


def _abbreviated(values: list, element: str) -> str:
    """'<uint8[921600]: 1, 2, 3, ...>' for an array too long to print."""
    preview = ', '.join(yaml_scalar(v) for v in values[:PREVIEW_VALUES])
    return yaml_scalar(f'<{element}[{len(values)}]: {preview}, ...>')


def _emit_array(
    key: str, value, field_type: str, pad: str, lines: list[str], truncate: int | None
) -> None:
    """Lines of one array field: inline numbers, block list of strings or messages."""
    element = element_type(field_type)
    items = (
        list(value)
        if not isinstance(value, (np.ndarray, array.array, bytes))
        else _plain_array(value, field_type)
    )
    if not items:
        lines.append(f'{pad}{key}: []')
    elif is_message(items[0]):
        lines.append(f'{pad}{key}:')
        for item in items:
            item_lines: list[str] = []
            _emit_fields(item, pad + '  ', item_lines, truncate)
            if not item_lines:
                lines.append(f'{pad}- {{}}')
                continue
            item_lines[0] = f'{pad}- ' + item_lines[0][len(pad) + 2 :]
            lines.extend(item_lines)
    elif element in NUMERIC_TYPES:
        items = [_plain_scalar(v, element) for v in items]
        if truncate is not None and len(items) > truncate:
            lines.append(f'{pad}{key}: {_abbreviated(items, element)}')
        else:
            lines.append(f'{pad}{key}: [{", ".join(yaml_scalar(v) for v in items)}]')
    else:
        lines.append(f'{pad}{key}:')
        shown = items if truncate is None else items[:truncate]
        lines.extend(f'{pad}- {yaml_scalar(_plain_scalar(v, element))}' for v in shown)
        if len(shown) < len(items):
            lines.append(f'{pad}- {yaml_scalar(f"... {len(items) - len(shown)} more")}')


def _emit_fields(msg, pad: str, lines: list[str], truncate: int | None) -> None:
    """YAML lines of every field of ``msg`` at indentation ``pad``."""
    for name, field_type in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if is_message(value):
            if value.get_fields_and_field_types():
                lines.append(f'{pad}{name}:')
                _emit_fields(value, pad + '  ', lines, truncate)
            else:
                lines.append(f'{pad}{name}: {{}}')
        elif is_array_type(field_type):
            _emit_array(name, value, field_type, pad, lines, truncate)
        else:
            lines.append(f'{pad}{name}: {yaml_scalar(_plain_scalar(value, field_type))}')


def format_cell(value) -> str:
    """Return a table or CSV cell.

    Integers exact, floats in the shortest form that round-trips at their precision.
    """
    if isinstance(value, np.floating):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, np.generic):
        return str(value.item())
    return str(value)


def format_table(names: list[str], columns: list, max_rows: int | None = None) -> list[str]:
    """Right-aligned text table lines: a header of ``names`` then at most ``max_rows`` rows."""
    count = len(columns[0]) if columns else 0
    shown = count if max_rows is None else min(count, max_rows)
    cells = [[format_cell(v) for v in column[:shown]] for column in columns]
    widths = [max([len(name)] + [len(c) for c in column]) for name, column in zip(names, cells)]
    lines = ['  '.join(name.rjust(w) for name, w in zip(names, widths))]
    lines += [
        '  '.join(column[row].rjust(w) for column, w in zip(cells, widths)) for row in range(shown)
    ]
    if shown < count:
        lines.append(f'... {count - shown} more points ({count} in all)')
    return lines


def pointcloud_table(msg, max_rows: int | None = None) -> list[str]:
    """Lines of a table of the points of a PointCloud2: field names, then one row per point."""
    points = pointcloud_to_array(msg)
    names, columns = table_columns(points)
    return format_table(names, columns, max_rows)


def message_to_yaml(
    msg, truncate_length: int | None = DEFAULT_TRUNCATE, max_rows: int | None = 20
) -> str:
    """Return a message as ``ros2 topic echo`` style YAML (no trailing '---').

    Numeric arrays longer than ``truncate_length`` are abbreviated (None prints
    everything).  A PointCloud2 gets a ``points`` block with a table of its
    first ``max_rows`` points (None: all, 0: no table).
    """
    lines: list[str] = []
    _emit_fields(msg, '', lines, truncate_length)
    if not lines:
        lines.append('{}')
    if isinstance(msg, PointCloud2) and max_rows != 0:
        try:
            table = pointcloud_table(msg, max_rows)
        except ValueError as exc:
            lines.append(f'points: {yaml_scalar(f"<cannot decode: {exc}>")}')
        else:
            lines.append('points: |2-')
            lines.extend('  ' + line for line in table)
    return '\n'.join(lines) + '\n'


def _flatten(prefix: str, value, field_type: str, out: dict, max_array_length: int | None) -> None:
    """Add the leaves of one field to ``out`` under dotted/indexed names."""
    if is_message(value):
        for name, sub_type in value.get_fields_and_field_types().items():
            _flatten(
                f'{prefix}.{name}' if prefix else name,
                getattr(value, name),
                sub_type,
                out,
                max_array_length,
            )
    elif is_array_type(field_type):
        element = element_type(field_type)
        numeric = element in NUMERIC_TYPES
        items = _plain_array(value, field_type) if numeric else list(value)
        if numeric and max_array_length is not None and len(items) > max_array_length:
            out[prefix] = f'<{element}[{len(items)}]>'
            return
        for index, item in enumerate(items):
            _flatten(f'{prefix}[{index}]', item, element, out, max_array_length)
    else:
        out[prefix] = _plain_scalar(value, field_type)


def flatten_message(msg, max_array_length: int | None = None) -> dict:
    """Leaf fields of a message as one flat dict for CSV rows: 'header.stamp.sec', 'position[0]'.

    Numeric arrays longer than ``max_array_length`` become one '<type[n]>' cell.
    """
    out: dict = {}
    _flatten('', msg, '', out, max_array_length)
    return out
