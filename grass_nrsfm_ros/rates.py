"""Rate and stamp-delay bookkeeping for ``/diagnostics``, in diagnostic_updater's shape.

No ROS import: the node counts events and stamps here and formats what :meth:`status` returns
into a ``DiagnosticStatus``. The conventions (keys, messages, the sliding window of snapshots
taken once per update) are those of diagnostic_updater's ``FrequencyStatus`` and
``TimeStampStatus`` (C++), which is not available as a Python wheel, except that a missing
or off-rate stream is a WARN (the node may simply be idle), never an ERROR.

A status is ``(level, message, [(key, value text), ...])`` with ``level`` one of OK, WARN.
Times are seconds: ``now`` from a monotonic clock for rates, ROS time for stamp delays.
"""
from collections import deque
import math
import threading
import time

OK, WARN = 0, 1
#: snapshots in the sliding window (diagnostic_updater's default window_size)
WINDOW_SIZE = 5


class FrequencyStatus:
    """Events per second over the last ``window_size`` updates, against ``[min_hz, max_hz]``
    widened by ``tolerance`` (a fraction). ``expected_hz`` 0 checks nothing (reports only)."""

    def __init__(self, expected_hz, tolerance=0.1, window_size=WINDOW_SIZE, now=0.0):
        self.min_hz = self.max_hz = float(expected_hz)
        self.tolerance = float(tolerance)
        self._count = 0
        self._snapshots = deque([(0, float(now))], maxlen=int(window_size) + 1)
        self._lock = threading.Lock()

    def tick(self, n=1):
        """Count ``n`` events (any thread)."""
        with self._lock:
            self._count += n

    def reset(self, now):
        """Forget the window (not the total), e.g. after a reset of the node."""
        with self._lock:
            self._snapshots = deque([(self._count, float(now))], maxlen=self._snapshots.maxlen)

    @property
    def checked(self):
        return self.max_hz > 0

    def status(self, now):
        """Take this update's snapshot and return ``(level, message, values)``."""
        with self._lock:
            count = self._count
            self._snapshots.append((count, float(now)))
            first_count, first_time = self._snapshots[0]
        events = count - first_count
        duration = float(now) - first_time
        freq = events / duration if duration > 0 else 0.0
        low, high = self.min_hz * (1 - self.tolerance), self.max_hz * (1 + self.tolerance)
        if not self.checked:
            level, message = OK, 'Frequency not checked (expected_rate 0)'
        elif events == 0:
            level, message = WARN, 'No events recorded.'
        elif freq < low:
            level, message = WARN, 'Frequency too low.'
        elif freq > high:
            level, message = WARN, 'Frequency too high.'
        else:
            level, message = OK, 'Desired frequency met'
        values = [('Events in window', f'{events:d}'), ('Events since startup', f'{count:d}'),
                  ('Duration of window (s)', f'{duration:f}'),
                  ('Actual frequency (Hz)', f'{freq:f}')]
        if self.checked:
            values += [('Target frequency (Hz)', f'{self.min_hz:f}'),
                       ('Minimum acceptable frequency (Hz)', f'{low:f}'),
                       ('Maximum acceptable frequency (Hz)', f'{high:f}')]
        return level, message, values


class TimeStampStatus:
    """Delay of message stamps behind the clock (``now - stamp``, seconds) seen since the last
    update: the earliest and latest delay, and that of the newest stamp; acceptable within
    ``[min_acceptable, max_acceptable]``."""

    def __init__(self, min_acceptable=-1.0, max_acceptable=5.0):
        self.min_acceptable, self.max_acceptable = float(min_acceptable), float(max_acceptable)
        self._lock = threading.Lock()
        self._delays = []
        self._newest = None              # (stamp, delay) of the newest stamp ever seen
        self._late = self._early = self._zero_seen = 0

    def tick(self, stamp, now):
        """One message stamped ``stamp`` observed at clock time ``now`` (any thread)."""
        delay = float(now) - float(stamp)
        with self._lock:
            self._delays.append(delay)
            if self._newest is None or stamp >= self._newest[0]:
                self._newest = (float(stamp), delay)

    def status(self):
        """``(level, message, values)`` over the stamps since the last call."""
        with self._lock:
            delays, self._delays = self._delays, []
            newest = self._newest
        values = []
        if not delays:
            self._zero_seen += 1
            level, message = WARN, 'No data since last update.'
            earliest = latest = math.nan
        else:
            earliest, latest = min(delays), max(delays)
            level, message = OK, 'Timestamps are reasonable.'
            if earliest < self.min_acceptable:
                self._early += 1
                level, message = WARN, 'Timestamps too far in future seen.'
            if latest > self.max_acceptable:
                self._late += 1
                level, message = WARN, 'Timestamps too late.'
        values += [('Earliest timestamp delay', f'{earliest:f}'),
                   ('Latest timestamp delay', f'{latest:f}'),
                   ('Newest timestamp delay', f'{newest[1]:f}' if newest else 'nan'),
                   ('Earliest acceptable timestamp delay', f'{self.min_acceptable:f}'),
                   ('Latest acceptable timestamp delay', f'{self.max_acceptable:f}'),
                   ('Late diagnostic update count', f'{self._late:d}'),
                   ('Early diagnostic update count', f'{self._early:d}'),
                   ('Zero seen diagnostic update count', f'{self._zero_seen:d}')]
        return level, message, values


class NodeRates:
    """The reconstruction node's rates: input and output frequency and output stamp delay.
    :meth:`snapshot` (once a second) takes every status at once; :meth:`statuses` gives the
    last snapshot as ``(name, level, message, [(key, value), ...])``."""

    def __init__(self, expected_hz, tolerance, now=None):
        now = time.monotonic() if now is None else now
        self.input = FrequencyStatus(expected_hz, tolerance, now=now)
        self.output = FrequencyStatus(expected_hz, tolerance, now=now)
        self.delay = TimeStampStatus()
        self._last = []

    def output_published(self, stamp, now):
        """One output cloud of ``stamp`` published at ROS time ``now`` (seconds)."""
        self.output.tick()
        self.delay.tick(stamp, now)

    def reset(self, now=None):
        now = time.monotonic() if now is None else now
        self.input.reset(now)
        self.output.reset(now)

    def snapshot(self, input_topic, output_topic, now=None):
        now = time.monotonic() if now is None else now
        self._last = [(f'{input_topic} input frequency', *self.input.status(now)),
                      (f'{output_topic} output frequency', *self.output.status(now)),
                      (f'{output_topic} output timestamp delay', *self.delay.status())]

    def statuses(self):
        return list(self._last)
