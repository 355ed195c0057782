"""Mapping backends: where a :class:`~grass_nrsfm_ros.mapper.Mapper` solves the closed windows.

One small interface: ``feed(frame)`` (every accepted Frame, in order), ``submit(window)``,
``updates()`` (the Updates ready, in order; never blocks), ``reset()``, ``close()``;
``notify`` (given at construction) is called whenever updates are ready.

* :class:`InlineBackend` solves each window in ``submit``, before the next frame: the output
  equals for the same input whoever runs it (the offline tools, the node with ``mapping:
  inline``).
* :class:`ProcessBackend` (the node's default, ``mapping: process``, docs/decisions/0410)
  holds the mapper in a child process ('spawn': never a fork of a process with rclpy's
  threads) under SCHED_IDLE (else a lower priority): the live tracking goes first. Frames
  cross as they are accepted (a multiprocessing Queue:
  its feeder thread pickles, the tracking thread only appends), windows as stamps; the child
  keeps the frames a later window can still name and solves only the newest window waiting (a
  newer one replaces it: 'dropped', 'skipped'). Updates come back through a pipe read by a
  receiver thread. A child that dies is reported (``on_exit``) and restarted with an empty
  store: windows naming frames it lacks fail with a clear message until new frames fill it.

Pure Python: no ROS import.
"""
from collections import deque
import ctypes
from dataclasses import dataclass
import multiprocessing
from multiprocessing.connection import wait
import os
import threading
import time
import traceback

from threadpoolctl import threadpool_limits

from grass_nrsfm_ros.mapper import make_mapper, Update, WindowError
from grass_nrsfm_ros.windowing import Window

START_METHOD = 'spawn'
#: the child's niceness above the parent's: on a busy machine the scheduler serves the
#: tracking (and the publishing) first, the mapping with what is left (where SCHED_IDLE is not
#: there; with it the child runs only on CPU time nothing else wants, docs/decisions/0434)
MAPPING_NICE = 5
HANDOVERS_KEPT = 300        # hand-over times kept for /diagnostics
STOP_GRACE_S = 1.0           # close() waits this long for the child, then terminates it
#: allocations from this size on are mmapped (returned to the system when freed): a fixed
#: glibc threshold, see :func:`fix_mmap_threshold`
MMAP_THRESHOLD = 1 << 20
M_MMAP_THRESHOLD = -3        # glibc's mallopt parameter


class SolveCancelled(Exception):
    """Raised in a solve's progress callback once its backend is stopping."""


def fix_mmap_threshold(size=MMAP_THRESHOLD):
    """Fix glibc's mmap threshold at ``size`` bytes; True if set (False: not glibc). glibc's
    dynamic threshold rises to the size of the largest mmapped block freed (up to 32 MB), so
    after a solve frees its arrays the next ones of up to that size stay in the threads'
    heaps, which fragment and keep the memory."""
    try:
        return bool(ctypes.CDLL(None).mallopt(M_MMAP_THRESHOLD, int(size)))
    except (OSError, AttributeError):
        return False


def solve_update(mapper, window, progress=None):
    """``mapper.solve(window)`` as an Update: 'failed' for a WindowError or any other
    exception (with its traceback: a solver failure must not stop the mapping), 'dropped'
    ('stopping') when ``progress`` cancelled it."""
    try:
        return mapper.solve(window, progress=progress)
    except SolveCancelled:
        return Update.of(window, 'dropped', message='stopping')
    except WindowError as exc:
        return Update.of(window, 'failed', message=f'window not solved: {exc}')
    except Exception as exc:
        return Update.of(window, 'failed', message=(
            f'window {window.index} failed: {type(exc).__name__}: {exc}\n'
            f'{traceback.format_exc()}'))


class InlineBackend:
    """Solves each window as it is submitted (see the module docstring)."""

    def __init__(self, mapper, notify=None):
        self.mapper, self._notify = mapper, notify or (lambda: None)
        self._updates = deque()
        self._stopping = threading.Event()
        self.outstanding, self.restarts = 0, 0

    def feed(self, frame):
        """Nothing to do: the windows carry their frames."""

    def submit(self, window):
        self._updates.append(solve_update(self.mapper, window, self._cancel_if_stopping))
        self._notify()

    def updates(self):
        out = []
        while self._updates:
            out.append(self._updates.popleft())
        return out

    def reset(self):
        self.mapper.reset()

    def close(self):
        self._stopping.set()

    def _cancel_if_stopping(self, iteration, report):
        if self._stopping.is_set():
            raise SolveCancelled(f'stopping at iteration {iteration}')


@dataclass(frozen=True)
class WindowSpec:
    """A closed Window without its frames, which the child has: stamps of its frames
    (``stamps: (F,)``) and of its context (oldest first), its common ``ids: (P,)``."""

    sequence: int
    index: int
    stamps: tuple
    ids: object
    closed_at: float
    context_stamps: tuple
    fresh: tuple = ()
    final: bool = False
    preview: bool = False

    @classmethod
    def of(cls, window):
        return cls(window.sequence, window.index, tuple(int(s) for s in window.stamps),
                   window.ids, window.closed_at, tuple(f.stamp_ns for f in window.context),
                   window.fresh, window.final, window.preview)


class FrameStore:
    """The child's frames by ``(sequence, stamp)``; :meth:`prune` keeps what later windows can
    name: a window's context is drawn from the previous window's context and frames and the
    frames after them (KeyFrames only thin, the history only takes frames leaving the buffer)."""

    def __init__(self):
        self.frames = {}

    def add(self, frame):
        self.frames[(frame.sequence, frame.stamp_ns)] = frame

    def window(self, spec):
        """The Window ``spec`` names (context frames missing from the store left out); raises
        WindowError if one of its own frames is missing."""
        missing = [s for s in spec.stamps if (spec.sequence, s) not in self.frames]
        if missing:
            raise WindowError(f'window {spec.index}: {len(missing)} of its {len(spec.stamps)} '
                              'frames are missing in the mapping process (restarted since)')
        frames = tuple(self.frames[(spec.sequence, s)] for s in spec.stamps)
        context = tuple(self.frames[(spec.sequence, s)] for s in spec.context_stamps
                        if (spec.sequence, s) in self.frames)
        return Window(spec.sequence, spec.index, frames, spec.ids, spec.closed_at, context,
                      spec.fresh, spec.final, spec.preview)

    def prune(self, spec):
        """Drop the frames no window after ``spec`` can name."""
        first = spec.stamps[0]
        keep = {(spec.sequence, s) for s in spec.context_stamps}
        self.frames = {k: f for k, f in self.frames.items()
                       if k[0] > spec.sequence or (k[0] == spec.sequence and k[1] >= first)
                       or k in keep}

    def clear(self):
        self.frames = {}


class _Child:
    """The child's state: the store and the window waiting, filled by a reader thread from
    ``inbox``; the main thread solves (see :func:`child_main`)."""

    def __init__(self, mapper, inbox, outbox, cancel):
        self.mapper, self.inbox, self.outbox, self.cancel = mapper, inbox, outbox, cancel
        self.store = FrameStore()
        self.pending, self.stopping, self.reset_due = None, False, False
        self.cond = threading.Condition()
        self.send_lock = threading.Lock()

    def send(self, message):
        with self.send_lock:
            self.outbox.send(message)

    def read(self):
        """Reader thread: apply every message from the parent, in order."""
        while True:
            message = self.inbox.get()
            kind = message[0]
            with self.cond:
                if kind == 'frame':
                    self.store.add(message[1])
                elif kind == 'window':
                    self._take_window(message[1])
                elif kind == 'reset':
                    self._reset()
                elif kind == 'stop':
                    self.stopping = True
                self.cond.notify_all()
            if kind == 'stop':
                return

    def _take_window(self, spec):
        if spec.preview and self.pending is not None:       # a waiting window goes first
            self.send(Update.of(spec, 'dropped', message='skipped'))
            return
        self.store.prune(spec)
        if self.pending is not None:
            self.send(Update.of(self.pending, 'dropped', message='skipped'))
        self.pending = spec

    def _reset(self):
        self.store.clear()
        self.reset_due = True
        if self.pending is not None:
            self.send(Update.of(self.pending, 'dropped', message='reset'))
            self.pending = None

    def run(self):
        """Main thread: solve the newest window waiting until told to stop."""
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.pending is not None or self.stopping)
                if self.stopping:
                    return
                spec, self.pending = self.pending, None
                if self.reset_due:
                    self.mapper.reset()
                    self.reset_due = False
                try:
                    window = self.store.window(spec)
                except WindowError as exc:
                    self.send(Update.of(spec, 'failed', message=f'window not solved: {exc}'))
                    continue
            self.send(solve_update(self.mapper, window, self._cancel_if_stopping))

    def _cancel_if_stopping(self, iteration, report):
        if self.cancel.is_set():
            raise SolveCancelled(f'stopping at iteration {iteration}')


def child_main(config, solver_factory, inbox, outbox, cancel, blas_threads,
               nice=MAPPING_NICE):
    """The child process: a mapper fed by ``inbox``; Updates to ``outbox`` (a Connection).
    Exits on 'stop' or when the parent dies."""
    if nice:
        os.nice(nice)
    idle_scheduling()
    fix_mmap_threshold()
    threadpool_limits(limits=blas_threads)
    child = _Child(make_mapper(config, solver_factory), inbox, outbox, cancel)
    threading.Thread(target=_exit_with_parent, daemon=True).start()
    threading.Thread(target=child.read, daemon=True).start()
    child.send(('ready', os.getpid()))
    child.run()


def idle_scheduling():
    """Put this process under SCHED_IDLE (Linux): it runs only when no other task wants the
    CPU. True if done."""
    if not hasattr(os, 'SCHED_IDLE'):
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except OSError:
        return False
    return True


def _exit_with_parent():
    """Leave at once if the parent goes (killed: no orphan solving on)."""
    wait([multiprocessing.parent_process().sentinel])
    os._exit(3)


class ProcessBackend:
    """The mapper in a child process; see the module docstring.

    ``config`` and ``solver_factory`` are those of :func:`grass_nrsfm_ros.mapper.make_mapper`
    and must pickle (module-level classes). ``notify()`` is called on the receiver thread when
    an Update arrived; ``on_exit(exitcode, restarted)`` when the child died unasked (it is
    restarted, at most ``max_restarts`` times); ``nice``: the child's niceness increment.
    """

    def __init__(self, config, solver_factory=None, *, notify=None, on_exit=None,
                 blas_threads=1, max_restarts=5, nice=MAPPING_NICE):
        self._args = (dict(config), solver_factory)
        self._blas_threads, self._nice = int(blas_threads), int(nice)
        self._notify = notify or (lambda: None)
        self._on_exit = on_exit or (lambda code, restarted: None)
        self._ctx = multiprocessing.get_context(START_METHOD)
        self._lock = threading.Lock()
        self._queue_lock = threading.Lock()
        self._updates = deque()
        self._closing = False
        self.outstanding = 0            # windows submitted, not yet answered
        self.restarts, self.max_restarts = 0, int(max_restarts)
        self.pid = None                 # the child's, once it has started
        self.handovers = deque(maxlen=HANDOVERS_KEPT)     # seconds per frame handed over
        self._start()

    def _start(self):
        self._inbox = self._ctx.Queue()
        receive, send = self._ctx.Pipe(duplex=False)
        self._cancel = self._ctx.Event()
        self.process = self._ctx.Process(
            target=child_main, name='grass_nrsfm_mapping', daemon=True,
            args=(*self._args, self._inbox, send, self._cancel, self._blas_threads,
                  self._nice))
        self.process.start()
        send.close()
        self._receive = receive
        self._receiver = threading.Thread(target=self._receive_loop, args=(receive,),
                                          name='grass_nrsfm_mapping_receiver', daemon=True)
        self._receiver.start()

    @property
    def alive(self):
        return self.process is not None and self.process.is_alive()

    # -- tracking thread ------------------------------------------------------------------------
    def feed(self, frame):
        """Hand one accepted Frame over; returns at once (its time kept in ``handovers``)."""
        started = time.perf_counter()
        self._put(('frame', frame))
        self.handovers.append(time.perf_counter() - started)

    def submit(self, window):
        """Hand a closed Window over (as a WindowSpec: the child has its frames)."""
        with self._lock:
            self.outstanding += 1
        self._put(('window', WindowSpec.of(window)))

    def updates(self):
        with self._lock:
            out, self._updates = list(self._updates), deque()
        return out

    def reset(self):
        """Drop the child's frames and the window waiting (a solve running finishes)."""
        self._put(('reset',))

    def _put(self, message):
        with self._queue_lock:           # not while a restart swaps the queue
            if not self._closing and self.process is not None:
                self._inbox.put(message)

    # -- receiver thread ------------------------------------------------------------------------
    def _receive_loop(self, conn):
        process = self.process
        while True:
            ready = wait([conn, process.sentinel])
            if conn in ready:
                try:
                    message = conn.recv()
                except (EOFError, OSError):
                    message = None
                if message is not None:
                    self._handle(message)
                    continue
            process.join()
            if not self._closing:
                self._restart(process.exitcode)
            return

    def _handle(self, message):
        if isinstance(message, tuple) and message[0] == 'ready':
            self.pid = message[1]
            return
        with self._lock:
            self.outstanding = max(0, self.outstanding - 1)
            self._updates.append(message)
        try:
            self._notify()
        except Exception:                   # the receiver must go on (the node tearing down)
            if not self._closing:
                traceback.print_exc()

    def _restart(self, exitcode):
        """The child died unasked: report it, start a fresh one (its windows in flight are
        lost: counted as answered)."""
        with self._lock:
            self.outstanding = 0
            self.restarts += 1
            give_up = self.restarts > self.max_restarts
        with self._queue_lock:
            self._inbox.cancel_join_thread()
            self._inbox.close()
            if give_up:
                self.process = None
            else:
                self.pid = None
                self._start()
        self._on_exit(exitcode, not give_up)

    # -- shutdown -------------------------------------------------------------------------------
    def close(self, grace=STOP_GRACE_S):
        """Stop the child: cancel its solve, ask it to stop, terminate it after ``grace``
        seconds (kill after one more); no process is left behind."""
        self._closing = True
        process = self.process
        if process is None:
            return
        self._cancel.set()
        self._inbox.put(('stop',))
        process.join(grace)
        if process.is_alive():
            process.terminate()
            process.join(1.0)
        if process.is_alive():
            process.kill()
            process.join()
        self._inbox.cancel_join_thread()
        self._inbox.close()
        self._receiver.join(1.0)
        self._receive.close()
