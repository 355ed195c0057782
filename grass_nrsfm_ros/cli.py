"""``grass-nrsfm``: the command line. Each subcommand lives in ``grass_nrsfm_ros.commands.<name>``
and provides ``add_arguments(parser)`` and ``run(args) -> int`` (the exit code); modules are
imported only when their subcommand runs, so ``grass-nrsfm evaluate`` needs no ROS.

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
    'replay': 'Publish the tracks topic of a bag with its original timing.',
    'convert': 'Turn an .npz with W (and optional S) into a tracks bag.',
    'recover': 'Rebuild a killed recording (no metadata, no index) into a readable bag.',
    'render': 'Draw reconstructed frames (and ground truth) as a PNG.',
}


class UserError(Exception):
    """An error the user can fix (bad file, bad argument); printed without a traceback."""


def build_parser(argv):
    """The top-level parser; only the chosen subcommand's module is imported."""
    parser = argparse.ArgumentParser(prog='grass-nrsfm', description=__doc__.split('\n')[0])
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    chosen = next((a for a in argv if a in COMMANDS), None)
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            importlib.import_module(f'grass_nrsfm_ros.commands.{name}').add_arguments(p)
    return parser


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['node']:
        # ROS arguments (--ros-args ...) go to rclpy untouched.
        from grass_nrsfm_ros import node
        return node.main(['grass-nrsfm-node'] + argv[1:])
    args = build_parser(argv).parse_args(argv)
    module = importlib.import_module(f'grass_nrsfm_ros.commands.{args.command}')
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
