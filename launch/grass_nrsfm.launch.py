"""Start the grass_nrsfm node (and RViz on request).

    ros2 launch grass_nrsfm_ros grass_nrsfm.launch.py [namespace:=cam0]
        [params_file:=my_params.yaml] [tracks:=/tracker/tracks] [points:=points]
        [record_path:=/tmp/run1] [rviz:=true]

``params_file`` defaults to the installed ``config/params.yaml``; ``record_path`` (empty: off)
overrides the file's; ``tracks`` and ``points`` remap the node's input and output topics.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'grass_nrsfm_ros'

ARGUMENTS = (
    ('namespace', '', 'namespace of the node (and of its relative topics)'),
    ('params_file', None, 'parameter file (default: the installed config/params.yaml)'),
    ('tracks', 'tracks', 'topic the tracks come in on'),
    ('points', 'points', 'topic the reconstructions go out on'),
    ('record_path', '', 'rosbag2 (MCAP) directory recording tracks and points; empty: off'),
    ('rviz', 'false', 'start RViz with config/grass_nrsfm.rviz'),
)


def generate_launch_description():
    share = FindPackageShare(PACKAGE)
    defaults = {'params_file': PathJoinSubstitution([share, 'config', 'params.yaml'])}
    arguments = [DeclareLaunchArgument(name, default_value=defaults.get(name, default),
                                       description=description)
                 for name, default, description in ARGUMENTS]
    node = Node(package=PACKAGE, executable='node', name='grass_nrsfm',
                namespace=LaunchConfiguration('namespace'), output='screen',
                parameters=[LaunchConfiguration('params_file'),
                            {'record_path': LaunchConfiguration('record_path')}],
                remappings=[('tracks', LaunchConfiguration('tracks')),
                            ('points', LaunchConfiguration('points'))])
    rviz = Node(package='rviz2', executable='rviz2', name='rviz2', output='screen',
                arguments=['-d', PathJoinSubstitution([share, 'config', 'grass_nrsfm.rviz'])],
                condition=IfCondition(LaunchConfiguration('rviz')))
    return LaunchDescription([*arguments, node, rviz])
