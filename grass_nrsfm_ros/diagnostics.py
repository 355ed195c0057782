"""The reconstruction node's ``/diagnostics`` without ROS: a snapshot in, key/value pairs out.

:func:`snapshot` reads the live pipeline's rooms once (plain numbers and strings);
:func:`values` turns a snapshot into the ordered ``{key: text}`` of the node's status, and
:func:`summary` into its level ('ok' or 'warn') and message. The node wraps them in
``diagnostic_msgs`` (keys as shown: spaces, no underscores).
"""
import numpy as np


def snapshot(pipeline, *, latencies=(), handovers=(), counts=None, last_solve=None):
    """What the diagnostics show of ``pipeline`` (a LivePipeline): its rooms' figures, the
    node's ``latencies`` (seconds from receipt to publication of each frame), the mapping's
    ``handovers`` (seconds the tracking spent handing a frame over), the node's ``counts``
    and the ``last_solve`` figures."""
    tracking, backend = pipeline.tracking, pipeline.backend
    return dict(
        latencies=tuple(latencies), handovers=tuple(handovers),
        last=dict(tracking.last), tracking=dict(tracking.stats),
        windowing=dict(pipeline.windowing.stats), refinement=dict(pipeline.refinement.stats),
        frames_lost=pipeline.frames_lost, pending=pipeline.pending_frames,
        backlog=backend.outstanding, restarts=backend.restarts,
        process=getattr(backend, 'pid', None) if getattr(backend, 'alive', True)
        else 'not running',
        inline=not hasattr(backend, 'pid'),
        counts=dict(counts or {}), last_solve=dict(last_solve or {}))


def _ms(seconds):
    return '' if seconds is None else f'{1e3 * seconds:.2f}'


def _percentiles(samples):
    return tuple(np.percentile(samples, [50, 95])) if len(samples) else (None, None)


def _blank(value):
    return '' if value is None else value


def values(snap):
    """The ordered ``{key: text}`` of the reconstruction status of a :func:`snapshot`."""
    last, tracking, counts = snap['last'], snap['tracking'], snap['counts']
    p50, p95 = _percentiles(snap['latencies'])
    out = {'windows solved': snap['refinement']['solved'],
           'frames published': tracking['tracked'],
           'tracking latency p50 ms': _ms(p50), 'tracking latency p95 ms': _ms(p95),
           'tracking residual': '' if last['residual'] is None else f"{last['residual']:.4g}",
           'model age frames': _blank(last['model_age']),
           'model rank': _blank(last['model_rank']), 'bootstrap': last['bootstrap'],
           'mapping backlog': snap['backlog']}
    if not snap['inline']:
        handover = _percentiles(snap['handovers'])[1]
        out.update({'mapping process': snap['process'] or 'starting',
                    'mapping hand-over p95 ms': '' if handover is None
                    else f'{1e3 * handover:.3f}',
                    'mapping restarts': snap['restarts']})
    out.update({'frames tracked': tracking['tracked'],
                'frames refined': snap['refinement']['published'],
                'frames not refined': snap['frames_lost'],
                'frames awaiting refinement': snap['pending'],
                'fresh windows requested': tracking['fresh_windows'],
                'frames not tracked (published flat)': tracking['tracking_failed'],
                'frames from a sheet model': tracking['sheet_frames'],
                'first model after frames': _blank(tracking['first_model_after'])})
    out.update({k.replace('_', ' '): v for k, v in snap['last_solve'].items()})
    out.update({'messages received': counts.get('messages', 0),
                'dropped messages': counts.get('dropped_messages', 0),
                'dropped windows': counts.get('dropped_windows', 0),
                # points: every accepted frame goes out on arrival, so none is lost or waits
                'frames lost': snap['windowing']['frames'] - tracking['tracked'],
                'frames pending': 0,
                'sequences': snap['windowing']['resets'] + 1,
                'windows not solved': snap['refinement']['failed'] + snap['restarts'],
                'solver busy': snap['backlog'] > 0})
    return {k: str(v) for k, v in out.items()}


def summary(snap, recording_error=None):
    """``(level, message)``: 'warn' with the reason when the recording failed, else 'ok'."""
    if recording_error:
        return 'warn', f'recording failed: {recording_error}'
    return 'ok', 'ok'
