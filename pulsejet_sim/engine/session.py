"""
The live engine without ROS.

A `Simulation`, the command it holds, the watchdog, the duration, the pacing and the health
numbers. It never publishes: every call returns *events* (a state to publish, an applied command, a
log line, a fault) and `sim_node` turns them into messages; tests drive it with a fake wall clock.

Pacing modes (`PACING_MODES`):
- ``real_time``: physics steps follow the wall clock times ``real_time_factor`` on a drift-free
  grid; a late tick catches up at most ``MAX_CATCH_UP_PERIODS`` publication periods or
  ``MAX_CATCH_UP_S`` of wall time, whichever is longer (at 1 kHz five periods are shorter than one
  scheduling hiccup of a loaded machine); the rest of a late wall interval is *dropped* (counted
  in ``dropped_wall_s`` and in the health numbers, never silently).
- ``as_fast_as_possible``: each tick steps for ``AFAP_BUDGET`` of a publication period.
- ``lockstep``: time advances only through `step` (``step_count`` steps per call).
- ``closed_loop``: lockstep with the controller: after every control period the state is
  published and the session waits for a command that answers it (stamped at or after that
  state's time, or unstamped); the command is applied and the next period runs at once. A closed
  loop is then deterministic at any machine speed and load (as PX4 SITL's lockstep with Gazebo).

Every publication carries the state at a multiple of the physics step: the session always
advances whole publication periods (``publish_every`` steps) on the grid of simulated time.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import math
from typing import Optional

from pulsejet_sim.core.model_io import check_command_value, Command, CommandError, SimulationBlowUp
from pulsejet_sim.core.topics import SERVICE_PAUSE, SERVICE_RESET, SERVICE_STEP

PACING_MODES = ('real_time', 'as_fast_as_possible', 'lockstep', 'closed_loop')
WATCHDOG_ACTIONS = ('safe', 'hold')
WATCHDOG_CLOCKS = ('sim', 'wall')
#: what the watchdog applies with watchdog_action=safe: pump off, valve open, cable released
SAFE_COMMAND = Command(pump_flow_m3_s=0.0, valve_opening=1.0, cable_force_n=0.0)
LEDGER_RATE_HZ = 5.0
HOLD_REPUBLISH_S = 0.5
MAX_CATCH_UP_PERIODS = 5
MAX_CATCH_UP_S = 0.05
DROP_LOG_PERIOD_S = 10.0  # at most one "fell behind" log line per this many wall seconds
AFAP_BUDGET = 0.8
RTF_WARN_FRACTION = 0.9
STABLE_MARGIN_WARN = 1.0
#: energy closure is judged against the energy in play: a relative figure of nearly nothing
#: (an idle scene) is not a fault
CLOSURE_WARN_RELATIVE = 0.05
CLOSURE_FLOOR_J = 1e-9
OK, WARN, ERROR = 'OK', 'WARN', 'ERROR'


# -- events ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Publish:
    """
    Publish this observation (and the mantle profile); with ``ledger`` also the energy ledger.

    ``due_wall``: with a lookahead, the wall time the state belongs to (publish it then, not now).
    """

    observation: object
    ledger: bool = False
    due_wall: Optional[float] = None


@dataclass(frozen=True)
class Applied:
    """The command held from ``time_s`` on (what re-simulation replays)."""

    command: Command
    time_s: float


@dataclass(frozen=True)
class PublishLedger:
    time_s: float


@dataclass(frozen=True)
class Log:
    level: str  # 'info' | 'warning' | 'error'
    text: str


@dataclass(frozen=True)
class Halted:
    """The physics stopped (blow-up or non-finite state): publish an ERROR diagnostic."""

    cause: str


def observation_is_finite(obs) -> bool:
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            return False
    return True


class Pacer:
    """
    Wall clock -> number of physics steps due, without drift.

    steps_due(now) = floor((now - t0) * rtf / dt) - steps_done, capped at max_steps per call; when
    the cap bites, t0 is moved forward so the lost time is not caught up later (no burst), and the
    wall time so skipped is counted in ``dropped_s``.
    """

    def __init__(self, dt_s: float, real_time_factor: float, max_steps: int, now: float):
        self.dt_s = dt_s
        self.rtf = real_time_factor
        self.max_steps = max(1, int(max_steps))
        self.t0 = now
        self.steps_done = 0
        self.dropped_s = 0.0

    def steps_due(self, now: float) -> int:
        target = int(math.floor((now - self.t0) * self.rtf / self.dt_s + 1e-9))
        due = target - self.steps_done
        if due > self.max_steps:
            shift = (due - self.max_steps) * self.dt_s / self.rtf
            self.t0 += shift
            self.dropped_s += shift
            due = self.max_steps
        return max(0, due)

    def advance(self, n: int):
        self.steps_done += n

    def lag_s(self, now: float) -> float:
        return max(0.0, (now - self.t0) - self.steps_done * self.dt_s / self.rtf)


@dataclass
class Window:
    """Counters over one health period."""

    wall0: float
    sim0: float
    physics_s: float = 0.0
    steps: int = 0
    free_running: bool = True


@dataclass
class SessionConfig:
    pacing: str = 'real_time'
    real_time_factor: float = 1.0
    publish_rate_hz: float = 100.0
    duration_s: float = 0.0
    step_count: int = 100
    watchdog_timeout_s: float = 0.0
    watchdog_action: str = 'safe'
    watchdog_clock: str = 'sim'
    control_period_s: float = 0.0  # closed_loop: 0 = one publication period
    #: real_time: simulated seconds the physics runs ahead of publication, so a slow step (a hard
    #: Newton solve) delays no state; each state is published at its own wall time
    #: (Publish.due_wall). Commands then act up to this much later. 0 = publish each state as soon
    #: as it is computed.
    lookahead_s: float = 0.0
    #: real_time: each state is sent this fraction of a publication period after its wall time
    #: (Publish.due_wall), its physics and messages computed before: their varying cost then
    #: stays out of the send times, which keep the wall grid as an idle process's wake-ups do
    #: (benchmarks/performance/bench_viewer.py). What is sent is unchanged: the state is computed
    #: at its wall time from the commands received by then, as with 0 (send once computed).
    publish_delay_periods: float = 0.0
    paused: bool = False

    def describe(self) -> str:
        """Return the pacing, duration and watchdog in words (a start-up log line)."""
        return (
            f'pacing {self.pacing}'
            + (f' x{self.real_time_factor:g}' if self.pacing == 'real_time' else '')
            + (', paused' if self.paused else '')
            + ', '
            + (
                f'duration {self.duration_s:g} s'
                if self.duration_s > 0
                else 'running until stopped'
            )
            + (
                f', watchdog {self.watchdog_timeout_s:g} s of {self.watchdog_clock} time '
                f'({self.watchdog_action})'
                if self.watchdog_timeout_s > 0
                else ''
            )
        )


class LogThrottle:
    """
    A token bucket for log lines: a burst, then a rate; the rest are counted, not logged.

    A publisher flooding bad values must not spend the node's time on logging; the next line that
    passes says how many were held back.
    """

    def __init__(self, burst: int, rate_hz: float, now: float = 0.0):
        self.burst, self.rate_hz = float(burst), float(rate_hz)
        self._tokens, self._refilled, self._held = float(burst), now, 0

    def admit(self, text: str, now: float) -> str | None:
        """Return the line to log now (with the count held back since the last), or None."""
        self._tokens = min(self.burst, self._tokens + (now - self._refilled) * self.rate_hz)
        self._refilled = now
        if self._tokens < 1.0:
            self._held += 1
            return None
        self._tokens -= 1.0
        if self._held:
            text += f' ({self._held} more not logged)'
            self._held = 0
        return text


@dataclass
class Session:
    """
    The live session: see the module docstring.

    Every call takes ``now``, the wall time in seconds (time.monotonic in the node, a fake clock in
    tests); ``physics_clock`` times the physics (time.perf_counter).
    """

    sim: object
    config: SessionConfig
    now: float
    physics_clock: object = None
    started: bool = False
    done: bool = False
    exit_code: int = 0
    watchdog_tripped: bool = False
    awaiting_command: bool = False
    publications: int = 0
    dropped_wall_s: float = 0.0
    physics_s_total: float = 0.0  # wall seconds spent in the physics since the start
    steps_total: int = 0
    _pacer: Optional[Pacer] = None
    _window: Window = None
    _applied: Optional[Command] = None
    _last_command_steps: int = 0
    _last_command_wall: Optional[float] = None
    _last_hold_publish: float = -math.inf
    _last_drop_log: float = -math.inf
    _started_wall: float = 0.0
    _deferring: bool = False
    events: list = field(default_factory=list)
    #: commands since the start: accepted, rejected (a bad value or message; the node logs them
    #: throttled, so these counts are the full record) and stale (closed-loop answers to old
    #: states)
    command_counts: dict = field(
        default_factory=lambda: {'accepted': 0, 'rejected': 0, 'stale': 0}
    )

    def __post_init__(self):
        import time

        self.physics_clock = self.physics_clock or time.perf_counter
        self.dt_s = float(self.sim.model.dt_s)
        self.command = self.sim.command
        self.publish_every = max(1, int(round(1.0 / (self.config.publish_rate_hz * self.dt_s))))
        self.ledger_every = max(1, int(round(self.config.publish_rate_hz / LEDGER_RATE_HZ)))
        self._window = Window(self.now, 0.0)
        self._last_command_wall = self.now
        self.paused = self.config.paused

    # -- helpers --------------------------------------------------------------------------------
    def _emit(self, event):
        self.events.append(event)

    def _take(self) -> list:
        out, self.events = self.events, []
        return out

    @property
    def control_steps(self) -> int:
        """
        Physics steps of one closed-loop control period.

        A whole number of publication periods.
        """
        period = self.config.control_period_s or self.publish_every * self.dt_s
        return max(1, int(round(period / self.dt_s)))

    def _reanchor(self, now: float):
        if self._pacer is not None:
            self.dropped_wall_s += self._pacer.dropped_s
        # the pacer counts publication periods, so that every state lies on the physics step's grid
        wall_periods = max(
            MAX_CATCH_UP_PERIODS, math.ceil(MAX_CATCH_UP_S * self.config.publish_rate_hz - 1e-9)
        )
        max_periods = (
            max(1, int(math.ceil(wall_periods * self.config.real_time_factor)))
            + self._lookahead_periods()
        )
        self._pacer = Pacer(
            self.dt_s * self.publish_every, self.config.real_time_factor, max_periods, now
        )
        self._window.free_running = False

    def _lookahead_periods(self) -> int:
        return int(math.ceil(self.config.lookahead_s / (self.dt_s * self.publish_every) - 1e-9))

    def dropped_s(self) -> float:
        """
        Return the wall seconds of real_time pacing that were not simulated.

        The physics or the machine could not keep up: the sim fell behind by that much and did not
        catch up.
        """
        return self.dropped_wall_s + (self._pacer.dropped_s if self._pacer else 0.0)

    # -- life -----------------------------------------------------------------------------------
    def _begin(self, now: float):
        self.started = True
        self._started_wall = now
        self._window = Window(now, self.sim.time_s)
        self._reanchor(now)

    def start(self, now: float) -> list:
        self._begin(now)
        self._publish_applied(self.command)
        self._emit(Publish(self.sim.observe(), ledger=True))
        self._last_hold_publish = now
        if self.config.pacing == 'closed_loop':
            self.awaiting_command = True
        return self._take()

    def tick(self, now: float) -> list:
        """Run one pacing tick; the node calls this at publish_rate_hz of wall time."""
        if self.done or not self.started or self.sim.fault is not None:
            return self._take()
        self._wall_watchdog(now)
        pacing = self.config.pacing
        if self.paused or pacing in ('lockstep', 'closed_loop'):
            if now - self._last_hold_publish >= HOLD_REPUBLISH_S:
                # late joiners (a controller waiting for its first state) see the current state
                self._emit(Publish(self.sim.observe()))
                self._last_hold_publish = now
            return self._take()
        if pacing == 'as_fast_as_possible':
            budget_end = now + AFAP_BUDGET / self.config.publish_rate_hz
            while self._run_periods(1) and not self.done and self._wall() < budget_end:
                pass
            self._reanchor(self._wall())
            self._window.free_running = False
            return self._take()
        dropped = self._pacer.dropped_s
        due = self._pacer.steps_due(now + self.config.lookahead_s / self.config.real_time_factor)
        if self._pacer.dropped_s > dropped and now - self._last_drop_log >= DROP_LOG_PERIOD_S:
            self._last_drop_log = now
            self._emit(
                Log(
                    'warning',
                    f'fell behind real time (factor {self.config.real_time_factor:g}): '
                    f'{self.dropped_s():.3f} s of wall time dropped so far, not caught up; '
                    f'{self._physics_cost_phrase()}',
                )
            )
        if due > 0:
            self._deferring = self.config.lookahead_s > 0 or self.config.publish_delay_periods > 0
            try:
                self._run_periods(due)
            finally:
                self._deferring = False
        self._check_duration()
        return self._take()

    def _wall(self) -> float:
        import time

        return time.monotonic()

    def physics_cost_rtf(self) -> float:
        """
        Return the simulated seconds per second of physics compute since the start.

        nan before any step.
        """
        return (
            (self.steps_total * self.dt_s / self.physics_s_total)
            if self.physics_s_total > 0
            else float('nan')
        )

    def _physics_cost_phrase(self) -> str:
        # before the first step there is no cost to report: say so rather than print 'nan'
        physics = self.physics_cost_rtf()
        if not math.isfinite(physics):
            return 'no step computed yet, so the node was not scheduled in time'
        return f'the physics alone runs at {physics:.3g}x real time'

    # -- stepping -------------------------------------------------------------------------------
    def _run_periods(self, periods: int) -> bool:
        """
        Advance ``periods`` publication periods, publishing the state after each.

        False after a fault.
        """
        for _ in range(periods):
            steps0 = self.sim.steps
            if not self._run_steps(self.publish_every):
                return False
            if self._pacer is not None:
                self._pacer.advance(1 if self.sim.steps > steps0 else 0)
            if self.done:
                break
        return True

    def _run_steps(self, n: int, publish: bool = True) -> bool:
        """
        Advance up to n steps (capped by the duration) holding the command, then publish the state.

        The run is split at the watchdog deadline. False after a blow-up (the physics stops).
        """
        if self.config.duration_s > 0:
            n = min(n, max(0, int(round((self.config.duration_s - self.sim.time_s) / self.dt_s))))
        obs = None
        remaining = n
        while remaining > 0:
            chunk = self._watchdog_chunk(remaining)
            command = self.command
            if command != self._applied:
                self._publish_applied(command)
            t0 = self.physics_clock()
            steps0 = self.sim.steps
            try:
                obs = self.sim.step(chunk, command)
            except SimulationBlowUp as exc:
                self._count(t0, self.sim.steps - steps0)
                self._halt(str(exc))
                return False
            self._count(t0, chunk)
            remaining -= chunk
            if not observation_is_finite(obs):
                self.sim.fault = f'non-finite observation at t={obs.time_s!r} s'
                self._halt(self.sim.fault)
                return False
        if obs is not None and publish:
            self.publications += 1
            ledger = self.publications % self.ledger_every == 0
            if ledger:
                self._publish_applied(self.command)
            due_wall = None
            if self._deferring:  # the wall time of the period being completed (the pacer's grid)
                pacer = self._pacer
                periods = pacer.steps_done + 1 + self.config.publish_delay_periods
                due_wall = pacer.t0 + periods * pacer.dt_s / pacer.rtf
            self._emit(Publish(obs, ledger=ledger, due_wall=due_wall))
        self._check_duration()
        return True

    def _count(self, t0: float, steps: int):
        spent = self.physics_clock() - t0
        self._window.physics_s += spent
        self._window.steps += max(0, steps)
        self.physics_s_total += spent
        self.steps_total += max(0, steps)

    def _check_duration(self):
        d = self.config.duration_s
        if d > 0 and not self.done and self.sim.time_s >= d - 0.5 * self.dt_s:
            self._emit(PublishLedger(self.sim.time_s))
            lag = self.dropped_s()
            self._emit(
                Log(
                    'info',
                    f'duration {d:g} s of simulated time reached'
                    + (
                        f' ({lag:.3f} s of wall time dropped: the run was not kept in real time)'
                        if lag > 0
                        else ''
                    )
                    + '; exiting',
                )
            )
            self.done = True

    def _halt(self, cause: str):
        self.exit_code = 1
        self._window.free_running = False
        self.awaiting_command = False
        self._emit(
            Log(
                'error',
                f'physics blew up: {cause}; stopped stepping at t={self.sim.time_s:.6f} s '
                f'(last good state kept, nothing more is published; {SERVICE_RESET} restarts)',
            )
        )
        self._emit(Halted(cause))
        if self.config.duration_s > 0:
            self.done = True

    def _publish_applied(self, command: Command):
        self._applied = command
        self._emit(Applied(command, self.sim.time_s))

    # -- commands and watchdog ------------------------------------------------------------------
    def accept(
        self, values: dict, now: float, stamp_s: float | None = None, source: str = 'command'
    ) -> list:
        """
        Apply a command: ``values`` maps Command fields to numbers.

        All are checked first and applied together at the current step (or none, if one is bad:
        CommandError names it). In closed_loop pacing a command that answers the awaited state
        releases the next control period.
        """
        stale = (
            self.config.pacing == 'closed_loop'
            and stamp_s is not None
            and stamp_s < self.sim.time_s - 0.5 * self.dt_s
        )
        checked = {}
        try:
            for name, value in values.items():
                if name not in Command.LIMITS:
                    raise CommandError(
                        f'{source}: {name!r} is not a command field; allowed: '
                        f'{", ".join(Command.LIMITS)}'
                    )
                low, high = self.sim.command_limits[name]
                checked[name] = check_command_value(name, value, low, high)
        except CommandError:
            self.command_counts['rejected'] += 1
            raise
        if stale:
            # an answer to an earlier state (a repeated publication answered twice): applying it
            # would make the closed loop depend on delivery timing
            self.command_counts['stale'] += 1
            return self._take()
        self.command_counts['accepted'] += 1
        self.command = dataclasses.replace(self.command, **checked)
        self._last_command_steps = self.sim.steps
        self._last_command_wall = now
        if self.watchdog_tripped:
            self.watchdog_tripped = False
            self._emit(
                Log('info', f'command watchdog cleared by {source} at t={self.sim.time_s:.4f} s')
            )
        if (
            self.config.pacing == 'closed_loop'
            and self.awaiting_command
            and self.started
            and not self.paused
            and (stamp_s is None or stamp_s >= self.sim.time_s - 0.5 * self.dt_s)
        ):
            self._closed_loop_period()
        return self._take()

    def _closed_loop_period(self):
        self.awaiting_command = False
        steps0 = self.sim.steps
        ok = self._run_steps(self.control_steps)
        if ok and self.sim.steps == steps0:
            return
        if ok and not self.done:
            self.awaiting_command = True

    def command_age_s(self) -> float:
        """Return the simulated seconds since the last accepted command (or the start / reset)."""
        return (self.sim.steps - self._last_command_steps) * self.dt_s

    def _watchdog_chunk(self, n: int) -> int:
        if (
            self.config.watchdog_timeout_s <= 0.0
            or self.watchdog_tripped
            or self.config.watchdog_clock != 'sim'
        ):
            return n
        limit = self._last_command_steps + max(
            1, int(math.ceil(self.config.watchdog_timeout_s / self.dt_s - 1e-9))
        )
        if self.sim.steps >= limit:
            self._trip_watchdog(f'{self.command_age_s():.3f} s of simulated time')
            return n
        return min(n, limit - self.sim.steps)

    def _wall_watchdog(self, now: float):
        if (
            self.config.watchdog_timeout_s > 0.0
            and self.config.watchdog_clock == 'wall'
            and not self.watchdog_tripped
            and now - self._last_command_wall > self.config.watchdog_timeout_s
        ):
            self._trip_watchdog(f'{now - self._last_command_wall:.3f} s of wall time')

    def _trip_watchdog(self, age: str):
        self.watchdog_tripped = True
        if self.config.watchdog_action == 'safe':
            self.command = SAFE_COMMAND
            what = 'applying the safe command (pump off, valve open, cable released)'
        else:
            what = f'holding the last command {self.command}'
        self._emit(
            Log(
                'warning',
                f'command watchdog tripped at t={self.sim.time_s:.4f} s: no command for {age} '
                f'(timeout {self.config.watchdog_timeout_s:g} s); {what}',
            )
        )

    # -- requests -------------------------------------------------------------------------------
    def configure(self, name: str, value, now: float) -> list:
        """Apply a live parameter change (already validated by the node)."""
        old = getattr(self.config, name)
        setattr(self.config, name, value)
        if name in ('real_time_factor', 'pacing') and value != old and self._pacer is not None:
            self._reanchor(now)
        if name == 'pacing' and value != old:
            self.awaiting_command = (
                value == 'closed_loop' and self.started and self.sim.fault is None
            )
            if self.awaiting_command:
                self._emit(Publish(self.sim.observe()))  # the state the controller answers next
        if name == 'watchdog_timeout_s' and value == 0.0:
            self.watchdog_tripped = False
        return self._take()

    def pause(self, flag: bool, now: float) -> tuple[bool, str, list]:
        if flag:
            msg = (
                'already paused' if self.paused else 'paused'
            ) + f' at t={self.sim.time_s:.6f} s'
            self.paused = True
            self._window.free_running = False
            return True, msg, self._take()
        if self.config.pacing == 'lockstep':
            return (
                False,
                (
                    'not resumed: pacing is lockstep, simulated time advances only through '
                    f'{SERVICE_STEP}; set pacing to real_time or as_fast_as_possible to run freely'
                ),
                self._take(),
            )
        was = self.paused
        self.paused = False
        if self._pacer is not None:
            self._reanchor(now)
        if was and self.started:
            # a recorder that joined during the pause missed the held command: say it again
            self._publish_applied(self.command)
        msg = ('resumed' if was else 'already running') + f' at t={self.sim.time_s:.6f} s'
        if self.sim.fault is not None:
            msg += f' (the physics is stopped after a fault; call {SERVICE_RESET})'
        return True, msg, self._take()

    def step(self, now: float) -> tuple[bool, str, list]:
        if self.sim.fault is not None:
            message = (
                f'refused: the physics is stopped after a fault ({self.sim.fault}); '
                f'call {SERVICE_RESET}'
            )
            return False, message, self._take()
        if self.done:
            return False, f'refused: duration_s={self.config.duration_s:g} s reached', self._take()
        if self.config.pacing not in ('lockstep', 'closed_loop') and not self.paused:
            return (
                False,
                (
                    f'refused: the simulation is running (pacing {self.config.pacing}); pause it '
                    'with '
                    f'{SERVICE_PAUSE} first or set pacing to lockstep'
                ),
                self._take(),
            )
        if not self.started:
            self._begin(now)
        steps0 = self.sim.steps
        ok = self._run_steps(self.config.step_count)
        if self._pacer is not None:
            self._reanchor(now)
        done = self.sim.steps - steps0
        return (
            ok,
            (
                f'advanced {done} steps to t={self.sim.time_s:.6f} s'
                if ok
                else f'physics blew up after {done} steps: {self.sim.fault}'
            ),
            self._take(),
        )

    def reset(self, now: float) -> tuple[str, list]:
        t_before, fault = self.sim.time_s, self.sim.fault
        obs = self.sim.reset()
        self.command = self.sim.command
        self.exit_code = 0
        self.watchdog_tripped = False
        self._last_command_steps = 0
        self._last_command_wall = now
        self.publications = 0
        self._window = Window(now, 0.0, free_running=False)
        if self.started:
            self._reanchor(now)
        self._publish_applied(self.command)
        self._emit(Publish(obs, ledger=True))
        self.awaiting_command = self.config.pacing == 'closed_loop' and self.started
        self._emit(
            Log(
                'info',
                f'reset at t={t_before:.6f} s'
                + (f' (clearing the fault: {fault})' if fault else '')
                + '; simulation time back to 0',
            )
        )
        return (
            f'reset to the initial state: simulation time back to 0 from t={t_before:.6f} s'
            + (', fault cleared' if fault else '')
        ), self._take()

    # -- health ---------------------------------------------------------------------------------
    def run_state(self) -> str:
        if self.sim.fault is not None:
            return 'fault'
        if self.done:
            return 'done'
        if not self.started:
            return 'waiting'
        if self.config.pacing in ('lockstep', 'closed_loop'):
            return self.config.pacing
        return 'paused' if self.paused else 'running'

    def health(self, now: float) -> tuple[str, str, dict]:
        """
        Return (level OK|WARN|ERROR, message, key -> value) over the window since the last call.

        The call resets the window.
        """
        w = self._window
        wall = max(now - w.wall0, 1e-9)
        achieved = (self.sim.time_s - w.sim0) / wall
        state = self.run_state()
        cfg = self.config
        lag = (
            self._pacer.lag_s(now)
            if (self._pacer is not None and state == 'running' and cfg.pacing == 'real_time')
            else 0.0
        )
        integrator = str(getattr(self.sim.model, 'integrator', 'explicit'))
        implicit = 'implicit' in integrator or 'backward' in integrator
        margin = float('nan')
        if not implicit:
            # only an explicit step has a stable bound to warn about; for the shell the estimate is
            # an eigenvalue solve that holds the GIL for tens of ms (a publication stall a second)
            try:
                margin = float(self.sim.stable_step_s()) / self.dt_s
            except Exception:  # a model that cannot estimate it at this state
                pass
        ledger = self.sim.energy_ledger()
        closure_j = float(ledger.get('closure_error', float('nan')))
        in_play = (
            abs(float(ledger.get('in_initial', 0.0)))
            + abs(float(ledger.get('in_actuation_work', 0.0)))
            + sum(abs(float(v)) for k, v in ledger.items() if k.startswith('stored_'))
        )
        closure = closure_j / in_play if in_play > CLOSURE_FLOOR_J else 0.0
        age = self.command_age_s()
        values = {
            'state': state,
            'pacing': cfg.pacing,
            'real_time_factor_requested': cfg.real_time_factor,
            'real_time_factor_achieved': achieved,
            'physics_real_time_factor': self.physics_cost_rtf(),
            'physics_us_per_step': (w.physics_s / w.steps * 1e6) if w.steps else float('nan'),
            'steps_in_window': w.steps,
            'lag_s': lag,
            'dropped_wall_s': self.dropped_s(),
            'stable_step_margin': margin,
            'energy_closure_relative': closure,
            'energy_closure_j': closure_j,
            'command_age_s': age,
            'command_age_wall_s': now - self._last_command_wall,
            **{f'commands_{k}': n for k, n in self.command_counts.items()},
            'watchdog': (
                'off'
                if cfg.watchdog_timeout_s <= 0
                else f'tripped ({cfg.watchdog_action})' if self.watchdog_tripped else 'armed'
            ),
            'watchdog_clock': cfg.watchdog_clock,
            'watchdog_timeout_s': cfg.watchdog_timeout_s,
            'awaiting_command': self.awaiting_command,
            'time_s': self.sim.time_s,
            'steps': self.sim.steps,
            'fault': self.sim.fault or '',
        }
        warn = []
        if self.watchdog_tripped:
            warn.append(
                f'command watchdog tripped (timeout {cfg.watchdog_timeout_s:g} s, '
                f'{cfg.watchdog_clock} time), '
                + (
                    'safe command applied'
                    if cfg.watchdog_action == 'safe'
                    else 'last command held'
                )
            )
        if math.isfinite(closure) and abs(closure) > CLOSURE_WARN_RELATIVE:
            warn.append(
                f'energy closure {closure:+.2%} of the energy in play ({closure_j:+.3g} J) '
                'exceeds '
                f'{CLOSURE_WARN_RELATIVE:.0%}'
            )
        values['integrator'] = integrator
        if math.isfinite(margin) and margin < STABLE_MARGIN_WARN and not implicit:
            warn.append(f'step above the stable step (margin {margin:.3g})')
        if (
            w.free_running
            and state == 'running'
            and cfg.pacing == 'real_time'
            and wall > 0.5
            and achieved < RTF_WARN_FRACTION * cfg.real_time_factor
        ):
            physics = self.physics_cost_rtf()
            cause = (
                'the physics cannot keep up'
                if math.isfinite(physics) and physics < cfg.real_time_factor
                else 'the machine did not schedule the node in time '
                f'({self._physics_cost_phrase()})'
            )
            warn.append(
                f'real-time factor {achieved:.3g} below the requested {cfg.real_time_factor:g}: '
                f'{cause}; '
                f'{self.dropped_s():.3f} s of wall time dropped so far'
            )
        if self.sim.fault is not None:
            level, message = ERROR, f'physics stopped: {self.sim.fault}'
        elif warn:
            level, message = WARN, '; '.join(warn)
        else:
            level = OK
            message = {
                'running': f'running ({cfg.pacing}'
                + (f' x{cfg.real_time_factor:g}' if cfg.pacing == 'real_time' else '')
                + f', achieved x{achieved:.3g})',
                'paused': 'paused',
                'lockstep': 'lockstep: waiting for step requests',
                'closed_loop': 'closed loop: '
                + (
                    "waiting for the controller's command"
                    if self.awaiting_command
                    else 'stepping'
                ),
                'waiting': 'waiting for subscribers',
                'done': 'duration reached',
            }.get(state, state)
        self._window = Window(now, self.sim.time_s, free_running=(state == 'running'))
        return level, message, values
