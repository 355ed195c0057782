"""MappingProcess: the mapping (window solves, models) in a child process beside the tracking.

The node's ``mapping: process``. The parent keeps the tracking (:class:`~grass_nrsfm_ros.live.
LivePipeline`, its own SlidingWindow deciding when windows close) and all publishing; the
child (a 'spawn' process: never a fork of a process with rclpy's threads) holds a second
SlidingWindow for the solve side (previous solution, warm start, alignment) and its own copy of
the frames, so a window crosses as stamps, not as 60 MB of pixels. Pure Python: no ROS import.

Parent -> child (one multiprocessing Queue: its feeder thread pickles and writes, the tracking
thread only appends), in order:

* ``('frame', sequence, Frame)``: every accepted frame (``ids: (P,)``, ``uv: (P, 2)``);
* ``('depth', sequence, stamp, z)``: the depth ``z: (P,)`` published for that frame before a
  model exists (bootstrap, or after a restart): the next model is flipped to agree with it;
* ``('window', WindowSpec)``: a closed window, its frames and context named by stamp;
* ``('reset',)``, ``('stop',)``.

Child -> parent (a pipe, read by the parent's receiver thread), one message per window:
``('solved', spec, results, model, figures)``, ``('failed', spec, kind, text)`` (kind
'window': a WindowError; 'error': any other exception, with its traceback) or
``('dropped', spec, why)`` (why 'skipped': a newer window replaced it while a solve ran;
'reset'). The child keeps the frames a later window can still name (its frames and context,
and every newer frame) and solves only the newest window waiting, as the worker thread does.

A child that dies is reported (``on_exit``) and restarted with an empty store: windows naming
frames it lacks fail with a clear message until new frames fill it.
"""
import ctypes
from dataclasses import dataclass
import multiprocessing
from multiprocessing.connection import wait
import os
import threading
import time
import traceback

from threadpoolctl import threadpool_limits

from grass_nrsfm_ros.live import solve_figures, solve_window
from grass_nrsfm_ros.pipeline import make_windows, Window, window_matrix, WindowError

START_METHOD = 'spawn'
#: the child's niceness above the parent's: on a busy machine the scheduler serves the
#: tracking (and the publishing) first, the mapping with what is left
MAPPING_NICE = 5
STOP_GRACE_S = 1.0           # close() waits this long for the child, then terminates it
#: allocations from this size on are mmapped (returned to the system when freed): a fixed
#: glibc threshold, see :func:`fix_mmap_threshold`
MMAP_THRESHOLD = 1 << 20
M_MMAP_THRESHOLD = -3        # glibc's mallopt parameter


def fix_mmap_threshold(size=MMAP_THRESHOLD):
    """Fix glibc's mmap threshold at ``size`` bytes; True if set (False: not glibc). glibc's
    dynamic threshold rises to the size of the largest mmapped block freed (up to 32 MB), so
    after a solve frees its arrays the next ones of up to that size stay in the threads'
    heaps, which fragment and keep the memory."""
    try:
        return bool(ctypes.CDLL(None).mallopt(M_MMAP_THRESHOLD, int(size)))
    except (OSError, AttributeError):
        return False


class SolveCancelled(Exception):
    """Raised in the child's progress callback once the parent is stopping."""


@dataclass(frozen=True)
class WindowSpec:
    """A closed Window without its pixels: ``stamps: (F,)`` of its frames, ``ids: (P,)`` its
    common tracks, ``context_stamps`` the stamps of its context Frames (oldest first)."""

    sequence: int
    index: int
    stamps: object
    frame_ids: tuple
    ids: object
    closed_at: float
    context_stamps: tuple
    final: bool = False

    @classmethod
    def of(cls, window):
        return cls(window.sequence, window.index, window.stamps, window.frame_ids, window.ids,
                   window.closed_at, tuple(f.stamp_ns for f in window.context), window.final)

    @property
    def n_frames(self):
        return len(self.stamps)


class FrameStore:
    """The child's frames by ``(sequence, stamp)``; :meth:`prune` keeps what later windows can
    name: a window's context is drawn from the previous window's context and frames and the
    frames after them (KeyFrames only thin, the history only takes frames leaving the buffer)."""

    def __init__(self):
        self.frames = {}

    def add(self, sequence, frame):
        self.frames[(sequence, frame.stamp_ns)] = frame

    def window(self, spec):
        """The Window ``spec`` names (context frames missing from the store left out); raises
        WindowError if one of its own frames is missing."""
        missing = [s for s in spec.stamps if (spec.sequence, int(s)) not in self.frames]
        if missing:
            raise WindowError(f'window {spec.index}: {len(missing)} of its {spec.n_frames} '
                              'frames are missing in the mapping process (restarted since)')
        frames = [self.frames[(spec.sequence, int(s))] for s in spec.stamps]
        context = tuple(self.frames[(spec.sequence, s)] for s in spec.context_stamps
                        if (spec.sequence, s) in self.frames)
        return Window(spec.sequence, spec.index, spec.stamps, spec.frame_ids, spec.ids,
                      window_matrix(frames, spec.ids), spec.closed_at, context, spec.final)

    def prune(self, spec):
        """Drop the frames no window after ``spec`` can name."""
        first = int(spec.stamps[0])
        keep = {(spec.sequence, s) for s in spec.context_stamps}
        self.frames = {k: f for k, f in self.frames.items()
                       if k[0] > spec.sequence or (k[0] == spec.sequence and k[1] >= first)
                       or k in keep}

    def clear(self):
        self.frames = {}


class _Child:
    """The child's state: the store, the window waiting, published depths; a reader thread
    fills them from ``inbox``, the main thread solves (see :func:`child_main`)."""

    def __init__(self, windows, output, inbox, outbox, cancel):
        self.windows, self.output = windows, output
        self.inbox, self.outbox, self.cancel = inbox, outbox, cancel
        self.store = FrameStore()
        self.depths = {}                # (sequence, stamp) -> z published before a model
        self.modelled = set()           # sequences this child has given a model
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
                    self.store.add(message[1], message[2])
                elif kind == 'depth':
                    if message[1] not in self.modelled:
                        self.depths[(message[1], message[2])] = message[3]
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
        self.store.prune(spec)
        self.depths = {k: z for k, z in self.depths.items() if k in self.store.frames}
        if self.pending is not None:
            self.send(('dropped', self.pending, 'skipped'))
        self.pending = spec

    def _reset(self):
        self.store.clear()
        self.depths, self.reset_due = {}, True
        if self.pending is not None:
            self.send(('dropped', self.pending, 'reset'))
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
                    self.windows.reset()
                    self.reset_due = False
                try:
                    window = self.store.window(spec)
                except WindowError as exc:
                    self.send(('failed', spec, 'window', str(exc)))
                    continue
                published = {s: (self.store.frames[(seq, s)].ids, z)
                             for (seq, s), z in self.depths.items() if seq == spec.sequence}
            self.send(self._solve(spec, window, published))

    def _solve(self, spec, window, published):
        started, released = time.monotonic(), self.windows.releases(window)
        try:
            results, model = solve_window(self.windows, window, self.output, published,
                                          progress=self._cancel_if_stopping)
        except SolveCancelled:
            return ('dropped', spec, 'stopping')
        except WindowError as exc:
            return ('failed', spec, 'window', str(exc))
        except Exception as exc:                      # a solver failure must not stop the child
            return ('failed', spec, 'error', f'{type(exc).__name__}: {exc}\n'
                    f'{traceback.format_exc()}')
        if model is not None:
            with self.cond:
                self.modelled.add(spec.sequence)
                self.depths = {k: z for k, z in self.depths.items() if k[0] != spec.sequence}
        figures = None if released else solve_figures(self.windows.previous,
                                                      time.monotonic() - started)
        return ('solved', spec, tuple(results), model, figures)

    def _cancel_if_stopping(self, iteration, report):
        if self.cancel.is_set():
            raise SolveCancelled(f'stopping at iteration {iteration}')


def child_main(config, solver_factory, warm_start_class, output, inbox, outbox, cancel,
               blas_threads, nice=MAPPING_NICE):
    """The child process: a SlidingWindow like the parent's, fed by ``inbox``; results to
    ``outbox`` (a Connection). Exits on 'stop' or when the parent dies."""
    if nice:
        os.nice(nice)
    fix_mmap_threshold()
    threadpool_limits(limits=blas_threads)
    windows = make_windows(config, solver_factory, warm_start_class=warm_start_class)
    child = _Child(windows, output, inbox, outbox, cancel)
    threading.Thread(target=_exit_with_parent, daemon=True).start()
    threading.Thread(target=child.read, daemon=True).start()
    child.send(('ready', os.getpid()))
    child.run()


def _exit_with_parent():
    """Leave at once if the parent goes (killed: no orphan solving on)."""
    wait([multiprocessing.parent_process().sentinel])
    os._exit(3)


class MappingProcess:
    """The parent's handle on the mapping child; see the module docstring.

    ``on_message(message)`` is called on the receiver thread for each message from the child
    (``'solved'``, ``'failed'``, ``'dropped'``); ``on_exit(exitcode, restarted)`` when the
    child died unasked (it is restarted, at most ``max_restarts`` times); ``nice``: the child's
    niceness increment (MAPPING_NICE). ``config``, ``solver_factory`` and
    ``warm_start_class`` are those of :func:`grass_nrsfm_ros.pipeline.make_windows` and
    must pickle (module-level classes).
    """

    def __init__(self, config, solver_factory=None, warm_start_class=None, *, output='live',
                 on_message=None, on_exit=None, blas_threads=1, max_restarts=5,
                 nice=MAPPING_NICE):
        self._args = (dict(config), solver_factory, warm_start_class, output)
        self._blas_threads, self._nice = int(blas_threads), int(nice)
        self._on_message = on_message or (lambda message: None)
        self._on_exit = on_exit or (lambda code, restarted: None)
        self._ctx = multiprocessing.get_context(START_METHOD)
        self._lock = threading.Lock()
        self._closing = False
        self.outstanding = 0            # windows submitted, not yet answered
        self.restarts, self.max_restarts = 0, int(max_restarts)
        self.pid = None                 # the child's, once it has started
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
    def add_frame(self, sequence, frame, depth=None):
        """Hand one accepted Frame of ``sequence`` over (and ``depth: (P,)`` published for it
        before a model, if any); returns at once."""
        self._put(('frame', sequence, frame))
        if depth is not None:
            self._put(('depth', sequence, frame.stamp_ns, depth))

    def submit(self, window):
        """Hand a closed Window over (as a WindowSpec: the child has its frames)."""
        with self._lock:
            self.outstanding += 1
        self._put(('window', WindowSpec.of(window)))

    def reset(self):
        """Drop the child's frames and the window waiting (a solve running finishes); returns
        the windows then outstanding."""
        self._put(('reset',))
        return self.outstanding

    def _put(self, message):
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
        if message[0] == 'ready':
            self.pid = message[1]
            return
        with self._lock:
            self.outstanding = max(0, self.outstanding - 1)
        try:
            self._on_message(message)
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
        self._inbox.cancel_join_thread()
        self._inbox.close()
        if give_up:
            self.process = None
            self._on_exit(exitcode, False)
            return
        self.pid = None
        self._on_exit(exitcode, True)
        self._start()

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
