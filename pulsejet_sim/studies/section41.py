"""
The figures paper 001 reports for its section 4.1 escape manoeuvre, measured on a lumped run.

Definitions (fixed before any result; docs/validation/papers.md, "Section 4.1 against the paper"):

- window: t = 0 to the end of the first deflation, the first time b' returns to >= 0 after it went
  negative (the fluid mass's first minimum), or the end of the run if it never does;
- added-mass share (primary): impulse share over the window, int F_amv dt / int (T + F_amv) dt,
  with F_amv = -m_x' U (positive when it propels) and T the jet thrust (paper, section 4.2 and
  conclusions: "as much as 75% of the propulsive force", "75% of the total thrust generated";
  Fig. 7 plots thrust, added-mass-variation force and drag over the pulsation);
- added-mass share (secondary): max_t F_amv / max_t (T + F_amv) over the window;
- deflation time: first time 90 % of the water above the rest volume is out,
  (m_f(0) - m_f(t)) / (m_f(0) - m_f(b0)) >= 0.9;
- k_x / k: the largest value over the run of the paper's fluid stiffness (section 3.5, eq. 10)
  over the shell's k (paper, section 4.2 and Fig. 6: "always negligible", conclusions "about 1%");
- settled fluid mass: mean over the last `settle_window_s` of the run (paper, section 4.2: "about
  1.0 kg"), with its spread (max - min) there;
- peak speed: max U over the run.

Sampling: every physics step inside the window (trapezoidal impulses), then every
`sample_period_s` (the same instants at every dt, so a run at dt/2 is comparable).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import math

import numpy as np
from pulsejet_sim.core.model_io import SimulationBlowUp
from pulsejet_sim.models.lumped import kernels as K


@dataclass
class Section41Figures:
    dt_s: float
    duration_s: float
    blow_up_s: float | None  # time the run stopped on a bound, None if it ran to the end
    blow_up_cause: str  # which bound stopped it ('' if none)
    window_end_s: float  # end of the first deflation (or of the run)
    deflation_90_s: float | None  # 90 % of the water above the rest volume out (None: never)
    share_impulse: float  # primary added-mass share
    share_peak: float  # secondary added-mass share
    kx_over_k_max: float  # over the run
    kx_over_k_window_max: float  # over the first deflation
    peak_speed_m_s: float
    fluid_mass_initial_kg: float
    fluid_mass_settled_kg: float | None  # None when the run stopped early
    fluid_mass_spread_kg: float | None
    fluid_mass_min_kg: float
    ledger: dict

    def as_dict(self) -> dict:
        return asdict(self)


def _fluid_mass(model, b: float) -> float:
    p = model.params
    return float(p[K.P_RHO] * (4.0 / 3.0 * math.pi * p[K.P_A] * b * b - p[K.P_V_SOLID]))


def section41_figures(
    model,
    duration_s: float = 20.0,
    settle_window_s: float = 3.0,
    sample_period_s: float = 0.01,
    max_window_s: float = 15.0,
) -> Section41Figures:
    """Run `model` (a LumpedModel) from its initial state with its initial command and measure."""
    dt = model.dt_s
    command = model.initial_command
    state = model.initial_state()
    initial = state.copy()
    k = model.params[K.P_K]
    m0 = _fluid_mass(model, state[K.Y_B])
    m_rest = _fluid_mass(model, model.params[K.P_B0])
    n_total = int(round(duration_s / dt))
    n_sample = max(1, int(round(sample_period_s / dt)))
    max_window_steps = int(round(max_window_s / dt))

    def sample():
        return model.diagnostics(state, command)

    def kx_now():
        # the paper's k_x (section 3.5, eq. 10) as a diagnostic, whether or not a coupling applies
        # it
        _, value = K.fluid_stiffness_force(state[K.Y_B], state[K.Y_U], model.params)
        return value

    d = sample()
    times, thrust, amv, kx, speed, mass = (
        [0.0],
        [d[K.D_THRUST]],
        [d[K.D_AMV_FORCE]],
        [kx_now()],
        [state[K.Y_U]],
        [_fluid_mass(model, state[K.Y_B])],
    )
    step = 0
    went_negative = False
    window_end_step = None
    blow_up_s, cause = None, ''
    deflation_90 = None

    def record(t_s):
        d = sample()
        times.append(t_s)
        thrust.append(d[K.D_THRUST])
        amv.append(d[K.D_AMV_FORCE])
        kx.append(kx_now())
        speed.append(state[K.Y_U])
        mass.append(_fluid_mass(model, state[K.Y_B]))

    try:
        # inside the first deflation: sample every step
        while step < n_total and step < max_window_steps:
            model.advance(state, step * dt, 1, command)
            step += 1
            record(step * dt)
            if state[K.Y_W] < 0.0:
                went_negative = True
            elif went_negative:
                window_end_step = step
                break
        # after it: sample every sample_period_s, at the same instants for every dt
        while step < n_total:
            n = min(n_sample - step % n_sample, n_total - step)
            model.advance(state, step * dt, n, command)
            step += n
            record(step * dt)
    except SimulationBlowUp as err:
        blow_up_s = err.time_s
        cause = str(err).split(': ', 1)[-1].split(' (')[0]
    t = np.array(times)
    thrust, amv, kx, speed, mass = (np.array(v) for v in (thrust, amv, kx, speed, mass))
    n_window = (
        window_end_step if window_end_step is not None else min(step, max_window_steps)
    ) + 1
    tw, tw_thrust, tw_amv = t[:n_window], thrust[:n_window], amv[:n_window]
    impulse_amv = float(np.trapezoid(tw_amv, tw))
    impulse_total = float(np.trapezoid(tw_thrust + tw_amv, tw))
    out_fraction = (m0 - mass) / (m0 - m_rest)
    reached = np.nonzero(out_fraction >= 0.9)[0]
    if reached.size:
        i = int(reached[0])
        # linear interpolation between the samples around the crossing
        f0, f1 = out_fraction[i - 1], out_fraction[i]
        deflation_90 = float(t[i - 1] + (0.9 - f0) / (f1 - f0) * (t[i] - t[i - 1]))
    settled = spread = None
    if blow_up_s is None:
        late = mass[t >= duration_s - settle_window_s - 1e-12]
        settled, spread = float(late.mean()), float(late.max() - late.min())
    ledger = model.energy_ledger(state, initial)
    return Section41Figures(
        dt_s=dt,
        duration_s=duration_s,
        blow_up_s=blow_up_s,
        blow_up_cause=cause,
        window_end_s=float(tw[-1]),
        deflation_90_s=deflation_90,
        share_impulse=impulse_amv / impulse_total if impulse_total > 0 else float('nan'),
        share_peak=float(tw_amv.max() / (tw_thrust + tw_amv).max()),
        kx_over_k_max=float(kx.max() / k),
        kx_over_k_window_max=float(kx[:n_window].max() / k),
        peak_speed_m_s=float(speed.max()),
        fluid_mass_initial_kg=m0,
        fluid_mass_settled_kg=settled,
        fluid_mass_spread_kg=spread,
        fluid_mass_min_kg=float(mass.min()),
        ledger=ledger,
    )
