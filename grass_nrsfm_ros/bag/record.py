"""Recording on a writer thread: :class:`Recorder` queues messages so the caller (the node's
callbacks) never waits on the disk, and finishes MCAP chunks every ``chunk_size`` bytes and at
least every ``flush_period`` seconds, so a recording killed with ``kill -9`` loses at most the
chunk in progress plus the messages still queued (:func:`grass_nrsfm_ros.bag.recover` turns the
rest into a normal bag).
"""
from pathlib import Path
import queue
import threading
import time

from grass_nrsfm_ros.bag.messages import BagError, message_definition
from grass_nrsfm_ros.bag.write import BagWriter, DEFAULT_CHUNK_SIZE

DEFAULT_FLUSH_PERIOD = 1.0               # seconds a chunk may stay open
DEFAULT_QUEUE_SIZE = 256                 # messages waiting for the writer thread
_STOP = object()                         # queued by close(): the writer thread ends


class Recorder:
    """Record messages into a rosbag2/MCAP bag on a writer thread; the caller never waits on
    the disk.

    ``write`` only puts ``(topic, data, t_ns)`` on a bounded queue (``queue_size`` messages);
    rclpy messages are serialized on the writer thread, so do not change one after writing it.
    Chunks are finished every ``chunk_size`` bytes and at least every ``flush_period`` seconds,
    so a killed process loses at most that chunk and the queue (see :func:`recover`).

    Errors never raise from ``write``: the first one (unwritable path, full disk) is stored in
    ``error`` and passed once to ``on_error(message)``; later messages are dropped and counted
    in ``dropped`` (as are messages that find the queue full). ``close()`` drains the queue,
    writes the index and ``metadata.yaml``, and is idempotent.
    """

    def __init__(self, path, *, chunk_size=DEFAULT_CHUNK_SIZE, flush_period=DEFAULT_FLUSH_PERIOD,
                 queue_size=DEFAULT_QUEUE_SIZE, compression=None, on_error=None):
        self.path = Path(path)
        self.error = None
        self.dropped = 0
        self.written = 0
        self.topics = set()                   # declared with add_topic
        self._on_error = on_error
        self._lock = threading.Lock()
        self._closed = False
        self._flush_period = float(flush_period)
        self._queue = queue.Queue(maxsize=queue_size)
        self._writer = None
        try:
            self._writer = BagWriter(path, chunk_size=chunk_size, compression=compression)
        except (OSError, BagError) as exc:
            self._fail(exc)
        self._thread = threading.Thread(target=self._run, name='grass_nrsfm_recorder',
                                        daemon=True)
        self._thread.start()

    @property
    def bytes_written(self):
        return self._writer.bytes_written if self._writer else 0

    def add_topic(self, topic, msgtype, *, qos=''):
        """Declare ``topic`` (e.g. '/points') of ``msgtype`` (e.g. sensor_msgs/msg/PointCloud2)."""
        message_definition(msgtype)           # unknown types fail here, in the caller
        self.topics.add(topic)
        self._put(('topic', topic, msgtype, qos), count=False)

    def write(self, topic, data, t_ns):
        """Queue one message (CDR bytes or a message); returns False if it was dropped."""
        return self._put(('msg', topic, data, int(t_ns)))

    def close(self, timeout=30.0):
        """Drain the queue, finish the bag; idempotent. Returns ``error`` (None when fine)."""
        with self._lock:
            if self._closed:
                return self.error
            self._closed = True
        self._queue.put(_STOP)
        self._thread.join(timeout)
        return self.error

    def _put(self, item, count=True):
        with self._lock:
            if self._closed or self.error is not None:
                self.dropped += count
                return False
            try:
                self._queue.put_nowait(item)
                return True
            except queue.Full:
                self.dropped += count
                return False

    def _fail(self, exc):
        if isinstance(exc, OSError):
            what = f'{exc.strerror or exc} ({exc.filename or self.path})'
        else:
            what = str(exc)
        with self._lock:
            if self.error is not None:
                return
            self.error = (f'recording to {self.path} failed: {what}; further messages are '
                          f'dropped. Rescue what was written with `grass-nrsfm recover '
                          f'{self.path}`')
        if self._writer is not None:
            self._writer.abort()
        if self._on_error is not None:
            self._on_error(self.error)

    def _run(self):
        opened_at = None                      # when the unflushed chunk got its first message
        while True:
            timeout = None
            if opened_at is not None:
                timeout = max(0.0, opened_at + self._flush_period - time.monotonic())
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                item = None
            if item is _STOP:
                break
            if self.error is not None:
                self._count_drop(item)
                opened_at = None              # nothing left to flush: block on the queue
                continue
            try:
                if item is not None:
                    opened_at = self._handle(item, opened_at)
                if opened_at is not None and time.monotonic() - opened_at >= self._flush_period:
                    self._writer.flush()
                    opened_at = None
            except OSError as exc:
                self._count_drop(item)
                self._fail(exc)
        if self.error is None and self._writer is not None:
            try:
                self._writer.close()
            except OSError as exc:
                self._fail(exc)

    def _count_drop(self, item):
        if item is not None and item[0] == 'msg':
            with self._lock:
                self.dropped += 1

    def _handle(self, item, opened_at):
        if item[0] == 'topic':
            self._writer.add_topic(item[1], item[2], qos=item[3])
            return opened_at
        _, topic, data, t_ns = item
        self._writer.write(topic, data, t_ns)
        self.written += 1
        return time.monotonic() if opened_at is None else opened_at
