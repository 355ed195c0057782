"""The tracker node's bookkeeping and its ``/diagnostics`` key/values, with no ROS import.

:class:`TrackerStats` counts what happened to each image (tracked and published, or skipped:
malformed, black or saturated, blank, not tracked) and keeps the last frames' latencies;
:meth:`TrackerStats.report` turns them into the ordered ``(key, value)`` string pairs, the
level and the message of one DiagnosticStatus, once per period (rates over that period).
Counts of tracks per frame come from :class:`grass_nrsfm_ros.frontend.TrackFrame.counts`.
"""
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

LATENCY_WINDOW = 300           # frames whose latencies give the percentiles (10 s at 30 Hz)
OK, WARN = 0, 1                # diagnostic_msgs/DiagnosticStatus levels
#: reasons an image gives no tracks message, as counted and reported
SKIPS = ('bad image', 'black', 'saturated', 'blank', 'not tracked')
#: per-frame track counts of the front end that are summed
TRACK_COUNTS = ('born', 'lost', 'failed', 'left', 'reanchored')


@dataclass(frozen=True)
class Report:
    """One diagnostics status: ``level`` (OK / WARN), ``message``, ``values`` [(key, str)]."""

    level: int
    message: str
    values: list


class TrackerStats:
    """Counts and latencies of the tracker node since start (or :meth:`reset_counts`), and
    of the current period for rates."""

    def __init__(self, now):
        self.totals = Counter()
        self.alive = 0
        self.processing = deque(maxlen=LATENCY_WINDOW)    # callback start -> published, s
        self.delays = deque(maxlen=LATENCY_WINDOW)        # image stamp -> published, s
        self._period = Counter()
        self._period_start = now

    def received(self):
        self.totals['images'] += 1
        self._period['images'] += 1

    def tracked(self, counts, processing_s, delay_s):
        """A frame tracked and published: the front end's ``counts``, seconds spent on it,
        seconds from its stamp to its publication."""
        self.totals['published'] += 1
        self._period['published'] += 1
        self.alive = int(counts.get('alive', 0))
        for key in TRACK_COUNTS:
            n = int(counts.get(key, 0))
            self.totals[key] += n
            self._period[key] += n
        self.processing.append(processing_s)
        self.delays.append(delay_s)

    def skipped(self, reason):
        """An image that gave no tracks message, for ``reason`` (one of :data:`SKIPS`)."""
        self.totals[reason] += 1
        self._period[reason] += 1

    def report(self, now, extra=()):
        """The status for the period since the last report (then a new period starts);
        ``extra``: more (key, value) pairs appended (camera, topics)."""
        elapsed = max(now - self._period_start, 1e-9)
        period, self._period, self._period_start = self._period, Counter(), now
        t = self.totals
        values = [('rate hz', f"{period['published'] / elapsed:.2f}"),
                  ('images rate hz', f"{period['images'] / elapsed:.2f}"),
                  ('tracks alive', str(self.alive)),
                  ('tracks born', str(t['born'])), ('tracks lost', str(t['lost'])),
                  ('failed checks', str(t['failed'])), ('tracks left the image', str(t['left'])),
                  ('re-anchored', str(t['reanchored'])),
                  ('images received', str(t['images'])),
                  ('frames published', str(t['published'])),
                  *((f'frames skipped ({reason})', str(t[reason])) for reason in SKIPS),
                  ('size changes', str(t['size changes'])),
                  *_percentiles('latency', self.processing),
                  *_percentiles('stamp to tracks', self.delays), *extra]
        skipped = {reason: period[reason] for reason in SKIPS if period[reason]}
        if skipped:
            what = ', '.join(f'{n} {reason}' for reason, n in skipped.items())
            return Report(WARN, f'images skipped in the last {elapsed:.1f} s: {what}', values)
        return Report(OK, 'tracking' if period['published'] else 'waiting for images', values)

    def count(self, key):
        """Count an event ``key`` (e.g. 'size changes', 'resets')."""
        self.totals[key] += 1


def _percentiles(name, seconds):
    """``(name p50 ms, ...)``, ``(name p95 ms, ...)``; empty strings before any frame."""
    if not seconds:
        return [(f'{name} p50 ms', ''), (f'{name} p95 ms', '')]
    p50, p95 = np.percentile(np.fromiter(seconds, float), [50, 95])
    return [(f'{name} p50 ms', f'{1e3 * p50:.2f}'), (f'{name} p95 ms', f'{1e3 * p95:.2f}')]
