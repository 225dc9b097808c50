"""
Start pulsejet nodes as processes in an isolated ROS domain: for tests, benchmarks, fuzz and soak.

One home for what every caller that starts nodes needs:

- a ROS_DOMAIN_ID of this process's own (`pick_domain_id`, `default_domain_id`), from the pid and
  an offset, in one of the ranges ROS documents as safe on Linux: 1-100 (of 0-101; the tests, one
  offset per test file) or 215-232 (the harness and the benchmarks when given none), so that a
  harness started without a domain never meets a test's nodes;
- the children's environment (`isolation_variables`, `isolated_environment`): that domain,
  ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (no traffic leaves the machine, nothing from other
  machines comes in), unbuffered and uncoloured logs so a log file is complete when read;
  `discover_localhost_only` gives this process's own participant the same discovery range;
- the command line (`node_params.node_command`: `python -m module --ros-args -p name:=value`, with
  this interpreter) and a started node (`NodeProcess`: output to a log file, stopped with SIGINT,
  killed after a timeout).

The pid of a NodeProcess is the node's: the rclpy wheels' bootstrap (ros_wheels_bootstrapper)
re-executes the interpreter at start-up with os.execve, which keeps the pid, and a child of a
bootstrapped process inherits the bootstrap's guard variable and does not re-execute at all. The
interpreter is started directly (no shell, no `ros2 run` wrapper), so /proc/<pid> (memory, CPU
time) and the stop signal reach the node itself.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess

TEST_DOMAINS = range(1, 101)  # of 0-101, a range ROS documents as safe on Linux
HARNESS_DOMAINS = range(215, 233)  # 215-232: the other range ROS documents as safe on Linux
STOP_TIMEOUT_S = 10.0


def pick_domain_id(offset: int = 0, domains: range = TEST_DOMAINS) -> int:
    """Return a ROS domain of this process: from its pid plus `offset`, one of `domains`."""
    return domains[(os.getpid() + offset) % len(domains)]


def default_domain_id() -> int:
    """Return the domain a harness or a benchmark takes when given none (215 + pid % 18)."""
    return pick_domain_id(0, HARNESS_DOMAINS)


def isolation_variables(domain_id: int) -> dict[str, str]:
    """Return the environment variables that put a node in `domain_id`, reachable on this host."""
    return {
        'ROS_DOMAIN_ID': str(int(domain_id)),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'RCUTILS_LOGGING_BUFFERED_STREAM': '0',
        'RCUTILS_COLORIZED_OUTPUT': '0',
        'PYTHONUNBUFFERED': '1',
    }


def isolated_environment(domain_id: int, base: dict | None = None) -> dict[str, str]:
    """Return the environment of a child node: `base` (default os.environ) plus the isolation."""
    env = dict(os.environ if base is None else base)
    env.update(isolation_variables(domain_id))
    return env


def discover_localhost_only(override: bool = True) -> None:
    """
    Give this process's own DDS participant localhost-only discovery, as its children have.

    Set before this process's rclpy context is created; override=False keeps a range already set.
    """
    if override:
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    else:
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


class NodeProcess:
    """One node as `python -m module --ros-args -p k:=v ...`, output to a log file."""

    def __init__(self, module: str, params: dict, log_path: Path, env: dict):
        from pulsejet_sim.ros.node_params import node_command  # (ROS message types: on use)

        self.module = module
        self.log_path = log_path
        args = node_command(module, params)
        self._log = open(log_path, 'wb')
        self.proc = subprocess.Popen(
            args, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env
        )

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        try:
            return self.log_path.read_text(errors='replace')
        except OSError:
            return ''

    def stop(self, timeout_s: float = STOP_TIMEOUT_S, sig=signal.SIGINT) -> int:
        """Send `sig` (default SIGINT, as Ctrl-C), kill after timeout_s; return the exit code."""
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if not self._log.closed:
            self._log.close()
        return self.proc.returncode
