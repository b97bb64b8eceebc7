"""The studio (cameras, body, initial pose) as a node receives it.

Nested parameters from the params file.

``--params-file studio.yaml`` hands every node the shared ``/**`` block as dotted parameter
overrides (``studio.cam_front.K``, ``body.torso.length``, ...). :func:`studio_from_node` folds them
back into the file's mapping and parses it with the same code as the tools, so a node and
``memo-ros`` never disagree.  The overrides are read, not declared, so they do not clutter ``ros2
param list``.
"""

from __future__ import annotations

from rclpy.node import Node

from memo_ros.core.formats.studio import WILDCARD, Studio

SHARED_ROOTS = ('studio', 'body', 'initial_pose')


def studio_from_node(node: Node) -> Studio:
    """Return the studio described by the node's ``studio.*``.

    ``body.*`` and ``initial_pose.*`` parameters.
    """
    nested: dict = {}
    # rclpy keeps the params-file values it has not declared yet in _parameter_overrides
    for name, param in {**node._parameter_overrides, **node._parameters}.items():
        root = name.split('.', 1)[0]
        if root not in SHARED_ROOTS:
            continue
        keys = name.split('.')
        target = nested
        for key in keys[:-1]:
            target = target.setdefault(key, {})
        value = param.value
        target[keys[-1]] = (
            list(value) if isinstance(value, (list, tuple)) or hasattr(value, 'tolist') else value
        )
    if 'studio' not in nested:
        raise ValueError(
            'no studio parameters: start the node with --ros-args --params-file STUDIO.yaml'
        )
    return Studio.from_yaml_dict({WILDCARD: {'ros__parameters': nested}}, 'parameters')
