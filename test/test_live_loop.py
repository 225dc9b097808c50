"""
The live loop (pulsejet_sim.engine.live_loop) on its own thread with a real session; no DDS.

What sim_node relies on: commands handed over from another thread are applied in arrival order
before the next tick, a closed loop through the thread is the same as one driven by hand, refusals
are reported in order and counted, a bug in a tick stops the loop with exit code 2.
"""

import queue
import threading
import time

from pulsejet_sim.engine import session as eng
from pulsejet_sim.engine.live_loop import LiveLoop
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene
import pytest

CONTROL_PERIOD_S = 0.05
PERIODS = 20


def session(pacing: str, now: float | None = None, **config) -> eng.Session:
    sim = Simulation(load_scene('pump_cycle').model)
    config = eng.SessionConfig(pacing=pacing, publish_rate_hz=100.0, **config)
    return eng.Session(sim, config, now=time.monotonic() if now is None else now)


def answer(time_s: float) -> dict:
    """Return a closed-loop controller's command for the state at `time_s`."""
    return {
        'pump_flow_m3_s': 2e-3 if time_s < 0.5 else 0.0,
        'valve_opening': 0.0 if time_s < 0.8 else 1.0,
    }


def states(events) -> list:
    return [
        (e.observation.time_s, e.observation.volume_m3, e.observation.velocity_m_s)
        for e in events
        if isinstance(e, eng.Publish)
    ]


def by_hand() -> list:
    """Return the closed loop's states driven on the session directly (test_session's way)."""
    s = session('closed_loop', now=0.0, control_period_s=CONTROL_PERIOD_S)
    out = states(s.start(0.0))
    for k in range(PERIODS):
        out += states(s.accept(answer(out[-1][0]), float(k), stamp_s=out[-1][0]))
    return out


@pytest.mark.timeout(120)
def test_closed_loop_through_the_thread_equals_the_loop_driven_by_hand():
    published = queue.Queue()
    rejected = []
    loop = LiveLoop(
        session('closed_loop', control_period_s=CONTROL_PERIOD_S),
        0.01,
        lambda events: [published.put(s) for s in states(events)],
        rejected.append,
        rejected.append,
    )
    loop.start()
    seen = [published.get(timeout=60)]
    try:
        for _ in range(PERIODS):
            # from this (the "executor") thread, as sim_node's subscriptions do
            loop.accept(answer(seen[-1][0]), seen[-1][0], 'test controller')
            seen.append(published.get(timeout=60))
    finally:
        loop.close()
    assert rejected == []
    assert seen == by_hand()
    assert [round(t / CONTROL_PERIOD_S) for t, _, _ in seen] == list(range(PERIODS + 1))


def test_refusals_are_reported_in_arrival_order_and_counted_and_the_command_is_kept():
    rejected = []
    loop = LiveLoop(session('lockstep'), 0.01, lambda events: None, rejected.append, pytest.fail)
    held = loop.session.command
    loop.reject('pulsejet/cmd/command: rejected: no names; command kept')
    loop.accept({'pump_flow_m3_s': -1.0}, None, 'pulsejet/cmd/pump_flow')
    loop.accept({'valve_opening': 0.5}, None, 'pulsejet/cmd/valve')
    assert rejected == []  # nothing is applied before the loop or a locked() caller takes them
    with loop.locked() as s:
        assert s.command.valve_opening == 0.5
        assert s.command.pump_flow_m3_s == held.pump_flow_m3_s
        assert s.command_counts['rejected'] == 2 and s.command_counts['accepted'] == 1
    assert rejected[0] == 'pulsejet/cmd/command: rejected: no names; command kept'
    assert rejected[1].startswith('pulsejet/cmd/pump_flow: ') and '-1.0' in rejected[1]
    assert len(rejected) == 2


@pytest.mark.timeout(60)
def test_an_exception_in_a_tick_stops_the_loop_with_exit_code_2():
    failures = []
    ended = threading.Event()

    def broken_tick(now):
        raise ZeroDivisionError('a bug')

    def on_failure(text):
        failures.append(text)
        ended.set()

    loop = LiveLoop(
        session('real_time'), 0.01, lambda events: None, pytest.fail, on_failure, broken_tick
    )
    loop.start()
    assert ended.wait(30)
    loop.close()
    assert failures == ['pacing thread stopped: ZeroDivisionError: a bug']
    assert loop.session.done and loop.session.exit_code == 2


@pytest.mark.timeout(60)
def test_close_stops_a_real_time_loop_that_has_published():
    published = threading.Event()
    loop = LiveLoop(
        session('real_time'),
        0.01,
        lambda events: states(events) and published.set(),
        pytest.fail,
        pytest.fail,
    )
    loop.start()
    assert published.wait(30)
    loop.close()
    assert not loop._thread.is_alive()
    assert not loop.session.done  # stopped from outside, not finished


def test_a_period_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match=r'period_s=0\.0 rejected; allowed: > 0 s'):
        LiveLoop(session('real_time'), 0.0, print, print, print)


@pytest.mark.timeout(120)
def test_a_thread_waiting_for_the_session_gets_it_while_the_loop_runs_behind():
    """
    A loop behind real time (it never sleeps) still lets a waiting thread in before its next tick.

    sim_node's executor takes the session (diagnostics, services, parameters) through locked();
    while the pacing thread catches up it re-took the lock at once, the executor waited, and the
    commands it should have been taking from DDS meanwhile tripped the watchdog (the soak's trips,
    one per diagnostics second). Here the tick holds the GIL the way a publication does and the
    loop's clock is always a period ahead, so the loop never waits.
    """
    ticks_while_waiting = [0]  # ticks begun while a thread was registered in locked()

    def busy_tick(now):
        if loop._waiting:
            ticks_while_waiting[0] += 1
        end = time.perf_counter() + 2e-4
        while time.perf_counter() < end:  # Python work: holds the GIL, like building messages
            pass
        return []

    fake_now = [0.0]

    def always_behind():
        fake_now[0] += 0.02  # two periods per reading: the next tick is always due
        return fake_now[0]

    loop = LiveLoop(
        session('real_time'), 0.01, lambda events: None, pytest.fail, pytest.fail, busy_tick
    )
    loop.clock = always_behind
    loop.start()
    try:
        waited = []
        for _ in range(50):
            ticks_while_waiting[0] = 0
            with loop.locked():
                waited.append(ticks_while_waiting[0])
            time.sleep(0.002)
    finally:
        loop.close()
    # none begins while a thread waits (one may, if the waiting thread is not scheduled within
    # HANDOFF_TIMEOUT_S on a loaded machine); a plain lock let 45 to 327 ticks pass here
    assert max(waited) <= 2, waited
