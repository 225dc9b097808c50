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
unless given) with localhost-only discovery, and talks to them from its own rclpy context and node
(never the global one): state subscriptions (`latest`, `states`, `wait_for`), command publishers
(`send`), the pulsejet/pause|step|reset services, the real parameter services of /sim_node
(`set_parameters`, `get_parameters`) and /diagnostics (`diagnostics`, `wait_for_diagnostics`).
Leaving the `with` block (also on an exception) stops the processes (SIGINT, then SIGKILL after
`stop_timeout_s`) and shuts the context down; `exit_codes` then holds their return codes.
The processes' output goes to `log_dir` (a temporary directory by default); `output()` reads it.

Notes: states are assembled on /clock (the node publishes it last in each batch) from the latest
values of the other state topics. While paused or in lockstep the node re-publishes its current
state every 0.5 s, so `states` may repeat a time. Two harnesses alive at once in one process need
distinct `domain_id`s (the default is per process). `reset()` makes the time go back to 0.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
from pathlib import Path
import tempfile
import time
from typing import Any, Callable

from pulsejet_sim.core import topics as names
from pulsejet_sim.ros.launching import (
    default_domain_id,
    discover_localhost_only,
    isolated_environment,
    NodeProcess,
    STOP_TIMEOUT_S,
)
from pulsejet_sim.scene import DEFAULT_SCENE

STARTUP_TIMEOUT_S = 90.0  # scene loading + JIT compilation of a cold cache
SERVICE_TIMEOUT_S = 30.0
SIM_NODE_NAME = '/sim_node'


class HarnessError(RuntimeError):
    """
    A node died, did not start, or a service could not be reached.

    The message has the log tail.
    """


@dataclasses.dataclass(frozen=True)
class SimState:
    """One published state of the simulator (SI units), built when its /clock sample arrives."""

    time_s: float
    velocity_m_s: float
    volume_m3: float
    mantle_radius_m: float
    thrust_n: float
    fluid_mass_kg: float
    wall_s: float  # time.monotonic() when it was received


@dataclasses.dataclass(frozen=True)
class Diagnostic:
    level: int  # diagnostic_msgs/DiagnosticStatus OK=0, WARN=1, ERROR=2
    message: str
    values: dict
    time_s: float
    wall_s: float


def _stamp_s(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


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
        self.processes: dict[str, NodeProcess] = {}
        self.exit_codes: dict[str, int] = {}
        self.states: collections.deque[SimState] = collections.deque(maxlen=history)
        self.diagnostics_received: collections.deque[Diagnostic] = collections.deque(maxlen=1000)
        self.applied: collections.deque[tuple[float, Any, float]] = collections.deque(
            maxlen=history
        )
        self.context = self.node = self.executor = None
        self._values: dict[str, float] = {}
        self._received = 0  # states received in total
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
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TwistStamped, WrenchStamped
        from pulsejet_sim.ros.executor import make_executor
        from rcl_interfaces.srv import GetParameters, SetParameters
        import rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64
        from std_srvs.srv import SetBool, Trigger

        env = self.environment()
        discover_localhost_only(override=False)  # this process's participant, as the children
        sim_params = {'scene': self.scene, 'pacing': self.pacing}
        sim_params.update(self.parameters)
        if isinstance(sim_params.get('scene_overrides'), dict):
            import yaml

            sim_params['scene_overrides'] = yaml.safe_dump(
                sim_params['scene_overrides'], default_flow_style=True
            ).strip()
        if self.controller:
            params = {'scene': self.scene}
            params.update(self.controller_parameters)
            self.processes['controller_node'] = NodeProcess(
                'pulsejet_ctrl.controller_node', params, self.log_dir / 'controller_node.log', env
            )
        self.processes['sim_node'] = NodeProcess(
            'pulsejet_sim.ros.sim_node', sim_params, self.log_dir / 'sim_node.log', env
        )

        self.context = rclpy.Context()
        rclpy.init(
            context=self.context,
            domain_id=self.domain_id,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
        self.node = rclpy.create_node(f'sim_harness_{os.getpid()}', context=self.context)
        self.executor = make_executor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.qos = qos
        for topic in (names.TOPIC_VOLUME, names.TOPIC_MANTLE_RADIUS, names.TOPIC_FLUID_MASS):
            self.node.create_subscription(Float64, topic, self._store_value(topic), qos)
        self.node.create_subscription(
            TwistStamped,
            names.TOPIC_VELOCITY,
            lambda m: self._values.__setitem__('velocity', m.twist.linear.x),
            qos,
        )
        self.node.create_subscription(
            WrenchStamped,
            names.TOPIC_THRUST,
            lambda m: self._values.__setitem__('thrust', m.wrench.force.x),
            qos,
        )
        self.node.create_subscription(Clock, names.TOPIC_CLOCK, self._on_clock, qos)
        self.node.create_subscription(
            JointState, names.TOPIC_APPLIED_COMMAND, self._on_applied, qos
        )
        self.node.create_subscription(
            DiagnosticArray, names.TOPIC_DIAGNOSTICS, self._on_diagnostics, qos
        )
        self._cmd_pubs = {
            field: self.node.create_publisher(Float64, topic, qos)
            for topic, field in names.COMMAND_FIELDS.items()
        }
        self._clients = {
            'pause': self.node.create_client(SetBool, names.SERVICE_PAUSE),
            'step': self.node.create_client(Trigger, names.SERVICE_STEP),
            'reset': self.node.create_client(Trigger, names.SERVICE_RESET),
            f'{SIM_NODE_NAME}/set_parameters': self.node.create_client(
                SetParameters, f'{SIM_NODE_NAME}/set_parameters'
            ),
            f'{SIM_NODE_NAME}/get_parameters': self.node.create_client(
                GetParameters, f'{SIM_NODE_NAME}/get_parameters'
            ),
        }
        if self.wait_started:
            self.wait_until_started()

    def wait_until_started(self, timeout_s: float | None = None) -> SimState:
        """
        Wait until services are available, command topics matched and a first state received.

        The controller, when started, must also be matched on /clock and the command topics.
        """
        timeout_s = self.startup_timeout_s if timeout_s is None else timeout_s
        end = time.monotonic() + timeout_s
        clients = list(self._clients.values())

        def ready():
            if not all(c.service_is_ready() for c in clients):
                return False
            if not all(p.get_subscription_count() > 0 for p in self._cmd_pubs.values()):
                return False
            if self.controller and (
                self.node.count_subscribers(names.TOPIC_CLOCK) < 2
                or self.node.count_publishers(names.TOPIC_CMD_VALVE) < 2
            ):
                return False
            return bool(self.states)

        self.spin_until(
            ready, timeout_s=max(0.0, end - time.monotonic()), what='sim_node to start'
        )
        return self.states[-1]

    def close(self) -> dict[str, int]:
        """Stop the processes (SIGINT, then kill) and shut the context down; idempotent."""
        if self._closed:
            return self.exit_codes
        self._closed = True
        for name in ('controller_node', 'sim_node'):
            if name in self.processes:
                self.exit_codes[name] = self.processes[name].stop(self.stop_timeout_s)
        if self.context is not None:
            import rclpy

            try:
                if self.executor is not None:
                    self.executor.shutdown(timeout_sec=1.0)
                if self.node is not None:
                    self.node.destroy_node()
            finally:
                rclpy.try_shutdown(context=self.context)
        if self._tmp is not None and not os.environ.get('PULSEJET_HARNESS_KEEP_LOGS'):
            self._keep = {name: p.output() for name, p in self.processes.items()}
            self._tmp.cleanup()
        return self.exit_codes

    # -- callbacks ------------------------------------------------------------------------------

    def _store_value(self, topic):
        key = topic.rsplit('/', 1)[1]

        def cb(msg):
            self._values[key] = msg.data

        return cb

    def _on_clock(self, msg):
        v = self._values
        self._received += 1
        self.states.append(
            SimState(
                time_s=_stamp_s(msg.clock),
                velocity_m_s=v.get('velocity', math.nan),
                volume_m3=v.get('volume', math.nan),
                mantle_radius_m=v.get('mantle_radius', math.nan),
                thrust_n=v.get('thrust', math.nan),
                fluid_mass_kg=v.get('fluid_mass', math.nan),
                wall_s=time.monotonic(),
            )
        )

    def _on_applied(self, msg):
        from pulsejet_sim.ros.messages import command_from_applied

        t, cmd = command_from_applied(msg)
        self.applied.append((t, cmd, time.monotonic()))

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.startswith('pulsejet: ') and status.name.endswith('sim_node'):
                self.diagnostics_received.append(
                    Diagnostic(
                        level=(
                            int.from_bytes(status.level, 'little')
                            if isinstance(status.level, bytes)
                            else int(status.level)
                        ),
                        message=status.message,
                        values={kv.key: kv.value for kv in status.values},
                        time_s=_stamp_s(msg.header.stamp),
                        wall_s=time.monotonic(),
                    )
                )

    # -- spinning and waiting -------------------------------------------------------------------

    def _check_alive(self):
        for name, p in self.processes.items():
            if not p.alive():
                raise HarnessError(
                    f'{name} exited with code {p.proc.returncode}:\n{p.output()[-3000:]}'
                )

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            self.executor.spin_once(timeout_sec=min(0.02, left))

    def spin_until(
        self,
        predicate: Callable[[], bool],
        timeout_s: float = 10.0,
        what: str = 'condition',
        check_alive: bool = True,
    ) -> None:
        end = time.monotonic() + timeout_s
        while not predicate():
            if check_alive:
                self._check_alive()
            if time.monotonic() > end:
                last = self.states[-1] if self.states else None
                raise TimeoutError(
                    f'timed out after {timeout_s:g} s waiting for {what}; last state: {last}\n'
                    f'sim_node log tail:\n{self.output()[-2000:]}'
                )
            self.executor.spin_once(timeout_sec=0.02)

    def wait_for_exit(self, name: str = 'sim_node', timeout_s: float = 60.0) -> int:
        """Spin until the process exits (e.g. duration_s reached); returns its exit code."""
        p = self.processes[name]
        self.spin_until(lambda: not p.alive(), timeout_s, f'{name} to exit', check_alive=False)
        return p.proc.returncode

    @property
    def latest(self) -> SimState | None:
        return self.states[-1] if self.states else None

    @property
    def time_s(self) -> float:
        return self.states[-1].time_s if self.states else math.nan

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
        first = self._received - 1 if since_wall is None else self._received - len(self.states)
        pos = [max(first, 0)]
        found: list[SimState] = []

        def check():
            states, total = self.states, self._received
            offset = total - len(states)  # index of states[0] in the whole stream
            for i in range(max(pos[0], offset), total):
                s = states[i - offset]
                if (since_wall is None or s.wall_s >= since_wall) and predicate(s):
                    found.append(s)
                    return True
            pos[0] = total
            return False

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
        from std_msgs.msg import Float64

        for field, value in (
            ('valve_opening', valve_opening),
            ('pump_flow_m3_s', pump_flow_m3_s),
            ('cable_force_n', cable_force_n),
        ):
            if value is not None:
                self._cmd_pubs[field].publish(Float64(data=float(value)))
        return time.monotonic()

    def call(self, name: str, request, timeout_s: float = SERVICE_TIMEOUT_S):
        """Call one of the harness's service clients and return the response."""
        client = self._clients[name]
        self.spin_until(client.service_is_ready, timeout_s, f'service {client.srv_name}')
        future = client.call_async(request)
        self.spin_until(future.done, timeout_s, f'the response of {client.srv_name}')
        return future.result()

    def pause(self):
        from std_srvs.srv import SetBool

        return self.call('pause', SetBool.Request(data=True))

    def resume(self):
        from std_srvs.srv import SetBool

        return self.call('pause', SetBool.Request(data=False))

    def step(self, n: int | None = None, check: bool = True):
        """
        Advance n physics steps (default: the node's step_count) while paused or in lockstep.

        Returns the new state (with check=False: the service response, even when refused).
        """
        from std_srvs.srv import Trigger

        if n is not None:
            self.set_parameters(check=True, step_count=int(n))
        response = self.call('step', Trigger.Request())
        if not check:
            return response
        if not response.success:
            raise HarnessError(f'step refused: {response.message}')
        return self._wait_published(response.message)

    def reset(self):
        """Back to the scene's initial state at t=0; returns the t=0 state."""
        from std_srvs.srv import Trigger

        t_call = time.monotonic()
        response = self.call('reset', Trigger.Request())
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
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        )
        results = list(
            self.call(self._parameter_client(node_name, 'set_parameters'), request).results
        )
        if check:
            bad = [f'{name}: {r.reason}' for name, r in zip(values, results) if not r.successful]
            if bad:
                raise HarnessError(f'parameters of {node_name} rejected: ' + '; '.join(bad))
        return results

    def get_parameters(self, *names: str, node_name: str = SIM_NODE_NAME) -> dict:
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        response = self.call(
            self._parameter_client(node_name, 'get_parameters'),
            GetParameters.Request(names=list(names)),
        )
        return {n: parameter_value_to_python(v) for n, v in zip(names, response.values)}

    def _parameter_client(self, node_name: str, service: str) -> str:
        from rcl_interfaces.srv import GetParameters, SetParameters

        key = f'{node_name}/{service}'
        if key not in self._clients:
            kind = SetParameters if service == 'set_parameters' else GetParameters
            self._clients[key] = self.node.create_client(kind, key)
        return key

    def output(self, name: str = 'sim_node') -> str:
        p = self.processes.get(name)
        if p is None:
            return ''
        text = p.output()
        return text or getattr(self, '_keep', {}).get(name, '')
