"""``python -m bench.table [--results DIR] [--write docs/results.md]``: the benchmark results
page, generated from the JSON in bench/results: a header saying how to regenerate it, then one
table per suite (with links to its plots); printed, or written to FILE with ``--write FILE``.
"""
import argparse
import json
import os
from pathlib import Path
import statistics
import sys

from . import common

#: where the page lives and how it is regenerated (the page's header)
PAGE = common.REPO / 'docs' / 'results.md'
HEADER = ('# Benchmark results', '',
          'Generated from `bench/results/*.json`; do not edit by hand. Regenerate with',
          '`python -m bench [--full]` (the quick subset, or every case) then '
          '`python -m bench.table --write docs/results.md`. Each table names the run it comes '
          'from (quick or full, date, commit, CPUs); the node and load figures have their own '
          'scripts (`python -m bench.live --node`, `python -m bench.load`).')
METHOD_NAMES = {'ours': 'ours', 'rigid': 'rigid', 'bmm': 'BMM', 'pta': 'PTA',
                'pta_dai': 'PTA (Dai R)'}


def load(results, suite):
    path = Path(results) / f'{suite}.json'
    return json.loads(path.read_text()) if path.is_file() else None


def fmt(v, digits=4):
    return '-' if v is None else f'{v:.{digits}f}'


def accuracy_table(doc):
    rows = doc['rows']
    methods = [m for m in METHOD_NAMES if any(r['method'] == m for r in rows)]
    seqs = list(dict.fromkeys(r['sequence'] for r in rows))
    lines = ['| sequence | F x P | ' + ' | '.join(METHOD_NAMES[m] for m in methods)
             + ' | published PTA / BMM |', '|---|---|' + '---|' * (len(methods) + 1)]
    for seq in seqs:
        by = {r['method']: r for r in rows if r['sequence'] == seq}
        any_row = next(iter(by.values()))
        cells = []
        for m in methods:
            r = by.get(m)
            if r is None:
                cells.append('-')
                continue
            cell = fmt(r['e3d'])
            if r.get('e3d_akhter') is not None:
                cell += f' (A {fmt(r["e3d_akhter"])})'
            if r.get('K_oracle'):
                cell += f' K={r["K_oracle"]}'
            cells.append(cell)
        pub = [by[m]['published']['value'] for m in ('pta', 'bmm')
               if m in by and by[m].get('published')]
        published = ' / '.join(fmt(v) for v in pub) + ' (A)' if pub else '-'
        label = f'{seq} (e3D with per-frame scale)' if any_row.get('family') == 'perspective' \
            else seq
        lines.append(f'| {label} | {any_row["F"]} x {any_row["P"]} | ' + ' | '.join(cells)
                     + f' | {published} |')
    return lines


def noise_table(doc):
    rows = doc['rows']
    methods = [m for m in METHOD_NAMES if any(r['method'] == m for r in rows)]
    ratios = sorted({r['r'] for r in rows})
    lines = [f'Noise on {doc.get("sequence")} ({doc.get("F")} x {doc.get("P")}), e3D mean '
             '± std over repeats:', '',
             '| r | ' + ' | '.join(METHOD_NAMES[m] for m in methods) + ' |',
             '|---|' + '---|' * len(methods)]
    for ratio in ratios:
        cells = []
        for m in methods:
            r = next((x for x in rows if x['method'] == m and x['r'] == ratio), None)
            cells.append('-' if r is None else f'{fmt(r["e3d_mean"])} ± {fmt(r["e3d_std"])}')
        lines.append(f'| {ratio:g} | ' + ' | '.join(cells) + ' |')
    return lines


def parameters_table(doc):
    """One row per parameter: e3D for each value (CPU seconds and group counts in the JSON)."""
    rows = doc['rows']
    cpu = [r['seconds_cpu'] for r in rows if r.get('seconds_cpu') is not None]
    spread = f', {min(cpu):.1f}-{max(cpu):.1f} CPU s per solve' if cpu else ''
    lines = [f'Ours on {doc.get("sequence")} ({doc.get("F")} x {doc.get("P")}){spread}:', '',
             '| parameter | e3D by value |', '|---|---|']
    for param in dict.fromkeys(r['param'] for r in rows):
        cells = ', '.join(f'{r["value"]}: {fmt(r["e3d"])}' for r in rows if r['param'] == param)
        lines.append(f'| {param} | {cells} |')
    return lines


def scale_table(doc):
    """One row per method: its CPU-time / memory growth exponents per sweep, its largest case."""
    exponents = doc.get('exponents', [])
    sweeps = list(dict.fromkeys((e['against'], *e['fixed'].items()) for e in exponents))
    heads = [f'exponent in {against} at {fk}={fv}' for against, (fk, fv) in sweeps]
    lines = ['| method | ' + ' | '.join(heads) + ' | largest case | CPU s | extra MiB |',
             '|---|' + '---|' * (len(sweeps) + 3)]
    for method in dict.fromkeys(e['method'] for e in exponents):
        cells = []
        for against, (fk, fv) in sweeps:
            e = next((x for x in exponents if x['method'] == method and x['against'] == against
                      and x['fixed'] == {fk: fv}), None)
            cells.append('-' if e is None else
                         f'{fmt(e["time_exponent"], 2)} / {fmt(e["memory_exponent"], 2)}')
        big = max((r for r in doc['rows'] if r['method'] == method),
                  key=lambda r: (r['F'] * r['P'], r['F']), default=None)
        largest = '- | - | -' if big is None else (
            f'{big["F"]} x {big["P"]} | {fmt(big["seconds_cpu"], 2)} | '
            f'{fmt(big.get("solve_extra_mb"), 0)}')
        lines.append(f'| {METHOD_NAMES[method]} | ' + ' | '.join(cells) + f' | {largest} |')
    ratios = [r for r in doc['rows'] if r.get('iteration_over_svd') is not None]
    if ratios:
        lines += ['', 'Ours, time per ADMM iteration / one economy SVD of S# (F x 3P): '
                  + ', '.join(f'{r["F"]}x{r["P"]}: {r["iteration_over_svd"]:.1f}'
                              for r in ratios)]
    return lines


def streaming_table(doc):
    lines = ['| tracks | solver | window/stride | fps | latency mean s | latency max s |',
             '|---|---|---|---|---|---|']
    for r in doc['rows']:
        lines.append(f'| {r["P"]} | {r["solver"]} | {r["window_size"]}/{r["window_stride"]} | '
                     f'{fmt(r["fps"], 1)} | {fmt(r["latency_mean_s"], 2)} | '
                     f'{fmt(r["latency_max_s"], 2)} |')
    return lines


def live_table(doc):
    lines = ['| sequence | F x P | points (all frames) | points / windows after 1st model | '
             "refined | windows | mapping CPU s / window (windows') | from the 3rd window | "
             'tracking ms p95 | first model after |', '|---|---|---|---|---|---|---|---|---|---|']
    for r in doc['rows']:
        after = (f'{fmt(r["e3d_points_after_first_model"])} / '
                 f'{fmt(r.get("e3d_windows_after_first_model"))}')
        lines.append(f'| {r["sequence"]} | {r["F"]} x {r["P"]} | {fmt(r["e3d_points"])} | '
                     f'{after} | {fmt(r["e3d_refined"])} | {fmt(r["e3d_windows"])} | '
                     f'{fmt(r["mapping_cpu_per_window_s"], 2)} '
                     f'({fmt(r["windows_cpu_per_window_s"], 2)}) | '
                     f'{fmt(r.get("mapping_cpu_from_third_window_s"), 2)} '
                     f'({fmt(r.get("windows_cpu_from_third_window_s"), 2)}) | '
                     f'{fmt(r["tracking_ms_p95"], 1)} | '
                     f'{r.get("first_model_after_frames", "-")} |')
    causal = [r for r in doc['rows'] if 'e3d_causal_startup' in r]
    if causal:
        lines += ['', 'A causal reference: frame t re-solved from every frame up to t (one solve '
                  'of the whole past, the windows solver), at every frame of the start-up '
                  '(before the first model) and at 10 later frames, against the points and the '
                  'windows on the same frames (e3D):', '',
                  '| sequence | start-up: causal / points / windows | '
                  'later: causal / points / windows |', '|---|---|---|']
        for r in causal:
            parts = [' / '.join(fmt(r.get(f'e3d_{kind}_{part}'))
                                for kind in ('causal', 'points', 'windows'))
                     for part in ('startup', 'later')]
            lines.append(f'| {r["sequence"]} | {parts[0]} | {parts[1]} |')
    node = load(common.RESULTS, 'live_node') or {}
    if node:
        lines += ['', 'The node over DDS, the slow face at 30 Hz (`python -m bench.live --node`; '
                  'the same pipeline offline on the same input: `--offline`, its `points`):', '',
                  '| run | frames back | latency ms p50 / p95 / max | e3D | offline e3D '
                  '(node / offline) | first model after | model age at the end | commit |',
                  '|---|---|---|---|---|---|---|---|']
        for key, r in sorted(node.items()):
            if 'frames' not in r:
                continue                        # an offline reference without its node run
            offline = r.get('offline_e3d_points')
            e3d_node = r.get('e3d_received_median', r['e3d_received'])
            versus = '-' if offline is None else \
                f'{fmt(offline)} ({fmt(e3d_node / offline, 3)})'
            lines.append(f'| {key} tracks | {r["frames_received"]} / {r["frames"]} | '
                         f'{fmt(r["latency_ms_p50"], 1)} / {fmt(r["latency_ms_p95"], 1)} / '
                         f'{fmt(r["latency_ms_max"], 1)} | {node_e3d(r)} | {versus} | '
                         f'{node_first_models(r)} frames | '
                         f'{r["diagnostics"].get("model age frames") or "-"} frames | '
                         f'{r.get("environment", {}).get("git") or "-"} |')
    return lines + load_table()


def node_e3d(run):
    """A node run's e3D: the median of its repeats with their range, or the one run's."""
    every = [r['e3d_received'] for r in run.get('runs', ()) if 'e3d_received' in r]
    if len(every) < 2:
        return fmt(run['e3d_received'])
    return f"{fmt(run['e3d_received_median'])} ({fmt(min(every))}-{fmt(max(every))}, " \
        f'{len(every)} runs)'


def node_first_models(run):
    """Frames before a node run's first model (each repeat's where recorded)."""
    every = [r['first_model_after_frames'] for r in run.get('runs', ())
             if r.get('first_model_after_frames') is not None]
    return ', '.join(every) if len(every) > 1 else \
        run['diagnostics'].get('first model after frames', '-')


#: the reliability.json runs of bench/load.py the live section shows
LOAD_RUNS = ('load', 'load_2min')


def load_table():
    """The node under sustained load (bench/load.py): frames, latency, memory slope."""
    runs = load(common.RESULTS, 'reliability') or {}
    runs = [(key, runs[key]) for key in LOAD_RUNS if key in runs]
    if not runs:
        return []
    lines = ['', 'The node under sustained load, recording (`python -m bench.load`; '
             '`--seconds 120 --key load_2min`):', '',
             '| run | tracks x Hz, s | frames sent / published | latency ms p50 / p95 / max | '
             'RSS MB/min after warm-up | recording complete | commit |',
             '|---|---|---|---|---|---|---|']
    for key, r in runs:
        lat = r['latency_ms']
        # a run whose node never accounted for every frame: its last diagnostics, and why
        published = r.get('frames published',
                          r.get('last_diagnostics', {}).get('frames published', '-'))
        complete = r.get('recording_complete', f'- ({r["error"]})' if 'error' in r else None)
        lines.append(f'| {key} | {r["points"]} x {r["rate"]:g}, {r["seconds"]:g} | '
                     f'{r["sent"]} / {published} | {lat["p50"]} / {lat["p95"]} / '
                     f'{lat["max"]} | {fmt(r["rss_mb"]["slope_mb_per_min"], 2)} | '
                     f'{complete} | {r.get("environment", {}).get("git", "-")} |')
    return lines


ROTATION_COLUMNS = (('dai', 'plain'), ('dai', 'weighted'), ('dai', 'weighted_beta0'),
                    ('dai', 'weighted_op_schedule'), ('dai', 'weighted_op_alone'),
                    ('op', 'plain'), ('op', 'weighted_op_schedule'))


def rotations_table(doc):
    """Akhter e3D (mocap) / e3D (synthetic) by rotations x shape setting; rotation error."""
    rows = doc['rows']
    cols = [c for c in ROTATION_COLUMNS
            if any((r['rotations'], r['shape']) == c for r in rows)]
    lines = ['| sequence | ' + ' | '.join(f'{m} R, {s}' for m, s in cols)
             + ' | rot. error Dai / OP (deg) | OP kept | published R-BMM / OP |',
             '|---|' + '---|' * (len(cols) + 3)]
    for seq in dict.fromkeys(r['sequence'] for r in rows):
        by = {(r['rotations'], r['shape']): r for r in rows if r['sequence'] == seq}
        key = 'e3d_akhter' if next(iter(by.values()))['family'] == 'mocap' else 'e3d'
        cells = [fmt(by[c][key]) if c in by else '-' for c in cols]
        dai, op = by.get(('dai', 'plain'), {}), by.get(('op', 'plain'), {})
        err = (f"{fmt(dai.get('rotation_error_deg'), 2)} / {fmt(op.get('rotation_error_deg'), 2)}"
               if dai.get('rotation_error_deg') is not None else '-')
        pub = (f"{fmt(dai['published_rbmm'])} / {fmt(dai['published_op'])}"
               if dai.get('published_op') is not None else '-')
        label = seq if key == 'e3d_akhter' else f'{seq} (e3D)'
        lines.append(f'| {label} | ' + ' | '.join(cells)
                     + f" | {err} | {fmt(op.get('kept_share'), 2)} | {pub} |")
    return lines


def grassmann_table(doc):
    """What the Grassmann branches change (bench.grassmann)."""
    lines = ['| sequence | setting | e3D | zeta_s / zeta_t share (max per iteration) | '
             'rank S# | points regrouped / block edges moved | Omega_s / Omega_t off-diag. |',
             '|---|---|---|---|---|---|---|']
    for r in doc['rows']:
        lines.append(f"| {r['sequence']} | {r['setting']} | {fmt(r['e3d'])} | "
                     f"{r['zeta_s_share_max']:.1e} / {r['zeta_t_share_max']:.1e} | "
                     f"{r['sharp_rank_final']} | {r['regrouped_points']} / "
                     f"{r['block_edges_moved']} | {fmt(r['omega_s_max_off_diagonal'], 2)} / "
                     f"{fmt(r['omega_t_max_off_diagonal'], 2)} |")
    return lines


def frontend_table(doc):
    t = doc.get('targets', {})
    lines = ['| sequence | method | step | tracks in frame 0 | error median / p95 px | '
             'frame-0 tracks alive at the end: where visible / where visible and within '
             f"{doc['rows'][0].get('facing_degrees', 75):.0f}° of face-on throughout | "
             'ms per frame (1 thread) at tracks (load average) | '
             'e3D tracked / perfect: orthographic solver; perspective | '
             'tracked, perspective / rigid (e3D) |',
             '|---|---|---|---|---|---|---|---|---|']
    for r in doc['rows']:
        timed = '-' if 'ms_per_frame_1_thread' not in r else (
            f"{fmt(r['ms_per_frame_1_thread'], 1)} at {r.get('timing_tracks_mean', 0):,.0f} "
            f"({fmt(r.get('load_average_1min'), 1)})")
        ratio = fmt(r.get('e3d_ratio'), 3)
        if 'e3d_ratio_perspective' in r:
            ratio += f"; {fmt(r['e3d_ratio_perspective'], 3)}"
        rigid = '-' if 'e3d_perspective_over_rigid' not in r else (
            f"{fmt(r['e3d_perspective_over_rigid'], 3)} ({fmt(r['e3d_tracked_perspective'])} / "
            f"{fmt(r['e3d_tracked_rigid'])})")
        facing = ('-' if 'alive_last_among_facing_always' not in r
                  else f"{100 * r['alive_last_among_facing_always']:.0f} %")
        if 'e3d_sheet_over_rigid' in r:
            rigid += (f"; surface sheet {fmt(r['e3d_sheet_over_rigid'], 3)} "
                      f"({fmt(r['e3d_tracked_sheet'])})")
        lines.append(f"| {r['sequence']} | {r['method']} | {r['step']} | {r['tracks_frame0']} | "
                     f"{fmt(r['error_median_px'], 2)} / {fmt(r['error_p95_px'], 2)} | "
                     f"{100 * r['alive_last_among_visible_last']:.0f} % / {facing} | "
                     f'{timed} | {ratio} | {rigid} |')
    face = doc.get('sequences', {}).get('face', {})
    if 'tracks_step2' in face:
        lines += ['', f"Tracks in the face's frame 0: {face['tracks_step2']:,} at step 2, "
                  f"{face['tracks_step1']:,} at step 1."]
    if t:
        lines += ['', f"Bars: face error {t['face_error_median_px']} / {t['face_error_p95_px']} "
                  f"px, sheet {t['sheet_error_median_px']} / {t['sheet_error_p95_px']} px, "
                  f"alive {100 * t['alive_last_among_visible_last']:.0f} %, "
                  f"{t['ms_per_frame_5000_tracks']} ms at 5,000 tracks, e3D ratio "
                  f"{t['e3d_ratio']}"
                  + (f", face perspective / rigid {t['face_perspective_over_rigid']}."
                     if 'face_perspective_over_rigid' in t else '.')]
    return lines


def camera_pipeline_table(doc):
    lines = ['| run | image | Fast DDS profile | frames back | image -> points p50 / p95 ms | '
             'load average | node: windows solved, frames from a sheet model (record 0732) |',
             '|---|---|---|---|---|---|---|']
    for key, run in doc.items():
        if not isinstance(run, dict) or 'environment' not in run:
            continue
        lat, node = run.get('image_to_points_ms', {}), run.get('node_diagnostics', {})
        load = max(run.get('load_average_before', [0])[0], run.get('load_average_after', [0])[0])
        lines.append(f"| {key} | {run['size'][1]} x {run['size'][0]} {run['encoding']} | "
                     f"{run.get('dds_profile', 'Fast DDS defaults')} | {run['points_back']} / "
                     f"{run['sent']} | {fmt(lat.get('p50'), 0)} / {fmt(lat.get('p95'), 0)} | "
                     f'{fmt(load, 1)} | {node.get("windows solved", "-")}, '
                     f'{node.get("frames from a sheet model", "-")} |')
    return lines


def kinect_paper_table(doc):
    gt = doc.get('ground_truth', {})
    lines = ['| tracks (frame 1 / complete / total) | ms per frame | reconstruction | e3D |',
             '|---|---|---|---|']
    cells = f"{doc['tracks_frame1']} / {doc['tracks_complete']} / {doc['tracks_total']}"
    for name, value in sorted((gt.get('e3d') or {}).items()):
        lines.append(f"| {cells} | {fmt(doc['ms_per_frame'], 0)} | {name} | {fmt(value)} |")
    auto = doc.get('surface_auto')
    if auto:
        chosen = ('a sheet (sheet_perspective)' if auto['sheet']
                  else 'not a sheet (whole_perspective)')
        lines += ['', f"surface 'auto' on the complete tracks: edge-length variation "
                  f"{fmt(auto['variation'])}, {chosen} (record 0726)."]
    if 'sheet_seconds' in doc:
        lines += ['', f"Wall seconds: whole {fmt(doc['solve_seconds'], 0)}, sheet_perspective "
                  f"{fmt(doc['sheet_seconds'], 0)} (records 0724, 0731), the live pipeline "
                  f"{fmt(doc['live_seconds'], 0)}."]
    live = doc.get('live')
    if live:
        p50, p95 = live['tracking_ms_p50_p95']
        lines += ['', f'The live pipeline: tracking {fmt(p50, 1)} / {fmt(p95, 1)} ms per frame '
                  f"(p50 / p95); from the sheet model (record 0732) {live['sheet_points']} of "
                  f"{doc['frames']} frames on points (the first: frame "
                  f"{live['first_sheet_frame']}), {live['sheet_refined']} on points/refined."]
    return lines


def perspective_table(doc):
    lines = ['| sequence | F x P | orthographic projections | first solve | perspective '
             '(reconstruct + K) | depth scale (record 0733) | rigid | perspective / orthographic '
             "| the same over draws of the tracks' rounding: median (range, draws) |",
             '|---|---|---|---|---|---|---|---|---|']
    for r in doc['rows']:
        lines.append(f"| {r['sequence']} | {r.get('F', '-')} x {r.get('P', '-')} | "
                     f"{fmt(r.get('e3d_orthographic_projection'))} | "
                     f"{fmt(r.get('e3d_first_solve_S'))} | {fmt(r.get('e3d_perspective'))} | "
                     f"{fmt(r.get('depth_scale'), 3)} | "
                     f"{fmt(r.get('e3d_rigid'))} | {fmt(r.get('ratio_to_orthographic'), 3)} | "
                     f"{over_draws(r.get('ratio_draws'))} |")
    return lines


def over_draws(ratios):
    """``median (low-high, n)`` of a row's ratios over draws, '-' without draws."""
    if not ratios:
        return '-'
    return (f'{fmt(statistics.median(ratios), 3)} ({fmt(min(ratios), 3)}-{fmt(max(ratios), 3)}, '
            f'{len(ratios)})')


def sheets_table(doc):
    options = list(dict.fromkeys(o for r in doc['rows'] for o in r['ratios']))
    lines = ['| sheet | projection | F x P | rigid | ' +
             ' | '.join(f'{o} (/ rigid)' for o in options) + ' |',
             '|---|---|---|---|' + '---|' * len(options)]
    for r in doc['rows']:
        lines.append(f"| {r['sequence']} | {r.get('projection', 'orthographic')} | {r['F']} x "
                     f"{r['P']} | {fmt(r['rigid'])} | "
                     + ' | '.join(f"{fmt(r[o])} ({fmt(r['ratios'][o], 2)})" if o in r else '-'
                                  for o in options)
                     + ' |')
    if doc.get('note'):
        lines += ['', doc['note']]
    runs = doc.get('runs') or []
    if len(runs) > 1:
        lines += ['', 'Rows merged from runs (`python -m bench.sheets --kinds ...` replaces its '
                  "kinds' rows): " + '; '.join(f"{', '.join(r['kinds'])}: {r['date']}, commit "
                                               f"{r['git']}" for r in runs) + '.']
    return lines


def track_streams_table(doc):
    lines = ['| sequence | stream seed | window track share | context share | refined e3D | '
             'coverage | CPU s |', '|---|---|---|---|---|---|---|']
    for r in doc['rows']:
        lines.append(f"| {r['sequence']} {doc['F']} x {doc['P']} | {r['seed']} | {r['share']} | "
                     f"{r['context']} | {fmt(r['e3d'])} | {fmt(r['coverage'], 3)} | "
                     f"{fmt(r['cpu_seconds'], 0)} |")
    return lines


def missing_table(doc):
    lines = ['| case | sequence | F x P | unseen | e3D | against | ratio (bar) |',
             '|---|---|---|---|---|---|---|']
    for r in doc['rows']:
        size = f"{r['F']} x {r['P']}"
        if r['case'] == 'back':
            lines.append(f"| real back, all tracks | {r['sequence']} | {size} | "
                         f"{fmt(r['unseen'], 3)} | {fmt(r['ours_all'])} over seen entries | "
                         f"rigid on the complete 126: {fmt(r['rigid_complete'])} (ours on them "
                         f"{fmt(r['ours_complete'])}) | {fmt(r['ratio'], 3)} ({r['bar']}); "
                         'rotations from all tracks completed '
                         f"{fmt(r['ratio_rotations_completed'], 3)}; oracle rotations "
                         f"{fmt(r['ratio_oracle_rotations'], 3)}; against rigid on all "
                         f"{r['P']} completed ({fmt(r['rigid_all'])}): "
                         f"{fmt(r['ours_all_over_rigid_all'], 3)} |")
        elif r['case'] == 'occlusion':
            lines.append(f"| occlusion blocks | {r['sequence']} s{r['seed']} | {size} | "
                         f"{fmt(r['unseen'], 3)} | {fmt(r['masked'])} (seen "
                         f"{fmt(r['masked_seen'])}); true rotations "
                         f"{fmt(r.get('masked_true_rotations'))} | complete: "
                         f"{fmt(r['complete'])}; true rotations "
                         f"{fmt(r.get('complete_true_rotations'))} | {fmt(r['ratio'], 3)} "
                         f"({r['bar']}); true rotations {fmt(r.get('ratio_true_rotations'), 3)} |")
        else:
            weighed = 'applied' if r.get('auto_weighed') else 'not applied'
            auto = f"'auto' {fmt(r['auto'])} (weights {weighed}); " if 'auto' in r else ''
            lines.append(f"| 5 % drifting 20 px | {r['sequence']} s{r['seed']} | {size} | - | "
                         f"{auto}'never' {fmt(r['never'])}; 'cauchy' {fmt(r['cauchy'])} (found "
                         f"{r['found']}/{r['drifting']}, clean touched {r['clean_touched']}); "
                         f"true rotations, 'never' {fmt(r.get('never_true_rotations'))} | "
                         f"clean: {fmt(r['clean'])}; true rotations "
                         f"{fmt(r.get('clean_true_rotations'))} | "
                         + (f"auto {fmt(r['ratio_auto'], 3)}; " if 'auto' in r else '')
                         + f"never {fmt(r['ratio_never'], 3)}; cauchy {fmt(r['ratio_cauchy'], 3)} "
                         f"({r['bar']}); true rotations {fmt(r.get('ratio_true_rotations'), 3)} |")
    return lines


#: (suite, heading, what the table shows, the table's lines from the suite's JSON)
SECTIONS = (('accuracy', 'Accuracy', 'e3D; "A": Akhter\'s metric, the one of the published mocap '
             'numbers; PTA K chosen against ground truth', accuracy_table),
            ('noise', 'Noise', '', noise_table),
            ('parameters', 'Parameters and ablation', '', parameters_table),
            ('scale', 'Scale', 'A fresh process per case; exponents: CPU time / memory',
             scale_table),
            ('streaming', 'Streaming', 'The sliding windows, no ROS', streaming_table),
            ('live', 'Live', 'Tracking on arrival, windows behind it; e3D; offline, each window '
             'solved as it closes', live_table),
            ('rotations', 'Rotations and shape norm', "Akhter's metric on mocap; Dai's vs Organic "
             "Priors' rotations, plain vs OP's weighted partial norm; records 0500, 0501",
             rotations_table),
            ('grassmann', 'Grassmann branches probed', 'Record 0502', grassmann_table),
            ('frontend', 'Camera front end', 'Rendered pinhole sequences, 640 x 480, tracks '
             'against the true projections (`python -m bench.frontend`)', frontend_table),
            ('frontend_seeds', 'Camera front end: other seeds', 'Other faces and sheets '
             '(identities, expressions, textures, turns), the same measures without the timing '
             '(`python -m bench.frontend --seeds 1,2,3`)', frontend_table),
            ('camera_pipeline', 'Images to points over DDS', 'Images at 30 Hz -> tracker node '
             '-> reconstruction node (`python -m bench.camera_pipeline`)', camera_pipeline_table),
            ('kinect_paper', "The paper's kinect_paper sequence", 'From its 191 images; e3D on '
             'the ground truth located in it, records 0622, 0722, 0723, 0724, 0731 '
             '(`python -m bench.kinect_paper`)',
             kinect_paper_table),
            ('perspective', 'Perspective', 'The projective-depth iteration; e3D with a '
             'per-frame scale (`python -m bench.perspective`)', perspective_table),
            ('perspective_faces', 'Perspective: other faces', 'Rendered identities and '
             'expressions held back from the choices (records 0716, 0730), the same measures '
             '(`python -m bench.perspective --seeds 3,4,5,6,7`)', perspective_table),
            ('missing', 'Missing data and tracker errors', 'Unseen entries and drifting '
             'tracks in the offline solver; record 0800, 0801, 0807, 0809, 0811, 0812, '
             '0814, 0816 (`python -m bench.missing`)',
             missing_table),
            ('sheets', 'Sheets', 'e3D and its ratio to rigid factorisation per option '
             '(`python -m bench.sheets`)', sheets_table),
            ('track_streams', 'Live windows on tracks that die and are born', 'The live '
             "pipeline's `points/refined` against the truth of the entries it publishes; "
             'coverage: their share of the tracked entries; record 0432 '
             '(`python -m bench.track_streams`)', track_streams_table))


def plot_links(doc, results, page_dir):
    """A 'Plots:' line linking ``doc``'s PNG files (paths relative to ``page_dir``), or []."""
    names = [n for n in doc.get('plots') or [] if (Path(results) / n).is_file()]
    if not names:
        return []
    here = Path(results).resolve()
    links = [f'[{Path(n).stem}]({Path(os.path.relpath(here / n, page_dir)).as_posix()})'
             for n in names]
    return ['Plots: ' + ', '.join(links), '']


def anchor(name):
    """The GitHub anchor of the heading ``name``."""
    return ''.join(c for c in name.lower().replace(' ', '-') if c.isalnum() or c == '-')


def sections(results):
    """``[(heading, detail, make, doc)]`` of the suites with rows in ``results``."""
    found = [(name, detail, make, load(results, suite))
             for suite, name, detail, make in SECTIONS]
    return [s for s in found if s[3] and (s[3].get('rows') or 'rows' not in s[3])]


def markdown(results, page_dir='.'):
    """A contents line, then the tables of every suite with results in ``results``, one
    section each (plots linked relative to ``page_dir``)."""
    present = sections(results)
    out = ['Contents: ' + ', '.join(f'[{name}](#{anchor(name)})' for name, *_ in present), '']
    for name, detail, make, doc in present:
        env = doc.get('environment') or next(
            (v['environment'] for v in doc.values() if isinstance(v, dict)
             and 'environment' in v), {})
        out += [f'## {name}', '', (f'{detail}. ' if detail else '')
                + f'From the {doc.get("mode", "one")} run of {env.get("date", "?")}, commit '
                f'{env.get("git", "?")}, {env.get("cpus", "?")} CPUs{machine_note(env)}.', '']
        out += make(doc) + [''] + plot_links(doc, results, page_dir)
    return '\n'.join(out).rstrip('\n') + '\n'


def machine_note(env):
    """`` (CPU model, BLAS kernel ...)`` of the machine a run was taken on, where recorded."""
    kernel = env.get('blas_kernel')
    parts = [p for p in (env.get('cpu_model'), kernel and f'BLAS kernel {kernel}') if p]
    return f" ({', '.join(parts)})" if parts else ''


def page(results, page_dir='.'):
    """The whole results page: the header, then :func:`markdown`."""
    return '\n'.join(HEADER) + '\n\n' + markdown(results, page_dir)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.table', description=__doc__)
    parser.add_argument('--results', default=str(common.RESULTS), help='folder of suite JSON')
    parser.add_argument('--write', metavar='FILE',
                        help=f'write the page to FILE (the one linked from the README: '
                        f'{PAGE.relative_to(common.REPO)})')
    args = parser.parse_args(argv)
    if not args.write:
        print(page(args.results), end='')
        return 0
    path = Path(args.write)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page(args.results, path.parent.resolve()))
    print(f'{path}: benchmark results page written')
    return 0


if __name__ == '__main__':
    sys.exit(main())
