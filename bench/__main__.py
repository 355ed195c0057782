"""``python -m bench [--full] [--only SUITE ...] [--smoke]``: run the benchmark suites.

Default: the quick subset (a few minutes on 2 cores). ``--full``: everything (hours: the
paper-sized dense faces and 70k-point scale cases). ``--smoke``: each suite's smallest case
(seconds), written to ``bench/results/smoke/``. The reliability figures have their own
script, ``python -m bench.reliability``; the node's load, ``python -m bench.load`` (ROS).
"""
import argparse
import importlib
import sys
import time

from . import common

SUITES = ('accuracy', 'noise', 'parameters', 'scale', 'streaming', 'live', 'rotations',
          'grassmann')


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='python -m bench', description=__doc__.splitlines()[0])
    size = parser.add_mutually_exclusive_group()
    size.add_argument('--full', action='store_true', help='run every case (slow)')
    size.add_argument('--smoke', action='store_true', help="each suite's smallest case only")
    parser.add_argument('--only', action='append', choices=SUITES, metavar='SUITE',
                        help=f'run only this suite (repeatable): {", ".join(SUITES)}')
    parser.add_argument('--out', help='results folder (default: bench/results, or '
                        'bench/results/smoke with --smoke)')
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    mode = common.Mode('full' if args.full else 'smoke' if args.smoke else 'quick', args.out)
    for suite in args.only or SUITES:
        start = time.perf_counter()
        payload = importlib.import_module(f'bench.{suite}').run(mode)
        payload['seconds'] = time.perf_counter() - start
        path = common.write_result(mode, suite, payload)
        print(f'{suite}: {len(payload["rows"])} rows, {len(payload.get("skipped", []))} '
              f'skipped, {payload["seconds"]:.1f} s -> {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
