"""
The ROS-free live engine (pulsejet_sim.engine.session) with a fake wall clock.

Pacing on the physics step's grid, visible dropped time, watchdog in simulated and wall time,
closed-loop lockstep, duration, faults, health. No DDS.
"""

import math

from pulsejet_sim.core.model_io import CommandError
from pulsejet_sim.engine import session as eng
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene
import pytest


def make(pacing='real_time', scene='pump_cycle', command_driven=False, **config):
    sim = Simulation(load_scene(scene, command_driven=command_driven).model)
    return eng.Session(
        sim,
        eng.SessionConfig(pacing=pacing, publish_rate_hz=100.0, **config),
        now=0.0,
        physics_clock=lambda: 0.0,
    )


def published(events):
    return [e.observation for e in events if isinstance(e, eng.Publish)]


def test_real_time_states_lie_on_the_step_grid_one_period_apart():
    s = make()
    s.start(0.0)
    times = []
    for k in range(1, 51):
        times += [o.time_s for o in published(s.tick(k * 0.01 + 0.003 * (k % 3)))]  # jittery ticks
    steps = [round(t / s.dt_s) for t in times]
    assert all(abs(t - n * s.dt_s) < 1e-12 for t, n in zip(times, steps))
    assert all(
        b - a == s.publish_every for a, b in zip(steps, steps[1:])
    )  # every period, none skipped
    assert times[-1] == pytest.approx(0.5, abs=0.011)


def test_a_late_tick_drops_wall_time_visibly_instead_of_silently():
    s = make()
    s.start(0.0)
    s.tick(0.01)
    events = s.tick(1.0)  # the node was not scheduled for ~1 s
    assert len(published(events)) == eng.MAX_CATCH_UP_PERIODS
    assert s.dropped_s() == pytest.approx(1.0 - 0.01 - eng.MAX_CATCH_UP_PERIODS * 0.01, abs=0.011)
    warnings = [e.text for e in events if isinstance(e, eng.Log) and e.level == 'warning']
    assert warnings and 'dropped' in warnings[0] and 'not caught up' in warnings[0]
    level, message, values = s.health(1.0)
    assert values['dropped_wall_s'] == pytest.approx(s.dropped_s())


def test_a_late_first_tick_says_no_step_was_computed_instead_of_nan():
    s = make()
    s.start(0.0)
    events = s.tick(1.0)  # late before any step: there is no physics cost to quote yet
    warnings = [e.text for e in events if isinstance(e, eng.Log) and e.level == 'warning']
    assert warnings and 'no step computed yet' in warnings[0], warnings
    assert 'nan' not in warnings[0], warnings[0]


def test_closed_loop_waits_for_each_answer_and_is_deterministic():
    def run(answer_delays):
        s = make('closed_loop', control_period_s=0.05)
        states = published(s.start(0.0))
        answered = []
        for k, delay in enumerate(answer_delays):
            # however late the controller answers (wall time), nothing moves without it
            assert published(s.tick(10.0 * k + delay)) == [] or s.awaiting_command
            t = states[-1].time_s
            cmd = {
                'pump_flow_m3_s': 2e-3 if t < 0.5 else 0.0,
                'valve_opening': 0.0 if t < 0.8 else 1.0,
            }
            states += published(s.accept(cmd, 10.0 * k + delay, stamp_s=t))
            answered.append(t)
        return [(o.time_s, o.volume_m3, o.velocity_m_s) for o in states], answered

    fast, t_fast = run([0.001] * 30)
    slow, t_slow = run([0.9, 0.0, 3.0] * 10)
    assert fast == slow and t_fast == t_slow
    assert [round(t / 0.05) for t, _, _ in fast] == list(
        range(31)
    )  # one control period per answer


def test_closed_loop_ignores_a_stale_answer():
    s = make('closed_loop', control_period_s=0.05)
    s.start(0.0)
    s.accept({'valve_opening': 1.0}, 0.1, stamp_s=0.0)
    assert s.sim.time_s == pytest.approx(0.05)
    s.accept({'valve_opening': 1.0}, 0.2, stamp_s=0.0)  # answers t=0, not the awaited t=0.05
    assert s.sim.time_s == pytest.approx(0.05)
    s.accept({'valve_opening': 1.0}, 0.3, stamp_s=0.05)
    assert s.sim.time_s == pytest.approx(0.10)


def test_atomic_command_applies_all_or_nothing():
    s = make('lockstep')
    s.start(0.0)
    with pytest.raises(CommandError, match='valve_opening'):
        s.accept({'pump_flow_m3_s': 1e-3, 'valve_opening': math.nan}, 0.0)
    assert s.command == s.sim.command  # nothing applied
    with pytest.raises(CommandError, match="'thrust'.*allowed"):
        s.accept({'thrust': 1.0}, 0.0)
    s.accept({'pump_flow_m3_s': 1e-3, 'valve_opening': 0.0}, 0.0)
    assert (s.command.pump_flow_m3_s, s.command.valve_opening) == (1e-3, 0.0)


@pytest.mark.parametrize('clock', ['sim', 'wall'])
def test_watchdog_applies_the_safe_command_in_its_clock(clock):
    s = make('real_time', watchdog_timeout_s=0.2, watchdog_clock=clock)
    s.start(0.0)
    s.accept({'pump_flow_m3_s': 2e-3, 'valve_opening': 0.0}, 0.0)
    if clock == 'sim':
        for k in range(1, 30):
            s.tick(k * 0.01)
        assert s.watchdog_tripped and s.command == eng.SAFE_COMMAND
        applied = [e for e in s.tick(0.3) if isinstance(e, eng.Applied)]
        assert s.sim.time_s > 0.2
    else:
        s.config.pacing = 'lockstep'  # simulated time stands still, wall time goes on
        assert not any(isinstance(e, eng.Log) for e in s.tick(0.1))
        events = s.tick(0.25)
        assert s.watchdog_tripped and s.command == eng.SAFE_COMMAND and s.sim.time_s == 0.0
        assert any(isinstance(e, eng.Log) and 'wall time' in e.text for e in events)
        applied = []
    del applied
    s.accept({'valve_opening': 1.0}, 0.4)
    assert not s.watchdog_tripped


def test_duration_ends_the_session_with_the_ledger():
    s = make('as_fast_as_possible', duration_s=0.1)
    s.start(0.0)
    events = []
    while not s.done:
        events += s.tick(0.0)
    assert s.sim.time_s == pytest.approx(0.1)
    assert any(isinstance(e, eng.PublishLedger) for e in events)


def test_a_blow_up_halts_without_publishing_nan_and_reset_recovers():
    s = make('lockstep', scene='escape', step_count=1000)
    s.start(0.0)
    s.sim.state[:] = math.nan  # a broken state: the next step must fail cleanly
    ok, message, events = s.step(0.0)
    assert not ok and 'blew up' in message and s.run_state() == 'fault'
    assert any(isinstance(e, eng.Halted) for e in events)
    assert all(eng.observation_is_finite(o) for o in published(events))
    level, _, values = s.health(0.1)
    assert level == eng.ERROR and values['fault']
    message, events = s.reset(0.2)
    assert s.sim.fault is None and s.sim.time_s == 0.0 and published(events)


def test_idle_scene_closure_is_judged_against_the_energy_in_play():
    s = make('real_time', scene='shell_robot', command_driven=True)  # no cable command: idle
    s.start(0.0)
    s.tick(0.05)
    level, message, values = s.health(0.05)
    assert 'energy closure' not in message, message
    assert abs(values['energy_closure_relative']) < 0.05


def test_closed_loop_does_not_apply_a_stale_answer():
    s = make('closed_loop', control_period_s=0.05)
    s.start(0.0)
    s.accept({'pump_flow_m3_s': 1e-3, 'valve_opening': 0.0}, 0.1, stamp_s=0.0)
    held = s.command
    s.accept(
        {'pump_flow_m3_s': 4e-3, 'valve_opening': 1.0}, 0.2, stamp_s=0.0
    )  # the t=0 state answered again
    assert s.command == held


def test_lookahead_computes_ahead_and_stamps_each_state_with_its_wall_time():
    ahead, plain = make(lookahead_s=0.05), make()
    for s in (ahead, plain):
        s.start(0.0)
    events = ahead.tick(0.01)
    states = [e for e in events if isinstance(e, eng.Publish)]
    # the physics runs 5 periods ahead of the wall clock; each state carries its own wall time
    assert [round(e.observation.time_s, 9) for e in states] == [0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
    assert [e.due_wall for e in states] == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05, 0.06])
    assert all(e.due_wall is None for e in plain.tick(0.01) if isinstance(e, eng.Publish))
    # the same states as without the lookahead, only computed earlier
    later = published(plain.tick(0.06))
    assert [o.time_s for o in later] == pytest.approx([o.observation.time_s for o in states[1:]])
    assert later[-1] == states[-1].observation
    assert ahead.dropped_s() == 0.0


def test_a_publish_delay_sends_the_same_states_a_fixed_part_of_a_period_after_their_time():
    delayed, plain = make(publish_delay_periods=0.2), make()
    for s in (delayed, plain):
        s.start(0.0)
    ticks = [k * 0.01 + 0.0007 * (k % 3) for k in range(1, 31)]  # jittery wake-ups
    delayed_states, plain_states = [], []
    for k, now in enumerate(ticks):
        if k == 10:  # a command between two ticks: taken at the next tick by both
            for s in (delayed, plain):
                s.accept({'pump_flow_m3_s': 4e-3, 'valve_opening': 0.5}, now - 0.004)
        delayed_states += [e for e in delayed.tick(now) if isinstance(e, eng.Publish)]
        plain_states += published(plain.tick(now))
    # the states are computed at the same ticks from the same commands: equal, bit for bit
    assert [e.observation for e in delayed_states] == plain_states
    # each is due 0.2 periods after its own wall time, on the grid whatever the wake-up jitter
    assert [e.due_wall for e in delayed_states] == pytest.approx(
        [(k + 0.2) * 0.01 for k in range(1, 31)], abs=1e-12
    )


def test_outbox_sends_each_batch_at_its_time_in_order_and_flush_sends_the_rest_now():
    import time

    from pulsejet_sim.engine.outbox import TimedOutbox

    sent = []
    box = TimedOutbox()
    box.start()
    t0 = time.monotonic()
    for k in range(5):
        box.put(t0 + 0.05 * (k + 1), [lambda k=k: sent.append((k, time.monotonic()))])
    box.put(t0 + 60.0, [lambda: sent.append(('late', time.monotonic()))])
    deadline = time.monotonic() + 30.0
    while len(sent) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [k for k, _ in sent] == [0, 1, 2, 3, 4]
    assert all(
        when >= t0 + 0.05 * (k + 1) for k, when in sent
    )  # never early (late only under load)
    assert box.pending() == 1
    box.flush()
    assert [k for k, _ in sent][-1] == 'late' and box.pending() == 0
    box.close()


def test_log_throttle_burst_then_rate_and_counts_the_rest():
    throttle = eng.LogThrottle(burst=3, rate_hz=2.0, now=0.0)
    passed = [throttle.admit(f'bad {i}', now=0.0) for i in range(10)]
    assert passed[:3] == ['bad 0', 'bad 1', 'bad 2'] and passed[3:] == [None] * 7
    assert throttle.admit('bad 10', now=0.2) is None  # 0.4 of a token refilled
    # half a second later one token is back: the line says how many were held back
    assert throttle.admit('bad 11', now=0.5) == 'bad 11 (8 more not logged)'
    assert throttle.admit('bad 12', now=0.5) is None
    assert throttle.admit('bad 13', now=100.0) == 'bad 13 (1 more not logged)'
    assert throttle.admit('bad 14', now=100.0) == 'bad 14'  # refilled up to the burst only
