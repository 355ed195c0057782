"""``python -m bench.reliability [--only fuzz|faults] [-k EXPR]``: the reliability figures.

Runs the fuzz tests (test/test_fuzz_cloud.py) and the fault tests (test/test_faults.py, ROS) in
a pytest subprocess with ``--junitxml``; the tests record what they tried and measured as
test-suite properties (``reliability_fuzz``, ``reliability_faults``: JSON) and write no file.
This script merges them into bench/results/reliability.json (key ``fuzz``, beside bench/load.py's
``load`` keys) and bench/results/reliability_faults.json. Figures are written only when every
selected test passed. A few minutes on 2 cores (the fault tests start node processes).
"""
import argparse
import json
from pathlib import Path
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ElementTree

from bench.common import merge_result, REPO, RESULTS

#: suite -> (test file, property the tests record, results file, key in it (None: the top))
SUITES = {
    'fuzz': ('test/test_fuzz_cloud.py', 'reliability_fuzz', RESULTS / 'reliability.json', 'fuzz'),
    'faults': ('test/test_faults.py', 'reliability_faults', RESULTS / 'reliability_faults.json',
               None),
}


def run_tests(files, junit, keyword=None):
    """pytest on ``files`` (from the repository root) writing ``junit``; its exit code."""
    command = [sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
               f'--junitxml={junit}', *files]
    if keyword:
        command += ['-k', keyword]
    return subprocess.run(command, cwd=REPO).returncode


def suite_properties(junit, names):
    """``{name: value}`` of the test-suite properties ``names`` in a JUnit XML file (values
    parsed as JSON; test cases carry properties of their own, such as hypothesis's)."""
    root = ElementTree.parse(junit).getroot()
    return {p.get('name'): json.loads(p.get('value'))
            for suite in root.iter('testsuite') for p in suite.findall('properties/property')
            if p.get('name') in names}


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.reliability',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--only', choices=SUITES, action='append', help='one suite (repeatable)')
    parser.add_argument('-k', dest='keyword', help="pytest -k expression (a subset's figures)")
    args = parser.parse_args(argv)
    chosen = args.only or list(SUITES)
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / 'junit.xml'
        code = run_tests([SUITES[s][0] for s in chosen], junit, args.keyword)
        properties = suite_properties(junit, [SUITES[s][1] for s in chosen]) \
            if junit.exists() else {}
    if code != 0:
        print(f'reliability: pytest exit code {code}; no figures written', file=sys.stderr)
        return code
    for suite in chosen:
        _, name, path, key = SUITES[suite]
        if name in properties:
            merge_result(path, key, properties[name])
            print(f'{suite}: -> {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
