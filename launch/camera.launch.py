"""A camera's images to live 3D: the tracker node, then the reconstruction node (and RViz on
request), in one namespace.

    ros2 launch grass_nrsfm_ros camera.launch.py [namespace:=cam_a]
        [image:=/camera/image_raw] [camera_info:=/camera/camera_info]
        [tracker_params_file:=my_tracker.yaml] [params_file:=my_params.yaml] [rviz:=true]
        [dds_profile:=my_fastdds.xml]

The tracker subscribes ``image`` and ``camera_info`` (remapped by the arguments; relative names
resolve inside ``namespace``) and publishes ``tracks``, which the reconstruction node reads in
the same namespace with the same ``camera_info`` (its points then in the camera frame through
the pinhole); it publishes ``points`` and ``points/refined`` there. Several cameras: one
launch per camera, each in its own namespace, over one ROS domain. ``tracker_params_file`` and
``params_file`` default to the installed ``config/tracker.yaml`` and ``config/params.yaml``.
``dds_profile`` (``FASTRTPS_DEFAULT_PROFILES_FILE`` of what this launch starts) defaults to that
variable where it is set, else to the installed ``config/fastdds_large_images.xml``.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import (EnvironmentVariable, LaunchConfiguration,
                                  PathJoinSubstitution)
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'grass_nrsfm_ros'

ARGUMENTS = (
    ('namespace', '', 'namespace of both nodes and of their relative topics'),
    ('image', 'image', 'topic of the camera images (sensor_msgs/Image)'),
    ('camera_info', 'camera_info', 'topic of the camera intrinsics (sensor_msgs/CameraInfo)'),
    ('tracker_params_file', None, 'parameter file of the tracker (default: the installed '
     'config/tracker.yaml)'),
    ('params_file', None, 'parameter file of the reconstruction node (default: the installed '
     'config/params.yaml)'),
    ('rviz', 'false', 'start RViz with config/grass_nrsfm.rviz'),
    ('dds_profile', None, 'Fast DDS XML profile of the nodes started here (default: '
     '$FASTRTPS_DEFAULT_PROFILES_FILE, else the installed config/fastdds_large_images.xml)'),
)
PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'


def generate_launch_description():
    share = FindPackageShare(PACKAGE)
    defaults = {'tracker_params_file': PathJoinSubstitution([share, 'config', 'tracker.yaml']),
                'params_file': PathJoinSubstitution([share, 'config', 'params.yaml']),
                'dds_profile': EnvironmentVariable(PROFILE_VARIABLE, default_value=[
                    PathJoinSubstitution([share, 'config', 'fastdds_large_images.xml'])])}
    arguments = [DeclareLaunchArgument(name, default_value=defaults.get(name, default),
                                       description=description)
                 for name, default, description in ARGUMENTS]
    namespace = LaunchConfiguration('namespace')
    tracker = Node(package=PACKAGE, executable='tracker', name='grass_nrsfm_tracker',
                   namespace=namespace, output='screen',
                   parameters=[LaunchConfiguration('tracker_params_file')],
                   remappings=[('image', LaunchConfiguration('image')),
                               ('camera_info', LaunchConfiguration('camera_info'))])
    node = Node(package=PACKAGE, executable='node', name='grass_nrsfm', namespace=namespace,
                output='screen', parameters=[LaunchConfiguration('params_file')],
                remappings=[('camera_info', LaunchConfiguration('camera_info'))])
    rviz = Node(package='rviz2', executable='rviz2', name='rviz2', output='screen',
                arguments=['-d', PathJoinSubstitution([share, 'config', 'grass_nrsfm.rviz'])],
                condition=IfCondition(LaunchConfiguration('rviz')))
    profile = SetEnvironmentVariable(PROFILE_VARIABLE, LaunchConfiguration('dds_profile'))
    return LaunchDescription([*arguments, profile, tracker, node, rviz])
