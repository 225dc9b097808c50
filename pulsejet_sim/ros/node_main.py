"""
The process life of a pulsejet node: rclpy start-up, SIGINT/SIGTERM, spinning, exit codes.

sim_node and controller_node share it so that both stop the same way: a signal ends the spin loop
(rclpy's own handlers are off, so the node can log and close cleanly), a bad scene or parameter is
one clear line and exit code 2, and a bug keeps its traceback.
"""

from __future__ import annotations

import gc
import signal
import sys
import time
import traceback
from typing import Callable

from pulsejet_sim.ros.executor import make_executor
import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

#: after the node says it is done, keep spinning this long so the last samples reach reliable
#: subscribers before the writers go away
DRAIN_S = 0.3
#: and wait at most this long (wall time) for every reliable subscriber to acknowledge them: on a
#: loaded machine a sample lost on first send is repeated only on the reader's request, which a
#: writer that has gone away never answers (a recording would miss the final state)
ACK_TIMEOUT_S = 5.0
#: the spin loop looks at a signal or ``node.done`` this often when nothing else wakes it. Each
#: wake-up of rclpy's single-threaded executor rebuilds its wait set in Python (~0.26 ms holding
#: the interpreter); at 20 Hz, as before, it overlapped sim_node's sends often enough to show in
#: their jitter p99 (benchmarks/results/viewer.md). A stop or the end of a run is seen this much
#: later at most (the events executor takes no guard condition a node could wake it with).
SPIN_TIMEOUT_S = 0.25


def wait_for_acknowledgements(node: Node, timeout_s: float) -> bool:
    """
    Wait until every reliable subscriber acknowledged all of the node's publications.

    Bounded by ``timeout_s`` in total; False when a subscriber had not acknowledged by then.
    """
    end = time.monotonic() + timeout_s
    acked = True
    for publisher in node.publishers:
        left = max(0.0, end - time.monotonic())
        acked = publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and acked
    return acked


def freeze_start_up_objects() -> None:
    """
    Move every object alive after start-up out of the garbage collector's reach.

    The imports (numba, scipy, rclpy) leave about 10^5 tracked objects; a full collection then
    takes about 50 ms, an eternity for a node handling a message every millisecond (a controller
    that stalls that long lets the command watchdog trip). Frozen, they are not scanned again;
    what the node allocates while running is collected as before.
    """
    gc.collect()
    gc.freeze()


def run_node(
    name: str, make_node: Callable[[], Node], args=None, executor_kind: str | None = None
) -> int:
    """
    Create the node, spin until a signal or until ``node.done``, then close it.

    Optional hooks on the node: ``executor_kind`` (str, the node's own choice, e.g. from a
    parameter), ``start()`` after it joined the executor, ``done`` (bool), ``exit_code`` (int,
    default 0), ``on_stop(signum or None)`` before closing, ``close()``.
    executor_kind: `pulsejet_sim.ros.executor.make_executor`'s kind when the node has none
    (default: its choice).
    Returns the process exit code.
    """
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    stop = {'signal': None}

    def on_signal(signum, _frame):
        stop['signal'] = signum

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    code = 0

    def running() -> bool:
        return rclpy.ok() and stop['signal'] is None

    try:
        node = make_node()
        executor = make_executor(kind=getattr(node, 'executor_kind', executor_kind))
        node.get_logger().info(f"spinning on rclpy's {type(executor).__name__}")
        executor.add_node(node)
        # before start(): the full collection holds the interpreter ~0.1-0.2 s, which a pacing
        # thread already running took for a lag at its first tick ('fell behind real time')
        freeze_start_up_objects()
        if hasattr(node, 'start'):
            node.start()
        while running() and not getattr(node, 'done', False):
            executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
        code = getattr(node, 'exit_code', 0)
        if getattr(node, 'done', False):
            wait_for_acknowledgements(node, ACK_TIMEOUT_S)
            end = time.monotonic() + DRAIN_S
            while running() and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
        if hasattr(node, 'on_stop'):
            node.on_stop(stop['signal'])
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, ParameterException) as exc:  # bad scene or parameter: one clear line
        print(f'{name}: error: {type(exc).__name__}: {exc}', file=sys.stderr, flush=True)
        code = 2
    except Exception as exc:  # a bug: keep the traceback
        traceback.print_exc()
        print(f'{name}: error: {type(exc).__name__}: {exc}', file=sys.stderr, flush=True)
        code = 2
    finally:
        if node is not None:
            if hasattr(node, 'close'):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return code
