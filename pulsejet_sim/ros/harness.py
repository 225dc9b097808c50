"""
Test harness: the real sim_node (and optionally controller_node) as processes.

The processes run in an isolated DDS domain.

    from pulsejet_sim.ros.harness import SimHarness

    with SimHarness(scene='pump_cycle', pacing='lockstep', parameters={'step_count': 1000}) as h:
        h.send(valve_opening=0.0, pump_flow_m3_s=2.5e-3)  # held from the next physics step on
        s = h.step()  # 1000 steps = 0.1 s, returns the new state
        assert s.time_s == pytest.approx(0.1)
        h.set_parameters(pacing='real_time', real_time_factor=2.0)
        # raises TimeoutError with the last state:
        h.wait_for(lambda s: s.volume_m3 > 2e-3, timeout_s=10)
        h.reset()  # simulated time back to 0

`SimHarness` starts `python -m pulsejet_sim.ros.sim_node` (and `pulsejet_ctrl.controller_node` with
`controller=True`) as subprocesses in their own ROS domain (`domain_id`, default 215 + pid % 18,
unless given) with localhost-only discovery (pulsejet_sim.ros.launching), and talks to them from
its own rclpy context and node (never the global one; pulsejet_sim.ros.client_node): state
subscriptions (`latest`, `states`, `wait_for`; pulsejet_sim.ros.state_listener), command
publishers (`send`), the pulsejet/pause|step|reset services, the real parameter services of
/sim_node (`set_parameters`, `get_parameters`; pulsejet_sim.ros.sim_controls) and /diagnostics
(`diagnostics_received`, `wait_for_diagnostics`).
Leaving the `with` block (also on an exception) stops the processes (SIGINT, then SIGKILL after
`stop_timeout_s`) and shuts the context down; `exit_codes` then holds their return codes.
The processes' output goes to `log_dir` (a temporary directory by default); `output()` reads it.

Notes: states are assembled on /clock (the node publishes it last in each batch) from the latest
values of the other state topics. While paused or in lockstep the node re-publishes its current
state every 0.5 s, so `states` may repeat a time. Two harnesses alive at once in one process need
distinct `domain_id`s (the default is per process). `reset()` makes the time go back to 0.
"""

from __future__ import annotations

import os
from pathlib import Path
import tempfile
import time
from typing import Callable

from pulsejet_sim.ros.client_node import ClientNode
from pulsejet_sim.ros.launching import (
    default_domain_id,
    discover_localhost_only,
    isolated_environment,
    NodeProcess,
    STOP_TIMEOUT_S,
)
from pulsejet_sim.ros.sim_controls import SIM_NODE_NAME, SimControls
from pulsejet_sim.ros.state_listener import Diagnostic, SimState, StateListener
from pulsejet_sim.scene import DEFAULT_SCENE

STARTUP_TIMEOUT_S = 90.0  # scene loading + JIT compilation of a cold cache
SERVICE_TIMEOUT_S = 30.0

__all__ = ['Diagnostic', 'HarnessError', 'SimHarness', 'SimState']


class HarnessError(RuntimeError):
    """
    A node died, did not start, or a service could not be reached.

    The message has the log tail.
    """


def sim_node_parameters(scene: str, pacing: str, parameters: dict) -> dict:
    """Return sim_node's parameters: scene, pacing, the others; scene_overrides given as YAML."""
    params = {'scene': scene, 'pacing': pacing}
    params.update(parameters)
    if isinstance(params.get('scene_overrides'), dict):
        import yaml

        params['scene_overrides'] = yaml.safe_dump(
            params['scene_overrides'], default_flow_style=True
        ).strip()
    return params


class SimHarness:
    """
    sim_node (+ controller_node) processes and an in-process client node; use as a context manager.

    scene, pacing: sim_node parameters (pacing: real_time | as_fast_as_possible | lockstep).
    parameters: further sim_node parameters ({'real_time_factor': 2.0, 'watchdog_timeout_s': 0.5,
        ...}); a dict value for 'scene_overrides' is passed as YAML.
    controller: also start controller_node (controller_parameters are its parameters; scene is
        shared).
    domain_id: ROS domain (default 215 + pid % 18); discovery is localhost only.
    wait_started: on entering, wait until the services answer and a first state arrived.

    The parts: the node processes (launching.NodeProcess), the client node (ClientNode: spin,
    spin_until, call), the state subscriptions (StateListener: states, applied, diagnostics) and
    the command publishers and service clients (SimControls).
    """

    def __init__(
        self,
        scene: str = DEFAULT_SCENE,
        controller: bool = False,
        pacing: str = 'real_time',
        parameters: dict | None = None,
        controller_parameters: dict | None = None,
        domain_id: int | None = None,
        log_dir: str | os.PathLike | None = None,
        startup_timeout_s: float = STARTUP_TIMEOUT_S,
        stop_timeout_s: float = STOP_TIMEOUT_S,
        wait_started: bool = True,
        history: int = 100_000,
    ):
        self.scene = scene
        self.pacing = pacing
        self.parameters = dict(parameters or {})
        self.controller = controller
        self.controller_parameters = dict(controller_parameters or {})
        self.domain_id = default_domain_id() if domain_id is None else int(domain_id)
        self._tmp = None
        if log_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix='pulsejet-harness-')
            log_dir = self._tmp.name
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.startup_timeout_s = startup_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.wait_started = wait_started
        self.history = history
        self.processes: dict[str, NodeProcess] = {}
        self.exit_codes: dict[str, int] = {}
        self.client: ClientNode | None = None
        self.listener: StateListener | None = None
        self.controls: SimControls | None = None
        self._closed = False

    # -- life cycle -----------------------------------------------------------------------------

    def __enter__(self) -> 'SimHarness':
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def environment(self) -> dict:
        return isolated_environment(self.domain_id)

    def start(self) -> None:
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.start_processes()
        discover_localhost_only(override=False)  # this process's participant, as the children
        self.client = ClientNode(f'sim_harness_{os.getpid()}', self.domain_id)
        self.qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.listener = StateListener(self.node, self.qos, self.history)
        self.controls = SimControls(self.node, self.qos)
        if self.wait_started:
            self.wait_until_started()

    def start_processes(self) -> None:
        """Start controller_node (if asked) and sim_node, each logging to log_dir."""
        env = self.environment()
        if self.controller:
            params = {'scene': self.scene}
            params.update(self.controller_parameters)
            self.processes['controller_node'] = NodeProcess(
                'pulsejet_ctrl.controller_node', params, self.log_dir / 'controller_node.log', env
            )
        self.processes['sim_node'] = NodeProcess(
            'pulsejet_sim.ros.sim_node',
            sim_node_parameters(self.scene, self.pacing, self.parameters),
            self.log_dir / 'sim_node.log',
            env,
        )

    def wait_until_started(self, timeout_s: float | None = None) -> SimState:
        """
        Wait until services are available, command topics matched and a first state received.

        The controller, when started, must also be matched on /clock and the command topics.
        """
        from pulsejet_sim.core import topics

        def ready():
            if not self.controls.connected():
                return False
            if self.controller and (
                self.node.count_subscribers(topics.TOPIC_CLOCK) < 2
                or self.node.count_publishers(topics.TOPIC_CMD_VALVE) < 2
            ):
                return False
            return bool(self.states)

        timeout_s = self.startup_timeout_s if timeout_s is None else timeout_s
        self.spin_until(ready, timeout_s=timeout_s, what='sim_node to start')
        return self.states[-1]

    def close(self) -> dict[str, int]:
        """Stop the processes (SIGINT, then kill) and shut the context down; idempotent."""
        if self._closed:
            return self.exit_codes
        self._closed = True
        for name in ('controller_node', 'sim_node'):
            if name in self.processes:
                self.exit_codes[name] = self.processes[name].stop(self.stop_timeout_s)
        if self.client is not None:
            self.client.close()
        if self._tmp is not None and not os.environ.get('PULSEJET_HARNESS_KEEP_LOGS'):
            self._keep = {name: p.output() for name, p in self.processes.items()}
            self._tmp.cleanup()
        return self.exit_codes

    def output(self, name: str = 'sim_node') -> str:
        p = self.processes.get(name)
        if p is None:
            return ''
        text = p.output()
        return text or getattr(self, '_keep', {}).get(name, '')

    # -- the client node ------------------------------------------------------------------------

    @property
    def context(self):
        return None if self.client is None else self.client.context

    @property
    def node(self):
        return None if self.client is None else self.client.node

    @property
    def executor(self):
        return None if self.client is None else self.client.executor

    def _check_alive(self):
        for name, p in self.processes.items():
            if not p.alive():
                raise HarnessError(
                    f'{name} exited with code {p.proc.returncode}:\n{p.output()[-3000:]}'
                )

    def spin(self, seconds: float) -> None:
        self.client.spin(seconds)

    def spin_until(
        self,
        predicate: Callable[[], bool],
        timeout_s: float = 10.0,
        what: str = 'condition',
        check_alive: bool = True,
    ) -> None:
        def timed_out():
            return TimeoutError(
                f'timed out after {timeout_s:g} s waiting for {what}; last state: {self.latest}\n'
                f'sim_node log tail:\n{self.output()[-2000:]}'
            )

        self.client.spin_until(
            predicate, timeout_s, timed_out, self._check_alive if check_alive else None
        )

    def wait_for_exit(self, name: str = 'sim_node', timeout_s: float = 60.0) -> int:
        """Spin until the process exits (e.g. duration_s reached); returns its exit code."""
        p = self.processes[name]
        self.spin_until(lambda: not p.alive(), timeout_s, f'{name} to exit', check_alive=False)
        return p.proc.returncode

    # -- the published state --------------------------------------------------------------------

    @property
    def states(self):
        return self.listener.states

    @property
    def applied(self):
        return self.listener.applied

    @property
    def diagnostics_received(self):
        return self.listener.diagnostics

    @property
    def latest(self) -> SimState | None:
        return None if self.listener is None else self.listener.latest

    @property
    def time_s(self) -> float:
        return self.latest.time_s if self.latest is not None else float('nan')

    def wait_for(
        self,
        predicate: Callable[[SimState], bool],
        timeout_s: float = 10.0,
        what: str | None = None,
        since_wall: float | None = None,
    ) -> SimState:
        """
        Return the first state satisfying predicate(state).

        Starts from the latest one already received (or, with since_wall, from the first received
        at or after that time.monotonic()); TimeoutError naming the last state otherwise.
        """
        listener = self.listener
        first = listener.received - (1 if since_wall is None else len(listener.states))
        position = [max(first, 0)]
        found: list[SimState] = []

        def check():
            state, position[0] = listener.first_match(predicate, position[0], since_wall)
            if state is not None:
                found.append(state)
            return state is not None

        name = getattr(predicate, '__name__', '<lambda>')
        self.spin_until(
            check,
            timeout_s,
            what or ('a state satisfying the predicate' if name == '<lambda>' else name),
        )
        return found[0]

    def wait_for_diagnostics(
        self,
        predicate: Callable[[Diagnostic], bool] = lambda d: True,
        timeout_s: float = 10.0,
        what: str = 'a diagnostic',
    ) -> Diagnostic:
        """Return the first /diagnostics status received from now on with predicate(d) true."""
        n0 = len(self.diagnostics_received)
        found = []

        def check():
            for d in list(self.diagnostics_received)[n0:]:
                if predicate(d):
                    found.append(d)
                    return True
            return False

        self.spin_until(check, timeout_s, what)
        return found[0]

    # -- commands, services, parameters ---------------------------------------------------------

    def send(
        self,
        pump_flow_m3_s: float | None = None,
        valve_opening: float | None = None,
        cable_force_n: float | None = None,
    ) -> float:
        """Publish the given commands (each on its topic); returns the wall time of publication."""
        return self.controls.publish(pump_flow_m3_s, valve_opening, cable_force_n)

    def call(self, name: str, request, timeout_s: float = SERVICE_TIMEOUT_S):
        """Call one of the harness's service clients and return the response."""
        return self.client.call(self.controls.clients[name], request, timeout_s, self.spin_until)

    def pause(self):
        return self.call('pause', SimControls.pause_request(True))

    def resume(self):
        return self.call('pause', SimControls.pause_request(False))

    def step(self, n: int | None = None, check: bool = True):
        """
        Advance n physics steps (default: the node's step_count) while paused or in lockstep.

        Returns the new state (with check=False: the service response, even when refused).
        """
        if n is not None:
            self.set_parameters(check=True, step_count=int(n))
        response = self.call('step', SimControls.trigger_request())
        if not check:
            return response
        if not response.success:
            raise HarnessError(f'step refused: {response.message}')
        return self._wait_published(response.message)

    def reset(self):
        """Back to the scene's initial state at t=0; returns the t=0 state."""
        t_call = time.monotonic()
        response = self.call('reset', SimControls.trigger_request())
        if not response.success:
            raise HarnessError(f'reset refused: {response.message}')
        return self.wait_for(
            lambda s: s.time_s == 0.0, 10.0, 'the state at t=0 after reset', since_wall=t_call
        )

    def _wait_published(self, message: str) -> SimState:
        # the response names the new time ('... to t=0.100000 s'); wait for its state, then drain
        try:
            t = float(message.split('to t=')[1].split()[0])
        except (IndexError, ValueError):
            return self.latest
        self.spin_until(
            lambda: self.states and abs(self.states[-1].time_s - t) < 5e-7,
            10.0,
            f'the state at t={t}',
        )
        self.spin(0.02)
        return self.latest

    def set_parameters(self, check: bool = False, **values) -> list:
        """
        Set sim_node parameters through its SetParameters service.

        Returns the rcl_interfaces/SetParametersResult list (check=True raises HarnessError on a
        rejection).
        """
        return self.set_parameters_of(SIM_NODE_NAME, check, **values)

    def set_parameters_of(self, node_name: str, check: bool = False, **values) -> list:
        """
        Set parameters of any node through its real parameter service.

        Like set_parameters, for any node (e.g. '/controller_node').
        """
        key = self.controls.parameter_client(node_name, 'set_parameters')
        results = list(self.call(key, SimControls.set_parameters_request(values)).results)
        if check:
            bad = [f'{name}: {r.reason}' for name, r in zip(values, results) if not r.successful]
            if bad:
                raise HarnessError(f'parameters of {node_name} rejected: ' + '; '.join(bad))
        return results

    def get_parameters(self, *names: str, node_name: str = SIM_NODE_NAME) -> dict:
        from rclpy.parameter import parameter_value_to_python

        key = self.controls.parameter_client(node_name, 'get_parameters')
        response = self.call(key, SimControls.get_parameters_request(names))
        return {n: parameter_value_to_python(v) for n, v in zip(names, response.values)}
