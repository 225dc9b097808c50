"""
The offline recorder's CDR bytes are the ones rclpy writes for the equivalent message.

For every topic the offline runner records, bag.cdr's bytes are compared with
rclpy.serialization.serialize_message of the message ros/messages.py builds from the same values
(real rclpy). rclpy's Fast-CDR leaves alignment padding as it was in memory, so the comparison
walks the message definition (rosbags' type store): every field byte must be equal, the lengths
equal, and our padding zero.
"""

import math

import numpy as np
from pulsejet_sim.bag import cdr
from pulsejet_sim.core.model_io import Command, Observation
from pulsejet_sim.core.topics import TOPIC_TYPES
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.ros import messages
from pulsejet_sim.scene import load_scene
import pytest
from rclpy.serialization import serialize_message
from rosbags.interfaces import Nodetype
from rosbags.typesys import get_typestore, Stores

STORE = get_typestore(Stores.ROS2_JAZZY)
_SIZES = {
    'bool': 1, 'byte': 1, 'char': 1, 'int8': 1, 'uint8': 1, 'int16': 2, 'uint16': 2,
    'int32': 4, 'uint32': 4, 'float32': 4, 'int64': 8, 'uint64': 8, 'float64': 8,
}


def field_bytes(raw: bytes, type_name: str) -> tuple[set[int], int]:
    """Positions of the bytes that hold field data (not padding) and where the data ends."""
    data: set[int] = set(range(4))  # the encapsulation header
    pos = 4

    def align(size):
        nonlocal pos
        pos += -(pos - 4) % size

    def take(n):
        nonlocal pos
        data.update(range(pos, pos + n))
        pos += n

    def uint32():
        align(4)
        value = int.from_bytes(raw[pos:pos + 4], 'little')
        take(4)
        return value

    def node(desc):
        kind, detail = desc
        if kind == Nodetype.BASE:
            name = detail[0]
            if name == 'string':
                take(uint32())
            else:
                align(_SIZES[name])
                take(_SIZES[name])
        elif kind == Nodetype.NAME:
            message(detail)
        elif kind == Nodetype.ARRAY:
            for _ in range(detail[1]):
                node(detail[0])
        else:
            for _ in range(uint32()):
                node(detail[0])

    def message(name):
        for _, desc in STORE.fielddefs[name][1]:
            node(desc)

    message(type_name)
    return data, pos


def assert_same_cdr(ours: bytes, msg, type_name: str) -> None:
    theirs = bytes(serialize_message(msg))
    assert isinstance(ours, bytes)
    assert len(ours) == len(theirs), (type_name, len(ours), len(theirs))
    data, end = field_bytes(theirs, type_name)
    assert end <= len(theirs)
    differ = [i for i in sorted(data) if ours[i] != theirs[i]]
    assert not differ, f'{type_name}: field bytes differ at {differ[:10]}'
    assert all(ours[i] == 0 for i in range(len(ours)) if i not in data), type_name
    # a ROS reader without rclpy decodes ours, and writes the same bytes back
    assert bytes(STORE.serialize_cdr(STORE.deserialize_cdr(ours, type_name), type_name)) == ours


def observations():
    """Observations from a lumped and a shell run plus edge values (negative, tiny, huge)."""
    out = []
    for name in ('pump_cycle', 'shell_robot'):
        sim = Simulation(load_scene(name).model)
        out.append((sim, sim.observe()))
        out.append((sim, sim.step(7, sim.command)))
    edge = Observation(
        time_s=1234.567891234, position_m=-0.1, velocity_m_s=-1e-300, acceleration_m_s2=0.0,
        mantle_radius_m=1e300, volume_m3=5e-324, fluid_mass_kg=-0.0, thrust_n=math.pi,
        added_mass_force_n=0.0, drag_n=0.0, jet_speed_m_s=0.0, cavity_pressure_pa=0.0,
        pump_flow_m3_s=0.0, valve_opening=0.0,
    )
    out.append((None, edge))
    return out


@pytest.mark.timeout(300)
def test_every_recorded_topic_has_the_bytes_rclpy_writes():
    encoder = cdr.TopicEncoder()
    covered = set()
    for sim, obs in observations():
        ns = cdr.stamp_ns(obs.time_s)
        assert ns == messages.stamp_ns(obs.time_s)
        ours = dict(encoder.observation(obs, ns))
        theirs = dict(messages.observation_messages(obs))
        assert list(ours) == list(theirs)
        for topic, msg in theirs.items():
            assert_same_cdr(ours[topic], msg, TOPIC_TYPES[topic])
            covered.add(topic)
        if sim is None:
            continue
        ledger = sim.energy_ledger()
        assert_same_cdr(
            encoder.ledger(ledger, ns), messages.ledger_message(ledger, obs.time_s),
            TOPIC_TYPES[messages.TOPIC_ENERGY_LEDGER],
        )
        covered.add(messages.TOPIC_ENERGY_LEDGER)
        profile = sim.profile()
        if profile is not None:
            # a shell's whole meridian (every node); the lumped mantle's sampled profile
            nodes = getattr(sim.model, 'n_nodes', None)
            assert len(profile[0]) == nodes if nodes is not None else len(profile[0]) > 20
            assert_same_cdr(
                encoder.profile(*profile, ns), messages.profile_message(*profile, obs.time_s),
                TOPIC_TYPES[messages.TOPIC_MANTLE_PROFILE],
            )
            covered.add(messages.TOPIC_MANTLE_PROFILE)
    for cmd, time_s in ((Command(2.5e-3, 1.0, 0.0), 0.0), (Command(-1e-9, 0.25, 37.5), 3.01)):
        ns = cdr.stamp_ns(time_s)
        ours = dict(encoder.commands(cmd))
        for topic, msg in messages.command_messages(cmd):
            assert_same_cdr(ours[topic], msg, TOPIC_TYPES[topic])
            covered.add(topic)
        assert_same_cdr(
            encoder.applied_command(cmd, ns), messages.applied_command_message(cmd, time_s),
            TOPIC_TYPES[messages.TOPIC_APPLIED_COMMAND],
        )
        covered.add(messages.TOPIC_APPLIED_COMMAND)
    assert covered == set(cdr.RECORDED_TOPICS)


@pytest.mark.parametrize(
    'ledger',
    [
        {'in_initial': 1.0, 'closure_relative': 0.01},
        {'in_initial': 1.0, 'closure_relative': -0.2, 'out_drag': 0.3},
        {'in_initial': 1.0, 'closure_relative': math.nan},
        {'in_initial': 1.0, 'in_actuation_work': -2.0, 'created_paper': 0.5,
         'closure_relative': 0.0},
        {},
    ],
)
def test_the_ledger_status_and_its_bytes_match_sim_node_for_every_level(ledger):
    msg = messages.ledger_message(ledger, 2.5)
    status = msg.status[0]
    assert cdr.ledger_status(ledger) == (ord(status.level), status.message)
    assert_same_cdr(
        cdr.TopicEncoder().ledger(ledger, cdr.stamp_ns(2.5)), msg,
        TOPIC_TYPES[messages.TOPIC_ENERGY_LEDGER],
    )


def test_other_frame_ids_and_a_short_profile_match_too():
    encoder = cdr.TopicEncoder('a', 'world/odometry_frame', 'base')
    obs = observations()[-1][1]
    ns = cdr.stamp_ns(obs.time_s)
    ours = dict(encoder.observation(obs, ns))
    for topic, msg in messages.observation_messages(obs, 'a', 'world/odometry_frame', 'base'):
        assert_same_cdr(ours[topic], msg, TOPIC_TYPES[topic])
    r, z = np.array([0.01, 0.02]), np.array([-0.3, 1e-3])
    assert_same_cdr(
        encoder.profile(r, z, ns), messages.profile_message(r, z, obs.time_s, 'a'),
        TOPIC_TYPES[messages.TOPIC_MANTLE_PROFILE],
    )


def test_bad_times_and_profiles_are_refused_with_the_value():
    for bad in (-1.0, math.nan, 2.0**31):
        with pytest.raises(ValueError, match='allowed: a finite time'):
            cdr.stamp_ns(bad)
    with pytest.raises(ValueError, match='same length'):
        cdr.TopicEncoder().profile([0.1, 0.2], [0.0], 0)
