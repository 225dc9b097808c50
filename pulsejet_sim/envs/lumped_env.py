"""
One lumped pump/valve robot (paper 001) as a gymnasium environment.

Action (SI, ``Box`` within ``Command.LIMITS``): ``[pump flow command (m^3/s), valve opening command
(0 shut .. 1 open)]``, held for one control period (``control_period_s``, default 0.05 s, a whole
number of the scene's physics steps). Out-of-range actions are clipped, and a valve opening below
the valve's seat (``VALVE_MIN_OPENING``, 0.15 %) shuts it (``info['action_clipped']``).

Observation (SI, ``Box``): ``[vehicle speed U (m/s), minor semi-axis b (m), db/dt (m/s), fluid
volume in the cavity (m^3), actual pump flow (m^3/s), actual valve opening (0..1)]``.

Reward: ``reward=`` one of ``pulsejet_sim.envs.rewards.REWARDS`` (definitions there).
Termination: a fault of the physics (``SimulationBlowUp``: a bound or a non-finite value) ends the
episode with ``terminated=True``, reward ``-fault_penalty`` and ``info['fault']`` (the message);
the observation is the last good state (never NaN). Truncation: ``max_episode_s`` of simulated
time. Seeding: ``reset(seed=...)`` draws the initial minor semi-axis ``b(0) (1 + u)``, ``u``
uniform in ``[-initial_b_jitter, initial_b_jitter]`` (0: the scene's exact state), so a seed fixes
the episode. The model, its integrator and its terms come from the scene (``scene_overrides``
merged in, e.g. ``{'simulation': {'integrator': 'adaptive'}}``).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
from gymnasium import spaces
import numpy as np
from pulsejet_sim.analysis import metrics
from pulsejet_sim.core.model_io import Command, SimulationBlowUp, VALVE_MIN_OPENING
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.envs import rewards as R
from pulsejet_sim.models.lumped import model as lumped
from pulsejet_sim.scene import load_scene

OBS_NAMES = (
    'speed_m_s',
    'minor_semi_axis_m',
    'minor_semi_axis_rate_m_s',
    'volume_m3',
    'pump_flow_m3_s',
    'valve_opening',
)
ACTION_NAMES = ('pump_flow_m3_s', 'valve_opening')


def lumped_observation(Y: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Observation rows from lumped states (NY... or (N, NY...)), float64."""
    return np.stack(
        [
            lumped.velocity_m_s(Y),
            lumped.minor_semi_axis_m(Y),
            lumped.minor_semi_axis_rate_m_s(Y),
            lumped.cavity_volume_m3(Y, params),
            lumped.pump_flow_m3_s(Y),
            lumped.valve_opening(Y),
        ],
        axis=-1,
    )


def lumped_spaces(params: np.ndarray) -> tuple[spaces.Box, spaces.Box]:
    a = lumped.major_semi_axis_m(params)
    q_lo, q_hi = Command.LIMITS['pump_flow_m3_s']
    v_lo, v_hi = Command.LIMITS['valve_opening']
    action = spaces.Box(np.array([q_lo, v_lo]), np.array([q_hi, v_hi]), dtype=np.float64)
    b_min, b_max = lumped.minor_semi_axis_bounds_m(params)
    u_max = lumped.speed_bound_m_s(params)
    v_max = 4.0 / 3.0 * math.pi * a * b_max**2  # the cavity at b_max, solid volume not taken off
    low = np.array([-u_max, b_min, -np.inf, -lumped.solid_volume_m3(params), -q_hi, 0.0])
    high = np.array([u_max, b_max, np.inf, v_max, q_hi, 1.0])
    return spaces.Box(low, high, dtype=np.float64), action


def clip_actions(actions: np.ndarray, space: spaces.Box) -> np.ndarray:
    """
    Return actions (..., 2) inside the Box, NaN as 0; a valve opening below the seat shuts it.

    A command refuses an opening between 0 and the valve's seat (VALVE_MIN_OPENING), where the
    lumped model cannot hold the flow; an agent's action there means "nearly shut", so it is shut.
    """
    act = np.clip(np.nan_to_num(actions, nan=0.0), space.low, space.high)
    act[..., 1] = np.where(act[..., 1] < VALVE_MIN_OPENING, 0.0, act[..., 1])
    return act


def lumped_mass_kg(params: np.ndarray) -> float:
    """Solid mass plus the water of the rest cavity (the cost of transport's m)."""
    return float(lumped.dry_mass_kg(params) + lumped.rest_cavity_water_kg(params))


def steps_per_period(control_period_s: float, dt_s: float) -> int:
    if not (math.isfinite(control_period_s) and control_period_s > 0):
        raise ValueError(
            f'control_period_s={control_period_s!r} rejected; allowed: a positive number of '
            'seconds'
        )
    n = int(round(control_period_s / dt_s))
    if n < 1 or abs(n * dt_s - control_period_s) > 1e-9 * max(1.0, control_period_s):
        raise ValueError(
            f'control_period_s={control_period_s!r} rejected; allowed: a whole multiple of the '
            f'physics step dt_s={dt_s:g} s'
        )
    return n


def episode_periods(max_episode_s: float, control_period_s: float) -> int:
    """Return the control periods of an episode (truncation); ValueError names a bad length."""
    if not (max_episode_s > 0 and math.isfinite(max_episode_s)):
        raise ValueError(
            f'max_episode_s={max_episode_s!r} rejected; allowed: a positive number of seconds'
        )
    return int(math.ceil(max_episode_s / control_period_s - 1e-9))


def check_b_jitter(initial_b_jitter: float) -> float:
    """Return the initial jitter of the minor semi-axis (fraction); ValueError outside [0, 0.5)."""
    if not 0.0 <= initial_b_jitter < 0.5:
        raise ValueError(f'initial_b_jitter={initial_b_jitter!r} rejected; allowed: [0, 0.5)')
    return float(initial_b_jitter)


class LumpedPumpValveEnv(gym.Env):
    metadata = {'render_modes': []}

    def __init__(
        self,
        scene: str = 'pump_cycle',
        scene_overrides: dict | None = None,
        control_period_s: float = 0.05,
        max_episode_s: float = 10.0,
        reward: str = 'distance',
        target_speed_m_s: float = 0.2,
        fault_penalty: float = 100.0,
        initial_b_jitter: float = 0.02,
        cot_min_distance_m: float = 0.01,
    ):
        self.scene = load_scene(scene, scene_overrides)
        self.model = self.scene.model
        if self.model.name != 'lumped':
            raise ValueError(
                f'scene {scene!r} is a {self.model.name} scene; allowed: a lumped scene'
            )
        self.reward_name = R.check_reward(reward)
        self.n_steps = steps_per_period(control_period_s, self.model.dt_s)
        self.control_period_s = self.n_steps * self.model.dt_s
        self.max_periods = episode_periods(max_episode_s, self.control_period_s)
        self.target_speed_m_s = float(target_speed_m_s)
        self.fault_penalty = float(fault_penalty)
        self.initial_b_jitter = check_b_jitter(initial_b_jitter)
        self.cot_min_distance_m = float(cot_min_distance_m)
        self.mass_kg = lumped_mass_kg(self.model.params)
        self.observation_space, self.action_space = lumped_spaces(self.model.params)
        self.sim = Simulation(self.model)
        self.periods = 0

    def _obs(self) -> np.ndarray:
        obs = lumped_observation(self.sim.state, self.model.params)
        return np.clip(obs, self.observation_space.low, self.observation_space.high)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.sim.reset()
        if self.initial_b_jitter > 0.0:
            u = self.np_random.uniform(-self.initial_b_jitter, self.initial_b_jitter)
            lumped.scale_minor_semi_axis(self.sim.state, self.model.params, 1.0 + u)
            self.sim.initial_state = self.sim.state.copy()
        self.periods = 0
        return self._obs(), {'time_s': 0.0, 'position_m': 0.0}

    def step(self, action):
        raw = np.asarray(action, dtype=np.float64).reshape(2)
        act = clip_actions(raw, self.action_space)
        command = Command(float(act[0]), float(act[1]), 0.0)
        y = self.sim.state
        x0, w0 = float(lumped.position_m(y)), float(lumped.pump_work_j(y))
        info: dict[str, Any] = {'action_clipped': bool(np.any(act != raw))}
        terminated = False
        try:
            self.sim.step(self.n_steps, command)
        except SimulationBlowUp as err:
            terminated = True
            info['fault'] = str(err)
        y = self.sim.state
        self.periods += 1
        if terminated:
            reward = -self.fault_penalty
        else:
            reward = float(
                R.reward(
                    self.reward_name,
                    x0=x0,
                    x1=float(lumped.position_m(y)),
                    x_start=0.0,
                    work0=w0,
                    work1=float(lumped.pump_work_j(y)),
                    period_s=self.control_period_s,
                    mass_kg=self.mass_kg,
                    target_speed_m_s=self.target_speed_m_s,
                    d_min_m=self.cot_min_distance_m,
                )
            )
        truncated = (not terminated) and self.periods >= self.max_periods
        info.update(
            time_s=self.periods * self.control_period_s,
            position_m=float(lumped.position_m(y)),
            actuation_work_j=float(lumped.pump_work_j(y)),
            cost_of_transport=float(
                metrics.cost_of_transport(
                    lumped.pump_work_j(y),
                    lumped.position_m(y),
                    self.mass_kg,
                    self.cot_min_distance_m,
                )
            ),
        )
        return self._obs(), reward, terminated, truncated, info
