"""The memo_ros graph on a ROS 2 Jazzy install: one contour_node per camera of a studio.

ros2 launch memo_ros memo.launch.py studio:=/path/to/studio.yaml [reliable_images:=true]
[role:=cameras]

``studio`` is a path or the name of a shipped studio (studio_orthogonal, street); every node gets
it as its params file, as ``memo-ros launch`` does without ROS. ``role`` splits the graph over
hosts: cameras (the contour nodes), tracking (the selector and the tracker, or the walker), all
(default).
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def _graph(context):
    from memo_ros.core.formats.studio import load_studio, studio_path
    from memo_ros.tools.launch import (
        REPLAY_CONTOUR_PARAMS,
        REPLAY_TRACKER_PARAMS,
        RESPAWN_DELAY_S,
        ROLES,
    )

    path = str(studio_path(LaunchConfiguration('studio').perform(context)).resolve())
    reliable = LaunchConfiguration('reliable_images').perform(context).lower() in ('true', '1')
    role = LaunchConfiguration('role').perform(context)
    if role not in ROLES:
        raise ValueError(f'role must be one of {", ".join(ROLES)}, not {role!r}')
    studio = load_studio(path)
    nodes = [
        Node(
            package='memo_ros',
            executable='contour_node',
            name='contour_node',
            namespace=camera,
            parameters=[path, REPLAY_CONTOUR_PARAMS if reliable else {}],
            output='screen',
            respawn=True,  # supervised like `memo-ros launch`: a node that dies comes back
            respawn_delay=RESPAWN_DELAY_S,
        )
        for camera in studio.camera_names
        if role != 'tracking'
    ]
    if role == 'cameras':
        return nodes
    if len(studio.camera_names) > 1 or 'tracker_node' in studio.node_parameters:
        nodes.append(
            Node(
                package='memo_ros',
                executable='selector_node',
                name='selector_node',
                parameters=[path],
                output='screen',
                respawn=True,
                respawn_delay=RESPAWN_DELAY_S,
            )
        )
        nodes.append(
            Node(
                package='memo_ros',
                executable='tracker_node',
                name='tracker_node',
                parameters=[path, REPLAY_TRACKER_PARAMS] if reliable else [path],
                output='screen',
                respawn=True,
                respawn_delay=RESPAWN_DELAY_S,
            )
        )
    if 'walker_node' in studio.node_parameters:
        nodes.append(
            Node(
                package='memo_ros',
                executable='walker_node',
                name='walker_node',
                parameters=[path],
                output='screen',
                respawn=True,
                respawn_delay=RESPAWN_DELAY_S,
            )
        )
    return nodes


def generate_launch_description():
    """Describe the graph for the studio, role and replay settings given on the command line."""
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'studio',
                default_value='studio_orthogonal',
                description='studio YAML: a path, or a shipped studio name',
            ),
            DeclareLaunchArgument(
                'reliable_images',
                default_value='false',
                description='bag replay: subscribe images reliably instead of best effort, and '
                'let '
                "the tracker wait 3 s for a frame's contours",
            ),
            DeclareLaunchArgument(
                'role',
                default_value='all',
                description='what this host runs: all, cameras (contour nodes) or tracking',
            ),
            OpaqueFunction(function=_graph),
        ]
    )
