"""
Where sim_node's late sends come from: a trace of its pacing loop on a live run.

    .venv/bin/python -m benchmarks.performance.trace_pacing [--seconds 30] [--scene shell_robot]
        [--marker] [--out /tmp/pacing_trace.json] [--analyse-only]

Runs sim_node as bench_sim_node does (a subprocess in an isolated ROS domain, real DDS, the idle
process wake_floor.py beside it), but with sim_node started through this module, which wraps the
pacing thread's steps with timestamps (time.monotonic, the pacing loop's own clock) before
calling sim_node's main: each wait of the pacing loop (asked delay and return time), each tick
(the physics steps inside it, the periods it ran), each publish call (topic, thread), /diagnostics
(and the health snapshot under the session's lock), the mantle Marker's build and send, each
executor spin_once and the garbage collector's passes (gc.callbacks). The trace is written when
sim_node exits; the analysis then takes /clock's publish calls as the send times (the source
timestamp bench_sim_node reads is stamped inside that call), measures each send's lateness
against the pacer's wall grid and the period jitter |T - T0| as the benchmark does, and lists what
ran in the interval before the sends that made the worst periods. Prints a report; not a test and
not part of sim_node (the wrappers are installed only in this process's sim_node).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import threading
import time

import numpy as np

TRACE_ENV = 'PULSEJET_PACING_TRACE'


# -- inside sim_node ------------------------------------------------------------------------------
def install(records: list) -> None:
    """Wrap sim_node's pacing steps so that each appends (kind, t0, t1, extra) to `records`."""
    import gc

    from pulsejet_sim.engine import live_loop
    from pulsejet_sim.engine import session as eng
    from pulsejet_sim.engine import simulation
    from pulsejet_sim.ros import sim_node as sn
    from pulsejet_sim.ros import state_publisher as sp
    import rclpy.executors
    import rclpy.publisher

    mono = time.monotonic
    rec = records.append
    gc_start = [0.0]

    def on_gc(phase, info):
        if phase == 'start':
            gc_start[0] = mono()
        else:
            rec(('gc', gc_start[0], mono(), info['generation']))

    gc.callbacks.append(on_gc)

    class TracedEvent(threading.Event):

        def wait(self, timeout=None):
            t0 = mono()
            woken = super().wait(timeout)
            rec(('wait', t0, mono(), [-1.0 if timeout is None else timeout, bool(woken)]))
            return woken

    loop_init = live_loop.LiveLoop.__init__

    def traced_loop_init(self, *args, **kwargs):
        loop_init(self, *args, **kwargs)
        self._wake = TracedEvent()

    live_loop.LiveLoop.__init__ = traced_loop_init

    def wrap(owner, name, kind, extra=None):
        original = getattr(owner, name)

        def traced(*args, **kwargs):
            t0 = mono()
            try:
                return original(*args, **kwargs)
            finally:
                rec((kind, t0, mono(), extra(*args) if extra else threading.current_thread().name))

        setattr(owner, name, traced)

    def pacer_state(node, *_):
        pacer = node.session._pacer
        return None if pacer is None else [pacer.t0, pacer.steps_done, pacer.dt_s]

    tick = sn.SimNode._tick

    def traced_tick(self, now):
        t0 = mono()
        events = tick(self, now)
        rec(('tick', now, mono(), [t0] + (pacer_state(self) or [])))
        return events

    sn.SimNode._tick = traced_tick
    wrap(sn.SimNode, '_emit', 'emit')
    wrap(sn.SimNode, '_publish_diagnostics', 'diagnostics')
    wrap(eng.Session, 'health', 'health')
    wrap(eng.Session, 'accept', 'accept')
    wrap(simulation.Simulation, 'step', 'physics', lambda sim, n, *a: n)
    wrap(simulation.Simulation, 'energy_ledger', 'energy_ledger')
    wrap(sp.StatePublisher, '_send_marker', 'marker')
    wrap(rclpy.executors.SingleThreadedExecutor, 'spin_once', 'spin_once')
    from pulsejet_sim.engine import outbox

    wrap(outbox.TimedOutbox, 'put', 'outbox put', lambda box, due, calls: due)
    wrap(outbox.TimedOutbox, '_call', 'outbox send')
    topics = {}

    def topic_of(publisher, *_):
        key = id(publisher)
        if key not in topics:
            topics[key] = publisher.topic_name
        return [topics[key], threading.current_thread().name]

    wrap(rclpy.publisher.Publisher, 'publish', 'publish', topic_of)


def node_main() -> int:
    """Run sim_node with the wrappers; write the trace to $PULSEJET_PACING_TRACE at exit."""
    records: list = []
    install(records)
    from pulsejet_sim.ros import sim_node

    try:
        return sim_node.main()
    finally:
        with open(os.environ[TRACE_ENV], 'w') as f:
            json.dump(records, f)


# -- the analysis -----------------------------------------------------------------------------
def analyse(records: list, period_s: float, window=None) -> str:
    """Return the report (see the module docstring); window: (t0, t1) monotonic, or all."""
    by_kind = collections.defaultdict(list)
    for kind, t0, t1, extra in records:
        by_kind[kind].append((t0, t1, extra))
    sends = [
        (t0, t1) for t0, t1, (topic, _) in by_kind['publish'] if topic == '/clock'
    ]
    sends = np.array(sends)
    # the pacer grid at each tick that ran periods: the wall end of the last period it ran
    ticks = [
        (now, t1, ex) for now, t1, ex in by_kind['tick'] if len(ex) == 4
    ]
    if window is not None:
        sends = sends[(sends[:, 0] >= window[0]) & (sends[:, 0] <= window[1])]
    clock = sends[:, 0]
    grid_t0, _, grid_dt = ticks[-1][2][1:]
    lateness = clock - grid_t0 - np.round((clock - grid_t0) / grid_dt - 0.5) * grid_dt
    # the period each send ended: its lateness against the grid's period end
    periods = np.diff(clock)
    jitter = np.abs(periods - period_s)
    lines = []

    def pct(a, unit=1e3):
        return (
            f'p50 {np.percentile(a, 50) * unit:.3f} / p90 {np.percentile(a, 90) * unit:.3f} /'
            f' p99 {np.percentile(a, 99) * unit:.3f} / max {a.max() * unit:.3f} ms'
        )

    lines.append(f'/clock sends: {clock.size}; period jitter |T - T0|: {pct(jitter)}')
    lines.append(f'send lateness against the pacer grid: {pct(lateness)}')
    # the pacing thread's waits: how late each returned after the delay it asked for
    waits = np.array(
        [(t0, t1, ex[0]) for t0, t1, ex in by_kind['wait'] if ex[0] > 0 and not ex[1]]
    )
    wake_late = waits[:, 1] - waits[:, 0] - waits[:, 2]
    lines.append(f'pacing wait returns late by: {pct(wake_late)} ({len(waits)} timed-out waits)')
    for kind in ('outbox put', 'outbox send', 'physics', 'emit', 'diagnostics', 'health',
                 'energy_ledger', 'marker', 'spin_once', 'gc', 'accept'):
        spans = np.array([(t0, t1) for t0, t1, _ in by_kind[kind]])
        if spans.size:
            d = spans[:, 1] - spans[:, 0]
            lines.append(f'{kind}: {len(d)} calls, duration {pct(d)}')
    # where in the publication period each kind of work starts (ms after the pacer's grid
    # point): a kind at a fixed phase meets the sends every time or never
    lines.append(f'send (/clock) phase in the period: p5 / p50 / p95'
                 f' {" / ".join(f"{v:.2f}" for v in np.percentile(lateness * 1e3, [5, 50, 95]))}'
                 ' ms')
    for kind in ('health', 'diagnostics', 'marker', 'spin_once'):
        starts = np.array([t0 for t0, _, _ in by_kind[kind]])
        if window is not None and starts.size:
            starts = starts[(starts >= window[0]) & (starts <= window[1])]
        if starts.size:
            phase = ((starts - grid_t0) / grid_dt % 1.0) * grid_dt * 1e3
            lines.append(
                f'{kind} start phase in the period: p5 / p50 / p95'
                f' {" / ".join(f"{v:.2f}" for v in np.percentile(phase, [5, 50, 95]))} ms'
                f' ({starts.size} starts)'
            )
    gens = collections.Counter(ex for _, _, ex in by_kind['gc'])
    lines.append(f'gc passes by generation: {dict(gens)}')
    # decompose each send: the wait before it, the tick's start, its physics, /clock's call
    wait_end = waits[:, 1]
    tick_arr = np.array([(now, ex[0], t1) for now, t1, ex in ticks])
    phys = np.array([(t0, t1) for t0, t1, _ in by_kind['physics']])
    pub_other = np.array(
        [(t0, t1) for t0, t1, (topic, thread) in by_kind['publish'] if topic != '/clock']
    )
    rows = []
    for i in range(clock.size):
        c = clock[i]
        grid = c - lateness[i]
        j = np.searchsorted(wait_end, c) - 1  # the last wait that returned before the send
        k = np.searchsorted(tick_arr[:, 0], c) - 1
        p = np.searchsorted(phys[:, 1], c) - 1
        rows.append(
            (
                lateness[i],
                wait_end[j] - grid if j >= 0 else np.nan,  # the wait's return against the grid
                tick_arr[k, 1] - tick_arr[k, 0] if k >= 0 else np.nan,  # lock + inbox
                phys[p, 1] - phys[p, 0] if p >= 0 else np.nan,
                c - phys[p, 1] if p >= 0 else np.nan,  # build + the publishes before /clock
            )
        )
    rows = np.array(rows)
    names = ('lateness', 'wake vs grid', 'tick entry', 'physics', 'physics end -> /clock')
    lines.append('')
    lines.append('each send decomposed (ms): ' + ', '.join(
        f'{n} p50 {np.nanpercentile(rows[:, m], 50) * 1e3:.3f} p99'
        f' {np.nanpercentile(rows[:, m], 99) * 1e3:.3f}' for m, n in enumerate(names)))
    # the worst 1 % of sends by lateness: what ran in the 12 ms before each
    worst = np.argsort(lateness)[::-1][: max(5, clock.size // 100)]
    lines.append('')
    lines.append(f'the {len(worst)} latest sends (lateness, decomposition, events in the'
                 ' 12 ms before, ms relative to the send):')
    spans = {
        kind: np.array([(t0, t1) for t0, t1, _ in by_kind[kind]])
        for kind in ('health', 'marker', 'spin_once', 'gc', 'energy_ledger', 'accept')
    }
    spans['other publish'] = pub_other
    counts = collections.Counter()
    base = collections.Counter()
    for i in range(clock.size):
        for kind, s in spans.items():
            if s.size and np.any((s[:, 1] > clock[i] - 0.012) & (s[:, 0] < clock[i])):
                base[kind] += 1
    for i in sorted(worst, key=lambda m: clock[m]):
        c = clock[i]
        near = []
        for kind, s in spans.items():
            if not s.size:
                continue
            hit = (s[:, 1] > c - 0.012) & (s[:, 0] < c)
            if kind == 'other publish':
                hit &= True
            if np.any(hit):
                counts[kind] += 1
                if kind != 'other publish':
                    near += [
                        f'{kind} [{(a - c) * 1e3:+.2f}, {(b - c) * 1e3:+.2f}]'
                        for a, b in s[hit]
                    ]
        r = rows[i]
        lines.append(
            f'  t={c - clock[0]:7.3f} s late {r[0] * 1e3:6.3f}: wake {r[1] * 1e3:6.3f}, tick'
            f' entry {r[2] * 1e3:5.3f}, physics {r[3] * 1e3:5.3f}, ->/clock'
            f' {r[4] * 1e3:5.3f}; ' + '; '.join(near)
        )
    lines.append('')
    lines.append('event within the 12 ms before a send: among the latest 1 % / among all sends')
    for kind in spans:
        lines.append(
            f'  {kind}: {counts[kind]}/{len(worst)} = {counts[kind] / len(worst):.0%}'
            f' / {base[kind]}/{clock.size} = {base[kind] / clock.size:.0%}'
        )
    return '\n'.join(lines)


def main(argv=None) -> int:
    if argv is None and sys.argv[1:2] == ['--node']:
        sys.argv.pop(1)
        return node_main()
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seconds', type=float, default=30.0)
    ap.add_argument('--scene', default='shell_robot')
    ap.add_argument('--marker', action='store_true', help='subscribe to the mantle Marker')
    ap.add_argument('--out', default='/tmp/pacing_trace.json')
    ap.add_argument('--publish-delay-periods', type=float, default=None)
    ap.add_argument('--analyse-only', action='store_true', help='analyse the trace in --out')
    args = ap.parse_args(argv)
    if not args.analyse_only:
        from benchmarks.performance import bench_sim_node

        os.environ[TRACE_ENV] = os.path.abspath(args.out)
        r = bench_sim_node.run(
            args.seconds, 1.0, 0.0, args.scene, False, subscribe_marker=args.marker,
            publish_delay_periods=args.publish_delay_periods,
            sim_module='benchmarks.performance.trace_pacing', sim_module_args=['--node'],
        )
        print(
            f"bench_sim_node: send jitter p50/p99 {r['send_jitter_p50_ms']:.3f} /"
            f" {r['send_jitter_p99_ms']:.3f} ms, idle p50/p99 {r['floor']['jitter_p50_ms']:.3f}"
            f" / {r['floor']['jitter_p99_ms']:.3f} ms, {r['markers_received']} Markers, CPU"
            f" {r['cpu_percent']:.0f} %, load {os.getloadavg()[0]:.2f}"
        )
        nominal = r['nominal_rate_hz']
    else:
        nominal = 100.0
    with open(args.out) as f:
        records = json.load(f)
    clock = [t0 for kind, t0, _, ex in records if kind == 'publish' and ex[0] == '/clock']
    # as the benchmark: from 1 s after the first /clock, the last second left out (the stop)
    print(analyse(records, 1.0 / nominal, (clock[0] + 2.0, clock[-1] - 1.0)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
