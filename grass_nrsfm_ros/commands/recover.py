"""``grass-nrsfm recover BAG [-o OUT]``: rebuild a killed recording into a readable bag.

A recording that was killed (``kill -9``, power loss, full disk) has no ``metadata.yaml``, no
MCAP summary or index, and a truncated last chunk. This reads every complete record in order
and writes a normal bag (default ``BAG_recovered``); the incomplete tail is reported.
"""
from grass_nrsfm_ros import bag


def add_arguments(parser):
    parser.add_argument('bag', help='bag directory or .mcap file')
    parser.add_argument('-o', '--output', help='bag directory to create (BAG_recovered)')


def run(args):
    report = bag.recover(args.bag, args.output)
    for topic, n in sorted(report.counts.items()):
        print(f'{topic}: {n} messages')
    for line in report.stopped:
        print(f'incomplete tail dropped: {line}')
    print(f'recovered {report.messages} messages from {len(report.files)} file(s) into '
          f'{report.out_path}')
    return 0
