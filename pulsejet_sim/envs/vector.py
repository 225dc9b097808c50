"""
N lumped robots as one gymnasium vector environment, advanced by one numba call per control period.

The call is ``lumped.batch.advance_batch_fast`` (or ``advance_batch_exact``): the single-robot
RK4 step and right-hand side, vectorised over blocks of robots, no Python object per robot.

Spaces, actions, observations, rewards and faults are those of ``LumpedPumpValveEnv``, batched:
actions (N, 2), observations (N, 6), rewards, terminations and truncations (N,). All robots share
one scene's parameters (``params`` may give one row per robot instead, shape
(N, lumped.kernels.NP)). ``exact``: False (default) uses the vectorised atanh of Lamb's added mass
and LLVM's reciprocal and fused multiply-add rewrites (each about an ulp; trajectories agree with
LumpedPumpValveEnv to 1e-12 of each component's scale), True libm's (bit for bit
LumpedPumpValveEnv, tested; 35-42 % fewer robot-steps/s than the default, with losses=True).
``losses``: False (default) integrates the state and the pump's work only (``info`` and the
rewards need no more; ``lumped.batch.LOSSES_OFF``, 14-28 % more robot-steps/s), True also the
energy ledger's losses in ``env.Y`` (lumped.kernels.Y_E_JET..Y_C_RAM; they stay 0 otherwise).
Autoreset: gymnasium's ``NEXT_STEP`` mode: the step after a robot's episode ended resets that robot
(its action is ignored, reward 0); ``info['fault']`` holds the robots' fault codes
(lumped.kernels.ERR_*, 0: none). Only the fixed-step RK4 integrator (the scene's ``dt_s``) runs in
batch.
"""

from __future__ import annotations

from typing import Any

from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
import numpy as np
from pulsejet_sim.envs import rewards as R
from pulsejet_sim.envs.lumped_env import (
    check_b_jitter,
    clip_actions,
    episode_periods,
    lumped_mass_kg,
    lumped_observation,
    lumped_spaces,
    steps_per_period,
)
from pulsejet_sim.models.lumped import batch as B
from pulsejet_sim.models.lumped import kernels as K
from pulsejet_sim.models.lumped import model as lumped
from pulsejet_sim.scene import load_scene


class LumpedPumpValveVectorEnv(VectorEnv):
    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 64,
        scene: str = 'pump_cycle',
        scene_overrides: dict | None = None,
        control_period_s: float = 0.05,
        max_episode_s: float = 10.0,
        reward: str = 'distance',
        target_speed_m_s: float = 0.2,
        fault_penalty: float = 100.0,
        initial_b_jitter: float = 0.02,
        cot_min_distance_m: float = 0.01,
        params: np.ndarray | None = None,
        exact: bool = False,
        losses: bool = False,
    ):
        if int(num_envs) < 1:
            raise ValueError(f'num_envs={num_envs!r} rejected; allowed: an integer >= 1')
        self.num_envs = int(num_envs)
        self.scene = load_scene(scene, scene_overrides)
        self.model = self.scene.model
        if self.model.name != 'lumped' or self.model.integrator != 'rk4':
            raise ValueError(
                f'scene {scene!r} rejected; allowed: a lumped scene with '
                'simulation.integrator: rk4'
            )
        self.reward_name = R.check_reward(reward)
        self.n_steps = steps_per_period(control_period_s, self.model.dt_s)
        self.control_period_s = self.n_steps * self.model.dt_s
        self.max_periods = episode_periods(max_episode_s, self.control_period_s)
        self.target_speed_m_s = float(target_speed_m_s)
        self.fault_penalty = float(fault_penalty)
        self.initial_b_jitter = check_b_jitter(initial_b_jitter)
        self.cot_min_distance_m = float(cot_min_distance_m)
        self.exact = bool(exact)
        n = self.num_envs
        if params is None:
            self.P = np.ascontiguousarray(np.tile(self.model.params, (n, 1)))
        else:
            self.P = np.ascontiguousarray(np.asarray(params, dtype=np.float64))
            if self.P.shape != (n, K.NP):
                raise ValueError(
                    f'params of shape {self.P.shape} rejected; allowed: ({n}, {K.NP})'
                )
        self.mass_kg = np.array([lumped_mass_kg(row) for row in self.P])
        self.single_observation_space, self.single_action_space = lumped_spaces(self.model.params)
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self.Y = np.zeros((n, K.NY))
        self.Y0 = np.zeros((n, K.NY))
        self.periods = np.zeros(n, np.int64)
        self.status = np.zeros(n, np.int64)
        self.done = np.zeros(n, np.int64)
        self._ended = np.zeros(n, bool)
        self.losses = bool(losses)
        self._flags = self.model.flags | (0 if self.losses else B.LOSSES_OFF)
        self._kernel = B.batch_kernel(self._flags, self.exact)
        self._rng, _ = seeding.np_random(None)

    def _reset_rows(self, rows: np.ndarray) -> None:
        y0 = self.model.initial_state()
        self.Y[rows] = y0
        if self.initial_b_jitter > 0.0 and rows.size:
            u = self._rng.uniform(-self.initial_b_jitter, self.initial_b_jitter, size=rows.size)
            for row, factor in zip(rows, 1.0 + u):
                lumped.scale_minor_semi_axis(self.Y[row], self.P[row], factor)
        self.Y0[rows] = self.Y[rows]
        self.periods[rows] = 0
        self.status[rows] = K.OK
        self._ended[rows] = False

    def _obs(self) -> np.ndarray:
        obs = lumped_observation(self.Y, self.P)
        return np.clip(obs, self.single_observation_space.low, self.single_observation_space.high)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._rng, _ = seeding.np_random(seed)
        self._reset_rows(np.arange(self.num_envs))
        return self._obs(), {}

    def step(self, actions):
        act = clip_actions(
            np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 2),
            self.single_action_space,
        )
        restart = np.flatnonzero(self._ended)
        if restart.size:
            self._reset_rows(restart)
        x0 = lumped.position_m(self.Y).copy()
        w0 = lumped.pump_work_j(self.Y).copy()
        q = np.ascontiguousarray(act[:, 0])
        v = np.ascontiguousarray(act[:, 1])
        if restart.size:
            self.status[restart] = -1  # just reset: not advanced this call (NEXT_STEP autoreset)
        self._kernel(
            self._flags,
            self.Y,
            self.P,
            q,
            v,
            self.n_steps,
            self.model.dt_s,
            self.done,
            self.status,
        )
        if restart.size:
            self.status[restart] = K.OK
            self.periods[restart] = -1
        self.periods += 1
        terminated = self.status != K.OK
        truncated = ~terminated & (self.periods >= self.max_periods)
        reward = R.reward(
            self.reward_name,
            x0=x0,
            x1=lumped.position_m(self.Y),
            x_start=lumped.position_m(self.Y0),
            work0=w0,
            work1=lumped.pump_work_j(self.Y),
            period_s=self.control_period_s,
            mass_kg=self.mass_kg,
            target_speed_m_s=self.target_speed_m_s,
            d_min_m=self.cot_min_distance_m,
        )
        reward = np.where(terminated, -self.fault_penalty, reward)
        if restart.size:
            reward[restart] = 0.0
            terminated[restart] = False
            truncated[restart] = False
        self._ended = terminated | truncated
        info = {
            'fault': self.status.copy(),
            'position_m': lumped.position_m(self.Y).copy(),
            'actuation_work_j': lumped.pump_work_j(self.Y).copy(),
        }
        return self._obs(), reward.astype(np.float64), terminated, truncated, info
