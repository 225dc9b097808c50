"""
Summary numbers and a 4-panel plot of a pulsejet MCAP recording (live or offline).

A shell recording's plot also shows meridian snapshots over one cycle (analysis.profiles).

Reads with pulsejet_sim.bag.reader (no rclpy). Time axes are simulation time (header stamps, or
log times mapped through /clock; see reader.load_series). Integrals use the trapezoidal rule over
the recorded samples, so their accuracy is that of the publishing rate.

cli.py calls main_summary(argv) / main_plot(argv) (profiles.main_animate uses _run too); they
return a process exit code (2 on bad input, with a one-line error naming the file and what was
expected).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from pulsejet_sim.analysis import metrics, profiles
from pulsejet_sim.analysis.tool import RecordingToolError, run_recording_tool
from pulsejet_sim.bag.reader import BagInfo, find_topic, iter_bag, load_series
from pulsejet_sim.core.topics import LEDGER_STATUS_NAME
from pulsejet_sim.core.topics import TOPIC_ENERGY_LEDGER as ENERGY_LEDGER
from pulsejet_sim.core.topics import TOPIC_FLUID_MASS as FLUID_MASS
from pulsejet_sim.core.topics import TOPIC_MANTLE_RADIUS as MANTLE_RADIUS
from pulsejet_sim.core.topics import TOPIC_THRUST as THRUST
from pulsejet_sim.core.topics import TOPIC_VELOCITY as VELOCITY
from pulsejet_sim.core.topics import TOPIC_VOLUME as VOLUME

PULSEJET_TOPICS = (VELOCITY, THRUST, MANTLE_RADIUS, VOLUME, FLUID_MASS, ENERGY_LEDGER)


class AnalysisError(RecordingToolError):
    """The file is readable but holds nothing to analyse (names the file and what was expected)."""


def _final_ledger(path: Path, topic: str) -> tuple[dict[str, float], str]:
    """Ledger (J) and level name of the last energy-ledger message; ({}, '') when there is none."""
    ledger: dict[str, float] = {}
    level = ''
    levels = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}
    for _, _, _, msg in iter_bag(path, topics=[topic]):
        if not hasattr(msg, 'status'):
            continue
        for status in msg.status:
            if status.name != LEDGER_STATUS_NAME:
                continue
            ledger = {}
            for kv in status.values:
                try:
                    ledger[kv.key] = float(kv.value)
                except ValueError:
                    ledger[kv.key] = math.nan
            raw = status.level
            code = raw[0] if isinstance(raw, (bytes, bytearray)) else int(raw)
            level = levels.get(code, str(code))
    return ledger, level


def summarize(path: str | Path) -> dict[str, Any]:
    """
    Key numbers of a run. Units in the key names; NaN where the topic needed is absent.

    peak_speed_m_s: max |v|; mean_speed_m_s: time average of |v| (metrics.time_mean_speed_m_s);
    distance_m: net forward travel ∫v dt; thrust_impulse_n_s: ∫thrust dt; duration_s: span of
    simulation time covered;
    fluid_mass_min_kg / _max_kg; message_counts: per stored topic; energy_ledger_j: last ledger;
    energy_ledger_level: its diagnostic level (OK / WARN). Raises BagReadError / AnalysisError.
    """
    p = Path(path)
    info = BagInfo(p)
    series = load_series(p, info=info)
    present = [rel for rel in PULSEJET_TOPICS if find_topic(info.topics, rel)]
    if not present:
        raise AnalysisError(
            f'{str(p)!r} has no pulsejet topics (found {sorted(info.topics) or "none"}); '
            f'expected some of {", ".join(PULSEJET_TOPICS)}'
        )

    def get(rel: str) -> tuple[np.ndarray, np.ndarray] | None:
        name = find_topic(series, rel)
        return series[name] if name else None

    out: dict[str, Any] = {
        'file': str(p),
        'truncated': info.truncated,
        'damage': info.damage_report(),
        'messages_recovered': info.message_count,
        'bytes_dropped': info.bytes_dropped,
        'file_bytes': info.file_size,
        'corrupt_chunks': info.corrupt_chunks,
        'undecodable_messages': dict(info.undecodable),
        'log_span_s': (
            None
            if info.first_log_ns is None
            else (info.first_log_ns * 1e-9, info.last_log_ns * 1e-9)
        ),
    }
    # Simulation-time span: header-stamped topics are exact, /clock next, log-time-mapped ones
    # last.
    span = None
    for group in ((VELOCITY, THRUST), ('/clock',), (MANTLE_RADIUS, VOLUME, FLUID_MASS)):
        times = [get(rel)[0] for rel in group if get(rel) is not None and len(get(rel)[0])]
        if times:
            span = (min(t[0] for t in times), max(t[-1] for t in times))
            break
    out['start_time_s'] = float(span[0]) if span else math.nan
    out['duration_s'] = float(span[1] - span[0]) if span else math.nan
    # a live recording logs wall time: simulated over wall seconds is the real-time factor
    # achieved; an offline run logs simulation time itself (the factor is then not a property of
    # the file)
    out['real_time_factor'] = math.nan
    if span and info.first_log_ns is not None and abs(info.first_log_ns * 1e-9 - span[0]) > 1.0:
        # log times are not simulation times: the first and last /clock message give the wall span
        # of the run (other topics, e.g. a late /diagnostics, would stretch it)
        clock = [
            (m.log_time_ns, m.msg.clock.sec + 1e-9 * m.msg.clock.nanosec)
            for m in iter_bag(p, topics=['/clock'])
        ]
        if len(clock) >= 2 and clock[-1][0] > clock[0][0]:
            out['real_time_factor'] = (clock[-1][1] - clock[0][1]) / (
                (clock[-1][0] - clock[0][0]) * 1e-9
            )

    velocity = get(VELOCITY)
    if velocity is not None and len(velocity[0]):
        t, v = velocity
        out['peak_speed_m_s'] = metrics.peak_speed_m_s(v)
        out['mean_speed_m_s'] = metrics.time_mean_speed_m_s(t, v)
        out['distance_m'] = metrics.distance_m(t, v)
        out['final_velocity_m_s'] = float(v[-1])
    else:
        out.update(
            peak_speed_m_s=math.nan,
            mean_speed_m_s=math.nan,
            distance_m=math.nan,
            final_velocity_m_s=math.nan,
        )

    thrust = get(THRUST)
    if thrust is not None and len(thrust[0]):
        out['thrust_impulse_n_s'] = metrics.trapezoid(thrust[1], thrust[0])
        out['peak_thrust_n'] = float(np.max(thrust[1]))
    else:
        out.update(thrust_impulse_n_s=math.nan, peak_thrust_n=math.nan)

    mass = get(FLUID_MASS)
    if mass is not None and len(mass[0]):
        out['fluid_mass_min_kg'] = float(np.min(mass[1]))
        out['fluid_mass_max_kg'] = float(np.max(mass[1]))
    else:
        out.update(fluid_mass_min_kg=math.nan, fluid_mass_max_kg=math.nan)

    out['message_counts'] = dict(sorted(info.counts.items()))
    ledger_topic = find_topic(info.topics, ENERGY_LEDGER)
    ledger, level = _final_ledger(p, ledger_topic) if ledger_topic else ({}, '')
    out['energy_ledger_j'] = ledger
    out['energy_ledger_level'] = level
    return out


def _fmt(value: float, spec: str = '.6g') -> str:
    return (
        'n/a'
        if value is None or (isinstance(value, float) and math.isnan(value))
        else format(value, spec)
    )


def format_summary(summary: dict[str, Any]) -> str:
    """Human-readable table of summarize()'s output, with units."""
    rows = [
        ('file', summary.get('file', ''), ''),
        ('duration', _fmt(summary.get('duration_s')), 's'),
        (
            'real-time factor',
            _fmt(summary.get('real_time_factor')),
            '(simulated / wall seconds, live recordings)',
        ),
        ('peak speed', _fmt(summary.get('peak_speed_m_s')), 'm/s'),
        ('mean speed', _fmt(summary.get('mean_speed_m_s')), 'm/s'),
        ('distance travelled', _fmt(summary.get('distance_m')), 'm'),
        ('thrust impulse', _fmt(summary.get('thrust_impulse_n_s')), 'N s'),
        ('peak thrust', _fmt(summary.get('peak_thrust_n')), 'N'),
        ('fluid mass min', _fmt(summary.get('fluid_mass_min_kg')), 'kg'),
        ('fluid mass max', _fmt(summary.get('fluid_mass_max_kg')), 'kg'),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f'{name:<{width}}  {value} {unit}'.rstrip() for name, value, unit in rows]
    if summary.get('damage'):
        lines.append(f'{"damaged":<{width}}  {summary["damage"]}')
        lines.append(
            f'{"":<{width}}  read up to the last complete chunk (a hard kill loses at most the '
            "writer's last flush period); `pulsejet repair FILE` writes a complete copy"
        )
    elif summary.get('truncated'):
        lines.append(
            f'{"note":<{width}}  file has no summary (writer killed hard); '
            'read up to the last complete chunk'
        )
    lines.append('')
    lines.append('messages per topic')
    counts = summary.get('message_counts', {})
    tw = max((len(t) for t in counts), default=5)
    lines += [f'  {topic:<{tw}}  {n}' for topic, n in counts.items()]
    ledger = summary.get('energy_ledger_j') or {}
    if ledger:
        lines.append('')
        lines.append(f'final energy ledger ({summary.get("energy_ledger_level") or "?"})')
        kw = max(len(k) for k in ledger)
        for key, value in ledger.items():
            unit = '' if key == 'closure_relative' else 'J'
            lines.append(f'  {key:<{kw}}  {_fmt(value, ".6g")} {unit}'.rstrip())
    return '\n'.join(lines)


def plot_figure(path: str | Path) -> Any:
    """
    Return the figure `plot` writes (a matplotlib Figure, no pyplot).

    4 stacked panels against simulation time: mantle radius (mm), volume (ml), velocity (m/s),
    thrust (N).

    A shell recording (mantle profiles recorded, stored scene not `model: lumped`) gets a fifth
    panel below them, in the same figure and PNG, not sharing their time axis: meridian snapshots
    (r, z) over the last whole actuation cycle, coloured by phase (profiles.draw_cycle_snapshots);
    the cycle is shaded on the time panels and the snapshot times are marked on the radius. A
    lumped recording gives the 4 panels alone, as before (see profiles.is_lumped_recording).
    """
    # a Figure of its own, no pyplot: the caller's backend and figures are left alone
    from matplotlib.figure import Figure

    p = Path(path)
    info = BagInfo(p)
    series = load_series(p, info=info)
    panels = [
        (MANTLE_RADIUS, 1e3, 'mantle radius [mm]'),
        (VOLUME, 1e6, 'volume [ml]'),
        (VELOCITY, 1.0, 'velocity [m/s]'),
        (THRUST, 1.0, 'thrust [N]'),
    ]
    if not any(find_topic(series, rel) for rel, _, _ in panels):
        raise AnalysisError(
            f'{str(p)!r} has no pulsejet state topics (found {sorted(info.topics) or "none"}); '
            f'expected some of {", ".join(rel for rel, _, _ in panels)}'
        )
    shell = profiles.shows_profiles(p, info)
    fig = Figure(figsize=(9, 12) if shell else (8, 9), constrained_layout=True)
    if shell:
        # the time panels keep their shared axis; the meridian panel below has its own (mm)
        grid = fig.add_gridspec(len(panels) + 1, 1, height_ratios=[1] * len(panels) + [1.2])
        axes = [fig.add_subplot(grid[0])]
        axes += [fig.add_subplot(grid[k], sharex=axes[0]) for k in range(1, len(panels))]
    else:
        axes = fig.subplots(len(panels), 1, sharex=True)
    for ax, (rel, scale, label) in zip(axes, panels):
        name = find_topic(series, rel)
        if name is not None:
            t, v = series[name]
            ax.plot(t, v * scale, lw=1.0)
        else:
            ax.text(
                0.5, 0.5, f'{rel}: not recorded', transform=ax.transAxes, ha='center', va='center'
            )
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel('simulation time [s]')
    axes[0].set_title(p.name)
    if shell:
        snapshot_ax = fig.add_subplot(grid[len(panels)], label=SNAPSHOT_AXES_LABEL)
        snapshots = profiles.draw_cycle_snapshots(snapshot_ax, p, series, info)
        if snapshots is not None:
            _mark_snapshots(axes, series, snapshots)
    return fig


SNAPSHOT_AXES_LABEL = (
    'mantle snapshots'  # the label of the meridian panel's Axes (tests find it by it)
)


def _mark_snapshots(
    time_axes: Sequence[Any], series: dict[str, tuple[np.ndarray, np.ndarray]], snapshots: Any
) -> None:
    """
    Shade the snapshot cycle on the time panels and mark the snapshot times on the radius.

    The marks are in the snapshots' colours, so the meridians can be read against the signals.
    """
    for ax in time_axes:
        ax.axvspan(snapshots.cycle.start_s, snapshots.cycle.end_s, color='0.5', alpha=0.12, lw=0)
    name = find_topic(series, MANTLE_RADIUS)
    if name is not None and len(series[name][0]):
        t, radius_m = series[name]
        time_axes[0].scatter(
            snapshots.time_s,
            np.interp(snapshots.time_s, t, radius_m) * 1e3,
            c=snapshots.colors,
            s=28,
            zorder=3,
            edgecolors='k',
            linewidths=0.5,
        )


def plot(path: str | Path, png_path: str | Path | None = None) -> Path:
    """
    Write plot_figure(path) as a PNG (default: the MCAP path with suffix .png).

    Returns its path.
    """
    p = Path(path)
    fig = plot_figure(p)
    out = Path(png_path) if png_path is not None else p.with_suffix('.png')
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out


def main_summary(argv: Sequence[str] | None = None) -> int:
    """`pulsejet summary FILE.mcap`: print the summary table. Returns the exit code."""

    def build(parser: argparse.ArgumentParser) -> None:
        parser.add_argument('file', help='MCAP recording (.mcap)')

    def action(args: argparse.Namespace) -> None:
        print(format_summary(summarize(args.file)))

    return run_recording_tool('pulsejet summary', argv, build, action)


def main_plot(argv: Sequence[str] | None = None) -> int:
    """`pulsejet plot FILE.mcap [--out PNG]`: write the PNG of plot_figure and print its path."""

    def build(parser: argparse.ArgumentParser) -> None:
        parser.add_argument('file', help='MCAP recording (.mcap)')
        parser.add_argument(
            '--out', default=None, help='PNG path (default: FILE with .png suffix)'
        )

    def action(args: argparse.Namespace) -> None:
        print(plot(args.file, args.out))

    return run_recording_tool('pulsejet plot', argv, build, action)
