"""
Node parameters over real processes (own DDS domain, localhost discovery; no mocks).

What they cover: sim_node's structured scene overrides (`-p scene.<section>.<key>:=value` and a
nested `scene:` block in a params file), the descriptors of replay and recorder through the real
DescribeParameters service, and controller_node following a best-effort /clock through rclpy's
time source (`use_sim_time`, true by default for it, `-p use_sim_time:=false` still honoured).
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess
import sys
import time

from conftest import isolate_ros
from pulsejet_sim.ros.node_params import node_command, ParamSpec, scene_overrides
import pytest

rclpy = pytest.importorskip('rclpy')
from builtin_interfaces.msg import Time  # noqa: E402, I100
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DOMAIN_OFFSET = 83
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


@pytest.fixture
def domain(monkeypatch):
    return isolate_ros(monkeypatch, DOMAIN_OFFSET)


def run_sim_node(*ros_args: str) -> subprocess.CompletedProcess:
    """sim_node to completion (a short duration_s, or a refused scene), output captured."""
    return subprocess.run(
        [sys.executable, '-m', 'pulsejet_sim.ros.sim_node', '--ros-args', *ros_args],
        capture_output=True,
        text=True,
        timeout=150,
        cwd=ROOT,
    )


def start_controller(params: dict, tmp_path: Path):
    """Start controller_node with `params`; return (process, its log file, output())."""
    log = open(tmp_path / 'controller.log', 'w+')
    proc = subprocess.Popen(
        node_command('pulsejet_ctrl.controller_node', params),
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
    )

    def output() -> str:
        log.flush()
        return (tmp_path / 'controller.log').read_text()

    return proc, log, output


def stop(proc: subprocess.Popen, timeout: float = 15.0) -> tuple[int, str]:
    """SIGTERM (a background shell may start children with SIGINT ignored), then the output."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return proc.returncode, out


class Client:
    """
    An in-process node in the test's domain.

    For parameter service calls, publishers and subscriptions.
    """

    def __init__(self, domain: int):
        self.context = rclpy.Context()
        rclpy.init(
            context=self.context,
            domain_id=domain,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
        self.node = rclpy.create_node('param_test_client', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout: float, what: str):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return
            self.executor.spin_once(timeout_sec=0.02)
        raise AssertionError(f'timed out after {timeout:g} s waiting for {what}')

    def call(self, srv_type, name: str, request, timeout: float = 60.0):
        client = self.node.create_client(srv_type, name)
        try:
            self.spin_until(client.service_is_ready, timeout, f'service {name}')
            future = client.call_async(request)
            self.spin_until(future.done, 10.0, f'the answer of {name}')
            return future.result()
        finally:
            self.node.destroy_client(client)

    def describe(self, node: str, names: list[str]) -> dict:
        response = self.call(
            DescribeParameters,
            f'{node}/describe_parameters',
            DescribeParameters.Request(names=names),
        )
        return {d.name: d for d in response.descriptors}

    def get(self, node: str, names: list[str]) -> list:
        return list(
            self.call(
                GetParameters, f'{node}/get_parameters', GetParameters.Request(names=names)
            ).values
        )

    def set_value(self, node: str, name: str, value: ParameterValue):
        return self.call(
            SetParameters,
            f'{node}/set_parameters',
            SetParameters.Request(parameters=[Parameter(name=name, value=value)]),
        ).results[0]

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def client(domain):
    c = Client(domain)
    yield c
    c.close()


# ---- structured scene overrides -----------------------------------------------------------------
def test_scene_override_parameters_nest_into_scene_sections():
    flat = {
        'scene.geometry.nozzle_radius_m': 0.01,
        'scene.options.coupling': 'paper',
        'scene.geometry.length_m': 1,
    }
    assert scene_overrides(flat) == {
        'geometry': {'nozzle_radius_m': 0.01, 'length_m': 1},
        'options': {'coupling': 'paper'},
    }
    with pytest.raises(
        ValueError, match=r'scene\.geometry\.length_m=0\.3 conflicts with scene\.geometry'
    ):
        scene_overrides({'scene.geometry': 3, 'scene.geometry.length_m': 0.3})
    with pytest.raises(
        ValueError, match=r"'scene\.\.x' rejected; allowed: scene\.<section>\.<key>"
    ):
        scene_overrides({'scene..x': 1})


@pytest.mark.timeout(180)
def test_sim_node_applies_scene_overrides_from_the_command_line(domain):
    """
    Scene overrides from the command line win over scene_overrides and reach the model.

    `-p scene.simulation.dt_s:=...` wins over the same key in the string scene_overrides, which
    still works; both reach the model (sim_node reports the step and rate of the scene it built).
    """
    proc = run_sim_node(
        '-p',
        'scene:=pump_cycle',
        '-p',
        'duration_s:=0.05',
        '-p',
        "scene_overrides:='{simulation: {dt_s: 2.0e-4, publish_rate_hz: 50}}'",
        '-p',
        'scene.simulation.dt_s:=5.0e-5',
        '-p',
        'scene.options.coupling:=paper',
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert (
        "scene overrides: scene.options.coupling='paper', scene.simulation.dt_s=5e-05" in out
    ), out[-3000:]
    # dt from the structured parameter, the rate from the string: 0.02 s / 5e-5 s = 400 steps
    assert 'dt 5e-05 s), publishing every 400 steps (50 Hz)' in out, out[-3000:]


@pytest.mark.timeout(180)
def test_sim_node_applies_a_nested_scene_block_of_a_params_file(domain, tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text(
        'sim_node:\n'
        '  ros__parameters:\n'
        '    duration_s: 0.05\n'
        '    scene:                  # rcl flattens this to scene.simulation.publish_rate_hz\n'
        '      simulation:\n'
        '        publish_rate_hz: 20\n'
    )
    # the scene's name cannot sit in the same nested block: it comes from the command line here
    proc = run_sim_node('--params-file', str(params), '-p', 'scene:=pump_cycle')
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert 'scene overrides: scene.simulation.publish_rate_hz=20' in out, out[-3000:]
    assert 'dt 0.0001 s), publishing every 500 steps (20 Hz)' in out, out[-3000:]


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    'override, named',
    [
        (
            'scene.bogus.x:=1',
            "scene 'pump_cycle': bogus: unknown section for the lumped model; allowed: model,",
        ),
        ('scene.geometry.bogus_m:=0.1', 'geometry.bogus_m: unknown key'),
        (
            'scene.geometry.nozzle_radius_m:=abc',
            "geometry.nozzle_radius_m: 'abc' is not a number; allowed:",
        ),
    ],
    ids=['unknown-section', 'unknown-key', 'bad-value'],
)
def test_sim_node_refuses_a_bad_scene_override(domain, override, named):
    proc = run_sim_node('-p', 'scene:=pump_cycle', '-p', override)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert 'sim_node: error: SceneError:' in proc.stderr and named in proc.stderr, proc.stderr[
        -2000:
    ]


# ---- doubles stay doubles -----------------------------------------------------------------------
@pytest.mark.timeout(150)
def test_a_double_parameter_stays_a_double(domain, client, tmp_path):
    """
    real_time_factor is a double: given as 2 at start-up it is declared 2.0, and said so.

    A live set with an integer is refused with rclpy's reason (the value kept), a double is taken.
    """
    proc = subprocess.Popen(
        node_command('pulsejet_sim.ros.sim_node', {'scene': 'pump_cycle'})
        + ['-p', 'real_time_factor:=2'],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    try:
        d = client.describe('/sim_node', ['real_time_factor'])['real_time_factor']
        assert d.type == ParameterType.PARAMETER_DOUBLE and not d.dynamic_typing, d
        (value,) = client.get('/sim_node', ['real_time_factor'])
        assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 2.0)
        result = client.set_value(
            '/sim_node',
            'real_time_factor',
            ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=3),
        )
        assert not result.successful and 'Wrong parameter type' in result.reason, result
        (value,) = client.get('/sim_node', ['real_time_factor'])
        assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 2.0)
        result = client.set_value(
            '/sim_node',
            'real_time_factor',
            ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=3.0),
        )
        assert result.successful, result
        (value,) = client.get('/sim_node', ['real_time_factor'])
        assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 3.0)
    finally:
        code, out = stop(proc)
    assert code == 0, out[-2000:]
    assert 'parameter real_time_factor:=2 given as an integer; declared as the double 2.0' in out
    assert 'real_time_factor set to 3.0' in out, out[-2000:]


@pytest.mark.timeout(120)
def test_a_double_given_as_a_word_is_refused_naming_the_range(domain):
    proc = run_sim_node('-p', 'scene:=pump_cycle', '-p', 'real_time_factor:=fast')
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (
        "parameter real_time_factor='fast' rejected; allowed: a number in [0.001, 1000]"
        in proc.stderr
    ), proc.stderr[-2000:]


# ---- descriptors of replay and recorder ---------------------------------------------------------
@pytest.mark.timeout(150)
def test_replay_and_recorder_describe_their_parameters(domain, client, tmp_path):
    from pulsejet_sim.ros import recorder, replay
    from pulsejet_sim.scene import load_scene
    from pulsejet_sim.studies.runner import run_scene

    bag = tmp_path / 'escape.mcap'
    run_scene(load_scene('escape'), 0.1, bag)
    # the replay waits for a /clock subscriber that never comes: it stays up, serving its
    # parameters
    player = subprocess.Popen(
        node_command('pulsejet_sim.ros.replay', {'bag': str(bag), 'rate': 2})
        + ['-p', "wait_for_topics:=['/clock']"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    rec = subprocess.Popen(
        node_command('pulsejet_sim.ros.recorder', {'output': str(tmp_path / 'rec.mcap')})
        + ['-p', "topics:=['pulsejet/velocity']"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    try:
        d = client.describe('/replay', list(replay.PARAMETERS))
        assert set(d) == set(replay.PARAMETERS)
        for name, desc in d.items():
            assert desc.description and 'allowed:' in desc.description, (name, desc)
            assert desc.read_only and desc.dynamic_typing, (name, desc)
        assert (
            'speed factor' in d['rate'].description
            and d['rate'].floating_point_range[0].from_value == 0.0
        )
        assert d['clock_rate_hz'].floating_point_range[0].to_value == 10000.0
        assert d['delay_s'].floating_point_range[0].from_value == 0.0
        # the values as set (an int rate kept as given: dynamic typing), the rest their defaults
        rate, loop = client.get('/replay', ['rate', 'loop'])
        assert (rate.type, rate.integer_value) == (ParameterType.PARAMETER_INTEGER, 2)
        assert (loop.type, loop.bool_value) == (ParameterType.PARAMETER_BOOL, False)

        d = client.describe('/recorder', ['output', 'topics'])
        assert d['output'].type == ParameterType.PARAMETER_STRING and d['output'].read_only
        assert 'MCAP file' in d['output'].description
        assert d['topics'].type == ParameterType.PARAMETER_STRING_ARRAY and d['topics'].read_only
        assert 'name:pkg/msg/Type' in d['topics'].description
        assert [spec.name for spec in recorder.PARAMETERS] == ['output', 'topics']
    finally:
        code_replay, out_replay = stop(player)
        code_rec, out_rec = stop(rec)
    assert code_replay == 0 and 'replay: stopped' in out_replay, out_replay[-2000:]
    assert '(stopped before playing)' in out_replay, out_replay[-2000:]  # not '(0 passes)'
    assert code_rec == 0 and 'recorder: wrote' in out_rec, out_rec[-2000:]


def test_string_array_spec_describes_and_checks():
    spec = ParamSpec('topics', ('a', 'b'), 'topics', read_only=True)
    assert spec.descriptor().type == ParameterType.PARAMETER_STRING_ARRAY
    assert spec.check(['x']) == ['x']
    with pytest.raises(ValueError, match=r'topics=\[3\] rejected; allowed: a list of strings'):
        spec.check([3])


# ---- controller_node on rclpy's time source -----------------------------------------------------
@pytest.mark.timeout(150)
def test_controller_node_follows_a_best_effort_clock_through_use_sim_time(
    domain, client, tmp_path
):
    """
    A best-effort /clock drives the routine through use_sim_time (on by default).

    A best-effort /clock (like a bag player's) drives the routine through use_sim_time, which is
    on by default; time going back restarts the routine and is answered at once.
    """
    params = {
        'scene': 'pump_cycle',
        'pump_flow_m3_s': 1.0e-3,
        'inflate_s': 0.5,
        'hold_s': 0.1,
        'jet_s': 0.4,
        'cycles': 1,
        'target_volume_m3': 0.0,
        'rate_hz': 50.0,
    }
    ctrl, log, output = start_controller(params, tmp_path)
    got = {'pump_flow': [], 'valve': []}
    subs = [
        client.node.create_subscription(
            Float64,
            f'pulsejet/cmd/{name}',
            lambda m, name=name: got[name].append(m.data),
            RELIABLE,
        )
        for name in got
    ]
    clock_pub = client.node.create_publisher(Clock, '/clock', BEST_EFFORT)

    try:
        client.spin_until(
            lambda: clock_pub.get_subscription_count() >= 1
            and all(s.get_publisher_count() > 0 for s in subs),
            60.0,
            'controller_node to match /clock and its command topics',
        )
        (use_sim_time,) = client.get('/controller_node', ['use_sim_time'])
        assert (use_sim_time.type, use_sim_time.bool_value) == (ParameterType.PARAMETER_BOOL, True)

        def at(t):
            """
            Publish /clock = t until a command answers it.

            It is published again and again: best effort may drop a sample.
            """
            ns = round(t * 1e9)
            for _ in range(20):
                n0 = len(got['valve'])
                clock_pub.publish(Clock(clock=Time(sec=ns // 10**9, nanosec=ns % 10**9)))
                try:
                    client.spin_until(
                        lambda: len(got['valve']) > n0 and len(got['pump_flow']) > n0,
                        0.5,
                        'a command',
                    )
                except AssertionError:
                    continue
                client.spin_until(
                    lambda: len(got['pump_flow']) == len(got['valve']), 2.0, 'both commands'
                )
                return got['pump_flow'][-1], got['valve'][-1]
            raise AssertionError(f'no command for /clock {t} s:\n{output()[-2000:]}')

        assert at(0.3) == (1.0e-3, 0.0)  # inflating
        assert at(0.55) == (0.0, 0.0)  # hold
        assert at(0.7) == (0.0, 1.0)  # jet
        assert at(1.2) == (0.0, 1.0)  # one cycle done: valve left open
        assert at(0.1) == (1.0e-3, 0.0)  # time went back: the routine restarts (inflating again)
        assert 'restarting the routine' in output()
    finally:
        code, _ = stop(ctrl)
        log.close()
    assert code == 0, output()[-2000:]


@pytest.mark.timeout(120)
def test_controller_node_pulls_a_cable_scene_with_the_pulse_it_is_given(domain, client, tmp_path):
    """A cable scene's routine as parameters, the pulse shape (a word) among them."""
    params = {
        'scene': 'shell_robot',
        'amplitude_n': 8.0,
        'frequency_hz': 1.0,
        'contraction_s': 0.4,
        'release_s': 0.4,
        'start_delay_s': 0.0,
        'pulse': 'triangle',
    }
    ctrl, log, output = start_controller(params, tmp_path)
    pulls = []
    sub = client.node.create_subscription(
        Float64, 'pulsejet/cmd/cable_force', lambda m: pulls.append(m.data), RELIABLE
    )
    clock_pub = client.node.create_publisher(Clock, '/clock', BEST_EFFORT)

    def at(t, standby_value=None):
        """
        Publish /clock = t until a cable command answers it (best effort may drop one).

        While its clock reads 0 the controller re-sends the t = 0 command (`standby_value`)
        every STANDBY_PERIOD_S of steady time; on a loaded machine one of those can arrive after
        the /clock was published, so it is not taken as the answer.
        """
        ns = round(t * 1e9)
        for _ in range(20):
            n0 = len(pulls)
            clock_pub.publish(Clock(clock=Time(sec=ns // 10**9, nanosec=ns % 10**9)))
            try:
                client.spin_until(
                    lambda: any(v != standby_value for v in pulls[n0:]), 0.5, 'a command'
                )
            except AssertionError:
                continue
            return next(v for v in pulls[n0:] if v != standby_value)
        raise AssertionError(f'no command for /clock {t} s:\n{output()[-2000:]}')

    try:
        client.spin_until(
            lambda: clock_pub.get_subscription_count() >= 1 and sub.get_publisher_count() > 0,
            60.0,
            'controller_node to match /clock and pulsejet/cmd/cable_force',
        )
        (pulse,) = client.get('/controller_node', ['pulse'])
        assert (pulse.type, pulse.string_value) == (ParameterType.PARAMETER_STRING, 'triangle')
        # a quarter of the way up a straight rise; the routine starts slack (0 N at t = 0)
        assert at(0.1, standby_value=0.0) == pytest.approx(2.0)
        assert at(0.6) == pytest.approx(4.0)  # half-way down
        assert at(0.9) == 0.0  # slack
    finally:
        code, _ = stop(ctrl)
        log.close()
    assert code == 0, output()[-2000:]


@pytest.mark.timeout(120)
def test_controller_node_on_wall_time_with_use_sim_time_false(domain, client):
    """
    `-p use_sim_time:=false` puts controller_node on wall time, without any /clock.

    `-p use_sim_time:=false` beats the node's own default: commands at rate_hz of wall time,
    without any /clock.
    """
    params = {'scene': 'pump_cycle', 'rate_hz': 20.0, 'use_sim_time': False}
    ctrl = subprocess.Popen(
        node_command('pulsejet_ctrl.controller_node', params),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    got = []
    sub = client.node.create_subscription(
        Float64, 'pulsejet/cmd/pump_flow', lambda m: got.append(time.monotonic()), RELIABLE
    )
    try:
        client.spin_until(
            lambda: sub.get_publisher_count() > 0, 60.0, "controller_node's command publisher"
        )
        (use_sim_time,) = client.get('/controller_node', ['use_sim_time'])
        assert (use_sim_time.type, use_sim_time.bool_value) == (
            ParameterType.PARAMETER_BOOL,
            False,
        )
        client.spin_until(lambda: len(got) >= 2, 10.0, 'two commands')
        first = len(got)
        t0 = time.monotonic()
        client.spin_until(lambda: time.monotonic() - t0 > 1.0, 5.0, 'one second')
        assert 10 <= len(got) - first <= 30, len(got) - first  # about 20 per wall second
    finally:
        code, out = stop(ctrl)
    assert code == 0, out[-2000:]
    assert 'Hz of wall time from now (use_sim_time false)' in out, out[-2000:]
