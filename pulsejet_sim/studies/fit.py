"""
`pulsejet fit`: calibrate named scene parameters to measured figures or to a recording.

A fit file (YAML) names a scene, the parameters to fit (dotted scene keys with bounds) and either
target figures (`targets:`) or a recorded MCAP (`recording:`); scipy.optimize.least_squares
(trust-region reflective, bounded) moves the parameters, every evaluation is a real run of the
ROS-free `runner.Drive` (the same model, Simulation.step and routine as the nodes; no rclpy here).
The report gives the fitted values beside the initial ones and the bounds, the residual of every
figure or signal, the cost, the number of runs, and a sensitivity / identifiability table from a
central-difference Jacobian at the solution. See docs/validation/calibration.md.

Fit file::

    name: shell_robot                      # default: the file's stem
    scene: shell_robot                     # name under config/ or a YAML path (relative to the fit
                                           # file)
    duration_s: 30.0                       # simulated seconds per run (default: the scene's;
                                           # recording: its span)
    overrides: {mesh: {elements: 60}}      # optional, applied to every run; NOT written into the
                                           # fitted scene
    parameters:                            # dotted scene keys (must be numbers in the scene)
      fluid.drag_coefficient: {low: 0.3, high: 3.0}                  # initial: the scene's value
      actuation.amplitude: {low: 2.0, high: 30.0, initial: 8.0}
      fluid.tangential_drag_coefficient: {low: 0.005, high: 0.5, vary: false}   # held; sensitivity
                                                                                # only
    targets:                               # figure -> {value, sigma (absolute) | tolerance
                                           # (relative)}
      mean_speed_m_s: {value: 0.135, tolerance: 0.1}
      stroke_volume_m3: {value: 35.0e-6, tolerance: 0.1}
    predict:                               # held-out figures: reported beside the model, not
                                           # fitted
      burst_speed_m_s: {value: 0.2}
    figures: {period_s: 0.625, periods: 8, settle_s: 20.0}   # or {start_s, end_s}
    options: {max_evals: 40, diff_step: 1.0e-3, sensitivity_step: 1.0e-2}

or, instead of `targets:` / `predict:`::

    recording: {file: run.mcap, start_s: 0.0, end_s: 4.0, time_offset_s: 0.0}   # or just the path
    signals: {velocity: {scale: auto}, volume: {scale: auto}}   # default: both, auto

Figures (computed from the run's published samples, `FIGURES` below):
- the window is the last `periods` whole actuation periods before the end of the run (period
  boundaries at multiples of `period_s` from t = 0; `period_s` defaults to 1 / the scene's
  `frequency_hz`), and must start at or after `settle_s`; or [start_s, end_s] if given;
- mean_speed_m_s: time average (trapezoidal) of the signed forward velocity over the window
  (`metrics.window_mean_velocity_m_s`; a sweep's mean speed is a sample mean of |v| instead);
- burst_speed_m_s: the largest forward velocity sample in the window; min_speed_m_s the smallest;
- stroke_volume_m3: max - min cavity volume within each whole period of the window, averaged over
  the periods (with an explicit [start_s, end_s] window: max - min over the window);
- max_radius_m: the largest published mantle radius in the window (shell: at mid-meridian);
  peak_thrust_n: the largest jet thrust.

Residuals: targets: (model - value) / sigma per figure. Recording: model minus recorded velocity
and volume, the model linearly interpolated onto the recording's sample times (recording time -
time_offset_s = simulation time), each signal divided by its scale (auto: the recorded signal's
standard deviation over the window) and by sqrt(its sample count), so each signal's block
contributes its mean squared normalised misfit.

Parameters move in normalised coordinates in [0, 1] between their bounds (log-spaced when
low > 0, `scale: log`, the default then; else linear), so x_scale is the bounds' span and
`diff_step` is the finite-difference step as a fraction of it (1e-3 by default: far above the
simulator's Newton tolerance, far below the figures' curvature).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import math
from pathlib import Path
import sys
import time
from typing import Any

import numpy as np
from pulsejet_sim.analysis import metrics
from pulsejet_sim.core import topics
from pulsejet_sim.core.schema import mapping, Number
import yaml

FIGURES = {
    'mean_speed_m_s': 'time-averaged forward velocity over the window (m/s)',
    'burst_speed_m_s': 'largest forward velocity sample in the window (m/s)',
    'min_speed_m_s': 'smallest forward velocity sample in the window (m/s)',
    'stroke_volume_m3': 'max - min cavity volume per whole period, averaged over the window (m^3)',
    'max_radius_m': 'largest published mantle radius in the window (m)',
    'peak_thrust_n': 'largest jet thrust in the window (N)',
}
SIGNALS = {'velocity': topics.TOPIC_VELOCITY, 'volume': topics.TOPIC_VOLUME}
TOP_KEYS = (
    'name',
    'description',
    'scene',
    'duration_s',
    'overrides',
    'parameters',
    'targets',
    'predict',
    'recording',
    'signals',
    'figures',
    'options',
)
PARAM_KEYS = ('low', 'high', 'initial', 'vary', 'scale')
OPTION_DEFAULTS = {
    'max_evals': 60,
    'diff_step': 1e-3,
    'sensitivity_step': 1e-2,
    'jac': '2-point',
    'ftol': 1e-8,
    'xtol': 1e-8,
    'gtol': 1e-8,
}
CORRELATION_LIMIT = 0.95
SINGULAR_LIMIT = 1e-6  # singular value / largest one below this: a direction the data do not see
FAULT_RESIDUAL = 1e3  # residual of a run that blew up (finite, so the optimiser backs off)


class FitError(ValueError):
    """A fit file that cannot be run (names the key, the value and what is allowed)."""


@dataclass
class Parameter:
    key: str
    low: float
    high: float
    initial: float
    vary: bool = True
    log: bool = True
    literature: float | None = None  # the scene's own value

    def to_unit(self, value: float) -> float:
        if self.log:
            return (math.log(value) - math.log(self.low)) / (
                math.log(self.high) - math.log(self.low)
            )
        return (value - self.low) / (self.high - self.low)

    def from_unit(self, u: float) -> float:
        u = min(max(float(u), 0.0), 1.0)
        if self.log:
            return math.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))
        return self.low + u * (self.high - self.low)


@dataclass
class Target:
    figure: str
    value: float
    sigma: float


@dataclass
class FitSpec:
    path: Path
    name: str
    scene: str
    scene_data: dict
    duration_s: float
    overrides: dict
    parameters: list[Parameter]
    targets: list[Target] = field(default_factory=list)
    predict: dict[str, float | None] = field(default_factory=dict)
    recording: Path | None = None
    record_window: tuple[float, float] = (-math.inf, math.inf)
    time_offset_s: float = 0.0
    signals: dict[str, float] = field(default_factory=dict)  # name -> scale
    recorded: dict[str, tuple[np.ndarray, np.ndarray]] = field(
        default_factory=dict
    )  # name -> (t, value)
    record_times_end: float = 0.0
    period_s: float | None = None
    periods: int = 4
    settle_s: float = 0.0
    window: tuple[float, float] | None = None
    options: dict = field(default_factory=lambda: dict(OPTION_DEFAULTS))

    @property
    def varied(self) -> list[Parameter]:
        return [p for p in self.parameters if p.vary]


# ---------------------------------------------------------------- fit file


def _number(
    value: Any,
    where: str,
    allowed: str,
    low: float = -math.inf,
    high: float = math.inf,
    positive: bool = False,
) -> float:
    """Return a fit file's number by the one schema rule (core.schema.Number), or FitError."""
    low_open = positive and low <= 0.0  # positive: > 0 (a low above 0 already says more)
    rule = Number(None, 0.0 if low_open else low, high, low_open=low_open)
    return rule.accept(value, where, error=FitError, allowed=allowed)


def _mapping(value: Any, where: str, allowed: str) -> dict:
    return mapping(value, where, allowed, error=FitError)


def _unknown(mapping: dict, where: str, allowed: tuple[str, ...]) -> None:
    for key in mapping:
        if key not in allowed:
            raise FitError(f'{where}{key}: unknown key; allowed: {", ".join(allowed)}')


def get_dotted(data: dict, key: str) -> Any:
    node: Any = data
    for part in key.split('.'):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(key)
        node = node[part]
    return node


def dotted_overrides(values: dict[str, float]) -> dict:
    """
    Nest dotted keys into mappings.

    {'fluid.drag_coefficient': 0.7} -> {'fluid': {'drag_coefficient': 0.7}}
    """
    out: dict = {}
    for key, value in values.items():
        node = out
        parts = key.split('.')
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return out


def load_fit(path: str | Path) -> FitSpec:
    """Read and validate a fit file (a path, or a name under config/fits/)."""
    from pulsejet_sim.scene import load_scene_data, merge, resolve_scene_path, SceneError
    from pulsejet_sim.scene.paths import read_config_file

    p, data = read_config_file(path, 'fits', 'fit file', FitError)
    if not isinstance(data, dict):
        raise FitError(
            f'{p}: {type(data).__name__} at top level; allowed: a mapping with keys '
            f'{", ".join(TOP_KEYS)}'
        )
    where = f'{p}: '
    _unknown(data, where, TOP_KEYS)
    if 'scene' not in data:
        raise FitError(
            f'{where}scene: missing; allowed: a scene name under config/ or a YAML path'
        )
    scene_ref = str(data['scene'])
    relative = p.parent / scene_ref
    if scene_ref.endswith(('.yaml', '.yml')) and relative.is_file():
        scene_ref = str(relative)
    try:
        resolve_scene_path(scene_ref)
        raw, _ = load_scene_data(scene_ref)
    except SceneError as err:
        raise FitError(f'{where}scene: {err}') from None
    overrides = _mapping(
        data.get('overrides'), f'{where}overrides', 'a mapping merged into the scene'
    )
    scene_data = merge(raw, overrides)

    # ---- parameters
    params_in = _mapping(
        data.get('parameters'),
        f'{where}parameters',
        'a mapping of dotted scene key -> {low, high, initial, vary, scale}',
    )
    if not params_in:
        raise FitError(
            f'{where}parameters: missing or empty; allowed: a mapping of dotted scene key -> '
            '{low, high, initial, vary, scale}, e.g. fluid.drag_coefficient: {low: 0.3, high: 3.0}'
        )
    parameters = []
    for key, body in params_in.items():
        w = f'{where}parameters.{key}'
        body = _mapping(body, w, '{low, high, initial, vary, scale}')
        _unknown(body, w + '.', PARAM_KEYS)
        try:
            current = get_dotted(scene_data, str(key))
        except KeyError:
            raise FitError(
                f'{w}: not found in scene {data["scene"]!r}; allowed: a dotted path to a number '
                'in the scene, e.g. fluid.drag_coefficient'
            ) from None
        if isinstance(current, bool) or not isinstance(current, (int, float)):
            raise FitError(
                f'{w}: the scene holds {current!r} there, not a number; allowed: a dotted path to '
                'a '
                'number in the scene'
            )
        for k in ('low', 'high'):
            if k not in body:
                raise FitError(
                    f'{w}.{k}: missing; allowed: a finite number (both low and high are required)'
                )
        low = _number(body['low'], f'{w}.low', 'a finite number')
        high = _number(body['high'], f'{w}.high', 'a finite number')
        if not low < high:
            raise FitError(f'{w}: bounds low={low:g} >= high={high:g}; allowed: low < high')
        scale = body.get('scale', 'log' if low > 0 else 'linear')
        if scale not in ('log', 'linear'):
            raise FitError(f'{w}.scale: {scale!r} rejected; allowed: log or linear')
        if scale == 'log' and low <= 0:
            raise FitError(
                f'{w}.scale: log with low={low:g}; allowed: log only when low > 0, else linear'
            )
        initial = _number(
            body.get('initial', current),
            f'{w}.initial',
            f'a number within [{low:g}, {high:g}]',
            low,
            high,
        )
        vary = body.get('vary', True)
        if not isinstance(vary, bool):
            raise FitError(f'{w}.vary: {vary!r} rejected; allowed: true or false')
        parameters.append(
            Parameter(str(key), low, high, initial, vary, scale == 'log', float(current))
        )
    if not any(q.vary for q in parameters):
        raise FitError(
            f'{where}parameters: every parameter has vary: false; allowed: at least one varied '
            'parameter'
        )

    spec = FitSpec(
        path=p,
        name=str(data.get('name', p.stem)),
        scene=scene_ref,
        scene_data=scene_data,
        duration_s=0.0,
        overrides=overrides,
        parameters=parameters,
    )

    # ---- options
    options = _mapping(data.get('options'), f'{where}options', ', '.join(OPTION_DEFAULTS))
    _unknown(options, f'{where}options.', tuple(OPTION_DEFAULTS))
    spec.options = dict(OPTION_DEFAULTS)
    for key, value in options.items():
        if key == 'jac':
            if value not in ('2-point', '3-point'):
                raise FitError(
                    f'{where}options.jac: {value!r} rejected; allowed: 2-point or 3-point'
                )
        elif key == 'max_evals':
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise FitError(
                    f'{where}options.max_evals: {value!r} rejected; allowed: an integer >= 1'
                )
        else:
            _number(
                value, f'{where}options.{key}', 'a number in (0, 0.5]', 0.0, 0.5, positive=True
            )
        spec.options[key] = value

    # ---- targets or recording
    has_targets, has_recording = 'targets' in data, 'recording' in data
    if has_targets == has_recording:
        raise FitError(
            f'{where}targets / recording: {"both given" if has_targets else "neither given"}; '
            'allowed: exactly one of targets (figures) or recording (an MCAP file)'
        )
    if has_targets:
        _load_targets(spec, data, where)
    else:
        _load_recording(spec, data, where)

    # ---- duration
    scene_duration = float((scene_data.get('simulation') or {}).get('duration_s', 10.0))
    default = scene_duration
    if spec.recording is not None:
        default = spec.record_times_end
    spec.duration_s = _number(
        data.get('duration_s', default),
        f'{where}duration_s',
        'a number of seconds in (0, 1e5]',
        0.0,
        1e5,
        positive=True,
    )
    if spec.recording is not None and spec.duration_s < spec.record_times_end - 1e-9:
        raise FitError(
            f'{where}duration_s: {spec.duration_s:g} s ends before the recording window '
            f'({spec.record_times_end:g} s); allowed: at least {spec.record_times_end:g}'
        )
    if has_targets:
        _load_figures(spec, data, where)
    # the scene must load with the initial values (catches a parameter the model refuses)
    try:
        build_scene(spec, {q.key: q.initial for q in parameters})
    except (SceneError, ValueError) as err:
        raise FitError(f'{where}scene with the initial parameter values: {err}') from None
    return spec


def _load_targets(spec: FitSpec, data: dict, where: str) -> None:
    allowed = ', '.join(FIGURES)
    targets = _mapping(
        data['targets'],
        f'{where}targets',
        f'a mapping of figure -> {{value, sigma | tolerance}}; ' f'figures: {allowed}',
    )
    if not targets:
        raise FitError(f'{where}targets: empty; allowed: one or more of {allowed}')
    for name, body in targets.items():
        w = f'{where}targets.{name}'
        if name not in FIGURES:
            raise FitError(f'{w}: unknown figure; allowed: {allowed}')
        if not isinstance(body, dict):
            body = {'value': body}
        _unknown(body, w + '.', ('value', 'sigma', 'tolerance'))
        if 'value' not in body:
            raise FitError(f'{w}.value: missing; allowed: the measured value (a finite number)')
        value = _number(body['value'], f'{w}.value', 'a finite number')
        if 'sigma' in body and 'tolerance' in body:
            raise FitError(f'{w}: both sigma and tolerance; allowed: one of them')
        if 'sigma' in body:
            sigma = _number(
                body['sigma'],
                f'{w}.sigma',
                "a positive number (absolute, the figure's unit)",
                positive=True,
            )
        else:
            tol = _number(
                body.get('tolerance', 0.1),
                f'{w}.tolerance',
                'a positive fraction of |value|',
                positive=True,
            )
            sigma = tol * abs(value)
            if sigma <= 0:
                raise FitError(
                    f'{w}: value 0 with a relative tolerance; allowed: give sigma (absolute)'
                )
        spec.targets.append(Target(str(name), value, sigma))
    predict = data.get('predict') or {}
    if isinstance(predict, list):
        predict = dict.fromkeys(predict)
    predict = _mapping(
        predict,
        f'{where}predict',
        f'a mapping of figure -> {{value}} (or a list); figures: {allowed}',
    )
    for name, body in predict.items():
        w = f'{where}predict.{name}'
        if name not in FIGURES:
            raise FitError(f'{w}: unknown figure; allowed: {allowed}')
        if name in targets:
            raise FitError(f'{w}: also a target; allowed: a figure is either fitted or predicted')
        if isinstance(body, dict):
            _unknown(body, w + '.', ('value',))
            body = body.get('value')
        spec.predict[str(name)] = (
            None if body is None else _number(body, f'{w}.value', 'a finite number')
        )
    if 'signals' in data:
        raise FitError(
            f'{where}signals: only with recording; allowed with targets: figures, predict'
        )


def _load_recording(spec: FitSpec, data: dict, where: str) -> None:
    from pulsejet_sim.bag.reader import BagReadError, find_topic, load_series

    rec = data['recording']
    if isinstance(rec, str):
        rec = {'file': rec}
    rec = _mapping(
        rec, f'{where}recording', 'an MCAP path or {file, start_s, end_s, time_offset_s}'
    )
    _unknown(rec, f'{where}recording.', ('file', 'start_s', 'end_s', 'time_offset_s'))
    if 'file' not in rec:
        raise FitError(
            f'{where}recording.file: missing; allowed: an MCAP path (relative to the fit file)'
        )
    file = Path(str(rec['file'])).expanduser()
    if not file.is_absolute() and not file.is_file():
        file = spec.path.parent / file
    if not file.is_file():
        raise FitError(
            f'{where}recording.file: {str(rec["file"])!r} does not exist; allowed: an MCAP '
            'recording path '
            '(relative to the fit file or absolute)'
        )
    spec.time_offset_s = _number(
        rec.get('time_offset_s', 0.0), f'{where}recording.time_offset_s', 'a finite number'
    )
    start = _number(
        rec.get('start_s', 0.0), f'{where}recording.start_s', 'a number of seconds >= 0', 0.0
    )
    end = _number(
        rec.get('end_s', 1e9),
        f'{where}recording.end_s',
        f'a number of seconds > start_s ({start:g})',
        start,
    )
    if end <= start:
        raise FitError(
            f'{where}recording.end_s: {end:g} <= start_s {start:g}; allowed: end_s > start_s'
        )
    signals_in = data.get('signals', {name: {} for name in SIGNALS})
    if isinstance(signals_in, list):
        signals_in = {name: {} for name in signals_in}
    signals_in = _mapping(
        signals_in,
        f'{where}signals',
        f'a mapping of signal -> {{scale}}; signals: {", ".join(SIGNALS)}',
    )
    if not signals_in:
        raise FitError(f'{where}signals: empty; allowed: one or more of {", ".join(SIGNALS)}')
    try:
        series = load_series(file)
    except BagReadError as err:
        raise FitError(f'{where}recording.file: {err}') from None
    spec.recording = file
    spec.record_window = (start, end)
    spec.recorded = {}
    t_last = 0.0
    for name, body in signals_in.items():
        w = f'{where}signals.{name}'
        if name not in SIGNALS:
            raise FitError(f'{w}: unknown signal; allowed: {", ".join(SIGNALS)}')
        body = _mapping(body, w, '{scale: auto | a positive number}')
        _unknown(body, w + '.', ('scale',))
        topic = find_topic(series, SIGNALS[name])
        if topic is None:
            raise FitError(
                f'{w}: the recording {str(file)!r} has no topic {SIGNALS[name]}; '
                f'found {", ".join(sorted(series)) or "none"}'
            )
        t, v = series[topic]
        t = t - spec.time_offset_s
        keep = (t >= start - 1e-12) & (t <= end + 1e-12) & (t >= -1e-12)
        if keep.sum() < 2:
            raise FitError(
                f'{w}: fewer than 2 samples of {topic} in the window [{start:g}, '
                f'{min(end, 1e9):g}] s '
                f'(after time_offset_s); allowed: a window holding the recording'
            )
        t, v = t[keep], v[keep]
        scale = body.get('scale', 'auto')
        if scale == 'auto':
            scale = float(np.std(v)) or float(np.max(np.abs(v))) or 1.0
        else:
            scale = _number(
                scale,
                f'{w}.scale',
                "auto or a positive number (the signal's unit)",
                positive=True,
            )
        spec.signals[str(name)] = scale
        spec.recorded[str(name)] = (t, v)
        t_last = max(t_last, float(t[-1]))
    spec.record_times_end = t_last
    for key in ('targets', 'predict', 'figures'):
        if key in data:
            raise FitError(f'{where}{key}: only with targets; allowed with recording: signals')


def _load_figures(spec: FitSpec, data: dict, where: str) -> None:
    fig = _mapping(
        data.get('figures'), f'{where}figures', '{period_s, periods, settle_s} or {start_s, end_s}'
    )
    _unknown(fig, f'{where}figures.', ('period_s', 'periods', 'settle_s', 'start_s', 'end_s'))
    if 'start_s' in fig or 'end_s' in fig:
        if set(fig) & {'period_s', 'periods', 'settle_s'}:
            raise FitError(
                f'{where}figures: start_s/end_s together with periods; allowed: one window form'
            )
        start = _number(
            fig.get('start_s', 0.0), f'{where}figures.start_s', 'a number of seconds >= 0', 0.0
        )
        end = _number(
            fig.get('end_s', spec.duration_s),
            f'{where}figures.end_s',
            f'a number of seconds in ({start:g}, duration_s = {spec.duration_s:g}]',
            start,
            spec.duration_s,
        )
        if end <= start:
            raise FitError(
                f'{where}figures.end_s: {end:g} <= start_s {start:g}; allowed: end_s > start_s'
            )
        spec.window = (start, end)
        return
    if 'period_s' in fig:
        spec.period_s = _number(
            fig['period_s'],
            f'{where}figures.period_s',
            'a positive number of seconds',
            positive=True,
        )
    else:
        freq = None
        for section in ('actuation', 'routine'):
            sec = spec.scene_data.get(section)
            if isinstance(sec, dict) and isinstance(sec.get('frequency_hz'), (int, float)):
                freq = float(sec['frequency_hz'])
        if not freq or freq <= 0:
            raise FitError(
                f'{where}figures.period_s: missing and the scene has no frequency_hz; allowed: a '
                'period '
                'in s, or figures: {start_s, end_s}'
            )
        spec.period_s = 1.0 / freq
    periods = fig.get('periods', 4)
    if isinstance(periods, bool) or not isinstance(periods, int) or periods < 1:
        raise FitError(f'{where}figures.periods: {periods!r} rejected; allowed: an integer >= 1')
    spec.periods = periods
    spec.settle_s = _number(
        fig.get('settle_s', 0.0), f'{where}figures.settle_s', 'a number of seconds >= 0', 0.0
    )
    end = math.floor(spec.duration_s / spec.period_s + 1e-9) * spec.period_s
    start = end - periods * spec.period_s
    if start < spec.settle_s - 1e-9:
        raise FitError(
            f'{where}figures: the last {periods} whole periods of {spec.period_s:g} s start at '
            f'{start:g} s, before settle_s = {spec.settle_s:g} s; allowed: duration_s >= '
            f'{math.ceil(spec.settle_s / spec.period_s + periods) * spec.period_s:g} s or fewer '
            'periods'
        )


# ---------------------------------------------------------------- evaluation


def build_scene(spec: FitSpec, values: dict[str, float]):
    from pulsejet_sim.scene import load_scene, merge

    return load_scene(spec.scene, merge(spec.overrides, dotted_overrides(values)))


@dataclass
class Series:
    t: np.ndarray
    velocity: np.ndarray
    volume: np.ndarray
    radius: np.ndarray
    thrust: np.ndarray
    fault: str | None


def simulate(spec: FitSpec, values: dict[str, float], duration_s: float | None = None) -> Series:
    """One run of the scene with `values` at its published samples (initial state included)."""
    from pulsejet_sim.studies.runner import Drive

    drive = Drive(build_scene(spec, values), spec.duration_s if duration_s is None else duration_s)
    first = drive.sim.observe()
    rows = [
        (first.time_s, first.velocity_m_s, first.volume_m3, first.mantle_radius_m, first.thrust_n)
    ]
    rows += [
        (o.time_s, o.velocity_m_s, o.volume_m3, o.mantle_radius_m, o.thrust_n) for _, _, o in drive
    ]
    a = np.asarray(rows, dtype=float)
    return Series(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], drive.fault)


def window_of(spec: FitSpec) -> tuple[float, float]:
    if spec.window is not None:
        return spec.window
    end = math.floor(spec.duration_s / spec.period_s + 1e-9) * spec.period_s
    return end - spec.periods * spec.period_s, end


def figures(spec: FitSpec, s: Series) -> dict[str, float]:
    """
    Return the FIGURES of a run (see the module docstring).

    NaN where the run ended before the window.
    """
    start, end = window_of(spec)
    eps = 1e-9
    m = (s.t >= start - eps) & (s.t <= end + eps)
    if s.fault is not None or m.sum() < 2 or s.t[-1] < end - eps:
        return {name: math.nan for name in FIGURES}
    t, v = s.t[m], s.velocity[m]
    out = {
        'mean_speed_m_s': metrics.window_mean_velocity_m_s(t, v),
        'burst_speed_m_s': metrics.burst_speed_m_s(v),
        'min_speed_m_s': float(v.min()),
        'max_radius_m': float(s.radius[m].max()),
        'peak_thrust_n': float(s.thrust[m].max()),
    }
    if spec.window is None:
        strokes = []
        for k in range(spec.periods):
            a = start + k * spec.period_s
            mk = (s.t >= a - eps) & (s.t <= a + spec.period_s + eps)
            strokes.append(float(s.volume[mk].max() - s.volume[mk].min()))
        out['stroke_volume_m3'] = float(np.mean(strokes))
    else:
        out['stroke_volume_m3'] = float(s.volume[m].max() - s.volume[m].min())
    return out


class Evaluator:
    """Residuals of parameter vectors, cached, counted (every count is a real simulator run)."""

    def __init__(self, spec: FitSpec, progress=None):
        self.spec = spec
        self.progress = progress
        self.cache: dict[tuple, tuple[np.ndarray, dict]] = {}
        self.runs = 0
        self.faults = 0
        self.wall_s = 0.0

    def values(self, x: np.ndarray, params: list[Parameter] | None = None) -> dict[str, float]:
        """
        Return all parameters: the varied ones from x, the held ones at their initial.

        The varied ones are taken from x as physical values.
        """
        out = {q.key: q.initial for q in self.spec.parameters}
        for q, value in zip(params or self.spec.varied, x):
            out[q.key] = float(value)
        return out

    def evaluate(self, values: dict[str, float]) -> tuple[np.ndarray, dict]:
        key = tuple(round(values[q.key], 14) for q in self.spec.parameters)
        if key in self.cache:
            return self.cache[key]
        start = time.perf_counter()
        spec = self.spec
        series = simulate(spec, values)
        self.runs += 1
        info: dict[str, Any] = {'fault': series.fault}
        if spec.recording is None:
            figs = figures(spec, series)
            info['figures'] = figs
            r = np.array([(figs[tg.figure] - tg.value) / tg.sigma for tg in spec.targets])
        else:
            blocks = []
            info['rms'] = {}
            for name, scale in spec.signals.items():
                t_rec, v_rec = spec.recorded[name]
                model = getattr(series, name)
                if series.fault is not None or series.t[-1] < t_rec[-1] - 1e-9:
                    block = np.full(len(t_rec), math.nan)
                else:
                    block = (
                        (np.interp(t_rec, series.t, model) - v_rec) / scale / math.sqrt(len(t_rec))
                    )
                info['rms'][name] = float(np.sqrt(np.sum(block**2)))
                blocks.append(block)
            r = np.concatenate(blocks)
        if not np.all(np.isfinite(r)):
            self.faults += 1
            info['fault'] = info['fault'] or "the run ended before the figures' window"
            r = np.where(np.isfinite(r), r, FAULT_RESIDUAL)
        self.cache[key] = (r, info)
        self.wall_s += time.perf_counter() - start
        if self.progress is not None:
            shown = ', '.join(f'{k.split(".")[-1]}={v:.6g}' for k, v in values.items())
            self.progress.write(
                f'  run {self.runs:3d}: {shown} -> cost {0.5 * float(r @ r):.6g}'
                f'{"  FAULT " + str(info["fault"]) if info["fault"] else ""}\n'
            )
            self.progress.flush()
        return r, info

    def residuals_unit(self, u: np.ndarray) -> np.ndarray:
        varied = self.spec.varied
        return self.evaluate(self.values(np.array([q.from_unit(ui) for q, ui in zip(varied, u)])))[
            0
        ]


# ---------------------------------------------------------------- fit and report


@dataclass
class FitResult:
    spec: FitSpec
    initial: dict[str, float]
    fitted: dict[str, float]
    cost_initial: float
    cost: float
    residuals: np.ndarray
    info: dict
    runs: int
    optimizer_evals: int
    status: str
    success: bool
    wall_s: float
    sensitivity: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        spec = self.spec
        out: dict[str, Any] = {
            'name': spec.name,
            'fit_file': str(spec.path),
            'scene': spec.scene,
            'mode': 'recording' if spec.recording is not None else 'targets',
            'success': self.success,
            'status': self.status,
            'cost_initial': self.cost_initial,
            'cost': self.cost,
            'simulator_runs': self.runs,
            'optimizer_evaluations': self.optimizer_evals,
            'wall_s': round(self.wall_s, 2),
            'duration_s': spec.duration_s,
            'parameters': [
                {
                    'key': q.key,
                    'vary': q.vary,
                    'scene_value': q.literature,
                    'initial': self.initial[q.key],
                    'fitted': self.fitted[q.key],
                    'low': q.low,
                    'high': q.high,
                    'scale': 'log' if q.log else 'linear',
                    'at_bound': (
                        'lower'
                        if q.to_unit(self.fitted[q.key]) < 1e-6
                        else 'upper' if q.to_unit(self.fitted[q.key]) > 1 - 1e-6 else ''
                    ),
                }
                for q in spec.parameters
            ],
        }
        if spec.recording is not None:
            out['recording'] = str(spec.recording)
            out['signals'] = {
                name: {
                    'scale': scale,
                    'normalised_rms': self.info['rms'][name],
                    'samples': int(len(spec.recorded[name][0])),
                }
                for name, scale in spec.signals.items()
            }
        else:
            figs = self.info['figures']
            start, end = window_of(spec)
            out['window_s'] = [start, end]
            out['figures'] = {}
            for tg, r in zip(spec.targets, self.residuals):
                out['figures'][tg.figure] = {
                    'role': 'fitted',
                    'measured': tg.value,
                    'sigma': tg.sigma,
                    'model': figs[tg.figure],
                    'residual_sigma': float(r),
                    'relative_error': figs[tg.figure] / tg.value - 1 if tg.value else None,
                }
            for name, value in figs.items():
                if name in out['figures']:
                    continue
                entry: dict[str, Any] = {
                    'role': 'predicted' if name in spec.predict else 'reported',
                    'model': value,
                }
                measured = spec.predict.get(name)
                if measured is not None:
                    entry.update(
                        measured=measured,
                        relative_error=value / measured - 1 if measured else None,
                    )
                out['figures'][name] = entry
        out['sensitivity'] = self.sensitivity
        return out


def run_fit(spec: FitSpec, max_evals: int | None = None, progress=None) -> FitResult:
    """Least-squares fit of the varied parameters; then the sensitivity table at the solution."""
    from scipy.optimize import least_squares

    ev = Evaluator(spec, progress)
    varied = spec.varied
    start = time.perf_counter()
    u0 = np.array([q.to_unit(q.initial) for q in varied])
    r0 = ev.residuals_unit(u0)
    opts = spec.options
    result = least_squares(
        ev.residuals_unit,
        u0,
        bounds=(np.zeros(len(u0)), np.ones(len(u0))),
        method='trf',
        x_scale=np.ones(len(u0)),
        jac=opts['jac'],
        diff_step=float(opts['diff_step']),
        ftol=float(opts['ftol']),
        xtol=float(opts['xtol']),
        gtol=float(opts['gtol']),
        max_nfev=int(max_evals or opts['max_evals']),
    )
    fitted = ev.values(np.array([q.from_unit(u) for q, u in zip(varied, result.x)]))
    r, info = ev.evaluate(fitted)
    optimizer_runs = ev.runs
    out = FitResult(
        spec=spec,
        initial={q.key: q.initial for q in spec.parameters},
        fitted=fitted,
        cost_initial=0.5 * float(r0 @ r0),
        cost=0.5 * float(r @ r),
        residuals=r,
        info=info,
        runs=optimizer_runs,
        optimizer_evals=int(result.nfev),
        status=str(result.message),
        success=bool(result.success),
        wall_s=0.0,
    )
    out.sensitivity = sensitivity(ev, fitted, r, info)
    out.runs = ev.runs
    out.wall_s = time.perf_counter() - start
    return out


def sensitivity(ev: Evaluator, fitted: dict[str, float], r: np.ndarray, info: dict) -> dict:
    """
    Compute central differences in ln p at the solution, for every parameter (held ones too).

    Linear-scale parameters: in p, step a fraction of the bounds' span. Returns the table as plain
    data.
    """
    spec = ev.spec
    h = float(spec.options['sensitivity_step'])
    columns, fig_cols, notes = [], [], {}
    for q in spec.parameters:
        p = fitted[q.key]
        if q.log:
            lo, hi = p * math.exp(-h), p * math.exp(h)
            span = 2 * h
        else:
            step = h * (q.high - q.low)
            lo, hi = p - step, p + step
            span = 2 * step
        try:
            r_hi, i_hi = ev.evaluate(dict(fitted, **{q.key: hi}))
        except ValueError:
            r_hi, i_hi, span = r, info, span / 2
        try:
            r_lo, i_lo = ev.evaluate(dict(fitted, **{q.key: lo}))
        except ValueError:
            r_lo, i_lo, span = r, info, span / 2
        if i_hi.get('fault') or i_lo.get('fault'):
            notes[q.key] = 'a run of the difference blew up or ended early'
        columns.append((r_hi - r_lo) / span)
        if spec.recording is None:
            fig_cols.append(
                {name: (i_hi['figures'][name] - i_lo['figures'][name]) / span for name in FIGURES}
            )
    J_all = np.array(columns).T if columns else np.zeros((len(r), 0))
    keys = [q.key for q in spec.parameters]
    wrt = ['d ln p' if q.log else 'd p' for q in spec.parameters]

    # figure sensitivities: d ln(figure) / d ln(p) (normalised) for targets; d(rms)/d ln p for
    # recordings
    table: dict[str, dict[str, float]] = {}
    if spec.recording is None:
        figs = info['figures']
        for name in FIGURES:
            row = {}
            for q, col in zip(spec.parameters, fig_cols):
                d = col[name]
                if q.log:
                    row[q.key] = d / figs[name] if figs[name] else math.nan
                else:
                    row[q.key] = (
                        d * fitted[q.key] / figs[name]
                        if figs[name] and fitted[q.key]
                        else math.nan
                    )
            table[name] = row
        kind = 'd ln(figure) / d ln(parameter)'
    else:
        first = 0
        for name in spec.signals:
            rows = slice(first, first + len(spec.recorded[name][0]))
            first = rows.stop
            table[name] = {k: float(np.linalg.norm(J_all[rows, i])) for i, k in enumerate(keys)}
        kind = (
            'rms change of the signal, in units of its scale, per unit change of ln(parameter) '
            "(|dr/d ln p| over the signal's block)"
        )

    def analyse(J: np.ndarray, names: list[str]) -> dict:
        m, n = J.shape
        if n == 0:
            return {}
        s = np.linalg.svd(J, compute_uv=False)
        smax = float(s.max()) if s.size else 0.0
        cond = float(smax / s.min()) if s.size and s.min() > 0 else math.inf
        JtJ = J.T @ J
        inv = np.linalg.pinv(JtJ, rcond=1e-12, hermitian=True)
        if spec.recording is not None:
            dof = max(m - n, 1)
            inv = inv * float(r @ r) / dof
        se = np.sqrt(np.clip(np.diag(inv), 0.0, None))
        with np.errstate(invalid='ignore', divide='ignore'):
            corr = inv / np.outer(se, se)
        corr = np.where(np.isfinite(corr), corr, 0.0)
        flags = {}
        for j, name in enumerate(names):
            reasons = []
            if np.linalg.norm(J[:, j]) <= SINGULAR_LIMIT * max(smax, 1e-300):
                reasons.append('the fitted figures do not depend on it')
            for k, other in enumerate(names):
                if k != j and abs(corr[j, k]) > CORRELATION_LIMIT:
                    reasons.append(f'correlation {corr[j, k]:+.3f} with {other}')
            flags[name] = reasons
        # directions of parameter space the residuals do not see (rank < n, e.g. fewer residuals
        # than parameters): a parameter with a sizeable component in them is not identifiable
        _, sv, vt = np.linalg.svd(J, full_matrices=True)
        rank = int(np.sum(sv > SINGULAR_LIMIT * max(smax, 1e-300)))
        null = vt[rank:]
        for j, name in enumerate(names):
            if (
                null.shape[0]
                and np.linalg.norm(null[:, j]) > 0.1
                and not any('singular' in x for x in flags[name])
            ):
                flags[name].append(
                    f'in the null space of the Jacobian (rank {rank} for {n} parameters: '
                    'a combination the residuals do not see)'
                )
        return {
            'parameters': names,
            'singular_values': [float(v) for v in s],
            'condition_number': cond,
            'standard_error_ln': {nm: float(v) for nm, v in zip(names, se)},
            'correlation': {
                nm: {o: float(corr[i, k]) for k, o in enumerate(names)}
                for i, nm in enumerate(names)
            },
            'not_identifiable': {nm: reasons for nm, reasons in flags.items() if reasons},
        }

    varied_idx = [i for i, q in enumerate(spec.parameters) if q.vary]
    fit_part = analyse(J_all[:, varied_idx], [keys[i] for i in varied_idx])
    for q in spec.parameters:
        if q.vary and q.log:
            fit_part.setdefault('standard_error', {})[q.key] = (
                fit_part['standard_error_ln'][q.key] * fitted[q.key]
            )
        elif q.vary:
            fit_part.setdefault('standard_error', {})[q.key] = fit_part['standard_error_ln'][q.key]
    out = {
        'kind': kind,
        'step': h,
        'wrt': dict(zip(keys, wrt)),
        'figures': table,
        'jacobian': {k: [float(x) for x in J_all[:, i]] for i, k in enumerate(keys)},
        'fit': fit_part,
        'notes': notes,
        'covariance': (
            "(J^T J)^-1 with residuals in units of the targets' sigma"
            if spec.recording is None
            else 's^2 (J^T J)^-1, s^2 = sum(r^2) / (m - n) (residual-based)'
        ),
    }
    if len(keys) > len(varied_idx):
        out['all_parameters'] = analyse(J_all, keys)
    return out


def _fmt(v: Any, spec: str = '.4g') -> str:
    if v is None:
        return '-'
    if isinstance(v, float) and not math.isfinite(v):
        return 'inf' if v > 0 else ('-inf' if v < 0 else 'nan')
    return format(v, spec)


def format_report(res: FitResult) -> str:
    d = res.as_dict()
    spec = res.spec
    sens = res.sensitivity
    lines = [
        f'# fit `{spec.name}`',
        '',
        f'Scene `{spec.scene}`, fit file `{spec.path}`, {d["mode"]} mode, {spec.duration_s:g} s '
        'per run. '
        f'{res.optimizer_evals} optimiser evaluations, {res.runs} simulator runs in total '
        f'(with the sensitivity runs), {res.wall_s:.1f} s wall. Cost 0.5 sum(r^2): '
        f'{res.cost_initial:.4g} initial -> **{res.cost:.4g}**. Optimiser: {res.status}',
        '',
        '| parameter | scene value | initial | fitted | bounds | std. error | |',
        '|---|---|---|---|---|---|---|',
    ]
    se = sens.get('fit', {}).get('standard_error', {})
    flagged = sens.get('fit', {}).get('not_identifiable', {})
    for p in d['parameters']:
        note = (
            'held (not fitted)'
            if not p['vary']
            else (
                'NOT identifiable: ' + '; '.join(flagged[p['key']]) if p['key'] in flagged else ''
            )
        )
        if p['vary'] and p['at_bound']:
            note = (
                note + '; ' if note else ''
            ) + f'at its {p["at_bound"]} bound (the data want it further)'
        lines.append(
            f'| `{p["key"]}` | {_fmt(p["scene_value"])} | {_fmt(p["initial"])} | '
            f'**{_fmt(p["fitted"], ".5g")}** | '
            f'[{_fmt(p["low"])}, {_fmt(p["high"])}] {p["scale"]} | '
            f'{_fmt(se.get(p["key"]), ".2g")} | {note} |'
        )
    lines.append('')
    if spec.recording is None:
        start, end = d['window_s']
        lines += [
            f'Figures over [{start:g}, {end:g}] s:',
            '',
            '| figure | measured | model | residual (sigma) | error | role |',
            '|---|---|---|---|---|---|',
        ]
        for name, f in d['figures'].items():
            err = f.get('relative_error')
            lines.append(
                f'| {name} | {_fmt(f.get("measured"))} | {_fmt(f["model"])} | '
                f'{_fmt(f.get("residual_sigma"), "+.3g")} | '
                f'{"-" if err is None else format(err, "+.1%")} | '
                f'{f["role"]} |'
            )
    else:
        lines += [
            f'Recording `{spec.recording}`:',
            '',
            '| signal | samples | scale | normalised rms misfit |',
            '|---|---|---|---|',
        ]
        for name, s in d['signals'].items():
            lines.append(
                f'| {name} | {s["samples"]} | {s["scale"]:.4g} | {s["normalised_rms"]:.3g} |'
            )
    lines += [
        '',
        f'Sensitivity at the solution ({sens["kind"]}, central differences, step '
        f'{sens["step"]:g}):',
        '',
    ]
    keys = [q.key for q in spec.parameters]
    lines.append(
        '| | '
        + ' | '.join(f'`{k}`{"" if q.vary else " (held)"}' for k, q in zip(keys, spec.parameters))
        + ' |'
    )
    lines.append('|---' * (len(keys) + 1) + '|')
    for name, row in sens['figures'].items():
        lines.append(f'| {name} | ' + ' | '.join(_fmt(row[k], '+.3f') for k in keys) + ' |')
    fitp = sens.get('fit', {})
    if fitp:
        lines += [
            '',
            f'Identifiability of the fitted parameters: singular values '
            f'{", ".join(_fmt(v, ".3g") for v in fitp["singular_values"])}, condition number '
            f'{_fmt(fitp["condition_number"], ".3g")}; covariance {sens["covariance"]}.',
            '',
        ]
        names = fitp['parameters']
        lines.append('| correlation | ' + ' | '.join(f'`{n}`' for n in names) + ' |')
        lines.append('|---' * (len(names) + 1) + '|')
        for n in names:
            lines.append(
                f'| `{n}` | '
                + ' | '.join(_fmt(fitp['correlation'][n][o], '+.3f') for o in names)
                + ' |'
            )
        if fitp['not_identifiable']:
            for n, reasons in fitp['not_identifiable'].items():
                lines.append(f'\n**{n} is not identifiable**: {"; ".join(reasons)}.')
        else:
            lines.append(
                '\nEvery fitted parameter is identifiable (no correlation above '
                f'{CORRELATION_LIMIT}, no singular value near zero).'
            )
    allp = sens.get('all_parameters')
    if allp:
        lines.append(
            f'\nWith the held parameters varied too: singular values '
            f'{", ".join(_fmt(v, ".3g") for v in allp["singular_values"])}, condition number '
            f'{_fmt(allp["condition_number"], ".3g")}'
            + (
                ': '
                + '; '.join(f'{n}: {", ".join(r)}' for n, r in allp['not_identifiable'].items())
                if allp['not_identifiable']
                else ''
            )
            + '.'
        )
    return '\n'.join(lines) + '\n'


def _yaml_number(value: float) -> str:
    text = f'{value:.6g}'
    if 'e' in text:
        mant, exp = text.split('e')
        if '.' not in mant:
            mant += '.0'
        text = f'{mant}e{exp}'
    return text


def fitted_scene_text(spec: FitSpec, values: dict[str, float], header: str = '') -> str:
    """
    Return the scene file with the fitted values written in.

    Comments are kept where the key is found on its own line; otherwise the scene is re-dumped.
    Fit-file overrides are not written.
    """
    from pulsejet_sim.scene import load_scene_data, merge

    raw, path = load_scene_data(spec.scene)
    text = path.read_text()
    lines = text.splitlines()
    import re

    pattern = re.compile(r'^(\s*)([A-Za-z0-9_]+):(\s*)([^#\n]*?)(\s*#.*)?$')
    for key, value in values.items():
        parts = key.split('.')
        stack: list[tuple[int, str]] = []
        done = False
        for i, line in enumerate(lines):
            mt = pattern.match(line)
            if not mt or line.lstrip().startswith('#'):
                continue
            indent = len(mt.group(1))
            while stack and stack[-1][0] >= indent:
                stack.pop()
            stack.append((indent, mt.group(2)))
            if [s for _, s in stack] == parts and mt.group(4).strip():
                lines[i] = (
                    f'{mt.group(1)}{mt.group(2)}:{mt.group(3) or " "}'
                    f'{_yaml_number(value)}{mt.group(5) or ""}'
                )
                done = True
                break
        if not done:
            lines = []
            break
    expected = merge(
        raw, dotted_overrides({k: yaml.safe_load(_yaml_number(v)) for k, v in values.items()})
    )
    out = '\n'.join(lines) + '\n' if lines else ''
    if not out or yaml.safe_load(out) != expected:
        out = yaml.safe_dump(expected, sort_keys=False)
    return header + out


def write_results(res: FitResult, out_dir: str | Path) -> dict[str, Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        'results': out / 'fit_results.yaml',
        'report': out / 'fit_report.md',
        'scene': out / f'{Path(res.spec.scene).stem}_fitted.yaml',
    }
    paths['results'].write_text(yaml.safe_dump(_plain(res.as_dict()), sort_keys=False))
    paths['report'].write_text(format_report(res))
    fitted = {
        q.key: res.fitted[q.key] for q in res.spec.parameters
    }  # held ones at their (fit file's) value
    header = (
        f'# Fitted by `pulsejet fit {res.spec.path}` (cost {res.cost:.4g}); '
        + ', '.join(
            f'{q.key} = {_yaml_number(res.fitted[q.key])}{"" if q.vary else " (held)"}'
            for q in res.spec.parameters
        )
        + '\n'
    )
    paths['scene'].write_text(fitted_scene_text(res.spec, fitted, header))
    return paths


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else str(v)
    if isinstance(x, np.integer):
        return int(x)
    return x


def main_fit(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog='pulsejet fit',
        description='Fit named scene parameters to target '
        'figures or to a recorded MCAP (scipy least squares).',
    )
    parser.add_argument('fit', help='fit YAML path or a name under config/fits/')
    parser.add_argument('--out', default=None, help='output folder (default: runs/fits/<name>)')
    parser.add_argument(
        '--max-evals',
        type=int,
        default=None,
        help="optimiser evaluations at most (default: the file's)",
    )
    parser.add_argument('--quiet', action='store_true', help='do not print every run')
    args = parser.parse_args(argv)
    if args.max_evals is not None and args.max_evals < 1:
        print(
            f'pulsejet fit: --max-evals {args.max_evals} rejected; allowed: 1 or more',
            file=sys.stderr,
        )
        return 2
    try:
        spec = load_fit(args.fit)
    except FitError as err:
        print(f'pulsejet fit: {err}', file=sys.stderr)
        return 2
    if spec.recording:
        source = 'recording ' + str(spec.recording)
    else:
        source = 'targets ' + ', '.join(t.figure for t in spec.targets)
    print(
        f'{spec.name}: fitting {", ".join(q.key for q in spec.varied)} of scene {spec.scene} '
        f'({source})'
    )
    res = run_fit(spec, args.max_evals, progress=None if args.quiet else sys.stderr)
    paths = write_results(res, args.out or Path('runs') / 'fits' / spec.name)
    print(format_report(res))
    print('\n'.join(f'{k}: {v}' for k, v in paths.items()))
    return 0


__all__ = [
    'FIGURES',
    'FitError',
    'FitSpec',
    'FitResult',
    'Parameter',
    'load_fit',
    'simulate',
    'figures',
    'run_fit',
    'format_report',
    'write_results',
    'fitted_scene_text',
    'main_fit',
]
