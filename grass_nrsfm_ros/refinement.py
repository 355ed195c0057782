"""The refinement policy (the publishing side): which solve's shapes of a frame go out on
``points/refined``, and the frame accounting. Pure Python: no ROS.

Each frame goes out once. With ``refined_after`` 1 (``refined_from: first_window``) from the
first window that solves it as one of its own frames. With ``refined_after`` n > 1
(``last_window``, n = ceil(window_size / window_stride)) from the solve that reconstructs it for
the n-th time, as one of a window's own frames or as context; a frame that leaves the solves
before (dropped context, a skipped window) goes out from its latest solve, and the last window
of a sequence releases every frame still waiting (docs/decisions/0416). Frames go out in stamp
order; a frame a later publication passed over is counted lost.

Accounting: ``stats['published'] + stats['frames_lost'] + pending`` is every frame of every
window :meth:`Refinement.expect` was told of.
"""
from collections import deque


#: frames of closed windows waiting at most (a mapping that never answers cannot grow it)
UNPUBLISHED_KEPT = 1_000_000


class Refinement:
    """See the module docstring. ``expect(window)`` for each closed window (in order),
    ``take(update)`` for each Update of the mapping (in order) gives the FrameResults to
    publish."""

    def __init__(self, refined_after=1):
        self.refined_after = int(refined_after)
        self._latest = (None, {})       # (sequence, {stamp: (FrameResult, solves)}) waiting
        self._unpublished = deque(maxlen=UNPUBLISHED_KEPT)   # (sequence, stamp) not published
        self._published_until = {}      # sequence -> newest published stamp
        self.stats = dict(solved=0, failed=0, published=0, frames_lost=0)

    def expect(self, window):
        """Note the frames of a closed ``window`` that no earlier window had."""
        self._unpublished.extend((window.sequence, int(s)) for s in window.fresh)

    def waiting(self, sequence):
        """True if frames of ``sequence``'s closed windows wait for a solve that can release
        them (a last window is worth closing)."""
        return self.refined_after > 1 and bool(self._unpublished) \
            and self._unpublished[-1][0] == sequence

    @property
    def pending(self):
        """Frames of closed windows neither published nor counted lost yet."""
        return len(self._unpublished)

    def take(self, update):
        """The FrameResults of ``update`` (an Update of the mapping) to publish, in stamp
        order."""
        if update.preview:                  # a model only: nothing to publish or count
            return []
        if update.kind == 'failed':
            self.stats['failed'] += 1
            return []
        if update.kind not in ('solved', 'released'):
            return []
        if update.kind == 'solved':
            self.stats['solved'] += 1
        if self.refined_after > 1:
            return self._take_latest(update)
        own = set(update.stamps)
        results = [r for r in update.results if r.stamp_ns in own]
        fresh = self._fresh(update.sequence, [r.stamp_ns for r in results])
        return self._published([results[i] for i in fresh])

    def _take_latest(self, update):
        """Note each result of ``update`` as its frame's latest, then publish, in stamp order
        and each from its latest solve, the waiting frames up to the newest that is due:
        solved ``refined_after`` times, or not reconstructed by this solve, or any (a final
        window)."""
        done = self._published_until.get(update.sequence)
        if self._latest[0] != update.sequence:
            self._latest = (update.sequence, {})
        latest = self._latest[1]
        solved = set()
        for result in update.results:
            stamp = result.stamp_ns
            if done is None or stamp > done:
                solves = latest[stamp][1] + 1 if stamp in latest else 1
                latest[stamp] = (result, solves)
                solved.add(stamp)
        due = [s for s, (_, n) in latest.items()
               if update.final or n >= self.refined_after or s not in solved]
        if not due:
            return []
        order = sorted(s for s in latest if s <= max(due))
        return self._published([latest.pop(order[i])[0]
                                for i in self._fresh(update.sequence, order)])

    def _published(self, results):
        self.stats['published'] += len(results)
        return results

    def _fresh(self, sequence, stamps):
        """Indices of ``stamps`` (ascending, of ``sequence``) not published before; marks them
        published and counts the frames this publication passed over as lost (in an older
        sequence, or before its newest frame but not among them: a skipped window's)."""
        done = self._published_until.get(sequence)
        fresh = [i for i, s in enumerate(stamps) if done is None or s > done]
        if not fresh:
            return []
        newest = int(stamps[fresh[-1]])
        going = {int(stamps[i]) for i in fresh}
        self._published_until[sequence] = newest
        while self._unpublished and self._unpublished[0] <= (sequence, newest):
            seq, stamp = self._unpublished.popleft()
            if seq < sequence or stamp not in going:
                self.stats['frames_lost'] += 1
        return fresh
