"""
Gymnasium environments (issue 9).

check_env, seeding, faults, the batched lumped kernel against single-robot runs, the 16384-robot
vector env and the shell robots in worker processes.
"""

import math
import warnings

import gymnasium as gym
from gymnasium.utils.env_checker import check_env
import numpy as np
from pulsejet_sim.core.model_io import Command, VALVE_MIN_OPENING
from pulsejet_sim.engine.simulation import Simulation
import pulsejet_sim.envs as E
from pulsejet_sim.envs.rewards import REWARDS
from pulsejet_sim.models.lumped import batch as B
from pulsejet_sim.models.lumped import kernels as K
from pulsejet_sim.scene import load_scene
import pytest


def _check(env):
    with warnings.catch_warnings():
        # the checker's advice on infinite rate bounds, non-[-1, 1] actions
        warnings.simplefilter('ignore')
        check_env(env.unwrapped, skip_render_check=True)


def test_lumped_env_passes_check_env_and_is_registered():
    assert E.LUMPED_ID in gym.registry and E.SHELL_ID in gym.registry
    env = gym.make(E.LUMPED_ID)
    _check(env)
    assert env.observation_space.shape == (6,) and env.action_space.shape == (2,)
    assert np.allclose(env.action_space.high, [Command.LIMITS['pump_flow_m3_s'][1], 1.0])


def test_shell_env_passes_check_env():
    env = gym.make(E.SHELL_ID, max_episode_s=0.2)
    _check(env)
    obs, _ = env.reset(seed=3)
    total = 0
    for k in range(4):
        obs, reward, terminated, truncated, info = env.step(np.array([8.0]))
        assert np.all(np.isfinite(obs)) and math.isfinite(reward) and not terminated
        total += 1
    assert truncated and info['actuation_work_j'] > 0.0


@pytest.mark.parametrize('reward', REWARDS)
def test_lumped_rewards_and_seeding(reward):
    env = E.LumpedPumpValveEnv(reward=reward, max_episode_s=1.0)
    actions = [np.array([2.5e-3, 0.0])] * 8 + [np.array([0.0, 1.0])] * 12

    def episode(seed):
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        rewards = []
        for a in actions:
            obs, r, terminated, truncated, info = env.step(a)
            trace.append(obs)
            rewards.append(r)
        return np.array(trace), np.array(rewards), truncated, info

    t1, r1, truncated, info = episode(7)
    t2, r2, _, _ = episode(7)
    t3, _, _, _ = episode(8)
    assert np.array_equal(t1, t2) and np.array_equal(r1, r2)  # a seed fixes the episode
    assert not np.array_equal(t1[0], t3[0])  # another seed another b(0)
    assert truncated and np.all(np.isfinite(r1))
    if reward == 'cost_of_transport':
        # the return telescopes to minus the episode's cost of transport
        assert math.isclose(r1.sum(), -info['cost_of_transport'], rel_tol=1e-9)
        assert info['cost_of_transport'] > 0
    if reward == 'distance':
        assert math.isclose(r1.sum(), info['position_m'], rel_tol=1e-9) and info['position_m'] > 0


def test_lumped_fault_terminates_with_penalty_not_nan():
    # paper 001's equations as written: an inflated shell released through an open valve collapses
    env = E.LumpedPumpValveEnv('escape', {'options': {'coupling': 'paper'}}, initial_b_jitter=0.0)
    env.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, truncated, info = env.step(np.array([0.0, 1.0]))
        if terminated:
            break
    assert terminated and not truncated
    assert reward == -env.fault_penalty and 'minor semi-axis' in info['fault']
    assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)


def test_batch_kernel_equals_single_robot_runs_bit_for_bit():
    model = load_scene('pump_cycle').model
    n = 4
    Y = np.tile(model.initial_state(), (n, 1))
    P = np.ascontiguousarray(np.tile(model.params, (n, 1)))
    commands = [Command(2.5e-3, 0.0), Command(2.5e-3, 0.0), Command(0.0, 1.0), Command(1e-3, 0.3)]
    q = np.array([c.pump_flow_m3_s for c in commands])
    v = np.array([c.valve_opening for c in commands])
    done = np.zeros(n, np.int64)
    status = np.zeros(n, np.int64)
    kernel = B.batch_kernel(model.flags, exact=True)
    for _ in range(3):
        kernel(model.flags, Y, P, q, v, 700, model.dt_s, done, status)
    assert np.all(status == K.OK) and np.all(done == 700)
    for i, cmd in enumerate(commands):
        sim = Simulation(model)
        for _ in range(3):
            sim.step(700, cmd)
        assert np.array_equal(sim.state, Y[i]), i
    assert np.array_equal(Y[0], Y[1])  # identical robots, identical trajectories
    assert not np.array_equal(Y[0], Y[3]) and not np.array_equal(Y[2], Y[3])


def _batch_against_single(
    scene,
    overrides,
    n,
    exact,
    calls=10,
    steps=300,
    fault_phase=False,
    losses_off=False,
    initial_losses=0.0,
):
    """
    Run n robots through the batch kernel and each robot through the single-robot kernel.

    The robots have per-robot stiffness and b(0) and get random commands that seal, throttle and
    open the valve. Returns (batch states, single states, batch done/status, single done/status,
    component scales). losses_off: the batch kernel runs with lumped.batch.LOSSES_OFF (the loss
    components are then compared with their initial values, not the single-robot ones);
    initial_losses: the loss components' value at the start.
    """
    model = load_scene(scene, overrides).model
    flags = model.flags | (B.LOSSES_OFF if losses_off else 0)
    rng = np.random.default_rng(5)
    Y = np.tile(model.initial_state(), (n, 1))
    Y[:, K.Y_B] *= 1.0 + rng.uniform(-0.02, 0.02, n)
    Y[:, slice(K.Y_W_PUMP + 1, K.N_INTEGRATED)] = initial_losses
    P = np.ascontiguousarray(np.tile(model.params, (n, 1)))
    P[:, K.P_K] *= 1.0 + rng.uniform(-0.1, 0.1, n)
    if fault_phase:
        # every other robot gets a lower bound of b just below its b(0): it trips mid-call
        P[::2, K.P_B_MIN] = Y[::2, K.Y_B] * (1.0 - rng.uniform(0.002, 0.02, P[::2].shape[0]))
    Ys = Y.copy()
    done, status = np.zeros(n, np.int64), np.zeros(n, np.int64)
    done_s, status_s = np.zeros(n, np.int64), np.zeros(n, np.int64)
    kernel = B.batch_kernel(flags, exact)
    single = K.specialised(
        K.advance, model.flags, model.initial_state(), model.params, 0.0, 0.0, 0, model.dt_s
    )
    scale = np.zeros(K.NY)
    for call in range(calls):
        if fault_phase:
            q, v = np.zeros(n), np.ones(n)
        else:
            q = rng.choice([0.0, 1e-3, 2.5e-3, 5e-3], n)
            # 0.005: RK4 sub-steps; 1 -> 0: the valve seals; 0.30001 and 0.0021 -> 0: its stroke
            # would pass below the valve's seat, where it seals
            v = rng.choice([0.0, 0.005, 0.3, 1.0, 0.30001, 0.0021], n)
        kernel(flags, Y, P, q, v, steps, model.dt_s, done, status)
        for i in range(n):
            if status_s[i] == K.OK:
                done_s[i], status_s[i] = single(
                    model.flags, Ys[i], P[i], q[i], v[i], steps, model.dt_s
                )
            else:
                done_s[i] = 0
        scale = np.maximum(scale, np.abs(Ys).max(axis=0))
        if exact:  # every call, not only the last
            assert (
                np.array_equal(Y, Ys)
                and np.array_equal(done, done_s)
                and np.array_equal(status, status_s)
            ), call
    return Y, Ys, status, status_s, scale


@pytest.mark.parametrize(
    'scene, overrides, fault_phase',
    [
        ('pump_cycle', None, False),
        ('pump_cycle', {'options': {'coupling': 'paper', 'added_mass_form': 'simplified'}}, False),
        # the shell collapses: faults mid-call
        ('escape', {'options': {'coupling': 'paper'}}, True),
    ],
)
def test_vector_batch_kernel_equals_single_robot_runs_bit_for_bit(scene, overrides, fault_phase):
    # 100 robots: one full SIMD block of 64 and a padded one of 36 (the vector path, not the
    # one-at-a-time path of a few robots); exact=True (libm's atanh) must equal the single-robot
    # kernel bit for bit, also for the steps it hands to _advance (sub-steps, sealing) and for
    # robots that fail
    Y, Ys, status, status_s, _ = _batch_against_single(
        scene, overrides, 100, True, fault_phase=fault_phase
    )
    if fault_phase:
        # flagged, others go on
        assert np.all(status[::2] == K.ERR_B_LOW) and np.all(status[1::2] == K.OK)
        assert np.all(np.isfinite(Y))  # the last good state, no nan


def test_vector_batch_kernel_fast_atanh_within_tolerance():
    # exact=False: the vectorised atanh (about 1 ulp like libm's, and equal to it for most inputs)
    # and LLVM's FAST_MATH rewrites (a shared reciprocal, fused multiply-adds); the trajectories
    # may then differ by rounding only: 1e-12 of each component's scale
    Y, Ys, status, status_s, scale = _batch_against_single('pump_cycle', None, 100, False)
    assert np.array_equal(status, status_s) and np.all(status == K.OK)
    assert np.all(np.abs(Y - Ys) <= 1e-12 * scale)


def test_vector_batch_kernel_without_the_losses_keeps_state_and_pump_work():
    # LOSSES_OFF (the vector env's default) integrates the state and the pump's work only: they
    # are those of the single-robot runs within the fast path's rounding, also through the steps
    # _slow_steps hands to the single-robot kernel (which integrates the losses: dropped) and for
    # the last 6 robots, which run one at a time (70 = 64 + 6 < SCALAR_BELOW); the loss
    # components keep the caller's values
    assert 70 - B.BLOCK < B.SCALAR_BELOW
    Y, Ys, status, status_s, scale = _batch_against_single(
        'pump_cycle', None, 70, False, losses_off=True, initial_losses=1.25
    )
    assert np.array_equal(status, status_s) and np.all(status == K.OK)
    kept = list(range(B.N_LOSSES_OFF)) + [K.Y_VALVE]
    assert np.all(np.abs(Y[:, kept] - Ys[:, kept]) <= 1e-12 * scale[kept])
    losses = slice(B.N_LOSSES_OFF, K.N_INTEGRATED)
    assert np.all(Y[:, losses] == 1.25)
    assert np.all(Ys[:, K.Y_E_VALVE] > 1.25)  # the single-robot runs did lose energy


def test_vector_fast_atanh_accuracy():
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [
            rng.uniform(0.0, 1.0, 200_000),
            1.0 - 10.0 ** rng.uniform(-16, 0, 100_000),
            10.0 ** rng.uniform(-300, 0, 50_000),
        ]
    )
    f = B.atanh_fast(x)
    ref = np.arctanh(x.astype(np.longdouble))
    ulps = np.abs((f.astype(np.longdouble) - ref) / np.spacing(np.abs(f)).astype(np.longdouble))
    assert ulps.max() <= 2.0  # libm's own atanh: 1.65 ulp on these inputs
    libm = np.array([math.atanh(v) for v in x[:20_000]])
    assert np.mean(f[:20_000] == libm) > 0.99
    special = B.atanh_fast(np.array([0.0, 1.0, 1.5, np.nan, 5e-324, 0.5]))
    assert (
        special[0] == 0.0
        and special[1] == np.inf
        and np.isnan(special[2])
        and np.isnan(special[3])
    )
    assert special[4] == 5e-324 and special[5] == math.atanh(0.5)


def test_vector_env_16384_robots_one_call():
    env = E.LumpedPumpValveVectorEnv(
        16384, control_period_s=1e-3, reward='mean_speed', initial_b_jitter=0.0
    )
    obs, _ = env.reset(seed=1)
    assert obs.shape == (16384, 6)
    actions = np.zeros((16384, 2))
    actions[:, 0] = np.linspace(0.0, 5e-3, 16384)  # different pump flows per robot
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(actions)
    assert reward.shape == (16384,) and np.all(np.isfinite(reward)) and not terminated.any()
    assert np.all(env.done == env.n_steps)
    assert env.single_observation_space.contains(obs[0]) and env.observation_space.contains(obs)
    # more pump flow, more water in the cavity
    assert obs[-1, 3] > obs[0, 3]


def test_vector_env_matches_single_env_and_autoresets():
    # the fast kernel of the same flags first: numba would compile the helpers both call with the
    # first caller's fastmath flags, and the exact env then differed (found by review)
    B.batch_kernel(load_scene('pump_cycle').model.flags | B.LOSSES_OFF, exact=False)
    kw = {'initial_b_jitter': 0.0, 'max_episode_s': 0.15, 'reward': 'distance'}
    venv = E.LumpedPumpValveVectorEnv(2, exact=True, **kw)
    env = E.LumpedPumpValveEnv(**kw)
    vobs, _ = venv.reset(seed=0)
    obs, _ = env.reset(seed=0)
    a = np.array([[2.5e-3, 0.0], [0.0, 1.0]])
    for k in range(3):
        vobs, vr, vterm, vtrunc, _ = venv.step(a)
        obs, r, term, trunc, _ = env.step(a[0])
        assert np.array_equal(vobs[0], obs) and vr[0] == r and vtrunc[0] == trunc
    assert vtrunc.all()
    vobs, vr, vterm, vtrunc, _ = venv.step(a)  # NEXT_STEP autoreset: back to the initial state
    assert np.array_equal(vobs[0], env.reset()[0]) and np.all(vr == 0.0)


def test_a_valve_action_below_the_seat_shuts_the_valve_in_both_envs():
    # the valve cannot hold an opening below its seat (VALVE_MIN_OPENING): a command there is
    # refused, so an agent's 0.1 % means shut; found by review: the single env raised CommandError
    # and the vector env flipped the valve between the seat and shut at every step
    kw = {'initial_b_jitter': 0.0, 'reward': 'distance'}
    venv = E.LumpedPumpValveVectorEnv(2, exact=True, **kw)
    env = E.LumpedPumpValveEnv(**kw)
    venv.reset(seed=0)
    env.reset(seed=0)
    a = np.array([[2.5e-3, 1.0], [2.5e-3, 1.0]])
    for _ in range(2):  # open, then nearly shut
        vobs, _, _, _, _ = venv.step(a)
        obs, _, term, _, info = env.step(a[0])
        assert np.array_equal(vobs[0], obs) and not term
        a[:, 1] = [1e-3, VALVE_MIN_OPENING / 2]
    assert info['action_clipped'] and 'fault' not in info
    for _ in range(4):
        vobs, _, vterm, _, _ = venv.step(a)
        obs, _, term, _, _ = env.step(a[0])
        assert np.array_equal(vobs[0], obs) and not term and not vterm.any()
    assert obs[5] == 0.0 and np.all(vobs[:, 5] == 0.0)  # shut, and it stays shut


def test_shell_robots_in_worker_processes():
    venv = E.make_shell_vector_env(2, max_episode_s=0.1)
    try:
        obs, _ = venv.reset(seed=[1, 2])
        assert obs.shape == (2, 5)
        assert not np.array_equal(obs[0], obs[1])  # seeds 1 and 2: different wall perturbations
        obs, reward, terminated, truncated, info = venv.step(np.array([[8.0], [0.0]]))
        assert np.all(np.isfinite(reward)) and not terminated.any()
        assert obs[0, 4] == 8.0 and obs[1, 4] == 0.0
    finally:
        venv.close()


def test_bad_env_arguments_refused():
    with pytest.raises(ValueError, match='reward'):
        E.LumpedPumpValveEnv(reward='fastest')
    with pytest.raises(ValueError, match='whole multiple'):
        E.LumpedPumpValveEnv(control_period_s=0.00015)
    with pytest.raises(ValueError, match='integrator: rk4'):
        E.LumpedPumpValveVectorEnv(2, scene_overrides={'simulation': {'integrator': 'adaptive'}})
    # the vector env checks an episode's length and the jitter as the single env does
    for env_class in (E.LumpedPumpValveEnv, lambda **kw: E.LumpedPumpValveVectorEnv(2, **kw)):
        for bad in (-1.0, 0.0, math.inf, math.nan):
            with pytest.raises(ValueError, match=f'max_episode_s={bad!r}'):
                env_class(max_episode_s=bad)
        with pytest.raises(ValueError, match='initial_b_jitter=0.5'):
            env_class(initial_b_jitter=0.5)
