"""Declaring node parameters with descriptions and ranges, and validating updates.

A node lists its parameters once as :class:`Param` entries; the same table
declares them (with ROS descriptors that carry the range, so
``ros2 param describe`` shows it), validates runtime changes, and renders the
README's parameter table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node


@dataclass(frozen=True)
class Param:
    """One node parameter: default, description, and a numeric range or a set of choices."""

    name: str
    default: object
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False

    def check(self, value) -> str | None:
        """Why ``value`` is refused, or None when it is acceptable."""
        if isinstance(self.default, bool):
            return None if isinstance(value, bool) else f'{self.name} must be true or false'
        if isinstance(self.default, (int, float)) and not isinstance(self.default, bool):
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                return f'{self.name} must be a number'
            if (
                self.low is not None
                and value < self.low
                or self.high is not None
                and value > self.high
            ):
                return f'{self.name}={value} is outside [{self.low}, {self.high}]'
        if self.choices and value not in self.choices:
            return f'{self.name}={value!r} is not one of {", ".join(self.choices)}'
        return None

    def descriptor(self) -> ParameterDescriptor:
        """Return the ROS ParameterDescriptor: description, range and read-only flag."""
        text = self.description + (f' (one of: {", ".join(self.choices)})' if self.choices else '')
        desc = ParameterDescriptor(name=self.name, description=text, read_only=self.read_only)
        if isinstance(self.default, float):
            desc.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high), step=0.0)
            ]
        elif isinstance(self.default, int) and not isinstance(self.default, bool):
            desc.integer_range = [
                IntegerRange(from_value=int(self.low), to_value=int(self.high), step=1)
            ]
        return desc


def declare(
    node: Node,
    params: tuple[Param, ...],
    on_change: Callable[[], None] | None = None,
    check: Callable[[dict], object] | None = None,
) -> dict:
    """Declare ``params`` on ``node`` and return their values, a dict kept current at runtime.

    A value out of its range, or a combination ``check(values)`` refuses by raising
    ValueError, is refused at start (ValueError) and at runtime (set_parameters
    fails with the reason); an accepted change updates the dict, then ``on_change()``
    rebuilds whatever the node derives from it.
    """
    values = {}
    for p in params:
        value = node.declare_parameter(p.name, p.default, p.descriptor()).value
        problem = p.check(value)
        if problem:
            raise ValueError(problem)
        values[p.name] = value
    if check is not None:
        check(values)
    combined = None if check is None else (lambda changes: check(values | changes))
    node.add_on_set_parameters_callback(validator(params, combined))

    def apply(changes) -> None:
        for change in changes:
            if change.name in values:
                values[change.name] = change.value
        if on_change is not None:
            on_change()

    node.add_post_set_parameters_callback(apply)
    return values


def validator(params: tuple[Param, ...], check: Callable[[dict], object] | None = None):
    """Return an on-set-parameters callback refusing out-of-range values.

    And combinations ``check`` refuses, with a reason.
    """
    table = {p.name: p for p in params}

    def callback(changes) -> SetParametersResult:
        for change in changes:
            p = table.get(change.name)
            if p is None:
                continue
            problem = p.check(change.value)
            if problem:
                return SetParametersResult(successful=False, reason=problem)
        if check is not None:
            try:
                check({c.name: c.value for c in changes if c.name in table})
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    return callback


def markdown_table(params: tuple[Param, ...]) -> str:
    """Return the README's parameter table."""
    rows = ['| parameter | type | default | range | description |', '|---|---|---|---|---|']
    for p in params:
        kind = type(p.default).__name__
        span = (
            ', '.join(p.choices)
            if p.choices
            else (f'[{p.low}, {p.high}]' if p.low is not None else '')
        )
        rows.append(f'| `{p.name}` | {kind} | `{p.default}` | {span} | {p.description} |')
    return '\n'.join(rows)
