"""
One shell cable robot (paper 000) as a gymnasium environment, and a vector of them.

The vector runs them in worker processes.

Action (SI, ``Box`` within ``Command.LIMITS``): ``[cable force command (N)]`` in
``[0, max_cable_force_n]`` (default 16 N, twice the robot's routine; up to the 1000 N limit), the
total radial cable pull, held for one control period (``control_period_s``, default 0.05 s, a whole
number of the scene's physics steps); the scene is loaded command-driven (``actuation.source:
command``), so the agent replaces the built-in cable routine. Out-of-range actions are clipped.

Observation (SI, ``Box``): ``[vehicle speed (m/s), largest mantle radius (m), its rate over the
last control period (m/s), cavity volume (m^3), applied cable force (N)]``.

Reward, termination on a fault (``info['fault']``, ``-fault_penalty``, never NaN), truncation at
``max_episode_s`` and seeding (the initial radial perturbation of the wall, uniform in
``[-initial_perturbation_m, initial_perturbation_m]``; 0: the scene's exact state) as in
``LumpedPumpValveEnv``; the cost of transport uses ``vehicle.mass_kg`` and the ledger's
``in_actuation_work`` (the cable's work).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import gymnasium as gym
from gymnasium import spaces
import numpy as np
from pulsejet_sim.analysis import metrics
from pulsejet_sim.core.model_io import Command, SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.envs import rewards as R
from pulsejet_sim.envs.lumped_env import episode_periods, steps_per_period
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.scene import load_scene

OBS_NAMES = (
    'speed_m_s',
    'mantle_radius_m',
    'mantle_radius_rate_m_s',
    'volume_m3',
    'cable_force_n',
)


class ShellCableEnv(gym.Env):
    metadata = {'render_modes': []}

    def __init__(
        self,
        scene: str = 'shell_robot',
        scene_overrides: dict | None = None,
        control_period_s: float = 0.05,
        max_episode_s: float = 10.0,
        reward: str = 'distance',
        target_speed_m_s: float = 0.05,
        fault_penalty: float = 100.0,
        initial_perturbation_m: float = 2e-4,
        cot_min_distance_m: float = 0.01,
        max_cable_force_n: float = 16.0,
    ):
        self.scene = load_scene(scene, scene_overrides, command_driven=True)
        self.model = self.scene.model
        if self.model.name != 'shell' or self.model.actuation.get('kind') != 'cable':
            raise ValueError(
                f'scene {scene!r} rejected; allowed: a shell scene with cable actuation'
            )
        self.reward_name = R.check_reward(reward)
        self.n_steps = steps_per_period(control_period_s, self.model.dt_s)
        self.control_period_s = self.n_steps * self.model.dt_s
        self.max_periods = episode_periods(max_episode_s, self.control_period_s)
        self.target_speed_m_s = float(target_speed_m_s)
        self.fault_penalty = float(fault_penalty)
        self.initial_perturbation_m = abs(float(initial_perturbation_m))
        self.cot_min_distance_m = float(cot_min_distance_m)
        vehicle = self.scene.data.get('vehicle') or {}
        self.mass_kg = float(
            vehicle.get('mass_kg', self.model.payload_kg + float(np.sum(self.model.node_mass)))
        )
        f_lo, f_hi = Command.LIMITS['cable_force_n']
        if not f_lo < max_cable_force_n <= f_hi:
            raise ValueError(
                f'max_cable_force_n={max_cable_force_n!r} rejected; allowed: ({f_lo}, {f_hi}] N'
            )
        f_hi = float(
            max_cable_force_n
        )  # the action's bound: 2x the robot's 8 N routine by default
        self.action_space = spaces.Box(np.array([f_lo]), np.array([f_hi]), dtype=np.float64)
        self.observation_space = spaces.Box(
            np.array([-100.0, 0.0, -np.inf, 0.0, f_lo]),
            np.array([100.0, 10.0, np.inf, 10.0, f_hi]),
            dtype=np.float64,
        )
        self._tail = 6 * self.model.n_nodes
        self.sim = Simulation(self.model, Command(0.0, 1.0, 0.0))
        self.periods = 0
        self._radius = 0.0

    def _obs(self, rate: float) -> np.ndarray:
        o = self.sim.observe()
        obs = np.array(
            [o.velocity_m_s, o.mantle_radius_m, rate, o.volume_m3, self.sim.command.cable_force_n]
        )
        return np.clip(np.nan_to_num(obs), self.observation_space.low, self.observation_space.high)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.sim.reset()
        if self.initial_perturbation_m > 0.0:
            d = self.np_random.uniform(-self.initial_perturbation_m, self.initial_perturbation_m)
            ref = self.model.ref
            xi = ref.X / ref.X[-1]
            q = self.sim.state[: 3 * self.model.n_nodes].reshape(-1, 3)
            q[1:-1, 0] += d * np.sin(math.pi * xi[1:-1])
            self.sim.initial_state = self.sim.state.copy()
        self.periods = 0
        self._radius = self.sim.observe().mantle_radius_m
        return self._obs(0.0), {'time_s': 0.0, 'position_m': 0.0}

    def step(self, action):
        raw = np.asarray(action, dtype=np.float64).reshape(1)
        act = np.clip(np.nan_to_num(raw, nan=0.0), self.action_space.low, self.action_space.high)
        command = Command(0.0, 1.0, float(act[0]))
        tail = self.sim.state[self._tail:]
        x0, w0 = float(tail[sk.S_X]), float(tail[sk.S_IN])
        info: dict[str, Any] = {'action_clipped': bool(np.any(act != raw))}
        terminated = False
        try:
            self.sim.step(self.n_steps, command)
        except SimulationBlowUp as err:
            terminated = True
            info['fault'] = str(err)
        tail = self.sim.state[self._tail:]
        x1, w1 = float(tail[sk.S_X]), float(tail[sk.S_IN])
        self.periods += 1
        if terminated or not (math.isfinite(x1) and math.isfinite(w1)):
            terminated = True
            reward = -self.fault_penalty
            info.setdefault('fault', 'non-finite state')
        else:
            reward = float(
                R.reward(
                    self.reward_name,
                    x0=x0,
                    x1=x1,
                    x_start=0.0,
                    work0=w0,
                    work1=w1,
                    period_s=self.control_period_s,
                    mass_kg=self.mass_kg,
                    target_speed_m_s=self.target_speed_m_s,
                    d_min_m=self.cot_min_distance_m,
                )
            )
        radius = self.sim.observe().mantle_radius_m
        rate = (radius - self._radius) / self.control_period_s
        self._radius = radius
        truncated = (not terminated) and self.periods >= self.max_periods
        info.update(
            time_s=self.periods * self.control_period_s,
            position_m=x1,
            actuation_work_j=w1,
            cost_of_transport=float(
                metrics.cost_of_transport(w1, x1, self.mass_kg, self.cot_min_distance_m)
            ),
        )
        return self._obs(rate), reward, terminated, truncated, info


def make_shell_vector_env(
    num_envs: int, context: str | None = None, **env_kwargs
) -> gym.vector.AsyncVectorEnv:
    """``num_envs`` ShellCableEnv, each in its own worker process (gymnasium's AsyncVectorEnv)."""
    if int(num_envs) < 1:
        raise ValueError(f'num_envs={num_envs!r} rejected; allowed: an integer >= 1')
    return gym.vector.AsyncVectorEnv(
        [functools.partial(ShellCableEnv, **env_kwargs)] * int(num_envs), context=context
    )
