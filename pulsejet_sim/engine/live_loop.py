"""
The real-time thread that drives a `Session` live, without ROS.

Commands arrive on any thread through an inbox (`accept`, `reject`): the caller never waits for a
physics batch. The pacing thread applies them in arrival order, then ticks the session on a grid of
wall-clock publication periods and hands every event to `emit`. Services and parameter changes
take the session through `locked()`, which first applies what the inbox holds, so they see every
command that arrived before them, and which the pacing thread lets in before its next tick even
when it runs behind and never sleeps (a plain lock would be re-taken at once by the thread that
just released it: sim_node's executor, waiting there for its 1 Hz diagnostics, took no commands
for a tenth of a second and more, and the command watchdog tripped). sim_node is DDS I/O around
this loop; the tests drive it with a real session and no DDS.
"""

from __future__ import annotations

import collections
import contextlib
import threading
import time
import traceback
from typing import Callable, Iterator, Mapping, Optional

from pulsejet_sim.core.model_io import CommandError
from pulsejet_sim.engine.session import Session

Events = list
#: the pacing thread joins within this time at close (a batch in progress finishes first)
JOIN_TIMEOUT_S = 2.0
#: the longest the pacing thread waits for a thread it let in to take the session (that thread is
#: already blocked on the lock, so it normally takes it within microseconds)
HANDOFF_TIMEOUT_S = 0.05


class LiveLoop:
    """
    Tick `session` every `period_s` of wall time on its own thread.

    tick(now) -> events: one publication period (sim_node's adds waiting for subscribers before
    the start; default `Session.tick`, or `Session.start` until the session started);
    emit(events): the caller's publishing; on_rejected(text): a command refused (the session
    counts it); on_failure(text): the loop stopped on an exception (a bug), the session is marked
    done with exit code 2.
    """

    def __init__(
        self,
        session: Session,
        period_s: float,
        emit: Callable[[Events], None],
        on_rejected: Callable[[str], None],
        on_failure: Callable[[str], None],
        tick: Optional[Callable[[float], Events]] = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        if not period_s > 0:
            raise ValueError(f'period_s={period_s!r} rejected; allowed: > 0 s')
        self.session = session
        self.period_s = period_s
        self.emit = emit
        self.on_rejected = on_rejected
        self.on_failure = on_failure
        self.tick = tick or self._default_tick
        self.clock = clock
        # the pacing thread and every other caller share the session under this lock
        self.lock = threading.RLock()
        # threads waiting in locked(): the pacing thread hands them the lock before its next tick
        self._waiting = 0
        self._waiting_lock = threading.Lock()
        self._admitted = threading.Event()  # set by a waiting thread once it holds the lock
        self._inbox: collections.deque = collections.deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    # -- any thread -------------------------------------------------------------------------------
    def accept(
        self, values: Mapping[str, float], stamp_s: Optional[float], source: str
    ) -> None:
        """Queue a command (actuator field -> value; stamp of the state it answers, or None)."""
        self._inbox.append((values, stamp_s, source, self.clock()))
        self._wake.set()

    def reject(self, reason: str) -> None:
        """Queue a message that did not parse: counted and reported in order with the others."""
        self._inbox.append((None, None, reason, self.clock()))
        self._wake.set()

    @contextlib.contextmanager
    def locked(self) -> Iterator[Session]:
        """Hold the session, with every command received so far applied."""
        with self._waiting_lock:
            self._waiting += 1
        try:
            self.lock.acquire()
        finally:
            with self._waiting_lock:
                self._waiting -= 1
        self._admitted.set()
        try:
            self.apply_inbox()
            yield self.session
        finally:
            self.lock.release()

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self.run, name='live loop', daemon=True)
            self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(JOIN_TIMEOUT_S)

    # -- the pacing thread ------------------------------------------------------------------------
    def apply_inbox(self) -> None:
        """Apply the commands received so far (call with the lock held)."""
        while self._inbox:
            values, stamp_s, source, received = self._inbox.popleft()
            if values is None:  # a message that did not parse; `source` holds the reason
                self.session.command_counts['rejected'] += 1
                self.on_rejected(source)
                continue
            try:
                events = self.session.accept(values, received, stamp_s, source)
            except CommandError as exc:
                self.on_rejected(f'{source}: {exc}; command kept at {self.session.command}')
                continue
            self.emit(events)

    def run(self) -> None:
        """Pace until the session is done or close() (the thread's body)."""
        period = self.period_s
        next_tick = self.clock()
        while not self._stop.is_set() and not self.session.done:
            # before draining: a command arriving from here on wakes the wait below
            self._wake.clear()
            now = self.clock()
            try:
                with self.lock:
                    self._admitted.clear()  # only a thread let in after this tick counts
                    self.apply_inbox()  # in closed_loop pacing this runs the next control period
                    if now >= next_tick:
                        self.emit(self.tick(now))
                        next_tick += period
                        if next_tick < now - period:  # more than a period late: no burst
                            next_tick = now
            except Exception as exc:  # a bug: report it, stop with a failure
                traceback.print_exc()
                self.session.exit_code = 2
                self.session.done = True
                self.on_failure(f'pacing thread stopped: {type(exc).__name__}: {exc}')
                return
            if self._waiting:  # let the waiting thread take the session before the next tick
                self._admitted.wait(HANDOFF_TIMEOUT_S)
            delay = next_tick - self.clock()
            if delay > 0:
                self._wake.wait(delay)  # a command (or the stop) wakes the loop early

    def _default_tick(self, now: float) -> Events:
        return self.session.tick(now) if self.session.started else self.session.start(now)
