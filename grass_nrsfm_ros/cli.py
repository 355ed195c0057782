"""``grass-nrsfm``: the command line. Each subcommand lives in ``grass_nrsfm_ros.commands.<name>``
and provides ``add_arguments(parser)`` and ``run(args) -> int`` (the exit code); modules are
imported only when their subcommand runs, so ``grass-nrsfm evaluate`` needs no ROS; a command
that needs ROS 2 (``node``, ``replay``) says so in one line where rclpy is missing.

Errors are reported once, here: a known error (bad input, missing file) becomes one line on
stderr and exit code 2.
"""
import argparse
import importlib
import sys

COMMANDS = {
    'demo': 'Generate the embedded synthetic sequence, reconstruct it, record a bag and a PNG.',
    'reconstruct': 'Reconstruct W from an .npz (or a tracks bag) into S, R and a report.',
    'evaluate': 'Print e3D of a reconstruction against ground truth.',
    'node': 'Start the ROS 2 node (same as `ros2 run grass_nrsfm_ros node`).',
    'tracker': 'Start the tracker node, images to tracks (`ros2 run grass_nrsfm_ros tracker`).',
    'track': 'Dense 2D tracks of a folder of images, a video or a bag, into an .npz or a bag.',
    'replay': 'Publish the tracks topic of a bag with its original timing.',
    'convert': 'Turn an .npz with W (and optional S) into a tracks bag.',
    'recover': 'Rebuild a killed recording (no metadata, no index) into a readable bag.',
    'render': 'Draw reconstructed frames (and ground truth) as a PNG.',
}
#: the ROS 2 packages that the optional 'ros' extra (or a sourced ROS install) provides
ROS_PACKAGES = ('rclpy', 'rosgraph_msgs', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs',
                'std_srvs', 'visualization_msgs', 'builtin_interfaces', 'rcl_interfaces')


class UserError(Exception):
    """An error the user can fix (bad file, bad argument); printed without a traceback."""


def command_module(name):
    """The module of subcommand ``name``; exit code 2 with one line where it needs ROS 2 and
    ROS 2 is not installed."""
    try:
        return importlib.import_module(f'grass_nrsfm_ros.commands.{name}')
    except ModuleNotFoundError as exc:
        if (exc.name or '').split('.')[0] not in ROS_PACKAGES:
            raise
        print(f'grass-nrsfm {name}: error: needs ROS 2 Jazzy ({exc.name} is missing): '
              "pip install 'grass_nrsfm_ros[ros]' or source /opt/ros/jazzy", file=sys.stderr)
        raise SystemExit(2) from None


def build_parser(argv):
    """The top-level parser; only the chosen subcommand's module is imported."""
    parser = argparse.ArgumentParser(prog='grass-nrsfm', description=__doc__.split('\n')[0])
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    chosen = next((a for a in argv if a in COMMANDS), None)
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            command_module(name).add_arguments(p)
    return parser


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['node']:
        # ROS arguments (--ros-args ...) go to rclpy untouched. Imported here, not at the top:
        # the node needs rclpy (the optional 'ros' extra) and the other commands do not.
        from grass_nrsfm_ros import node
        return node.main(['grass-nrsfm-node'] + argv[1:])
    args = build_parser(argv).parse_args(argv)
    module = command_module(args.command)
    try:
        return int(module.run(args) or 0)
    except (UserError, FileNotFoundError, ValueError) as exc:
        print(f'grass-nrsfm {args.command}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    # Run as `python -m grass_nrsfm_ros.cli`: use the importable module's main, so that its
    # UserError (not __main__.UserError) is the one caught.
    from grass_nrsfm_ros.cli import main as _main
    sys.exit(_main())
