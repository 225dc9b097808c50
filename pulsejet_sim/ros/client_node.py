"""
An rclpy node in a context and executor of its own (never the global ones), spun on demand.

What a test, a benchmark or the harness talks to live nodes with: `spin` for a while, `spin_until`
a condition holds (with a check between spins, e.g. that the nodes under test are alive), `call`
a service and wait for its response.
"""

from __future__ import annotations

import time
from typing import Callable


class ClientNode:
    """rclpy context + node + executor in `domain_id`; `close()` shuts them down (idempotent)."""

    def __init__(self, name: str, domain_id: int):
        from pulsejet_sim.ros.executor import make_executor
        import rclpy

        self._closed = False
        self.context = rclpy.Context()
        rclpy.init(
            context=self.context,
            domain_id=domain_id,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
        self.node = self.executor = None
        try:
            self.node = rclpy.create_node(name, context=self.context)
            self.executor = make_executor(context=self.context)
            self.executor.add_node(self.node)
        except BaseException:
            self.close()
            raise

    def spin(self, seconds: float) -> None:
        """Serve callbacks for `seconds` of wall time."""
        end = time.monotonic() + seconds
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            self.executor.spin_once(timeout_sec=min(0.02, left))

    def spin_until(
        self,
        predicate: Callable[[], bool],
        timeout_s: float,
        timed_out: Callable[[], BaseException],
        between: Callable[[], None] | None = None,
    ) -> None:
        """
        Serve callbacks until predicate() is true.

        `between()` runs before each spin (it may raise, e.g. when a node under test died);
        after timeout_s of wall time the exception `timed_out()` returns is raised.
        """
        end = time.monotonic() + timeout_s
        while not predicate():
            if between is not None:
                between()
            if time.monotonic() > end:
                raise timed_out()
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, client, request, timeout_s: float, spin_until: Callable | None = None):
        """
        Call a service (rclpy client) and return its response.

        Waits for the service, then for the response, each within timeout_s; `spin_until` (same
        arguments as a caller's spin_until(predicate, timeout_s, what)) replaces the plain wait.
        """
        if spin_until is None:

            def spin_until(predicate, timeout, what):
                self.spin_until(predicate, timeout, lambda: TimeoutError(f'waiting for {what}'))

        spin_until(client.service_is_ready, timeout_s, f'service {client.srv_name}')
        future = client.call_async(request)
        spin_until(future.done, timeout_s, f'the response of {client.srv_name}')
        return future.result()

    def close(self) -> None:
        """Shut the executor, node and context down; idempotent."""
        if self._closed:
            return
        self._closed = True
        import rclpy

        try:
            if self.executor is not None:
                self.executor.shutdown(timeout_sec=1.0)
            if self.node is not None:
                self.node.destroy_node()
        finally:
            rclpy.try_shutdown(context=self.context)
