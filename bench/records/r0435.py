"""Record 0435: a sequence's first window capped at WINDOW_BETA_MAX, and the first window
closed early (tried, not adopted): the live pipeline offline (every window solved inline as it
closes) with each variant, e3D of ``points`` and ``points/refined``, the frame of the first
model and the first window's CPU seconds.

    python -m bench.records.r0435
"""
import sys

from bench import common, live, streaming
from grass_nrsfm_ros import mapper, windowing
from grass_nrsfm_ros.nrsfm.metrics import e3d
from grass_nrsfm_ros.params import defaults

VARIANTS = (('shipped', False, True), ('first window uncapped', False, False),
            ('first window closed early', True, True))


def sequences():
    """The live bench's quick sequences plus two seeds of the hard kinds."""
    out = streaming.accuracy_sequences(common.Mode('quick'))
    return out + [(f'{k}60s1', *common.synthetic(k, 60, 1000, seed=1))
                  for k in ('waving', 'articulated')]


def run_variant(W, early, capped):
    """``(points e3D-ready, refined, first model frame, first window CPU s)`` of one variant:
    ``early`` closes a sequence's first window as soon as it can; ``capped`` False lets a
    window started from the rigid factorisation run the whole penalty schedule."""
    init, fit_kwargs = windowing.Windowing.__init__, mapper.Mapper._fit_kwargs

    def early_init(self, **kw):
        init(self, **kw)
        self._close_early = early       # the first window of the (only) sequence

    def uncapped(self, solver, problem, *args):
        started = self.started_from
        if not capped and started == 'rigid':
            self.started_from = 'model'     # not capped: the pre-0435 rule
        try:
            return fit_kwargs(self, solver, problem, *args)
        finally:
            self.started_from = started
    windowing.Windowing.__init__, mapper.Mapper._fit_kwargs = early_init, uncapped
    try:
        points, refined, pipe, cpu = live.run_pipeline(W, defaults()['mapping_tracks'])
    finally:
        windowing.Windowing.__init__, mapper.Mapper._fit_kwargs = init, fit_kwargs
    return points, refined, pipe.tracking.stats['first_model_after'], cpu[0]


def main():
    for name, W, S in sequences():
        cells = []
        for label, early, capped in VARIANTS:
            points, refined, first, cpu = run_variant(W, early, capped)
            cells.append(f'{label}: points {e3d(live.stacked(points), S):.4f} refined '
                         f'{e3d(live.stacked(refined), S):.4f} first model {first} '
                         f'first window {cpu:.2f} CPU s')
        print(name, '\n  ' + '\n  '.join(cells), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
