"""``python -m bench [--full] [--only SUITE ...] [--smoke]``: run the benchmark suites.

Default: the quick subset (under 10 minutes, about 400 CPU seconds, on 2 cores), without the
research suites of QUICK_SKIPS (run them with ``--only``). ``--full``: every case of every suite
(hours: the paper-sized dense faces and 70k-point scale cases). ``--smoke``: each suite's
smallest case (seconds), written to ``bench/results/smoke/``. Each suite's wall and CPU seconds
(this process and the children it waited for) go into its JSON and the summary line. The
reliability figures have their own script, ``python -m bench.reliability``; the node's load,
``python -m bench.load`` (ROS).
"""
import argparse
import importlib
import resource
import sys
import time

from . import common

SUITES = ('accuracy', 'noise', 'parameters', 'scale', 'streaming', 'live', 'rotations',
          'grassmann')
#: suites the quick run leaves out (research variants measured no better: Organic Priors'
#: rotations, the weighted norm, the Grassmann probes); ``--only SUITE`` still runs them
QUICK_SKIPS = ('rotations', 'grassmann')


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


def chosen_suites(mode_name, only=None):
    """The suites a run executes: ``only`` where given, else every suite but QUICK_SKIPS in
    quick mode and every suite otherwise."""
    if only:
        return list(only)
    return [s for s in SUITES if mode_name != 'quick' or s not in QUICK_SKIPS]


def cpu_seconds():
    """CPU seconds (user + system) of this process and of the children it has waited for."""
    own, children = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                         resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    mode = common.Mode('full' if args.full else 'smoke' if args.smoke else 'quick', args.out)
    total_wall, total_cpu = 0.0, 0.0
    for suite in chosen_suites(mode.name, args.only):
        start, cpu = time.perf_counter(), cpu_seconds()
        payload = importlib.import_module(f'bench.{suite}').run(mode)
        payload['seconds'] = time.perf_counter() - start
        payload['cpu_seconds'] = cpu_seconds() - cpu
        total_wall, total_cpu = total_wall + payload['seconds'], total_cpu + payload['cpu_seconds']
        path = common.write_result(mode, suite, payload)
        print(f'{suite}: {len(payload["rows"])} rows, {len(payload.get("skipped", []))} '
              f'skipped, {payload["seconds"]:.1f} s wall, {payload["cpu_seconds"]:.1f} CPU s '
              f'-> {path}', flush=True)
    print(f'{mode.name} run: {total_wall:.1f} s wall, {total_cpu:.1f} CPU s', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
