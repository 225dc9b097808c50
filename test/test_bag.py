"""
BagWriter output checked with independent readers, plus crash safety.

The independent readers: rosbags and the mcap library.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

from mcap.reader import make_reader
from pulsejet_sim.bag import msgdefs
from pulsejet_sim.bag.reader import bag_info, BagReadError, load_series, read_bag
from pulsejet_sim.bag.repair import repair
from pulsejet_sim.bag.writer import BagError, BagWriter, install_signal_handlers
from pulsejet_sim.core.model_io import Command, Observation
from pulsejet_sim.ros import messages
from pulsejet_sim.ros.bag_messages import write_message
import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader

REPO = Path(__file__).resolve().parents[1]
N_STEPS = 25
DT_S = 0.01


def observation(i: int) -> Observation:
    """Return a distinct, recognisable value per field and step."""
    t = i * DT_S
    return Observation(
        time_s=t,
        position_m=0.1 * i,
        velocity_m_s=0.01 * i,
        acceleration_m_s2=0.0,
        mantle_radius_m=0.05 + 1e-4 * i,
        volume_m3=1e-4 * (1 + i),
        fluid_mass_kg=0.1 * (1 + i),
        thrust_n=0.5 * i,
        added_mass_force_n=0.0,
        drag_n=-0.01 * i,
        jet_speed_m_s=0.0,
        cavity_pressure_pa=0.0,
        pump_flow_m3_s=1e-3,
        valve_opening=0.5,
    )


def write_run(path: Path, compression: str = 'zstd') -> None:
    """Every pulsejet topic, N_STEPS times, log time = simulation time (the offline-runner way)."""
    with BagWriter(path, compression=compression) as bag:
        for topic, type_name in messages.TOPIC_TYPES.items():
            bag.add_topic(topic, type_name)
        for i in range(N_STEPS):
            obs = observation(i)
            log_ns = messages.stamp_ns(obs.time_s)
            for topic, msg in messages.observation_messages(obs):
                bag.write(topic, serialize_message(msg), log_ns)
            for topic, msg in messages.command_messages(Command(1e-3 * i, 0.5, 2.0 * i)):
                bag.write(topic, serialize_message(msg), log_ns)
            bag.write(
                messages.TOPIC_MANTLE_PROFILE,
                serialize_message(
                    messages.profile_message([0.0, 0.01 * (1 + i)], [0.05, -0.05], obs.time_s)
                ),
                log_ns,
            )
            bag.write(
                messages.TOPIC_APPLIED_COMMAND,
                serialize_message(
                    messages.applied_command_message(Command(1e-3 * i, 0.5, 2.0 * i), obs.time_s)
                ),
                log_ns,
            )
            bag.write(
                messages.TOPIC_CMD_COMMAND,
                serialize_message(
                    messages.command_message(Command(1e-3 * i, 0.5, 2.0 * i), obs.time_s)
                ),
                log_ns,
            )
            ledger = {
                'stored_elastic': 0.25 * i,
                'in_actuation_work': 1.0 / 3.0,
                'closure_relative': 0.01 * i,
            }
            bag.write(
                'pulsejet/energy_ledger',
                serialize_message(messages.ledger_message(ledger, obs.time_s)),
                log_ns,
            )


@pytest.fixture(scope='module')
def run_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('bag') / 'run.mcap'
    write_run(path)
    return path


def test_rosbags_reads_names_types_counts(run_file: Path) -> None:
    with AnyReader([run_file]) as reader:
        found = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    expected = {
        (t if t.startswith('/') else '/' + t): (ty, N_STEPS)
        for t, ty in messages.TOPIC_TYPES.items()
    }
    assert found == expected


def test_rosbags_decodes_every_message_from_stored_definitions(run_file: Path) -> None:
    """
    Every message decodes with rosbags from the definitions stored in the file.

    AnyReader builds its types only from the definitions in the file, so decoding every
    message proves the definitions are complete (incl. Header and builtin_interfaces/Time).
    """
    values: dict[str, list] = {}
    with AnyReader([run_file]) as reader:
        assert {
            'std_msgs/msg/Header',
            'builtin_interfaces/msg/Time',
            'geometry_msgs/msg/Vector3',
            'diagnostic_msgs/msg/KeyValue',
        } <= set(reader.typestore.fielddefs)
        for conn, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            values.setdefault(conn.topic, []).append((log_ns, msg))
    for i in range(N_STEPS):
        obs = observation(i)
        log_ns, vel = values['/pulsejet/velocity'][i]
        assert log_ns == messages.stamp_ns(obs.time_s)
        assert vel.twist.linear.x == obs.velocity_m_s
        assert vel.header.frame_id == 'pulsejet/body'
        assert vel.header.stamp.sec * 10**9 + vel.header.stamp.nanosec == log_ns
        assert values['/pulsejet/thrust'][i][1].wrench.force.x == obs.thrust_n
        assert values['/pulsejet/mantle_radius'][i][1].data == obs.mantle_radius_m
        assert values['/pulsejet/volume'][i][1].data == obs.volume_m3
        assert values['/pulsejet/fluid_mass'][i][1].data == obs.fluid_mass_kg
        assert values['/pulsejet/cmd/cable_force'][i][1].data == 2.0 * i
        clock = values['/clock'][i][1].clock
        assert clock.sec * 10**9 + clock.nanosec == log_ns
        status = values['/pulsejet/energy_ledger'][i][1].status[0]
        assert status.name == 'pulsejet energy ledger'
        kv = {x.key: x.value for x in status.values}
        assert float(kv['in_actuation_work']) == 1.0 / 3.0  # repr keeps the exact float
        assert status.level == (0 if 0.01 * i <= 0.05 else 1)


def test_mcap_layout_matches_rosbag2(run_file: Path) -> None:
    with open(run_file, 'rb') as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == N_STEPS * len(
            messages.TOPIC_TYPES
        )
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
        for channel in summary.channels.values():
            assert set(channel.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {'zstd'}
        names = [m.name for m in reader.iter_metadata()]
        assert names == ['rosbag2']
    schema = next(
        s for s in summary.schemas.values() if s.name == 'geometry_msgs/msg/TwistStamped'
    )
    text = schema.data.decode()
    sep = '\n' + '=' * 80 + '\n'
    assert text.startswith(
        (msgdefs.find_share_dir('geometry_msgs') / 'msg/TwistStamped.msg').read_text()
    )
    assert [part.split('\n', 1)[0] for part in text.split(sep)[1:]] == [
        'MSG: geometry_msgs/Twist',
        'MSG: geometry_msgs/Vector3',
        'MSG: std_msgs/Header',
        'MSG: builtin_interfaces/Time',
    ]


def test_lz4_chunks_readable_by_rosbags(tmp_path: Path) -> None:
    path = tmp_path / 'lz4.mcap'
    write_run(path, compression='lz4')
    with AnyReader([path]) as reader:
        assert sum(1 for _ in reader.messages()) == N_STEPS * len(messages.TOPIC_TYPES)


def test_own_reader_and_series(run_file: Path) -> None:
    rows = list(read_bag(run_file, topics=['pulsejet/thrust']))
    assert [r[0] for r in rows] == ['/pulsejet/thrust'] * N_STEPS
    assert rows[3][1] == 'geometry_msgs/msg/WrenchStamped' and rows[3][3].wrench.force.x == 1.5
    series = load_series(run_file)
    t, v = series['/pulsejet/velocity']
    assert t[-1] == pytest.approx((N_STEPS - 1) * DT_S) and v[-1] == pytest.approx(
        0.01 * (N_STEPS - 1)
    )
    t, v = series['/pulsejet/volume']
    assert t[2] == pytest.approx(2 * DT_S) and v[2] == pytest.approx(3e-4)
    assert '/pulsejet/energy_ledger' not in series


def test_headerless_topics_mapped_to_sim_time_through_clock(tmp_path: Path) -> None:
    """A live recorder logs wall-clock receive times; /clock maps them onto simulation time."""
    path = tmp_path / 'live.mcap'
    wall0 = 1_700_000_000 * 10**9
    with BagWriter(path) as bag:
        for i in range(10):
            sim_s = 5.0 + 0.1 * i
            wall = wall0 + i * 50_000_000  # half real time: 0.05 s wall per 0.1 s sim
            write_message(
                bag, '/clock', messages.message_class('/clock')(clock=messages.stamp(sim_s)), wall
            )
            volume = messages.message_class('pulsejet/volume')(data=float(i))
            write_message(bag, 'pulsejet/volume', volume, wall + 25_000_000)
    t, v = load_series(path)['/pulsejet/volume']
    assert t[:9] == pytest.approx([5.05 + 0.1 * i for i in range(9)])


def test_stamp_rounding_and_ledger_levels() -> None:
    t = messages.stamp(1.9999999999)  # rounds up to the next second, not nanosec=1e9
    assert (t.sec, t.nanosec) == (2, 0)
    assert messages.stamp_ns(0.25) == 250_000_000
    with pytest.raises(ValueError, match='time_s=-1.0'):
        messages.stamp(-1.0)
    levels = {
        c: messages.ledger_message({'closure_relative': c}, 0.0).status[0].level
        for c in (0.0, 0.05, -0.051, float('nan'))
    }
    assert [levels[c] for c in (0.0, 0.05, -0.051)] == [b'\x00', b'\x00', b'\x01']
    assert list(levels.values())[-1] == b'\x01'  # not finite -> WARN
    ledger = {'in_actuation_work': 0.1 + 0.2, 'out_drag': 1e-17}
    assert messages.ledger_from_message(messages.ledger_message(ledger, 1.0)) == ledger


def test_writer_rejects_bad_use(tmp_path: Path) -> None:
    bag = BagWriter(tmp_path / 'bad.mcap')
    with pytest.raises(ValueError, match='std_msgs/Float64/x/y'):
        bag.add_topic('a', 'std_msgs/Float64/x/y')
    with pytest.raises(msgdefs.MessageDefinitionError, match='no_such_pkg'):
        bag.add_topic('a', 'no_such_pkg/msg/Thing')
    bag.add_topic('a', 'std_msgs/msg/Float64')
    with pytest.raises(BagError, match='already added'):
        bag.add_topic('a', 'std_msgs/msg/String')
    with pytest.raises(BagError, match="'/b' not added"):
        bag.write('b', b'', 0)
    with pytest.raises(BagError, match='log_time_ns=-1'):
        bag.write('a', b'', -1)
    bag.close()
    bag.close()  # idempotent
    with pytest.raises(BagError, match='closed'):
        bag.write('a', b'', 0)
    with pytest.raises(BagError, match='compression'):
        BagWriter(tmp_path / 'x.mcap', compression='gzip')


def test_reader_rejects_non_mcap(tmp_path: Path) -> None:
    junk = tmp_path / 'junk.mcap'
    junk.write_text('hello')
    with pytest.raises(BagReadError, match='junk.mcap.*not an MCAP'):
        list(read_bag(junk))
    with pytest.raises(BagReadError, match='no such file'):
        list(read_bag(tmp_path / 'missing.mcap'))


# --- crash safety: a child process writing when it gets a signal ---------------------------------

CHILD = textwrap.dedent("""
    import signal, sys, time
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64
    from pulsejet_sim.bag.writer import BagWriter, install_signal_handlers
    bag = BagWriter(sys.argv[1], chunk_size_bytes=4096, flush_period_s=0.2)
    # a background job of a non-interactive shell (CI) inherits SIGINT ignored:
    # ask for Python's own
    signal.signal(signal.SIGINT, signal.default_int_handler)
    install_signal_handlers(bag)
    bag.add_topic('pulsejet/volume', 'std_msgs/msg/Float64')
    i = 0
    try:
        while True:
            bag.write('pulsejet/volume', serialize_message(Float64(data=float(i))), 1000 + i)
            i += 1
            if i == 2000:
                bag.flush()          # the first 2000 are on disk whatever the scheduling
                print('ready', flush=True)
            if i > 2000:
                time.sleep(0.0002)
    except KeyboardInterrupt:
        print('interrupted', bag.message_counts['/pulsejet/volume'], bag.closed, flush=True)
""")


def start_child(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    path = tmp_path / 'child.mcap'
    script = tmp_path / 'child.py'
    script.write_text(CHILD)
    proc = subprocess.Popen(
        [sys.executable, str(script), str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout.readline().strip() == 'ready', proc.stderr.read()
    time.sleep(0.2)
    return proc, path


def rosbags_values(path: Path) -> list[float]:
    with AnyReader([path]) as reader:
        return [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()]


@pytest.mark.timeout(30)
def test_sigint_mid_write_leaves_complete_file(tmp_path: Path) -> None:
    proc, path = start_child(tmp_path)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    _, count, closed = out.split()
    values = rosbags_values(path)
    assert closed == 'True' and len(values) == int(count) > 2000
    assert values == [float(i) for i in range(len(values))]
    assert not bag_info(path).truncated


@pytest.mark.timeout(30)
def test_sigterm_mid_write_leaves_complete_file(tmp_path: Path) -> None:
    proc, path = start_child(tmp_path)
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=10)
    assert proc.returncode == -signal.SIGTERM  # still dies by the signal, as without the bag
    values = rosbags_values(path)
    assert len(values) > 2000 and values == [float(i) for i in range(len(values))]


@pytest.mark.timeout(30)
def test_hard_kill_loses_at_most_the_open_chunk_and_repairs(tmp_path: Path) -> None:
    proc, path = start_child(tmp_path)
    time.sleep(0.3)  # > flush_period_s: chunks are on disk
    proc.kill()
    proc.communicate(timeout=10)
    info = bag_info(path)
    assert info.truncated and info.counts['/pulsejet/volume'] > 2000
    fixed = repair(path)
    values = rosbags_values(fixed)
    assert len(values) == info.counts['/pulsejet/volume']
    assert values == [float(i) for i in range(len(values))]


def test_install_signal_handlers_restores_previous(tmp_path: Path) -> None:
    before = signal.getsignal(signal.SIGTERM)
    bag = BagWriter(tmp_path / 'r.mcap')
    restore = install_signal_handlers(bag)
    assert signal.getsignal(signal.SIGTERM) is not before
    restore()
    bag.close()
    assert signal.getsignal(signal.SIGTERM) == before
    assert os.path.getsize(tmp_path / 'r.mcap') > 0
