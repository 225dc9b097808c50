"""
Publication at the wall time a state belongs to, on a thread of its own (no ROS import).

With a lookahead (`SessionConfig.lookahead_s`) the physics computes states ahead of the wall clock;
the node builds each state's messages at once (so they hold that state, not a later one) and puts
them here with the state's wall time; this thread sends them then. A slow physics step therefore
delays no publication as long as the physics stays within its lookahead, and publication keeps
the period of the wall grid. Batches run in the order they were put; `flush` runs every pending
batch at once (before a state that is published immediately: a pause, a reset, a changed pacing)
so the order of publications never inverts and nothing computed is lost.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Callable, Sequence


class TimedOutbox:
    """Batches of calls, each run at (not before) its wall time `due` on this object's thread."""

    def __init__(self, clock: Callable[[], float] = time.monotonic, name: str = 'timed outbox'):
        self._clock = clock
        self._pending: collections.deque = collections.deque()
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._started = False

    def start(self) -> None:
        if not self._started:
            self._started = True
            self._thread.start()

    def put(self, due: float, calls: Sequence[Callable[[], object]]) -> None:
        with self._cond:
            self._pending.append((due, calls))
            self._cond.notify()

    def flush(self) -> None:
        """Run every pending batch now, in order (from any thread)."""
        with self._cond:
            while self._pending:
                _, calls = self._pending.popleft()
                self._call(calls)

    def pending(self) -> int:
        return len(self._pending)

    def close(self) -> None:
        """Run what is pending, then stop the thread."""
        self.flush()
        with self._cond:
            self._stop = True
            self._cond.notify()
        if self._started:
            self._thread.join(2.0)

    def _call(self, calls) -> None:
        for call in calls:
            call()

    def _run(self) -> None:
        with self._cond:
            while not self._stop:
                if not self._pending:
                    self._cond.wait(0.5)
                    continue
                due, calls = self._pending[0]
                delay = due - self._clock()
                if delay > 0:
                    # woken early by a put or a flush: look again (the head may have changed)
                    self._cond.wait(delay)
                    continue
                self._pending.popleft()
                # under the lock: a concurrent flush waits, so batches never run out of order
                self._call(calls)
