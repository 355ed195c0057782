"""``grass-nrsfm tracker --ros-args ...``: the tracker node (camera images -> dense tracks) where
there is no ``ros2`` CLI; everything after ``--ros-args`` goes to rclpy as it is (``-p
step:=2``, ``-r image:=/camera/image_raw``, ``--params-file config/tracker.yaml``)."""
import argparse

from grass_nrsfm_ros import tracker_node


def add_arguments(parser):
    parser.add_argument('--ros-args', dest='ros_args', nargs=argparse.REMAINDER, default=None,
                        metavar='ARG', help='ROS arguments: parameters (-p step:=2), remaps '
                        '(-r image:=/camera/image_raw), --params-file FILE')


def run(args):
    ros_args = [] if args.ros_args is None else ['--ros-args', *args.ros_args]
    return tracker_node.main(['grass-nrsfm-tracker', *ros_args])
