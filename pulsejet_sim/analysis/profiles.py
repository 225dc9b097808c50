"""
Mantle profiles of a shell recording, shown as a person would look at them.

A shell run records `pulsejet/mantle_profile` (geometry_msgs/PolygonStamped: x = axial position z,
y = radius r, metres, body frame, ring at z = 0, forward +). This module reads them (through
bag.reader, so a damaged file is read as far as it goes), finds one actuation cycle, chooses
snapshots evenly spaced over it, draws them as meridians (r, z) on a matplotlib Axes, and writes
an animation of the body section (the meridian mirrored about the axis) as GIF or MP4.

`pulsejet plot` (analysis.plot) adds the snapshot panel to its figure for recordings that hold
profiles; `pulsejet animate FILE` is main_animate here. Drawing uses matplotlib Figure objects only
(never pyplot), so the caller's backend and figures are left alone. Lengths are drawn in mm.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import math
from pathlib import Path
import shutil
import sys
from typing import Any, Iterable, Sequence

import numpy as np
from pulsejet_sim.analysis.tool import RecordingToolError, run_recording_tool
from pulsejet_sim.bag.reader import BagInfo, find_topic, iter_bag, read_metadata, stamp_to_s
from pulsejet_sim.core.topics import TOPIC_MANTLE_PROFILE, TOPIC_MANTLE_RADIUS

PROFILE_TYPE = 'geometry_msgs/msg/PolygonStamped'
METADATA_NAME = 'pulsejet'  # the runner's metadata record, key scene_yaml (see runner._record)
DEFAULT_PERIOD_S = 1.0  # when neither the scene nor the radius signal gives a period
SNAPSHOT_COUNT = 8
ANIMATION_SUFFIXES = ('.gif', '.mp4')
DEFAULT_FPS = 25.0
MAX_FPS = 100.0
# Pillow keeps every GIF frame in memory until it writes the file (~0.2 MB each, palette mode);
# MP4 goes to ffmpeg frame by frame and has no such limit.
MAX_GIF_FRAMES = 1000
MM_PER_M = 1e3


class ProfileError(RecordingToolError):
    """Bad input for the profile tools: names the file or value and what is allowed."""


@dataclass
class ProfileSeries:
    """Mantle meridians in time order: time_s[i] with node arrays radius_m[i], axial_m[i] (m)."""

    topic: str = ''
    time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    radius_m: list[np.ndarray] = field(default_factory=list)
    axial_m: list[np.ndarray] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.time_s)

    def sample_interval_s(self) -> float:
        """Median time between profiles (NaN with fewer than two)."""
        steps = np.diff(self.time_s)
        steps = steps[steps > 0]
        return float(np.median(steps)) if len(steps) else math.nan


@dataclass
class Cycle:
    """
    One actuation cycle [start_s, end_s]; phase 0 at origin_s (+ whole periods).

    source: where the period came from ('scene', 'radius signal' or 'default'); complete: False
    when the recording is too short to hold a whole cycle aligned on origin_s.
    """

    start_s: float
    end_s: float
    period_s: float
    origin_s: float
    source: str
    complete: bool = True

    def phase(self, time_s: np.ndarray | float) -> np.ndarray:
        return np.mod((np.asarray(time_s, dtype=float) - self.origin_s) / self.period_s, 1.0)


# ---- reading ------------------------------------------------------------------------------------
def profile_topic(info: BagInfo) -> str | None:
    """Return the stored name of the mantle-profile topic (namespaced or not), or None."""
    return find_topic(info.topics, TOPIC_MANTLE_PROFILE)


def _meridian(msg: Any) -> tuple[np.ndarray, np.ndarray] | None:
    points = msg.polygon.points
    axial_m = np.fromiter((p.x for p in points), dtype=float, count=len(points))
    radius_m = np.fromiter((p.y for p in points), dtype=float, count=len(points))
    # a profile that cannot be drawn (too short, NaN) is left out rather than spoiling the limits
    if len(points) < 2 or not (np.all(np.isfinite(axial_m)) and np.all(np.isfinite(radius_m))):
        return None
    return radius_m, axial_m


def read_profiles(
    path: str | Path,
    start_s: float | None = None,
    end_s: float | None = None,
    info: BagInfo | None = None,
) -> ProfileSeries:
    """
    Mantle profiles with header stamp (simulation time) in [start_s, end_s] (None: open end).

    Empty ProfileSeries when the file has none. BagReadError as bag.reader.iter_bag.
    """
    lo = -math.inf if start_s is None else start_s
    hi = math.inf if end_s is None else end_s
    found: dict[str, list[tuple[float, np.ndarray, np.ndarray]]] = {}
    for message in iter_bag(path, info=info, types=[PROFILE_TYPE]):
        if not message.topic.endswith(TOPIC_MANTLE_PROFILE):
            continue
        time_s = stamp_to_s(message.msg.header.stamp)
        # filtering while reading keeps memory to the window on long recordings
        if not lo <= time_s <= hi:
            continue
        meridian = _meridian(message.msg)
        if meridian is not None:
            found.setdefault(message.topic, []).append((time_s, *meridian))
    topic = find_topic(found, TOPIC_MANTLE_PROFILE)
    if topic is None:
        return ProfileSeries()
    rows = sorted(found[topic], key=lambda row: row[0])
    return ProfileSeries(
        topic=topic,
        time_s=np.array([row[0] for row in rows]),
        radius_m=[row[1] for row in rows],
        axial_m=[row[2] for row in rows],
    )


def no_profiles_error(path: str | Path, info: BagInfo) -> ProfileError:
    topics = ', '.join(sorted(info.topics)) or 'none'
    return ProfileError(
        f'{str(path)!r} holds no {TOPIC_MANTLE_PROFILE} messages (topics: {topics}); '
        'allowed: a shell-model recording, e.g. from `pulsejet run shell_robot`'
    )


# ---- the cycle ----------------------------------------------------------------------------------
def _positive(value: Any) -> float | None:
    """Return a finite number > 0 from untrusted YAML, else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) and value > 0 else None


def _nonnegative(value: Any) -> float | None:
    if value is None:
        return 0.0
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value < 0
    ):
        return None
    return float(value)


def period_from_scene_data(data: Any) -> tuple[float, float] | None:
    """
    (period_s, origin_s) of the actuation a scene mapping describes, or None.

    A `routine:` block (what the controller sends) wins over the shell's built-in cable
    (`actuation:` with frequency_hz). A pump/valve routine that inflates to a target volume has
    no fixed period (it ends on a measurement), so it gives None.
    """
    if not isinstance(data, dict):
        return None
    routine = data.get('routine')
    if isinstance(routine, dict):
        delay = _nonnegative(routine.get('start_delay_s'))
        if routine.get('kind', 'pump_valve') == 'cable':
            freq = _positive(routine.get('frequency_hz', 1.6))
            return (1.0 / freq, delay) if freq and delay is not None else None
        if _positive(routine.get('target_volume_m3')):
            return None
        # the routine's defaults when a key is left out (pulsejet_sim.routines.PUMP_VALVE_SPEC)
        parts = [
            _nonnegative(routine.get(key, default))
            for key, default in (('inflate_s', 2.0), ('hold_s', 0.2), ('jet_s', 1.8))
        ]
        if None in parts or delay is None or sum(parts) <= 0:
            return None
        return sum(parts), delay
    actuation = data.get('actuation')
    if isinstance(actuation, dict) and actuation.get('source', 'routine') == 'routine':
        freq = _positive(actuation.get('frequency_hz'))
        delay = _nonnegative(actuation.get('start_delay_s'))
        if freq and delay is not None:
            return 1.0 / freq, delay
    return None


def stored_scene_data(path: str | Path, info: BagInfo | None = None) -> dict[str, Any] | None:
    """
    Return the scene mapping the runner stored in the recording, or None.

    It is stored in the `pulsejet` metadata, key scene_yaml. Uses info's metadata when a read
    already filled it (no second pass over the file). The stored YAML is untrusted: read with the
    safe loader; callers take only plain numbers and names from it.
    """
    from pulsejet_sim.core.schema import safe_load_yaml, YAMLInputError

    if info is not None and info.metadata:
        found: dict[str, str] = {}
        for name, values in info.metadata:
            if name == METADATA_NAME:
                found.update(values)
    else:
        found = read_metadata(path, METADATA_NAME)
    text = found.get('scene_yaml')
    if not text:
        return None
    try:
        data = safe_load_yaml(text, 'scene stored in the recording')
    except YAMLInputError:
        return None
    return data if isinstance(data, dict) else None


def stored_scene_period(
    path: str | Path, info: BagInfo | None = None
) -> tuple[float, float] | None:
    """(period_s, origin_s) of the actuation of the scene stored in the recording, or None."""
    return period_from_scene_data(stored_scene_data(path, info))


def is_lumped_recording(path: str | Path, info: BagInfo | None = None) -> bool:
    """
    Tell whether the stored scene says `model: lumped`.

    The lumped model records a mantle profile too, but it is only the ellipsoid its one mantle
    radius implies (nothing the radius panel does not show), so the profile views are kept for the
    shell model. A recording without a stored scene (a live one) cannot be told apart and is taken
    for what its topics say.
    """
    data = stored_scene_data(path, info)
    return data is not None and data.get('model') == 'lumped'


def shows_profiles(path: str | Path, info: BagInfo) -> bool:
    """Whether `pulsejet plot` adds the snapshot panel: profiles recorded, not a lumped model."""
    return profile_topic(info) is not None and not is_lumped_recording(path, info)


def radius_period_s(
    time_s: np.ndarray, radius_m: np.ndarray, min_correlation: float = 0.3
) -> float | None:
    """
    Period of a (roughly periodic) radius signal from its autocorrelation, or None.

    The signal is resampled on its median step and detrended (a slow drift would otherwise
    correlate with itself at every lag); the period is the lag of the highest autocorrelation after
    its first negative dip, accepted if that peak is above min_correlation.
    """
    t = np.asarray(time_s, dtype=float)
    r = np.asarray(radius_m, dtype=float)
    ok = np.isfinite(t) & np.isfinite(r)
    t, r = t[ok], r[ok]
    if len(t) < 8:
        return None
    steps = np.diff(t)
    step_s = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    if step_s <= 0:
        return None
    grid = np.arange(t[0], t[-1], step_s)
    x = np.interp(grid, t, r)
    x = x - np.polyval(np.polyfit(grid - grid[0], x, 1), grid - grid[0])
    if len(x) < 8 or not np.any(np.abs(x) > 1e-12 * max(1e-12, float(np.abs(r).max()))):
        return None
    # FFT autocorrelation: O(n log n), so an hour-long live recording is still quick
    n = len(x)
    spectrum = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    acf = acf / acf[0]
    below = np.flatnonzero(acf < 0)
    if not len(below):
        return None
    lag = int(below[0] + np.argmax(acf[below[0]: n // 2 + 1])) if below[0] <= n // 2 else 0
    if lag <= 0 or acf[lag] < min_correlation:
        return None
    return lag * step_s


def cycle_period(
    path: str | Path,
    series: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
    info: BagInfo | None = None,
) -> tuple[float, float | None, str]:
    """
    Return (period_s, origin_s or None, source) of the cycle.

    The stored scene's actuation period first, then the period of the recorded mantle radius
    (`series` from reader.load_series), else DEFAULT_PERIOD_S.
    """
    stored = stored_scene_period(path, info)
    if stored is not None:
        return stored[0], stored[1], 'scene'
    radius = find_topic(series or {}, TOPIC_MANTLE_RADIUS)
    if radius is not None:
        period = radius_period_s(*series[radius])
        if period is not None:
            return period, None, 'radius signal'
    return DEFAULT_PERIOD_S, None, 'default'


def last_cycle(
    first_s: float, last_s: float, period_s: float, origin_s: float | None, source: str = ''
) -> Cycle:
    """
    Return the last whole cycle within [first_s, last_s].

    Aligned on origin_s + k period when the origin is known (phase 0 = start of the actuation),
    else the last period_s seconds.

    A recording shorter than that gives the partial cycle it holds (complete=False).
    """
    tol_s = 1e-6 * period_s  # stamps are whole ns: 0.625 s may come back as 0.6249999999
    if origin_s is not None:
        cycles = math.floor((last_s - origin_s) / period_s + 1e-6)
        end_s = origin_s + cycles * period_s
        if end_s - period_s >= first_s - tol_s and cycles >= 1:
            return Cycle(end_s - period_s, end_s, period_s, origin_s, source)
    start_s = last_s - period_s
    complete = start_s >= first_s - tol_s
    start_s = max(start_s, first_s)
    return Cycle(
        start_s, last_s, period_s, start_s if origin_s is None else origin_s, source, complete
    )


def snapshot_indices(time_s: np.ndarray, cycle: Cycle, count: int = SNAPSHOT_COUNT) -> np.ndarray:
    """
    Return the indices of the profiles nearest `count` times evenly spaced over the cycle.

    In time order.

    The cycle's end is left out (it is the next cycle's phase 0); a sparse recording may give
    fewer distinct profiles than `count`.
    """
    if count < 1:
        raise ProfileError(f'count={count!r} rejected; allowed: an integer >= 1')
    t = np.asarray(time_s, dtype=float)
    inside = np.flatnonzero((t >= cycle.start_s - 1e-9) & (t <= cycle.end_s + 1e-9))
    if not len(inside):
        return inside
    span_s = cycle.end_s - cycle.start_s
    targets = (
        cycle.start_s + span_s * np.arange(count) / count
        if cycle.complete
        else np.linspace(cycle.start_s, cycle.end_s, count)
    )
    nearest = inside[np.abs(t[inside][None, :] - targets[:, None]).argmin(axis=1)]
    return np.unique(nearest)


# ---- drawing ------------------------------------------------------------------------------------
@dataclass
class Snapshots:
    """What draw_cycle_snapshots drew: times, their colours (RGBA) and the cycle."""

    time_s: np.ndarray
    colors: list[tuple[float, float, float, float]]
    cycle: Cycle


def draw_snapshots(
    ax: Any, profiles: ProfileSeries, indices: Iterable[int], cycle: Cycle, cmap: str = 'viridis'
) -> Snapshots:
    """
    Draw the meridians of the chosen profiles on `ax`.

    Axial position z (mm, forward +) across, radius r (mm) up, equal aspect, coloured by phase of
    the cycle, legend of times.
    """
    from matplotlib import colormaps

    colormap = colormaps[cmap]
    indices = list(indices)
    times = profiles.time_s[indices]
    colors = []
    for i, time_s in zip(indices, times):
        phase = float(cycle.phase(time_s))
        # the colour map over the phase: the same colour means the same moment of any cycle
        color = colormap(0.9 * phase)
        colors.append(color)
        ax.plot(
            profiles.axial_m[i] * MM_PER_M,
            profiles.radius_m[i] * MM_PER_M,
            color=color,
            lw=1.4,
            label=f'{time_s:.3f} s (phase {phase:.2f})',
            gid='mantle snapshot',
        )
    ax.axhline(0.0, color='0.4', lw=0.8, ls='-.', gid='axis')  # the axis of symmetry
    # equal aspect in a box that fits the drawn meridians: r from just below the axis, so the
    # panel is as flat as the body (a data-limited aspect would pad r with empty millimetres)
    z_mm = np.concatenate([profiles.axial_m[i] for i in indices]) * MM_PER_M
    r_mm = np.concatenate([profiles.radius_m[i] for i in indices]) * MM_PER_M
    pad_z = 0.03 * max(float(np.ptp(z_mm)), 1e-3)
    pad_r = 0.12 * max(float(np.abs(r_mm).max()), 1e-3)
    ax.set_xlim(float(z_mm.min()) - pad_z, float(z_mm.max()) + pad_z)
    ax.set_ylim(min(0.0, float(r_mm.min())) - pad_r, float(r_mm.max()) + pad_r)
    ax.set_aspect('equal', adjustable='box')
    ax.set_xlabel('axial position z [mm] (forward +)')
    ax.set_ylabel('radius r [mm]')
    ax.grid(True, alpha=0.3)
    what = 'one cycle' if cycle.complete else 'a partial cycle (recording shorter than the period)'
    ax.set_title(
        f'mantle meridian over {what}: {cycle.start_s:.3f}-{cycle.end_s:.3f} s, '
        f'period {cycle.period_s:.3f} s ({cycle.source})',
        fontsize='medium',
    )
    # below the panel: beside it, the legend would narrow every panel sharing the figure's width
    ax.legend(
        title='time (phase of the cycle)',
        fontsize='small',
        title_fontsize='small',
        ncol=4,
        loc='upper center',
        bbox_to_anchor=(0.5, -0.32),
        frameon=False,
    )
    return Snapshots(times, colors, cycle)


def draw_cycle_snapshots(
    ax: Any,
    path: str | Path,
    series: dict[str, tuple[np.ndarray, np.ndarray]],
    info: BagInfo,
    count: int = SNAPSHOT_COUNT,
) -> Snapshots | None:
    """
    Read the profiles of the last whole cycle of a recording and draw them on `ax`.

    series / info: what reader.load_series returned and filled (the period comes from the scene in
    info's metadata, else from the radius series). None, with a note on `ax`, when no profile can
    be read (a damaged file): the rest of the plot is still worth having.
    """
    period_s, origin_s, source = cycle_period(path, series, info)
    # only the last two periods can hold the last cycle: read (and keep) no more than that
    ends = [t[-1] for t, _ in series.values() if len(t)]
    start_s = max(ends) - 2.0 * period_s - 1.0 if ends else None
    profiles = read_profiles(path, start_s=start_s)
    if not len(profiles):
        ax.text(
            0.5,
            0.5,
            f'{TOPIC_MANTLE_PROFILE}: no readable profiles',
            transform=ax.transAxes,
            ha='center',
            va='center',
        )
        return None
    cycle = last_cycle(profiles.time_s[0], profiles.time_s[-1], period_s, origin_s, source)
    return draw_snapshots(ax, profiles, snapshot_indices(profiles.time_s, cycle, count), cycle)


# ---- animation ----------------------------------------------------------------------------------
def check_output(out: str | Path) -> Path:
    """
    Return the animation path if its suffix is one we can write, else raise ProfileError.

    .mp4 only with ffmpeg.
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in ANIMATION_SUFFIXES:
        raise ProfileError(
            f'output {str(out)!r}: suffix {suffix or "(none)"!r} rejected; allowed: '
            f'{", ".join(ANIMATION_SUFFIXES)} (.mp4 needs ffmpeg on PATH)'
        )
    if suffix == '.mp4' and shutil.which('ffmpeg') is None:
        raise ProfileError(
            f'output {str(out)!r}: .mp4 needs ffmpeg, which is not on PATH; allowed: .gif, '
            'or install ffmpeg for .mp4'
        )
    return out


def default_stride(profiles: ProfileSeries, fps: float) -> int:
    """Every how many profiles a frame is taken so the clip plays at about real time."""
    step_s = profiles.sample_interval_s()
    if not math.isfinite(step_s) or step_s <= 0:
        return 1
    return max(1, round(1.0 / (fps * step_s)))


def _section(profiles: ProfileSeries, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Outline of the body section (mm): the meridian and its mirror image about the axis."""
    z = profiles.axial_m[i] * MM_PER_M
    r = profiles.radius_m[i] * MM_PER_M
    return np.concatenate([z, z[::-1]]), np.concatenate([r, -r[::-1]])


def _section_limits(
    profiles: ProfileSeries, indices: Sequence[int]
) -> tuple[tuple[float, float], float]:
    """
    Return fixed axes limits over the whole clip, with a margin.

    (z_min, z_max) and r_max in mm.
    """
    z_lo = min(float(profiles.axial_m[i].min()) for i in indices) * MM_PER_M
    z_hi = max(float(profiles.axial_m[i].max()) for i in indices) * MM_PER_M
    r_hi = max(float(np.abs(profiles.radius_m[i]).max()) for i in indices) * MM_PER_M
    pad = 0.06 * max(z_hi - z_lo, 2.0 * r_hi, 1e-3)
    return (z_lo - pad, z_hi + pad), r_hi + pad


class _SectionFigure:
    """One Figure redrawn per frame: the body section filled, its outline, the axis, the time."""

    def __init__(self, profiles: ProfileSeries, indices: Sequence[int], title: str):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.patches import Polygon

        self.profiles, self.title = profiles, title
        self.fig = Figure(figsize=(7.2, 2.8), dpi=100, constrained_layout=True)
        self.canvas = FigureCanvasAgg(self.fig)
        ax = self.fig.add_subplot()
        (z_lo, z_hi), r_hi = _section_limits(profiles, indices)
        ax.set_xlim(z_lo, z_hi)
        ax.set_ylim(-r_hi, r_hi)
        ax.set_aspect('equal')
        ax.axhline(0.0, color='0.4', lw=0.8, ls='-.')
        ax.set_xlabel('axial position z [mm] (forward +)')
        ax.set_ylabel('r [mm]')
        ax.grid(True, alpha=0.3)
        z, r = _section(profiles, indices[0])
        self.body = ax.add_patch(
            Polygon(
                np.column_stack([z, r]),
                closed=True,
                fc=(0.95, 0.6, 0.4, 0.55),
                ec=(0.55, 0.2, 0.1),
                lw=1.5,
            )
        )
        self.ax = ax
        # with constrained layout the axes move when the title text changes width: fix them once
        self.show(indices[0])
        self.canvas.draw()
        self.fig.set_layout_engine('none')

    def show(self, i: int) -> None:
        z, r = _section(self.profiles, i)
        self.body.set_xy(np.column_stack([z, r]))
        self.ax.set_title(f'{self.title}   t = {self.profiles.time_s[i]:.3f} s', fontsize='medium')


def _with_progress(indices: Sequence[int], stream: Any) -> Iterable[int]:
    """Show a tqdm bar on a terminal; nothing in a log or a pipe (no carriage returns in files)."""
    if stream is not None and getattr(stream, 'isatty', lambda: False)():
        from tqdm import tqdm

        return tqdm(indices, file=stream, unit='frame', dynamic_ncols=True)
    return indices


def _write_gif(
    figure: _SectionFigure, indices: Sequence[int], out: Path, fps: float, stream: Any
) -> None:
    from PIL import Image

    frames = []
    palette = None
    for i in _with_progress(indices, stream):
        figure.show(i)
        figure.canvas.draw()
        rgb = Image.frombuffer(
            'RGBA',
            figure.canvas.get_width_height(),
            figure.canvas.buffer_rgba(),
            'raw',
            'RGBA',
            0,
            1,
        ).convert('RGB')
        # one palette for the whole clip (the first frame's: the colours never change), so the
        # frames do not flicker and each costs one byte per pixel in memory
        if palette is None:
            palette = rgb.quantize(colors=128, dither=Image.Dither.NONE)
        frames.append(rgb.quantize(palette=palette, dither=Image.Dither.NONE))
    # GIF delays are whole centiseconds: 25 fps -> 40 ms
    frames[0].save(
        out, save_all=True, append_images=frames[1:], duration=round(1000.0 / fps), loop=0
    )


def _write_mp4(
    figure: _SectionFigure, indices: Sequence[int], out: Path, fps: float, stream: Any
) -> None:
    from matplotlib.animation import FFMpegWriter

    # yuv420p: the pixel format every player reads (the frame is 720 x 280, even sides as it needs)
    writer = FFMpegWriter(fps=fps, codec='h264', extra_args=['-pix_fmt', 'yuv420p'])
    with writer.saving(figure.fig, str(out), dpi=figure.fig.dpi):
        for i in _with_progress(indices, stream):
            figure.show(i)
            writer.grab_frame()


def frame_indices(profiles: ProfileSeries, stride: int) -> list[int]:
    if stride < 1:
        raise ProfileError(f'stride={stride!r} rejected; allowed: an integer >= 1')
    return list(range(0, len(profiles), stride))


def write_animation(
    profiles: ProfileSeries,
    out: str | Path,
    fps: float = DEFAULT_FPS,
    stride: int | None = None,
    title: str = '',
    stream: Any = sys.stderr,
) -> tuple[Path, int]:
    """
    Animate the body section over `profiles` into a .gif or .mp4.

    Every `stride`-th profile (None: about real time at fps). Returns (path, frames written).
    ProfileError names a bad value.
    """
    out = check_output(out)
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise ProfileError(f'fps={fps!r} rejected; allowed: a number in (0, {MAX_FPS:g}]')
    if not len(profiles):
        raise ProfileError('no mantle profiles to animate; allowed: a non-empty ProfileSeries')
    indices = frame_indices(profiles, default_stride(profiles, fps) if stride is None else stride)
    if out.suffix.lower() == '.gif' and len(indices) > MAX_GIF_FRAMES:
        raise ProfileError(
            f'{len(indices)} frames for {str(out)!r}; allowed: at most {MAX_GIF_FRAMES} GIF '
            'frames '
            '(raise --stride, narrow --start/--end, or write .mp4)'
        )
    figure = _SectionFigure(profiles, indices, title)
    out.parent.mkdir(parents=True, exist_ok=True)
    writer = _write_gif if out.suffix.lower() == '.gif' else _write_mp4
    writer(figure, indices, out, float(fps), stream)
    return out, len(indices)


# ---- CLI ----------------------------------------------------------------------------------------
def _number(kind: type, low: float, what: str):
    """
    Return an argparse type: a finite number > low (an integer when kind is int).

    Otherwise the type reports a message naming the value and what is allowed.
    """
    from pulsejet_sim.core.schema import Number

    rule = Number(None, low, low_open=True, integer=kind is int)

    def parse(text: str):
        return rule.accept(
            text, '', error=argparse.ArgumentTypeError, allowed=what, sep='', from_text=True
        )

    return parse


def _build_animate(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        'Animate the mantle of a shell recording: the body section (meridian mirrored '
        'about the axis) frame by frame, fixed axes, simulation time in the title.'
    )
    parser.add_argument(
        'file', help='MCAP recording (.mcap) holding pulsejet/mantle_profile (shell model)'
    )
    parser.add_argument(
        '-o',
        '--out',
        default=None,
        help='animation path, .gif or .mp4 (.mp4 needs ffmpeg; default: FILE with .gif suffix)',
    )
    parser.add_argument(
        '--fps',
        type=_number(float, 0.0, f'a number in (0, {MAX_FPS:g}] frames per second'),
        default=DEFAULT_FPS,
        help=f'frames per second of the clip (default {DEFAULT_FPS:g}; GIF '
        'viewers often slow down above 50)',
    )
    parser.add_argument(
        '--start', type=float, default=None, help='first simulation time in s (default: the first)'
    )
    parser.add_argument(
        '--end', type=float, default=None, help='last simulation time in s (default: the last)'
    )
    parser.add_argument(
        '--stride',
        type=_number(int, 0, 'an integer >= 1'),
        default=None,
        help='take every K-th recorded profile (default: about real time at --fps)',
    )


def animate(
    path: str | Path,
    out: str | Path | None = None,
    fps: float = DEFAULT_FPS,
    start_s: float | None = None,
    end_s: float | None = None,
    stride: int | None = None,
    stream: Any = sys.stderr,
) -> tuple[Path, int, ProfileSeries]:
    """
    Read the profiles of `path` in [start_s, end_s] and write the animation.

    Default output: path with .gif. Returns (path, frames, profiles read). ProfileError /
    BagReadError name what is wrong.
    """
    for name, value in (('--start', start_s), ('--end', end_s)):
        if value is not None and not math.isfinite(value):
            raise ProfileError(f'{name} {value!r} rejected; allowed: a finite time in s')
    if start_s is not None and end_s is not None and start_s >= end_s:
        raise ProfileError(
            f'--start {start_s:g} >= --end {end_s:g} rejected; allowed: start < end'
        )
    # checked before the (slow) read, so a typo in the output name fails at once
    target = check_output(Path(path).with_suffix('.gif') if out is None else out)
    info = BagInfo(Path(path))
    profiles = read_profiles(path, start_s, end_s, info=info)
    if is_lumped_recording(path, info):
        raise ProfileError(
            f'{str(path)!r} is a lumped-model recording (stored scene model: lumped); its '
            f'{TOPIC_MANTLE_PROFILE} is only the ellipsoid its mantle radius implies; allowed: '
            'a shell-model recording, e.g. from `pulsejet run shell_robot`'
        )
    if not len(profiles):
        if profile_topic(info) is None:
            raise no_profiles_error(path, info)
        span = read_profiles(path).time_s
        raise ProfileError(
            f'{str(path)!r}: no mantle profiles between --start {start_s} and --end {end_s} s; '
            f'allowed: a window within the recorded {span[0]:.3f}-{span[-1]:.3f} s'
        )
    written, frames = write_animation(
        profiles, target, fps, stride, title=Path(path).name, stream=stream
    )
    return written, frames, profiles


def main_animate(argv: Sequence[str] | None = None) -> int:
    """
    Run `pulsejet animate`: write the animation and print its path.

    `pulsejet animate FILE.mcap [-o OUT.gif|.mp4] [--fps N] [--start S] [--end S] [--stride K]`.
    Exit code 2 on bad input, with a one-line error.
    """

    def action(args: argparse.Namespace) -> None:
        out, frames, profiles = animate(
            args.file, args.out, args.fps, args.start, args.end, args.stride
        )
        print(
            f'{out} ({frames} frames of {len(profiles)} profiles, '
            f'{profiles.time_s[0]:.3f}-{profiles.time_s[-1]:.3f} s, {args.fps:g} fps)'
        )

    return run_recording_tool('pulsejet animate', argv, _build_animate, action)
