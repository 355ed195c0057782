"""``grass-nrsfm reconstruct IN -o OUT [--config FILE]``.

``IN.npz`` holds ``W: (2F, P)`` (and optionally ground truth ``S: (3F, P)``, then e3D is
printed, and pinhole intrinsics ``K: (3, 3)``); ``OUT.npz`` gets ``S``, ``R``, ``translation``,
``groups``, ``projection`` and the solver report (JSON string ``report``), and ``K`` where one
was used. With ``K`` (the npz's, or ``--camera FX FY CX CY``, which wins) the pixel tracks are
normalised (``K^-1 [u, v, 1]``) and solved with the perspective model (solver parameter
``projection`` 'auto'): ``S`` is in the camera frame, its pinhole image ``K [x/z, y/z, 1]`` the
tracks, in units of each frame's mean depth (``--scale``: that depth, e.g. the camera's
distance to the surface in metres, for metres). Without ``K`` the pixels are solved as
orthographic projections, as before, with a warning. Tracks need not be complete: ``W`` holds
NaN where a track is not seen (or ``visible: (F, P)`` says so), and every track is
reconstructed in every frame (the unseen entries filled by the low-rank model; the perspective
model takes complete tracks, so incomplete ones are solved orthographically, with a warning);
``OUT`` then gets ``visible: (F, P)``, the entries observed (the others were filled), and
``track_weights: (P,)``, the robust data term's weights (1: not down-weighted). Frames seeing
fewer than 4 tracks and tracks seen in fewer than 2 frames are left out with a warning (NaN in
``S``, ``R`` and ``translation``). ``--complete-tracks`` reconstructs only the tracks seen in
every frame (their columns saved as ``points``, which ``evaluate`` uses). A bag directory or
``.mcap``/``.bag`` file runs the node's live pipeline offline (each window solved inline as it
closes) and writes an output bag (there, each window uses the tracks it sees throughout):
:func:`reconstruct_bag`, which the demo uses too, owns that offline run. The bag's intrinsics
come from ``--camera`` or its CameraInfo topic (``--camera-info-topic``, or the sibling
``camera_info`` of the tracks topic, or its only one); ``--scale`` is then the output's
``scene_depth``.
"""
from collections import Counter
from dataclasses import dataclass, field
import json
import os
from pathlib import Path
import shutil
import sys
import time

import numpy as np

from grass_nrsfm_ros import bag
from grass_nrsfm_ros.cli import UserError
from grass_nrsfm_ros.cloud import CloudError, decode_tracks
from grass_nrsfm_ros.commands.npz import complete_tracks, load_camera, load_tracks
from grass_nrsfm_ros.frontend.sources import bag_camera, SourceError
from grass_nrsfm_ros.nrsfm import e3d, GrassmannNRSfM
from grass_nrsfm_ros.nrsfm.camera import (intrinsics, normalise, resolved_projection,
                                          warn_orthographic)
from grass_nrsfm_ros.nrsfm.measurement import InvalidInputError, validate_shapes
from grass_nrsfm_ros.nrsfm.missing import MIN_FRAME_TRACKS, MIN_TRACK_FRAMES
from grass_nrsfm_ros.params import load_config, solver_kwargs
from grass_nrsfm_ros.pipeline import live_events, make_pipeline


def add_arguments(parser):
    parser.add_argument('input', help='.npz with W (2F, P), or a tracks bag')
    parser.add_argument('-o', '--output', required=True, help='output .npz (or bag directory)')
    parser.add_argument('--config', help="params.yaml (the node's file works too)")
    parser.add_argument('--topic', default='/tracks', help='tracks topic when IN is a bag')
    parser.add_argument('--camera-info-topic',
                        help="a bag's CameraInfo topic (default: the tracks topic's sibling "
                             'camera_info, or the only one)')
    parser.add_argument('--quiet', action='store_true', help='no progress display')
    parser.add_argument('--camera', type=float, nargs=4, metavar=('FX', 'FY', 'CX', 'CY'),
                        help='pinhole intrinsics of the pixel tracks (pixels; overrides the '
                             "npz's K)")
    parser.add_argument('--scale', type=float, default=1.0,
                        help="with K: each frame's mean depth in the output's units (default "
                             '1; the distance to the surface in metres gives metres)')
    parser.add_argument('--complete-tracks', action='store_true',
                        help='reconstruct only the tracks seen in every frame (saved as '
                             '`points` in OUT) instead of every track with its unseen '
                             'entries filled')


def solver_from_config(path):
    """A GrassmannNRSfM built from the solver entries of a params file (or defaults)."""
    config = load_config(path) if path else {}
    return GrassmannNRSfM(**solver_kwargs(config)), config


class Progress:
    """One overwritten status line on stderr while the solver iterates."""

    def __init__(self, enabled):
        self.enabled = enabled and sys.stderr.isatty()
        self.start = time.monotonic()

    def __call__(self, iteration, report):
        if not self.enabled:
            return
        gap = max(report.gaps[-1]) if report.gaps else float('nan')
        sys.stderr.write(f'\r  iteration {iteration:4d}  gap {gap:9.3e}  '
                         f'{time.monotonic() - self.start:6.1f} s')
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write('\n')


@dataclass
class Tracks:
    """The tracks of an input .npz as solved: ``W: (2F, P)`` with NaN where not seen, the
    ground truth ``S_gt: (3F, P)`` or None (NaN allowed where not seen), ``points: (P',)`` the
    columns solved with --complete-tracks (None: all), ``seen: (F, P)`` the entries observed
    (None: all), ``frames: (F',)`` and ``tracks: (P'',)`` those solved (None: all)."""

    W: np.ndarray
    S_gt: np.ndarray = None
    points: np.ndarray = None
    seen: np.ndarray = None
    frames: np.ndarray = None
    tracks: np.ndarray = None


def warn(path, text):
    print(f'{path}: warning: {text}', file=sys.stderr)


def observation(W, visible, path):
    """``seen: (F, P)`` the entries of ``W: (2F, P)`` observed (``visible``, both u and v
    finite); warns about an entry with only one of u, v finite and one visible but not
    finite (both then unseen)."""
    F, P = W.shape[0] // 2, W.shape[1]
    finite = np.isfinite(W).reshape(F, 2, P)
    half = int((finite[:, 0] != finite[:, 1]).sum())
    if half:
        warn(path, f'{half} entries have a finite u or v but not both: taken as not seen')
    seen = finite.all(axis=1)
    if visible is not None:
        complete_tracks(visible, F, P, path)                      # checks the shape
        wrong = int((visible & ~seen).sum())
        if wrong:
            warn(path, f'{wrong} entries marked visible are not finite: taken as not seen')
        seen &= visible
    return seen


def usable(seen, path):
    """``(frames: (F',), tracks: (P',))`` the frames and tracks a masked solve can use: it
    leaves out, with a warning, frames seeing fewer than MIN_FRAME_TRACKS tracks and tracks
    seen in fewer than MIN_TRACK_FRAMES frames (until none is left to leave out)."""
    frames, tracks = np.arange(seen.shape[0]), np.arange(seen.shape[1])
    while True:
        sub = seen[np.ix_(frames, tracks)]
        bad_f = sub.sum(axis=1) < MIN_FRAME_TRACKS
        bad_t = sub.sum(axis=0) < MIN_TRACK_FRAMES
        if not (bad_f.any() or bad_t.any()):
            return frames, tracks
        if bad_f.any():
            warn(path, f'{int(bad_f.sum())} frames see fewer than {MIN_FRAME_TRACKS} tracks '
                       f'(first: frame {int(frames[bad_f][0])}): left out (NaN in OUT)')
            frames = frames[~bad_f]
        else:
            warn(path, f'{int(bad_t.sum())} tracks are seen in fewer than {MIN_TRACK_FRAMES} '
                       f'frames (first: track {int(tracks[bad_t][0])}): left out (NaN in OUT)')
            tracks = tracks[~bad_t]


def observed_tracks(path, complete_only):
    """The :class:`Tracks` of an .npz: every track, its unseen entries NaN (frames and tracks
    a solve cannot use left out, with a warning), or with ``complete_only`` the tracks seen in
    every frame."""
    W, S_gt, visible = load_tracks(path)
    if W.ndim != 2 or W.shape[0] % 2:
        return Tracks(W)                         # the solver says what is wrong
    F, P = W.shape[0] // 2, W.shape[1]
    if S_gt is not None:                 # checked before a long solve, not after it
        validate_shapes(np.nan_to_num(S_gt), n_frames=F, n_points=P,
                        name=f'{path}: ground truth S')
    seen = observation(W, visible, path)
    if seen.all():
        return Tracks(W, S_gt)
    if not seen.any():
        raise UserError(f'{path}: W has no observed entry (every entry non-finite or not '
                        'visible)')
    if complete_only:
        points = np.flatnonzero(seen.all(axis=0))
        print(f'{path}: keeping the {points.size} of {P} tracks seen in every frame')
        return Tracks(W[:, points], None if S_gt is None else S_gt[:, points], points)
    frames, tracks = usable(seen, path)
    if frames.size < 3 or tracks.size < 4:
        raise UserError(f'{path}: {frames.size} frames and {tracks.size} tracks are seen '
                        'often enough; at least 3 frames and 4 tracks needed')
    W = np.where(np.repeat(seen, 2, axis=0), W, np.nan)
    print(f'{path}: {int((~seen).sum())} of {seen.size} entries not seen '
          f'({int((~seen.all(axis=0)).sum())} of {P} tracks incomplete): filled')
    return Tracks(W, S_gt, seen=seen, frames=frames, tracks=tracks)


def check_writable(path):
    """UserError unless ``path``'s folder exists and may be written to."""
    folder = Path(path).resolve().parent
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        raise UserError(f'cannot write {path}: folder {folder} does not exist or is not '
                        'writable')


def chosen_camera(args):
    """``K: (3, 3)`` of ``--camera`` or of the input npz, or None."""
    K = load_camera(args.input)
    if args.camera is None:
        return K
    if K is not None:
        print(f'{args.input}: its K replaced by --camera {" ".join(map(str, args.camera))}')
    try:
        return intrinsics(*args.camera)
    except InvalidInputError as exc:
        raise UserError(f'--camera: {exc}') from None


def chosen_bag_camera(args):
    """``(K: (3, 3) or None, where it came from)`` of ``--camera`` or the bag's
    camera_info."""
    if args.camera is not None:
        try:
            return intrinsics(*args.camera), 'from --camera'
        except InvalidInputError as exc:
            raise UserError(f'--camera: {exc}') from None
    try:
        camera, topic = bag_camera(args.input, args.topic, args.camera_info_topic)
    except SourceError as exc:
        raise UserError(str(exc)) from None
    if camera is None:
        return None, None
    return camera.K, f'from the bag topic {topic}'


def check_scale(scale):
    """``--scale`` if a finite number > 0, else UserError."""
    if not (np.isfinite(scale) and scale > 0):
        raise UserError(f'--scale {scale}: expected a finite number > 0')
    return float(scale)


def solved_tracks(W, K, solver, scale, complete=True):
    """``(W_solved: (2F, P), projection)``: the tracks as the solver takes them (normalised
    with K under the perspective model) and the projection resolved (the solver's parameter
    set to it); warns once where pixels are solved without K, and where incomplete tracks
    (not ``complete``) make 'auto' orthographic."""
    projection = resolved_projection(solver.projection, K)
    check_scale(scale)
    if projection == 'perspective' and not complete:
        if solver.projection == 'perspective':
            raise UserError("projection 'perspective' takes complete tracks; these have "
                            'unseen entries (--complete-tracks keeps the complete ones)')
        print('warning: the perspective model takes complete tracks: the incomplete tracks '
              'are solved as orthographic projections of the pixels', file=sys.stderr)
        projection = 'orthographic'
    if projection == 'orthographic' and scale != 1.0:
        raise UserError('--scale applies to the perspective model (with K)')
    solver.set_params(projection=projection)
    if projection == 'orthographic' and K is None:
        warn_orthographic()
    if projection == 'perspective' and K is not None:
        return normalise(W, K), projection
    return W, projection


def spread(tracks, result):
    """The result's arrays over every frame and track of the input: ``{name: array}``, NaN
    (groups -1) for the frames and tracks left out; ``visible`` and ``track_weights``."""
    F, P = tracks.W.shape[0] // 2, tracks.W.shape[1]
    weights = result.track_weights if result.track_weights is not None else \
        np.ones(result.S.shape[1])
    if tracks.frames is None:
        out = {'S': result.S, 'R': result.R, 'translation': result.translation,
               'groups': result.groups, 'track_weights': weights}
        if tracks.seen is not None:
            out['visible'] = tracks.seen
        return out
    f, p = tracks.frames, tracks.tracks
    S = np.full((F, 3, P), np.nan)
    S[np.ix_(f, np.arange(3), p)] = result.S.reshape(f.size, 3, p.size)
    R = np.full((F, 3, 3), np.nan)
    R[f] = result.R
    translation = np.full((F, 2, 1), np.nan)
    translation[f] = result.translation.reshape(f.size, 2, 1)
    groups = np.full(P, -1, dtype=np.asarray(result.groups).dtype)
    groups[p] = result.groups
    track_weights = np.full(P, np.nan)
    track_weights[p] = weights
    visible = np.zeros((F, P), dtype=bool)
    visible[np.ix_(f, p)] = tracks.seen[np.ix_(f, p)]
    return {'S': S.reshape(3 * F, P), 'R': R, 'translation': translation.reshape(2 * F, 1),
            'groups': groups, 'track_weights': track_weights, 'visible': visible}


def print_errors(S, tracks, scaled):
    """e3D of ``S: (3F, P)`` against the ground truth: over every entry where the truth is
    known, and over the observed ones where some were not."""
    F, P = S.shape[0] // 3, S.shape[1]
    known = (np.isfinite(tracks.S_gt).reshape(F, 3, P).all(axis=1)
             & np.isfinite(S).reshape(F, 3, P).all(axis=1))
    label = f'per-frame Procrustes, {"with" if scaled else "no"} scale'
    if known.all():
        print(f'e3D ({label}): {e3d(S, tracks.S_gt, scale=scaled):.4f}')
    else:
        print(f'e3D ({label}, the {int(known.sum())} entries with truth): '
              f'{e3d(S, tracks.S_gt, scale=scaled, visible=known):.4f}')
    if tracks.seen is not None and (known & ~tracks.seen).any():
        seen = known & tracks.seen
        print(f'e3D over the observed entries: '
              f'{e3d(S, tracks.S_gt, scale=scaled, visible=seen):.4f}')


def reconstruct_npz(args):
    tracks = observed_tracks(args.input, args.complete_tracks)
    solver, _ = solver_from_config(args.config)
    K = chosen_camera(args)
    W = tracks.W
    if tracks.frames is not None:
        W = W.reshape(-1, 2, W.shape[1])[np.ix_(tracks.frames, [0, 1], tracks.tracks)]
        W = W.reshape(2 * tracks.frames.size, tracks.tracks.size)
    W_in, projection = solved_tracks(W, K, solver, args.scale, tracks.seen is None)
    check_writable(args.output)                          # before a long solve, not after it
    progress = Progress(not args.quiet)
    try:
        result = solver.fit(W_in, progress=progress)
    finally:
        progress.close()
    report = result.report
    arrays = spread(tracks, result)
    if projection == 'perspective':
        arrays['S'] = arrays['S'] * args.scale
    extra = {} if tracks.points is None else {'points': tracks.points}
    if K is not None:
        extra['K'] = K
    np.savez_compressed(args.output, projection=projection,
                        report=json.dumps(report.to_dict()), **arrays, **extra)
    F, P = tracks.W.shape[0] // 2, tracks.W.shape[1]
    print(f'{args.input}: F={F} P={P} {projection} K_rot={report.K_rot} '
          f'iterations={report.iterations} seconds={report.seconds["total"]:.1f} -> '
          f'{args.output}')
    if report.relief != 1.0:
        print(f'relief: depths scaled by {report.relief:g} (docs/decisions/0734)')
    if report.downweighted_tracks:
        print(f'robust: {len(report.downweighted_tracks)} tracks down-weighted (track_weights '
              'in OUT)')
    if report.perspective is not None:
        p = report.perspective
        print(f'perspective: kept round {p["kept"]} of {len(p["rounds"]) - 1} '
              f'({p["stopped"]}); S in the camera frame, each frame\'s mean depth '
              f'{args.scale:g}')
    if tracks.S_gt is not None:
        print_errors(arrays['S'], tracks, projection == 'perspective')  # scale unknown there
    return 0


@dataclass
class ReconstructionReport:
    """What :func:`reconstruct_bag` did: frames in and out, windows, refusals, timings."""

    out_path: Path
    frames_in: int = 0
    frames_out: int = 0
    frames_refined: int = 0
    windows: int = 0
    refused: list = field(default_factory=list)      # one line per refused frame or window
    copied: Counter = field(default_factory=Counter)  # input topic -> messages copied
    seconds: float = 0.0
    cpu_seconds: float = 0.0


def text_progress(stream=None, width=30):
    """A ``progress(done, total)`` callback drawing ``[####    ] done/total`` on stderr."""
    stream = stream or sys.stderr
    state = {'last': -1.0}

    def draw(done, total):
        now = time.monotonic()
        if done < total and now - state['last'] < 0.1:
            return
        state['last'] = now
        filled = int(width * done / max(total, 1))
        stream.write(f'\r[{"#" * filled}{" " * (width - filled)}] {done}/{total} frames')
        if done >= total:
            stream.write('\n')
        stream.flush()
    return draw


def reconstruct_bag(in_path, out_path, pipeline, *, topic=bag.TRACKS_TOPIC,
                    points_topic=bag.POINTS_TOPIC, refined_topic=bag.REFINED_TOPIC,
                    copy_inputs=True, progress=None, skip_errors=(ValueError,)):
    """Run the pipeline over a tracks bag offline, each window solved as it closes (so the
    output is reproducible), as fast as the solver goes, and write a bag at ``out_path`` with
    ``points_topic`` (one cloud per frame as tracked on arrival), ``refined_topic`` (each frame
    once the refinement policy lets it out), both stamped with the frame's stamp and logged at
    its tracks' receive time, and, with ``copy_inputs``, every input message (CDR as recorded;
    for a ROS 1 source only the tracks, re-encoded).

    ``pipeline`` is an inline :class:`grass_nrsfm_ros.pipeline.LivePipeline` (or anything with
    ``add_frame(stamp_ns, ids, uv, frame_id) -> (result,)``, ``refined() -> (results,
    updates)`` and ``flush()``; a result has ``stamp_ns, frame_id, ids: (P,), xyz: (P, 3)``, an
    update ``kind``, ``index`` and ``message``), driven as
    :func:`~grass_nrsfm_ros.pipeline.reconstruct_live` drives it, with the bag read and
    written as it goes. Frames that raise one of ``skip_errors`` and windows that fail are
    refused and listed in the report. ``progress(done, total)`` is called after every input
    frame. Returns a :class:`ReconstructionReport`.
    """
    report = ReconstructionReport(out_path=Path(out_path))
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    with bag.BagReader(in_path) as src, bag.BagWriter(out_path) as out:
        tracks_conns = src.connections(topic)
        total = sum(c.msgcount for c in tracks_conns)
        received = {}                                  # stamp -> receive time of its tracks
        conns = src.reader.connections if copy_inputs else tracks_conns
        if not src.is_ros1:
            for c in conns:
                out.add_topic(c.topic, c.msgtype, definition=bag.definition_of(c))

        def frames():
            """The bag's tracks frames, inputs copied on the way; undecodable ones refused."""
            for conn, t_ns, raw in src.messages(conns):
                if copy_inputs and not src.is_ros1:
                    out.write(conn.topic, raw, t_ns)
                    report.copied[conn.topic] += 1
                if conn.topic != topic:
                    continue
                msg = src.decode(raw, conn)
                stamp = bag.stamp_ns(msg.header.stamp)
                if copy_inputs and src.is_ros1:
                    out.add_topic(topic, bag.POINTCLOUD2)
                    out.write(topic, bag.cloud_cdr(bag.tracks_fields(msg), stamp,
                                                   msg.header.frame_id), t_ns)
                    report.copied[topic] += 1
                report.frames_in += 1
                try:
                    tracks = decode_tracks(msg)
                except CloudError as exc:
                    report.refused.append(f'frame {report.frames_in - 1} (stamp {stamp}): {exc}')
                else:
                    received.setdefault(stamp, t_ns)
                    yield stamp, tracks.ids, tracks.uv, msg.header.frame_id
                if progress is not None:
                    progress(report.frames_in, total)

        for kind, item in live_events(pipeline, frames(), refuse=skip_errors):
            if kind in ('points', 'refined'):
                out.write_points(np.asarray(item.xyz), np.asarray(item.ids), item.stamp_ns,
                                 item.frame_id, topic=points_topic if kind == 'points'
                                 else refined_topic, t_ns=received.get(item.stamp_ns,
                                                                       item.stamp_ns))
                report.frames_out += kind == 'points'
                report.frames_refined += kind == 'refined'
            elif kind == 'update':
                report.windows += not item.preview
                if item.kind == 'failed':
                    what = 'the preview window' if item.preview else f'window {item.index}'
                    report.refused.append(f'{what}: {item.message}')
            else:
                stamp, exc = item
                report.refused.append(f'frame {report.frames_in - 1} (stamp {stamp}): {exc}')
    report.seconds = time.perf_counter() - t_wall
    report.cpu_seconds = time.process_time() - t_cpu
    return report


def reconstruct_bag_file(args):
    """The node's live pipeline over a tracks bag, offline, into an output bag; a
    refused input (corrupt or truncated bag, missing topic) leaves no output behind."""
    config = load_config(args.config) if args.config else {}
    known = bag.topics(args.input)                      # corrupt bags fail here, before output
    if args.topic not in known:
        raise bag.TopicNotFoundError(f'bag {args.input} has no topic {args.topic!r} (topics: '
                                     f'{", ".join(sorted(known)) or "none"})')
    camera, where = chosen_bag_camera(args)
    if camera is not None:
        config['scene_depth'] = check_scale(args.scale)
        print(f"{args.input}: K {where}: points in the camera frame, each frame's mean depth "
              f'{args.scale:g}')
    elif args.scale != 1.0:
        raise UserError('--scale applies to the perspective model (with K)')
    pipeline = make_pipeline(config, camera=camera)     # inline: the output is reproducible
    out = Path(args.output)
    existed = out.exists()
    try:
        report = reconstruct_bag(args.input, out, pipeline, topic=args.topic,
                                 progress=None if args.quiet else text_progress())
    except BaseException:
        if not existed and out.exists():
            shutil.rmtree(out)                          # no half-written output bag
        raise
    finally:
        pipeline.close()
    print(f'{args.input}: {report.frames_in} frames in, {report.frames_out} reconstructed in '
          f'{report.windows} windows, {report.seconds:.1f} s -> {args.output}')
    for line in report.refused:
        print(f'refused: {line}', file=sys.stderr)
    return 0


def run(args):
    if Path(args.input).suffix == '.npz':
        return reconstruct_npz(args)
    return reconstruct_bag_file(args)
