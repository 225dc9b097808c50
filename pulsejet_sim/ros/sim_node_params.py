"""
The parameters of sim_node: declarations with ranges, and what they build (scene, session).

sim_node parameters (PARAMETERS holds their ranges; `ros2 param describe /sim_node <name>`
shows them):
  scene                 (string, read-only)  scene name under config/ or a YAML path; default
                                             shell_robot
  scene_overrides       (string, read-only)  YAML mapping merged into the scene (kept for
                                             compatibility)
  scene.<section>.<key> (any, read-only)     one scene key each, merged over scene_overrides, e.g.
                                             `-p scene.geometry.nozzle_radius_m:=0.01`, or a nested
                                             `scene:` mapping in a params file (rcl flattens it)
  pacing                (string, live)       real_time | as_fast_as_possible | lockstep |
                                             closed_loop
  real_time_factor      (double, live)       simulated s per wall s under real_time pacing
  publish_rate_hz       (double, read-only)  publication rate; 0 = scene value or 100. Every state
                                             lies on the physics step's grid, one publication
                                             period apart
  control_period_s      (double, read-only)  closed_loop: simulated s per control period (0 = one
                                             publication period)
  lookahead_s           (double, read-only)  real_time: simulated s the physics runs ahead; each
                                             state is sent at its own wall time, so slow steps do
                                             not jitter publication (default 0)
  publish_delay_periods (double, read-only)  real_time: each state is sent this fraction of a
                                             period after its wall time, computed before, so
                                             computing does not jitter the send times (default
                                             0 = sent once computed; 0.2 for a viewer)
  duration_s            (double, read-only)  simulated time after which the node exits (0 =
                                             forever)
  wait_for_subscribers  (int, read-only)     hold the clock at 0 until `/clock` has this many
                                             subscribers
  wait_for_topics       (string[], read-only) hold the clock at 0 until each topic has a
                                             subscriber; ["*"]: every topic sim_node publishes
  wait_timeout_s        (double, read-only)  see wait_for_subscribers; default 10
  start_paused          (bool, read-only)    start paused (resume with pulsejet/pause false)
  step_count            (int, live)          physics steps per pulsejet/step call; default 100
  watchdog_timeout_s    (double, live)       command age before the watchdog trips; 0 = off
                                             (default)
  watchdog_clock        (string, live)       sim (simulated seconds, reproducible) | wall (wall
                                             seconds)
  watchdog_action       (string, live)       safe (pump off, valve open, cable released) | hold
  executor              (string, read-only)  single (default: services and parameters answered
                                             in turn under a command flood) | events (a faster
                                             closed loop: hardware in the loop at 1 kHz)
  diagnostics_period_s  (double, read-only)  /diagnostics period in wall seconds; default 1
  odom_frame_id         (string, read-only)  header frame of `odom` (nav_msgs/Odometry); default
                                             odom
  base_frame_id         (string, read-only)  the body frame: child of `odom`, frame of velocity,
                                             thrust, profile and Marker; default base_link
  frame_prefix          (string, read-only)  prefix of both frames (robot_state_publisher's
                                             frame_prefix; the namespace does not set it)
  publish_tf            (bool, read-only)    odom -> body on /tf with every state, when tf2_msgs
                                             is installed; default true
"""

from __future__ import annotations

from typing import Any

from pulsejet_sim.core.topics import BASE_FRAME_ID, ODOM_FRAME_ID
from pulsejet_sim.engine import session as eng
from pulsejet_sim.ros.executor import EXECUTOR_KINDS
from pulsejet_sim.ros.node_params import (
    declare as declare_spec,
    ParamSpec,
    scene_override_descriptor,
    scene_override_names,
    scene_overrides,
)
from pulsejet_sim.scene import DEFAULT_SCENE

DEFAULT_PUBLISH_RATE_HZ = 100.0
PARAMETERS = (
    ParamSpec(
        'scene',
        DEFAULT_SCENE,
        'scene name under config/ or path to a scene YAML',
        read_only=True,
        allowed='a scene name under config/ or a YAML file path',
    ),
    ParamSpec(
        'scene_overrides',
        '',
        'YAML mapping merged into the scene section by section '
        '(e.g. "{material: {stiffness_n_m: 200}}"); empty = none',
        read_only=True,
        allowed='empty or a YAML mapping',
    ),
    ParamSpec(
        'pacing',
        'real_time',
        'how simulated time advances: real_time (scaled by real_time_factor), '
        'as_fast_as_possible, lockstep (only through the pulsejet/step service) or closed_loop '
        '(one control '
        'period per command that answers the last state)',
        choices=eng.PACING_MODES,
    ),
    ParamSpec(
        'real_time_factor',
        1.0,
        'simulated seconds per wall-clock second under real_time pacing',
        1e-3,
        1000.0,
    ),
    ParamSpec(
        'publish_rate_hz',
        0.0,
        'state publication rate in Hz; 0 = the scene value or 100',
        0.0,
        10000.0,
        read_only=True,
        allowed='0 (scene value) or a rate in [0, 10000] Hz',
    ),
    ParamSpec(
        'control_period_s',
        0.0,
        'closed_loop pacing: simulated seconds per control period ' '(0 = one publication period)',
        0.0,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        'lookahead_s',
        0.0,
        'real_time pacing: simulated seconds the physics runs ahead of publication, so '
        'slow steps do not delay states (each is published at its wall time, plus '
        'publish_delay_periods); commands act that '
        'much '
        'later (0 = publish each state as soon as it is computed)',
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        'publish_delay_periods',
        0.0,
        'real_time pacing: each state is sent this fraction of a publication period after its '
        'wall time, computed (physics and messages) before, so its varying cost does not jitter '
        'the send times; the states are the same as with 0 (sent as soon as computed, a latency '
        'that much lower)',
        0.0,
        0.9,
        read_only=True,
    ),
    ParamSpec(
        'duration_s',
        0.0,
        'simulated seconds after which the node exits (0 = run forever)',
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec(
        'wait_for_subscribers',
        0,
        'hold the simulation at t=0 until /clock has this many subscribers',
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        'wait_for_topics',
        (),
        'hold the simulation at t=0 until each of these topics has a subscriber; "*" = every '
        'topic sim_node publishes but /tf (a recorder started beside it then holds t=0 on every '
        'topic)',
        read_only=True,
        allowed='a list of topic names (relative ones resolved in the node namespace) or ["*"]',
    ),
    ParamSpec(
        'wait_timeout_s',
        10.0,
        'wall seconds to wait for subscribers before starting anyway',
        0.0,
        3600.0,
        read_only=True,
    ),
    ParamSpec(
        'start_paused',
        False,
        'start paused (resume with the pulsejet/pause service, data false)',
        read_only=True,
    ),
    ParamSpec(
        'step_count', 100, 'physics steps advanced by one pulsejet/step call', 1, 10_000_000
    ),
    ParamSpec(
        'watchdog_timeout_s',
        0.0,
        'command age before the command watchdog trips (0 = off)',
        0.0,
        3600.0,
    ),
    ParamSpec(
        'watchdog_clock',
        'sim',
        'what the watchdog measures the command age in: sim (simulated '
        'seconds) or wall (wall-clock seconds)',
        choices=eng.WATCHDOG_CLOCKS,
    ),
    ParamSpec(
        'watchdog_action',
        'safe',
        'what the tripped watchdog does: safe = pump off, valve open, cable '
        'released; hold = keep the last command',
        choices=eng.WATCHDOG_ACTIONS,
    ),
    ParamSpec(
        'executor',
        'single',
        'the rclpy executor: single answers services and parameters in turn under a command '
        'flood; events answers a 1 kHz closed loop faster (median command-to-state latency '
        'about half, benchmarks/results/hil.md) but queues them behind a flood',
        choices=EXECUTOR_KINDS,
        read_only=True,
    ),
    ParamSpec(
        'diagnostics_period_s',
        1.0,
        'period of /diagnostics in wall seconds',
        0.05,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        'odom_frame_id',
        ODOM_FRAME_ID,
        'frame of the odometry pose (REP 105)',
        read_only=True,
        allowed='a frame name',
    ),
    ParamSpec(
        'base_frame_id',
        BASE_FRAME_ID,
        'the body frame (REP 105): child of the odometry, frame of the velocity, thrust, mantle '
        'profile and Marker',
        read_only=True,
        allowed='a frame name',
    ),
    ParamSpec(
        'frame_prefix',
        '',
        'put in front of odom_frame_id and base_frame_id, as robot_state_publisher does (e.g. '
        '"robot1/"; the namespace does not set it): two robots on one /tf keep their frames apart',
        read_only=True,
        allowed='a string, e.g. robot1/ (empty: none)',
    ),
    ParamSpec(
        'publish_tf',
        True,
        'broadcast odom -> body on /tf with every state (when tf2_msgs is installed); false when '
        'something else publishes that transform',
        read_only=True,
    ),
)
PARAMETER_SPECS = {p.name: p for p in PARAMETERS}
LIVE_CONFIG = (
    'pacing',
    'real_time_factor',
    'step_count',
    'watchdog_timeout_s',
    'watchdog_clock',
    'watchdog_action',
)


def declare(node) -> dict[str, Any]:
    """Declare every parameter on `node` and return the checked values (ValueError: a bad one)."""
    return {spec.name: declare_spec(node, spec) for spec in PARAMETERS}


def load_scene_from_parameters(node, values: dict[str, Any]):
    """
    Load the scene named by the parameters, with its overrides.

    `scene_overrides` (a YAML mapping) first, then every `scene.<key>` parameter given at start-up
    (declared here, so that `ros2 param list/describe` shows it). The scene's validation refuses
    unknown keys and bad values; ValueError names them.
    """
    from pulsejet_sim.core.schema import safe_load_yaml, YAMLInputError
    from pulsejet_sim.scene import load_scene, merge
    import yaml

    text = values['scene_overrides']
    overrides = None
    if text.strip():
        try:
            overrides = safe_load_yaml(text, 'parameter scene_overrides')
        except (yaml.YAMLError, YAMLInputError) as exc:
            raise ValueError(
                f'parameter scene_overrides={text!r} rejected: not YAML ({exc})'
            ) from None
        if not isinstance(overrides, dict):
            raise ValueError(
                f'parameter scene_overrides={text!r} rejected; allowed: empty or a YAML mapping'
            )
    names = scene_override_names(node._parameter_overrides)
    for name in names:
        node.declare_parameter(
            name, node._parameter_overrides[name].value, scene_override_descriptor(name)
        )
    if names:
        given = {n: node.get_parameter(n).value for n in names}
        overrides = merge(overrides or {}, scene_overrides(given))
        node.get_logger().info(
            'scene overrides: ' + ', '.join(f'{n}={v!r}' for n, v in given.items())
        )
    # command_driven: a shell scene's built-in cable routine comes from pulsejet/cmd/* instead
    return load_scene(values['scene'], overrides=overrides, command_driven=True)


def session_config(values: dict[str, Any], publish_rate_hz: float) -> eng.SessionConfig:
    """Return the engine's configuration from the parameter values."""
    return eng.SessionConfig(
        pacing=values['pacing'],
        real_time_factor=values['real_time_factor'],
        publish_rate_hz=publish_rate_hz,
        duration_s=values['duration_s'],
        step_count=values['step_count'],
        watchdog_timeout_s=values['watchdog_timeout_s'],
        watchdog_action=values['watchdog_action'],
        watchdog_clock=values['watchdog_clock'],
        control_period_s=values['control_period_s'],
        paused=values['start_paused'],
        lookahead_s=values['lookahead_s'],
        publish_delay_periods=values['publish_delay_periods'],
    )
