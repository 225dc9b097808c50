"""
The executor the pulsejet processes spin.

rclpy's `EventsExecutor` (rclpy.experimental, in Jazzy's rclpy since 7.1) where this rclpy has
it, else `SingleThreadedExecutor`. The events executor takes each message from a queue the
middleware fills instead of rebuilding a wait set per callback: on a 1 kHz /clock subscription it
costs about a third of the CPU (benchmarks/performance/bench_executor.py, results in
benchmarks/results/executor.md). On a 2-core machine that runs sim_node, a controller and a
recorder at 1 kHz this is the difference between a machine with headroom and one that drops
simulated time. It raises a callback's exception from spin_once, as the single-threaded
executor does, and runs wall-clock timers on time (test/test_executor.py).

No pulsejet node runs an rclpy timer on simulated time: rclpy 7.1.6's events executor waits for
such a timer in wall time and then fires it in bursts, more often than its period, whenever the
simulated clock does not run at the wall rate (a 20 ms timer over 1 s of simulated time published
at half the wall rate fired 63 times, not 50). controller_node schedules its commands from the
clock's own updates instead (a jump callback per /clock). Nor does it pass a subscription's
message info (a two-argument callback raises SystemError), which the recorder's send times need.

sim_node keeps the single-threaded executor by default. The events executor serves events in
arrival order, so under a flood of commands beyond the node's capacity
(benchmarks/reliability/live_fuzz.py, 1.9 kHz of commands into the shell scene) a parameter or
service request waited behind every queued message event: parameter dumps took up to 21 s (4 of 125
over 10 s; benchmarks/results/live_fuzz_events_executor.md), against at most 0.63 s with the
single-threaded executor (live_fuzz.md), whose wait set takes each ready entity in turn. sim_node's
parameter `executor:=events` trades that for speed: it halves the median command-to-state latency
of a 1 kHz closed loop (benchmarks/results/hil.md), what hardware in the loop wants. The controller
and the recorder, which take the 1 kHz state, use the events executor.

`PULSEJET_EXECUTOR=single` selects the single-threaded executor everywhere but in a sim_node given
`executor:=events` (e.g. to rule the events executor out when chasing a bug).
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
from typing import Iterator, TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: EXECUTOR_KINDS is read without ROS (parameter tables)
    from rclpy.executors import Executor

EXECUTOR_ENV = 'PULSEJET_EXECUTOR'
EXECUTOR_KINDS = ('events', 'single')


def executor_kind() -> str:
    """Return the executor `make_executor` builds: 'events' where available, or the env's."""
    wanted = os.environ.get(EXECUTOR_ENV, 'events') or 'events'
    if wanted not in EXECUTOR_KINDS:
        raise ValueError(
            f'{EXECUTOR_ENV}={wanted!r} rejected; allowed: one of {", ".join(EXECUTOR_KINDS)}'
        )
    if wanted == 'events':
        try:
            from rclpy.experimental import EventsExecutor  # noqa: F401
        except ImportError:  # an rclpy older than the events executor
            return 'single'
    return wanted


@contextlib.contextmanager
def _stderr_with_a_file() -> Iterator[None]:
    try:
        sys.stderr.fileno()
        has_file = True
    except (AttributeError, OSError, io.UnsupportedOperation, ValueError):
        has_file = False
    if has_file or sys.__stderr__ is None:
        yield
        return
    saved, sys.stderr = sys.stderr, sys.__stderr__
    try:
        yield
    finally:
        sys.stderr = saved


def make_executor(context=None, kind: str | None = None) -> Executor:
    """Return a new executor of `kind` (default `executor_kind()`) on `context`."""
    kind = executor_kind() if kind is None else kind
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError as exc:  # asked for by name (sim_node's parameter): say so, no fallback
            raise ValueError(
                f"executor 'events' rejected: this rclpy has no rclpy.experimental.EventsExecutor "
                f'({exc}); allowed: single'
            ) from None

        # it calls faulthandler.enable(), which needs a real file behind sys.stderr: under a
        # capturing test runner or a GUI there is none, so it is given the process's own
        with _stderr_with_a_file():
            return EventsExecutor(context=context)
    if kind == 'single':
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor(context=context)
    raise ValueError(f'kind={kind!r} rejected; allowed: one of {", ".join(EXECUTOR_KINDS)}')
