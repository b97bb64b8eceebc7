"""The graph benchmark's figures.

Latency per stage and end to end, drops by reason, CPU per frame, the table.
"""

from __future__ import annotations

import numpy as np

from memo_ros.tools.benchmarks.graph_probe import FrameTrace, Probe, Restamper
from memo_ros.tools.benchmarks.graph_processes import cpu_between
from memo_ros.tools.benchmarks.report import percentiles

SETTLE = 2.0  # s after matching (the nodes' readers match the players' writers); idle CPU
SUSTAINED = 0.98  # output rate at least this fraction of the input rate: the graph keeps pace


TARGETS = {30.0: 'zero drops, end-to-end p99 < 50 ms, sustained', 60.0: 'drops < 1 %, sustained'}


def drop_reason(trace: FrameTrace, cameras: list[str]) -> str | None:
    """Why a frame has no joint_states (None: it has)."""
    if trace.joint_states is not None:
        return None
    if trace.outcome is not None:
        return (
            f'tracker: {trace.outcome}'
            if trace.outcome != 'tracking'
            else 'joint_states not received here'
        )
    if not trace.contours and trace.assignment is None:
        return 'no contours nor assignment (lost before or in the nodes)'
    return (
        f'never finished by the tracker (contours {len(trace.contours)}/{len(cameras)}, '
        f'assignment {"yes" if trace.assignment is not None else "no"})'
    )


def rate_figures(
    rate_hz: float,
    cameras: list[str],
    warmup: int,
    restamper: Restamper,
    probe: Probe,
    pids: dict[int, str],
    window: dict,
    peak_rss: dict[int, float | None],
) -> dict:
    """Latencies, rates, drops and per-process figures of one rate's run from the frame traces."""
    ms = 1e-6
    frames = sorted(restamper.frames.values(), key=lambda t: t.index)
    timed = [t for t in frames if t.index >= warmup]
    contours_last = [
        ms * (max(t.contours.values()) - t.stamp) for t in timed if len(t.contours) == len(cameras)
    ]
    e2e = [ms * (t.joint_states - t.stamp) for t in timed if t.joint_states is not None]
    # the tracker's own share: from its last input's publication to joint_states
    tracker_stage = [
        ms * (t.joint_states - max([*t.contours.values(), t.assignment or 0]))
        for t in timed
        if t.joint_states is not None and t.contours
    ]
    drops: dict[str, int] = {}
    outcomes: dict[str, int] = {}
    for t in timed:
        if (reason := drop_reason(t, cameras)) is not None:
            drops[reason] = drops.get(reason, 0) + 1
        if t.outcome is not None:
            outcomes[t.outcome] = outcomes.get(t.outcome, 0) + 1
    out_stamps = sorted(t.joint_states for t in timed if t.joint_states is not None)
    in_span = (timed[-1].stamp - timed[0].stamp) * 1e-9 if len(timed) > 1 else 0.0
    out_span = (out_stamps[-1] - out_stamps[0]) * 1e-9 if len(out_stamps) > 1 else 0.0
    tenth = max(len(e2e) // 10, 1)
    result = {
        'rate_hz': rate_hz,
        'frames_published': len(frames),
        'warmup_frames': min(warmup, len(frames)),
        'timed_frames': len(timed),
        'frames_out': len(e2e),
        'frames_dropped': len(timed) - len(e2e),
        'drop_pct': 100.0 * (len(timed) - len(e2e)) / len(timed) if timed else None,
        'drops': dict(sorted(drops.items(), key=lambda kv: -kv[1])),
        'outcomes': outcomes,
        'contours_missing': {c: sum(c not in t.contours for t in timed) for c in cameras},
        'input_fps': (len(timed) - 1) / in_span if in_span > 0 else None,
        'output_fps': (len(out_stamps) - 1) / out_span if out_span > 0 else None,
        'latency_ms': {
            # the player's own lag: its images go out from another thread than the camera_info
            # that stamps the frame
            'images_out': percentiles(
                [ms * (t.images_out - t.stamp) for t in timed if t.images_out is not None]
            ),
            'contours': percentiles(contours_last),
            'contours_per_camera': {
                c: percentiles([ms * (t.contours[c] - t.stamp) for t in timed if c in t.contours])
                for c in cameras
            },
            'assignment': percentiles(
                [ms * (t.assignment - t.stamp) for t in timed if t.assignment is not None]
            ),
            'joint_states': percentiles(e2e),
            'processed': percentiles(
                [ms * (t.processed - t.stamp) for t in timed if t.processed is not None]
            ),
        },
        'stage_ms': {
            'contour_node': percentiles(contours_last),
            'selector_node': percentiles(
                [ms * (t.assignment - t.stamp) for t in timed if t.assignment is not None]
            ),
            'tracker_node': percentiles(tracker_stage),
        },
        'e2e_drift_ms': float(np.median(e2e[-tenth:]) - np.median(e2e[:tenth])) if e2e else None,
        'outputs_without_frame': probe.unknown,
        # every timed frame, for plots: bag index, tracker outcome, latencies (ms, None: none)
        'per_frame': {
            'index': [t.index for t in timed],
            'outcome': [t.outcome for t in timed],
            'images_out_ms': [
                round(ms * (t.images_out - t.stamp), 2) if t.images_out else None for t in timed
            ],
            'contours_ms': [
                round(ms * (max(t.contours.values()) - t.stamp), 2) if t.contours else None
                for t in timed
            ],
            'assignment_ms': [
                round(ms * (t.assignment - t.stamp), 2) if t.assignment else None for t in timed
            ],
            'joint_states_ms': [
                round(ms * (t.joint_states - t.stamp), 2) if t.joint_states else None
                for t in timed
            ],
        },
        'messages_published': dict(sorted(restamper.messages.items())),
        'processes': _process_figures(
            pids, window, peak_rss, _frames_handled(timed, cameras), probe.frame_ms
        ),
        'nodes': _node_figures(probe.diagnostics, restamper.messages, pids),
    }
    per_frame = [
        p['cpu_ms_per_frame'] for p in result['processes'] if p['process'] in result['nodes']
    ]
    # what one frame costs when every node handles it: the CPU the rate needs, whatever the
    # machine's load
    result['nodes_cpu_ms_per_frame'] = (
        float(sum(per_frame)) if per_frame and None not in per_frame else None
    )
    result['target'] = target_check(result)
    return result


def _frames_handled(timed: list[FrameTrace], cameras: list[str]) -> dict[str, int]:
    """Time frames each node worked on.

    Contours published, assignments published, frames tracked (not skipped or late).
    """
    handled = {f'{c}/contour_node': sum(c in t.contours for t in timed) for c in cameras}
    handled['selector_node'] = sum(t.assignment is not None for t in timed)
    handled['tracker_node'] = sum(t.outcome not in (None, 'skipped', 'late') for t in timed)
    return handled


def _process_figures(
    pids: dict[int, str],
    window: dict,
    peak_rss: dict[int, float | None],
    handled: dict[str, int],
    frame_ms: dict[str, list[tuple[float, float]]],
) -> list[dict]:
    """Per process.

    CPU % over the timed frames (first timed frame published to the last one the tracker finished)
    and while idle before playback, CPU per frame handled, the median of the frame times the node
    reported on /diagnostics during the timed frames (wall time of one frame's work), peak RSS.
    """
    rows = []
    start = window.get('start')
    for pid, label in pids.items():
        busy = cpu_between(start, window.get('end'), pid)
        idle = cpu_between(*window.get('idle', (None, None)), pid)
        frames = handled.get(label)
        reported = [ms for t, ms in frame_ms.get(label, []) if start and t >= start[0]]
        rows.append(
            {
                'process': label,
                'pid': pid,
                'cpu_pct': 100.0 * busy[0] / busy[1] if busy else None,
                'idle_cpu_pct': 100.0 * idle[0] / idle[1] if idle else None,
                'frames_handled': frames,
                'cpu_ms_per_frame': 1000.0 * busy[0] / frames if busy and frames else None,
                'reported_frame_ms': float(np.median(reported)) if reported else None,
                'peak_rss_mb': peak_rss.get(pid),
            }
        )
    return rows


def _node_figures(
    diagnostics: dict[str, dict], messages: dict[str, int], pids: dict[int, str]
) -> dict:
    """Each node's counters from its last /diagnostics and its drops by reason.

    The counters cover the whole run, warm-up included.
    """
    nodes = {}
    for label in pids.values():
        if label not in diagnostics:
            continue
        values = diagnostics[label]['values']
        counters = {
            k: int(v)
            for k, v in values.items()
            if v.lstrip('-').isdigit() and not k.startswith('dropped.')
        }
        dropped = {
            k.removeprefix('dropped.'): int(v)
            for k, v in values.items()
            if k.startswith('dropped.') and k != 'dropped.total' and int(v)
        }
        entry = {'counters': counters, 'dropped': dropped}
        if label.endswith(
            '/contour_node'
        ):  # images that never reached the node (best-effort transport)
            published = messages.get(f'/{label.split("/")[0]}/image_raw', 0)
            entry['images_lost_before_node'] = published - counters.get('frames_in', 0)
        if 'last_frame_ms' in values:
            entry['last_frame_ms'] = float(values['last_frame_ms'])
        nodes[label] = entry
    return nodes


def target_check(r: dict) -> dict | None:
    """Return the issue's target for this rate, and whether this run met it.

    None for rates without one.
    """
    target = TARGETS.get(r['rate_hz'])
    if target is None or not r['timed_frames']:
        return None
    sustained = r['output_fps'] is not None and r['output_fps'] >= SUSTAINED * r['rate_hz']
    e2e = r['latency_ms']['joint_states']
    if r['rate_hz'] == 30.0:
        met = sustained and r['frames_dropped'] == 0 and e2e is not None and e2e['p99'] < 50.0
    else:
        met = sustained and r['drop_pct'] < 1.0
    return {'target': target, 'sustained': sustained, 'met': bool(met)}


def _f(value, spec: str = '.1f') -> str:
    return '-' if value is None else format(value, spec)


def _p(stats: dict | None) -> str:
    return '-' if stats is None else f'{stats["p50"]:.1f}/{stats["p99"]:.1f}'


def print_graph_benchmark(report: dict) -> None:
    """Per rate.

    Latencies, rates, drops; then per process CPU and memory; then the nodes' drop counters.
    """
    rows = report['rates']
    recorded = (
        'each rate its own bag, simulated at that rate (the person moves as before such a camera)'
        if report['bag'] == 'simulated'
        else f'recorded at {report["bag_hz"]:.0f} Hz, played faster or slower'
    )
    print(
        f'graph: {report["scenario"]} ({report["bag"]}), {len(report["cameras"])} cameras '
        f'{report["size"]}, {report["bag_frames"]} frames, {recorded}; '
        '`memo-ros launch STUDIO`, best-effort images (as from live cameras); ROS_DOMAIN_ID '
        f'{report["domain_id"]}'
    )
    print(
        'every frame restamped to the wall clock when its first image goes out; latency = output '
        f'publication (DDS source timestamp) - stamp; the first {report["warmup_frames"]} frames '
        'are warm-up (background learning, tracker start), not counted'
    )
    if report.get('player_shm_segment_mb'):
        print(
            f'the player (this process, all cameras) has a {report["player_shm_segment_mb"]:.0f} '
            'MiB Fast DDS '
            f'shared-memory segment, as separate camera drivers would have between them'
        )
    print()
    print(
        f'{"rate":>5} {"in/s":>5} {"out/s":>6} {"out/timed":>10} {"drop %":>6}  '
        f'{"contours":>11} {"selector":>11} {"tracker":>11} {"end to end":>11} {"drift":>6}  '
        'target'
    )
    print(
        f'{"Hz":>5} {"":>5} {"":>6} {"":>10} {"":>6}  {"p50/p99 ms":>11} {"p50/p99 ms":>11} '
        f'{"p50/p99 ms":>11} {"p50/p99 ms":>11} {"ms":>6}'
    )
    for r in rows:
        target = r['target']
        verdict = (
            '-'
            if target is None
            else f'{"met" if target["met"] else "NOT met"} ({target["target"]})'
        )
        print(
            f'{r["rate_hz"]:>5.0f} {_f(r["input_fps"]):>5} {_f(r["output_fps"]):>6} '
            f'{r["frames_out"]:>4}/{r["timed_frames"]:<5} {_f(r["drop_pct"], ".2f"):>6}  '
            f'{_p(r["stage_ms"]["contour_node"]):>11} {_p(r["stage_ms"]["selector_node"]):>11} '
            f'{_p(r["stage_ms"]["tracker_node"]):>11} {_p(r["latency_ms"]["joint_states"]):>11} '
            f'{_f(r["e2e_drift_ms"]):>6}  {verdict}'
        )
    print()
    print(
        "contours = publication of the last of the cameras' contours; selector = the assignment "
        '(it starts on '
        'camera_info, beside the contour nodes); tracker = joint_states after the later of the '
        'two; end to end = '
        'joint_states; drift = median end to end of the last tenth of the frames - of the first '
        'tenth'
    )
    print()
    for r in rows:
        drops = ', '.join(f'{n} {reason}' for reason, n in r['drops'].items()) or 'none'
        missing = ', '.join(f'{c} {n}' for c, n in r['contours_missing'].items() if n) or 'none'
        print(
            f'{r["rate_hz"]:.0f} Hz: frames without joint_states: {drops}; contours missing: '
            f'{missing}'
        )
    print()
    labels = list(dict.fromkeys(p['process'] for r in rows for p in r['processes']))
    columns = ('cpu_pct', 'idle_cpu_pct', 'cpu_ms_per_frame', 'reported_frame_ms', 'peak_rss_mb')
    print(f'{"":<26}' + ''.join(' ' + format(f'{r["rate_hz"]:.0f} Hz', '<38') for r in rows))
    print(
        f'{"process":<26}'
        + f' {"CPU %":>6} {"idle %":>6} {"CPU ms/f":>8} {"frame ms":>8} {"RSS MB":>6}' * len(rows)
    )
    for label in labels:
        line = f'{label:<26}'
        for r in rows:
            p = next((p for p in r['processes'] if p['process'] == label), {})
            line += ''.join(
                f' {_f(p.get(k), ".0f" if k == "peak_rss_mb" else ".1f"):>{w}}'
                for k, w in zip(columns, (6, 6, 8, 8, 6))
            )
        print(line)
    line = f'{"all":<26}'
    for r in rows:
        busy = sum(p['cpu_pct'] or 0.0 for p in r['processes'])
        idle = sum(p['idle_cpu_pct'] or 0.0 for p in r['processes'])
        line += f' {busy:>6.1f} {idle:>6.1f} {"":>8} {"":>8} {"":>6}'
    print(line)
    for r in rows:
        if r['nodes_cpu_ms_per_frame'] is not None:
            need = r['nodes_cpu_ms_per_frame'] * r['rate_hz'] / 1000.0
            print(
                f'{r["rate_hz"]:.0f} Hz: one frame through every node costs '
                f'{r["nodes_cpu_ms_per_frame"]:.1f} ms '
                f'of CPU (sum of CPU ms/f), so {r["rate_hz"]:.0f} frames/s need {need:.2f} cores '
                f'({report.get("cpus", "?")} here)'
            )
    print(
        'CPU % of one core, from the first timed frame to the last frame the tracker finished; '
        'idle % = the graph up '
        f'and fed nothing ({SETTLE:g} s before playback); CPU ms/f = CPU time per frame the node '
        'worked on '
        '(tracker: tracked, not skipped); frame ms = median of the per-frame work time the node '
        'reports on '
        '/diagnostics (once a second); RSS = peak (VmHWM)'
    )
    for r in rows:
        growth = [m for m in r.get('memory', []) if m['growth_mb'] is not None]
        if growth:
            print(
                f'{r["rate_hz"]:.0f} Hz, bag played {r.get("loops", 1)}x: resident memory warm '
                '-> end (growth), MB: '
                + ', '.join(
                    f'{m["process"]} {m["rss_warm_mb"]:.0f} -> {m["rss_end_mb"]:.0f} '
                    f'({m["growth_mb"]:+.1f})'
                    for m in growth
                )
            )
    print()
    print('node drop counters (whole run, warm-up included), from /diagnostics:')
    for r in rows:
        for label, n in r['nodes'].items():
            dropped = ', '.join(f'{k} {v}' for k, v in n['dropped'].items())
            lost = n.get('images_lost_before_node')
            extra = f'; images lost before the node {lost}' if lost else ''
            print(f'  {r["rate_hz"]:.0f} Hz {label:<24} {dropped or "none"}{extra}')
