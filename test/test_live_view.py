"""
`pulsejet view`: the run served live over the Foxglove WebSocket protocol, read by a real client.

The server runs as the user starts it (`python -m pulsejet_sim.cli view ...`, a subprocess, a free
loopback port); a `websockets` client speaks the Foxglove WebSocket protocol to it (the subprotocol
foxglove-sdk 0.30 accepts is named foxglove.sdk.v1; it answers foxglove.websocket.v1, the older
name, with HTTP 400, which a test here checks): it reads the advertised
channels, subscribes to every one, and decodes the binary message frames (opcode 0x01:
subscription id, log time, payload). JSON payloads are parsed; protobuf ones (foxglove's
SceneUpdate, FrameTransform, PoseInFrame) are decoded field by field with the schema the server
advertised (a FileDescriptorSet, read with a small protobuf wire-format reader here: no protobuf
package needed). What arrives is held to an offline run of the same scene (runner.Drive, the loop
`pulsejet run` records) at the same simulation times.
"""

import asyncio
import base64
import json
import math
import os
from pathlib import Path
import signal
import struct
import subprocess
import sys
import time

import numpy as np
from pulsejet_sim.scene import load_scene_data
import pytest

REPO = Path(__file__).resolve().parent.parent
SUBPROTOCOL = 'foxglove.sdk.v1'
OP_MESSAGE_DATA = 0x01
OP_TIME = 0x02
SCENE = 'shell_robot'
#: the scene's mesh, as its file says (the Marker has one band of facets per element)
MESH_ELEMENTS = load_scene_data(SCENE)[0]['mesh']['elements']
DURATION_S = 0.6

websockets = pytest.importorskip('websockets')


# -- protobuf wire format, read with the advertised FileDescriptorSet -----------------------------
def _varint(buf: bytes, i: int):
    value, shift = 0, 0
    while True:
        byte = buf[i]
        i += 1
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, i
        shift += 7


def _wire_fields(buf: bytes):
    """Yield (field number, wire type, raw value) of one protobuf message."""
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i:i + 8], i + 8
        elif wire == 2:
            size, i = _varint(buf, i)
            value, i = buf[i:i + size], i + size
        elif wire == 5:
            value, i = buf[i:i + 4], i + 4
        else:
            raise ValueError(f'wire type {wire} of field {number}')
        yield number, wire, value


def _message_types(descriptor_set: bytes) -> dict:
    """Return '.package.Name' -> {field number: (name, type, type name, repeated)}."""
    types = {}
    for number, _, file_proto in _wire_fields(descriptor_set):
        if number != 1:
            continue
        parts = list(_wire_fields(file_proto))
        package = next((v.decode() for n, _, v in parts if n == 2), '')
        for n, _, message in parts:
            if n != 4:
                continue
            fields, name = {}, ''
            for m, _, value in _wire_fields(message):
                if m == 1:
                    name = value.decode()
                elif m == 2:
                    spec = {k: v for k, _, v in _wire_fields(value)}
                    fields[spec[3]] = (
                        spec[1].decode(),
                        spec[5],
                        spec.get(6, b'').decode(),
                        spec.get(4) == 3,
                    )
            types[f'.{package}.{name}'] = fields
    return types


_FIXED = {1: '<d', 2: '<f', 6: '<Q', 7: '<I', 15: '<i', 16: '<q'}


def _decode(buf: bytes, type_name: str, types: dict) -> dict:
    out = {}
    for number, wire, raw in _wire_fields(buf):
        name, kind, sub, repeated = types[type_name][number]
        if kind == 11:
            values = [_decode(raw, sub, types)]
        elif kind in _FIXED:
            fmt = _FIXED[kind]
            size = struct.calcsize(fmt)
            values = [struct.unpack_from(fmt, raw, k)[0] for k in range(0, len(raw), size)]
        elif kind == 9:
            values = [raw.decode()]
        elif kind == 12:
            values = [raw]
        elif wire == 2:  # packed varints
            values, i = [], 0
            while i < len(raw):
                v, i = _varint(raw, i)
                values.append(v)
        else:
            values = [raw]
        if repeated:
            out.setdefault(name, []).extend(values)
        else:
            out[name] = values[0]
    return out


# -- the server and a client ----------------------------------------------------------------------
def _sigint_default():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_view(*args):
    """Start `pulsejet view` on a free loopback port; return (process, port)."""
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    proc = subprocess.Popen(
        [sys.executable, '-m', 'pulsejet_sim.cli', 'view', *args],
        cwd=REPO,
        env=env,
        # Ctrl-C as in a terminal: a background job of a non-interactive shell (CI) starts its
        # children with SIGINT ignored, and Python then installs no KeyboardInterrupt for it
        preexec_fn=_sigint_default,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()
    if 'ws://' not in line:
        proc.kill()
        raise AssertionError(f'no server address: {line!r} {proc.stderr.read()[-2000:]}')
    port = int(line.split('ws://', 1)[1].split()[0].rsplit(':', 1)[1])
    return proc, port


async def receive_run(port: int, timeout_s: float = 120.0):
    """Connect, subscribe to every advertised channel, collect frames until the server closes."""
    channels, frames = {}, []
    async with websockets.connect(
        f'ws://127.0.0.1:{port}', subprotocols=[SUBPROTOCOL], max_size=None
    ) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        subscribed = False
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=max(0.1, end - time.monotonic()))
            except websockets.ConnectionClosed:
                break
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg['op'] == 'advertise':
                    channels.update({c['id']: c for c in msg['channels']})
                    if not subscribed and len(channels) >= 5:
                        subscribed = True
                        await ws.send(
                            json.dumps(
                                {
                                    'op': 'subscribe',
                                    'subscriptions': [
                                        {'id': 100 + c, 'channelId': c} for c in channels
                                    ],
                                }
                            )
                        )
                continue
            frames.append((time.monotonic(), raw))
    return channels, frames


def decode_frames(channels, frames):
    """Return topic -> [(log time ns, decoded payload, wall s)], and the server's time frames."""
    types = {}
    by_topic, times = {}, []
    for wall, raw in frames:
        if raw[0] == OP_TIME:
            times.append(struct.unpack_from('<Q', raw, 1)[0])
            continue
        assert raw[0] == OP_MESSAGE_DATA, raw[:1]
        subscription, log_time = struct.unpack_from('<IQ', raw, 1)
        payload = raw[13:]
        channel = channels[subscription - 100]
        if channel['encoding'] == 'json':
            value = json.loads(payload)
        else:
            assert channel['encoding'] == 'protobuf'
            assert channel['schemaEncoding'] == 'protobuf'
            if channel['id'] not in types:
                types[channel['id']] = _message_types(base64.b64decode(channel['schema']))
            value = _decode(payload, '.' + channel['schemaName'], types[channel['id']])
        by_topic.setdefault(channel['topic'], []).append((log_time, value, wall))
    return by_topic, times


def offline_states(scene_name: str, duration_s: float):
    """Return {stamp ns: (observation, meridian)} of the offline run (runner.Drive)."""
    from pulsejet_sim.bag.cdr import stamp_ns
    from pulsejet_sim.scene import load_scene
    from pulsejet_sim.studies.runner import Drive

    drive = Drive(load_scene(scene_name), duration_s)
    states = {stamp_ns(0.0): (drive.sim.observe(), drive.sim.profile())}
    for _, _, obs in drive:
        states[stamp_ns(obs.time_s)] = (obs, drive.sim.profile())
    return states


@pytest.fixture(scope='module')
def live_run():
    proc, port = start_view(
        SCENE, '--duration', str(DURATION_S), '--port', '0', '--wait-for-client'
    )
    try:
        channels, frames = asyncio.run(receive_run(port))
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err[-3000:]
    by_topic, times = decode_frames(channels, frames)
    return channels, by_topic, times, out


def test_channels_advertised_with_their_schemas(live_run):
    channels, _, _, _ = live_run
    got = {c['topic']: (c['encoding'], c.get('schemaName')) for c in channels.values()}
    assert got['pulsejet/mantle'] == ('protobuf', 'foxglove.SceneUpdate')
    assert got['tf'] == ('protobuf', 'foxglove.FrameTransform')
    assert got['pulsejet/pose'] == ('protobuf', 'foxglove.PoseInFrame')
    assert got['pulsejet/state'][0] == 'json' and got['pulsejet/command'][0] == 'json'
    state_schema = json.loads(
        next(c['schema'] for c in channels.values() if c['topic'] == 'pulsejet/state')
    )
    assert state_schema['properties']['velocity_m_s'] == {'type': 'number', 'description': 'm/s'}
    assert state_schema['properties']['thrust_n']['description'] == 'N'


def test_states_match_the_offline_run_at_the_same_times(live_run):
    _, by_topic, times, _ = live_run
    offline = offline_states(SCENE, DURATION_S)
    states = by_topic['pulsejet/state']
    # the run waited for the subscription: every state from t = 0 to the end arrives
    assert len(states) == len(offline) and min(t for t, _, _ in states) == 0
    for log_time, payload, _ in states:
        assert payload['timestamp']['sec'] * 10**9 + payload['timestamp']['nsec'] == log_time
        obs, _ = offline[log_time]
        for name in ('velocity_m_s', 'thrust_n', 'volume_m3', 'mantle_radius_m', 'position_m'):
            assert math.isfinite(payload[name])
            assert payload[name] == pytest.approx(getattr(obs, name), rel=1e-12, abs=1e-300)
    assert max(abs(p['velocity_m_s']) for _, p, _ in states) > 0  # it swims
    # the server time follows the simulation time
    assert times and sorted(times) == times and max(times) == max(t for t, _, _ in states)
    for log_time, payload, _ in by_topic['tf']:
        obs, _ = offline[log_time]
        assert payload['parent_frame_id'] == 'odom' and payload['child_frame_id'] == 'base_link'
        assert payload['translation'].get('x', 0.0) == pytest.approx(obs.position_m, rel=1e-12)
        assert payload['rotation']['w'] == 1.0
    poses = by_topic['pulsejet/pose']
    assert len(poses) == len(states) and poses[-1][1]['frame_id'] == 'odom'
    assert poses[-1][1]['pose']['position']['x'] == pytest.approx(
        offline[poses[-1][0]][0].position_m, rel=1e-12
    )


def test_mantle_scene_is_the_revolved_meridian(live_run):
    from pulsejet_sim.view.mesh import mantle_vertices

    _, by_topic, _, _ = live_run
    offline = offline_states(SCENE, DURATION_S)
    updates = by_topic['pulsejet/mantle']
    # at 10 Hz of simulated time (every 10th state of 100 Hz) and the initial state
    assert len(updates) == 1 + int(round(DURATION_S * 10))
    for log_time, update, _ in updates:
        (entity,) = update['entities']
        assert entity['frame_id'] == 'base_link'
        (triangles,) = entity['triangles']
        points = np.array(
            [[p.get('x', 0.0), p.get('y', 0.0), p.get('z', 0.0)] for p in triangles['points']]
        )
        expected = mantle_vertices(*offline[log_time][1])
        # six vertices (two triangles) per facet, 24 facets around, one band per element
        elements = len(offline[log_time][1][0]) - 1
        assert elements == MESH_ELEMENTS
        assert points.shape == expected.shape == (6 * 24 * elements, 3)
        assert np.array_equal(points, expected)


def test_paced_in_real_time(live_run):
    _, by_topic, _, _ = live_run
    states = by_topic['pulsejet/state']
    wall = [w for _, _, w in states]
    # DURATION_S of simulated time at a real-time factor of 1: the last state arrives that long
    # after the first, not in one burst
    assert wall[-1] - wall[0] >= 0.8 * DURATION_S


@pytest.mark.parametrize(
    'args, named',
    [
        (['--host', '0.0.0.0'], "'0.0.0.0'"),
        (['--port', '70000'], '70000'),
        (['--real-time-factor', '0'], '0.0'),
        (['--real-time-factor', 'nan'], 'nan'),
        (['--duration', '-1'], '-1.0'),
    ],
)
def test_bad_arguments_are_refused_naming_the_value(args, named):
    proc = subprocess.run(
        [sys.executable, '-m', 'pulsejet_sim.cli', 'view', SCENE, *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    message = proc.stderr.strip().splitlines()[-1]
    assert named in message and 'allowed' in message, message


async def _connect_with(port: int, subprotocol: str):
    async with websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=[subprotocol]) as ws:
        return ws.subprotocol


def test_a_taken_port_is_refused_ctrl_c_stops_and_only_the_sdk_subprotocol_is_spoken():
    first, port = start_view(SCENE, '--duration', '30', '--port', '0', '--wait-for-client')
    try:
        # foxglove-sdk 0.30 names the protocol foxglove.sdk.v1 and refuses the older name
        assert asyncio.run(_connect_with(port, SUBPROTOCOL)) == SUBPROTOCOL
        with pytest.raises(websockets.InvalidStatus, match='400'):
            asyncio.run(_connect_with(port, 'foxglove.websocket.v1'))
        proc = subprocess.run(
            [sys.executable, '-m', 'pulsejet_sim.cli', 'view', SCENE, '--port', str(port)],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=120,
        )
        # Ctrl-C stops the first server cleanly (it was waiting for a client)
        first.send_signal(signal.SIGINT)
        out, err = first.communicate(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert proc.returncode == 2
    assert f'127.0.0.1:{port}' in proc.stderr and 'did not start' in proc.stderr
    assert first.returncode == 0 and 'interrupted (SIGINT)' in out, (out, err[-2000:])


def test_sigterm_stops_the_run_too():
    proc, _ = start_view(SCENE, '--duration', '30', '--port', '0')
    time.sleep(1.0)  # running: paced in real time
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0 and 'interrupted (SIGTERM)' in out, (out, err[-2000:])
