"""
`pulsejet view SCENE`: a run served live over the Foxglove WebSocket protocol, without ROS.

The scene is stepped as `pulsejet run` steps it (runner.Drive: the scene's routine, one
publication period per batch), each state sent at its wall time (simulation time / real-time
factor), on ws://HOST:PORT with foxglove-sdk (protocol foxglove.websocket.v1). Channels:

  pulsejet/mantle   foxglove.SceneUpdate (protobuf): the mantle surface, the meridian revolved
                    about the body's x axis (view.mesh.mantle_vertices, the mesh of sim_node's
                    Marker) as one TriangleListPrimitive in base_link, at MANTLE_RATE_HZ (shell
                    models; the lumped model has no meridian)
  tf                foxglove.FrameTransform (protobuf): odom -> base_link, x = distance swum, m
  pulsejet/pose     foxglove.PoseInFrame (protobuf): the body's pose in odom
  pulsejet/state    JSON (schema STATE_SCHEMA): every field of the observation, SI units as the
                    names say (velocity_m_s, thrust_n, volume_m3, mantle_radius_m, ...)
  pulsejet/command  JSON: the command held over the period that ends at that state

Every message's log time, and the server time (the Time capability), is the simulation time in
ns, as ROS stamps carry it. The server binds a loopback address only: the protocol has no
authentication. No rclpy import (an offline tool).
"""

from __future__ import annotations

import argparse
import dataclasses
import ipaddress
import math
import signal
import sys
import threading
import time

#: scene updates at most this often (the 14,400 vertices of the shell robot cost the view ~10 ms
#: of the interpreter each as foxglove Point3 objects)
MANTLE_RATE_HZ = 10.0
DEFAULT_HOST = '127.0.0.1'
#: the Foxglove app's default for a WebSocket connection (ws://localhost:8765)
DEFAULT_PORT = 8765
TOPIC_MANTLE = 'pulsejet/mantle'
TOPIC_TF = 'tf'
TOPIC_POSE = 'pulsejet/pose'
TOPIC_STATE = 'pulsejet/state'
TOPIC_COMMAND = 'pulsejet/command'
#: --wait-for-client starts the run once the client's subscriptions stopped coming for this long (a
#: panel subscribes to its channels one by one; t = 0 should reach every one)
SUBSCRIBE_SETTLE_S = 0.3
#: how long close() waits for foxglove's server to stop before the process goes on to exit (a stop
#: that hangs must not keep a Ctrl-C from ending the run)
SERVER_STOP_TIMEOUT_S = 5.0
#: the colour of sim_node's Marker (r, g, b, a)
MANTLE_RGBA = (0.95, 0.55, 0.35, 0.8)

#: unit of a field by the end of its name (the longest ending that matches)
_UNITS = {
    '_s': 's',
    '_m': 'm',
    '_m_s': 'm/s',
    '_m_s2': 'm/s^2',
    '_m3': 'm^3',
    '_m3_s': 'm^3/s',
    '_kg': 'kg',
    '_n': 'N',
    '_pa': 'Pa',
    'valve_opening': '0 (closed) .. 1 (open)',
}


def _unit(name: str) -> str:
    ends = [end for end in _UNITS if name.endswith(end)]
    return _UNITS[max(ends, key=len)] if ends else ''


def _schema(title: str, names) -> dict:
    """Return a JSON schema: a foxglove timestamp and one number per name (unit described)."""
    properties = {
        'timestamp': {
            'type': 'object',
            'description': 'simulation time',
            'properties': {'sec': {'type': 'integer'}, 'nsec': {'type': 'integer'}},
        }
    }
    for name in names:
        properties[name] = {'type': 'number', 'description': _unit(name)}
    return {'title': title, 'type': 'object', 'properties': properties}


def state_fields() -> list[str]:
    from pulsejet_sim.core.model_io import Observation

    return [f.name for f in dataclasses.fields(Observation)]


def command_fields() -> list[str]:
    from pulsejet_sim.core.model_io import Command

    return [f.name for f in dataclasses.fields(Command)]


def timestamp(time_ns: int) -> dict:
    return {'sec': time_ns // 1_000_000_000, 'nsec': time_ns % 1_000_000_000}


def state_payload(obs, time_ns: int) -> dict:
    """Return the JSON message of one observation (every field, as float)."""
    payload = {'timestamp': timestamp(time_ns)}
    payload.update((name, float(getattr(obs, name))) for name in state_fields())
    return payload


def command_payload(command, time_ns: int) -> dict:
    payload = {'timestamp': timestamp(time_ns)}
    payload.update((name, float(getattr(command, name))) for name in command_fields())
    return payload


def mantle_scene(r_m, z_m, time_ns: int, frame_id: str):
    """Return the mantle surface as a foxglove SceneUpdate of one entity, one triangle list."""
    from foxglove.messages import (
        Color,
        Point3,
        SceneEntity,
        SceneUpdate,
        Timestamp,
        TriangleListPrimitive,
    )
    from pulsejet_sim.view.mesh import mantle_vertices

    points = [Point3(x=x, y=y, z=z) for x, y, z in mantle_vertices(r_m, z_m).tolist()]
    r, g, b, a = MANTLE_RGBA
    entity = SceneEntity(
        timestamp=Timestamp(sec=time_ns // 1_000_000_000, nsec=time_ns % 1_000_000_000),
        frame_id=frame_id,
        id='mantle',
        frame_locked=True,
        triangles=[TriangleListPrimitive(points=points, color=Color(r=r, g=g, b=b, a=a))],
    )
    return SceneUpdate(entities=[entity])


def body_transform(position_m: float, time_ns: int, parent: str, child: str):
    """Return odom -> body as a foxglove FrameTransform (the body moves along odom's x)."""
    from foxglove.messages import FrameTransform, Quaternion, Timestamp, Vector3

    return FrameTransform(
        timestamp=Timestamp(sec=time_ns // 1_000_000_000, nsec=time_ns % 1_000_000_000),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=float(position_m), y=0.0, z=0.0),
        rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
    )


def body_pose(position_m: float, time_ns: int, frame_id: str):
    from foxglove.messages import Pose, PoseInFrame, Quaternion, Timestamp, Vector3

    return PoseInFrame(
        timestamp=Timestamp(sec=time_ns // 1_000_000_000, nsec=time_ns % 1_000_000_000),
        frame_id=frame_id,
        pose=Pose(
            position=Vector3(x=float(position_m), y=0.0, z=0.0),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )


class Subscriptions:
    """foxglove ServerListener: counts the clients' subscriptions (`wait_for_client` waits)."""

    def __init__(self):
        self.count = 0
        self.last_s = 0.0  # monotonic time of the latest subscription
        self.first = threading.Event()

    def on_subscribe(self, client, channel) -> None:
        self.count += 1
        self.last_s = time.monotonic()
        self.first.set()

    def on_unsubscribe(self, client, channel) -> None:
        self.count -= 1

    def wait(self, settle_s: float = SUBSCRIBE_SETTLE_S) -> None:
        """Return once a client subscribed and no further subscription came for settle_s."""
        while not self.first.wait(0.2):
            pass
        while time.monotonic() - self.last_s < settle_s:
            time.sleep(settle_s / 5)


class LiveView:
    """The server and its channels; `send(obs, command, scene_due)` logs one state."""

    def __init__(self, scene_name: str, host: str, port: int, has_mantle: bool):
        import foxglove
        from foxglove.channels import (
            FrameTransformChannel,
            PoseInFrameChannel,
            SceneUpdateChannel,
        )
        from foxglove.websocket import Capability
        from pulsejet_sim.core.topics import BASE_FRAME_ID, ODOM_FRAME_ID

        self.frames = (ODOM_FRAME_ID, BASE_FRAME_ID)
        self.subscriptions = Subscriptions()
        self.server = foxglove.start_server(
            name=f'pulsejet {scene_name}',
            host=host,
            port=port,
            capabilities=[Capability.Time],
            server_listener=self.subscriptions,
        )
        self.mantle = SceneUpdateChannel(TOPIC_MANTLE) if has_mantle else None
        self.tf = FrameTransformChannel(TOPIC_TF)
        self.pose = PoseInFrameChannel(TOPIC_POSE)
        self.state = foxglove.Channel(
            TOPIC_STATE, schema=_schema('pulsejet state', state_fields())
        )
        self.command = foxglove.Channel(
            TOPIC_COMMAND, schema=_schema('pulsejet command', command_fields())
        )

    @property
    def port(self) -> int:
        return self.server.port

    def send(self, obs, command, profile, time_ns: int) -> None:
        """Log one state (and the mantle when `profile` is given), stamped time_ns."""
        self.server.broadcast_time(time_ns)
        odom, body = self.frames
        self.tf.log(body_transform(obs.position_m, time_ns, odom, body), log_time=time_ns)
        self.pose.log(body_pose(obs.position_m, time_ns, odom), log_time=time_ns)
        self.state.log(state_payload(obs, time_ns), log_time=time_ns)
        if command is not None:
            self.command.log(command_payload(command, time_ns), log_time=time_ns)
        # the mesh only while someone looks (its Point3 objects are the view's largest cost)
        if profile is not None and self.mantle is not None and self.mantle.has_sinks():
            self.mantle.log(mantle_scene(*profile, time_ns, body), log_time=time_ns)

    def close(self) -> None:
        """Stop the server; say so and go on if it does not stop within SERVER_STOP_TIMEOUT_S."""
        stopper = threading.Thread(target=self.server.stop, name='foxglove stop', daemon=True)
        stopper.start()
        stopper.join(SERVER_STOP_TIMEOUT_S)
        if stopper.is_alive():
            print(
                f'pulsejet view: the server did not stop within {SERVER_STOP_TIMEOUT_S:g} s; '
                'leaving it to the process exit',
                file=sys.stderr,
                flush=True,
            )


def serve(
    scene,
    duration_s: float,
    real_time_factor: float = 1.0,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    wait_for_client: bool = False,
    out=print,
) -> int:
    """
    Run `scene` for duration_s simulated seconds, serving every state live; return an exit code.

    Each state is sent when wall time since the start reaches its simulation time divided by
    real_time_factor (never before; a late one at once). 0: duration reached; 1: the physics blew
    up (said, nothing non-finite sent).
    """
    from pulsejet_sim.bag.cdr import stamp_ns
    from pulsejet_sim.engine.session import observation_is_finite
    from pulsejet_sim.studies.runner import Drive

    drive = Drive(scene, duration_s)
    sim = drive.sim
    has_mantle = sim.profile() is not None
    view = LiveView(scene.name, host, port, has_mantle)
    try:
        out(
            f'pulsejet view: {scene.name} on ws://{host}:{view.port} (Foxglove: Open connection'
            f' -> Foxglove WebSocket), {duration_s:g} s simulated at {real_time_factor:g}x'
            ' real time; Ctrl-C stops'
        )
        if wait_for_client:
            out('pulsejet view: waiting for a client to subscribe')
            view.subscriptions.wait()
        mantle_every = max(1, int(math.ceil(scene.publish_rate_hz / MANTLE_RATE_HZ - 1e-9)))
        start = time.monotonic()
        obs = sim.observe()
        view.send(obs, None, sim.profile(), stamp_ns(obs.time_s))
        for index, (_, command, obs) in enumerate(drive, start=1):
            if not observation_is_finite(obs):
                drive.fault = f'a non-finite state at t={obs.time_s:.6g} s'
                break
            delay = start + obs.time_s / real_time_factor - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            profile = sim.profile() if index % mantle_every == 0 else None
            view.send(obs, command, profile, stamp_ns(obs.time_s))
    finally:
        view.close()
    if drive.fault is not None:
        out(f'pulsejet view: stopped at t={sim.time_s:.6g} s: {drive.fault}')
        return 1
    out(f'pulsejet view: {sim.time_s:.6g} s simulated; done')
    return 0


def _loopback(host: str) -> bool:
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog='pulsejet view',
        description='Run a scene in real time and serve it live to the Foxglove app (Foxglove '
        'WebSocket protocol; no ROS): the mantle in 3D, the pose, the state as plots.',
    )
    parser.add_argument('scene', help='scene name under config/ or a YAML path')
    parser.add_argument(
        '--duration', type=float, default=None, help="simulated seconds (default: the scene's)"
    )
    parser.add_argument(
        '--real-time-factor',
        type=float,
        default=1.0,
        help='simulated seconds per wall second (default 1)',
    )
    parser.add_argument(
        '--host',
        default=DEFAULT_HOST,
        help=f'loopback address to bind (default {DEFAULT_HOST}; the protocol has no '
        'authentication, so no other address is served)',
    )
    parser.add_argument(
        '--port',
        type=int,
        default=DEFAULT_PORT,
        help=f"TCP port (default {DEFAULT_PORT}, the Foxglove app's; 0 = any free port, printed)",
    )
    parser.add_argument(
        '--dt', type=float, default=None, help='physics step in s (overrides the scene)'
    )
    parser.add_argument(
        '--wait-for-client',
        action='store_true',
        help='hold t = 0 until a client subscribes to a channel',
    )
    args = parser.parse_args(argv)
    rtf = args.real_time_factor
    if not (math.isfinite(rtf) and 0.0 < rtf <= 1000.0):
        parser.error(f'--real-time-factor {rtf!r} rejected; allowed: a number in (0, 1000]')
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        parser.error(
            f'--duration {args.duration!r} rejected; allowed: a positive finite number of seconds'
        )
    if not 0 <= args.port <= 65535:
        parser.error(f'--port {args.port} rejected; allowed: 0 (any free port) to 65535')
    if not _loopback(args.host):
        parser.error(
            f'--host {args.host!r} rejected; allowed: a loopback address (127.0.0.1, ::1, '
            'localhost): the Foxglove WebSocket protocol has no authentication'
        )
    return args


def _interrupt(signum, frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def main_view(argv: list[str]) -> int:
    """Entry point of `pulsejet view` (cli.COMMANDS)."""
    args = parse_args(argv)
    try:
        import foxglove  # noqa: F401
    except ImportError as err:
        print(
            f'pulsejet view: the Foxglove SDK is not installed ({err}); install it with '
            '`pip install foxglove-sdk==0.30.3` (or the extra: `pip install .[view]`)',
            file=sys.stderr,
        )
        return 2
    from pulsejet_sim.scene import load_scene, SceneError

    if threading.current_thread() is threading.main_thread():
        # SIGTERM (a service manager, a test harness) stops the run as Ctrl-C does
        signal.signal(signal.SIGTERM, _interrupt)
    try:
        overrides = {'simulation': {'dt_s': args.dt}} if args.dt is not None else None
        scene = load_scene(args.scene, overrides)
        duration = scene.duration_s if args.duration is None else args.duration
        return serve(
            scene,
            duration,
            args.real_time_factor,
            args.host,
            args.port,
            args.wait_for_client,
            out=lambda text: print(text, flush=True),
        )
    except (SceneError, ValueError) as err:
        print(f'pulsejet view: {err}', file=sys.stderr)
        return 2
    except RuntimeError as err:  # foxglove's server did not start (the port is taken, ...)
        print(
            f'pulsejet view: the server did not start on {args.host}:{args.port}: {err}',
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt as err:
        print(f'pulsejet view: interrupted ({str(err) or "SIGINT"})', flush=True)
        return 0
