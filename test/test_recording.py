"""
The offline recording path: batched CDR records, the same messages, readable by rosbags and ours.

`pulsejet run` lays out a chunk of publications at a time with numpy (bag.publications) and
writes it with BagWriter.write_chunk; BagWriter.write_records appends a publication's bag.cdr
bytes to mcap's open chunk. These tests hold write_records and write_chunk to the file the public
per-message path writes, byte for byte, the runner's chunks to the messages of a write_records
call per publication, message for message, and the recording of both default scenes to what a
ROS reader and the project's reader decode, value for value against the physics.
"""

import datetime
from pathlib import Path
import types

import numpy as np
from pulsejet_sim.bag import cdr, writer as bag_writer
from pulsejet_sim.bag.reader import bag_info, read_bag
from pulsejet_sim.core.topics import TOPIC_TYPES
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import Drive, run_scene
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores


class _FixedClock(datetime.datetime):

    @classmethod
    def now(cls, tz=None):
        return datetime.datetime(2026, 1, 2, 3, 4, 5, 678901, tzinfo=tz)


@pytest.fixture
def fixed_close_time(monkeypatch):
    """Fix the rosbag2 metadata's closed_at, so two files written at different times compare."""
    monkeypatch.setattr(
        bag_writer, 'datetime',
        types.SimpleNamespace(datetime=_FixedClock, timezone=datetime.timezone),
    )


def runner_batches(name: str, duration_s: float):
    """(log time ns, [(topic, CDR)]) batches as the runner writes them for a scene."""
    encoder = cdr.TopicEncoder()
    drive = Drive(load_scene(name), duration_s)
    batches = []
    for start_s, command, obs in drive:
        batches.append((cdr.stamp_ns(start_s), encoder.commands(command)))
        ns = cdr.stamp_ns(obs.time_s)
        records = encoder.observation(obs, ns)
        profile = drive.sim.profile()
        if profile is not None:
            records.append((cdr.TOPIC_MANTLE_PROFILE, encoder.profile(*profile, ns)))
        records.append((cdr.TOPIC_ENERGY_LEDGER, encoder.ledger(drive.sim.energy_ledger(), ns)))
        batches.append((ns, records))
    return batches


def write_file(path: Path, batches, batched: bool, compression: str) -> bag_writer.BagWriter:
    # small chunks: several close in the middle of a batch
    with bag_writer.BagWriter(
        path, compression=compression, chunk_size_bytes=3000, flush_period_s=1e6
    ) as bag:
        bag.add_metadata('pulsejet', {'scene': 'test'})
        for ns, records in batches:
            if batched:
                bag.write_records(records, ns)
            else:
                for topic, data in records:
                    bag.add_topic(topic, TOPIC_TYPES[topic])
                    bag.write(topic, data, ns)
    return bag


@pytest.mark.parametrize('compression', ['zstd', 'none'])
def test_batched_records_write_the_file_per_message_writes_write(
    tmp_path, fixed_close_time, monkeypatch, compression
):
    batches = runner_batches('shell_robot', 0.3)
    per_message = tmp_path / 'per_message' / 'run.mcap'  # same name: rosbag2 metadata has it
    write_file(per_message, batches, batched=False, compression=compression)
    fast = tmp_path / 'fast' / 'run.mcap'
    bag = write_file(fast, batches, batched=True, compression=compression)
    assert bag._fast is not None  # the pinned mcap takes the fast path
    assert fast.read_bytes() == per_message.read_bytes()
    # and a library that does not look as expected takes the public path, same bytes
    monkeypatch.setattr(bag_writer._FastChunk, 'attach', classmethod(lambda cls, w, s: None))
    public = tmp_path / 'public' / 'run.mcap'
    bag = write_file(public, batches, batched=True, compression=compression)
    assert bag._fast is None
    assert public.read_bytes() == per_message.read_bytes()


def test_write_records_refuses_bad_input_with_the_value(tmp_path):
    with bag_writer.BagWriter(tmp_path / 'x.mcap') as bag:
        with pytest.raises(bag_writer.BagError, match='not a pulsejet topic'):
            bag.write_records([('no/such/topic', b'\x00\x01\x00\x00')], 0)
        with pytest.raises(bag_writer.BagError, match='log_time_ns=-1'):
            bag.write_records([(cdr.TOPIC_VOLUME, cdr.TopicEncoder().float64(1.0))], -1)
    with pytest.raises(bag_writer.BagError, match='closed'):
        bag.write_records([(cdr.TOPIC_VOLUME, cdr.TopicEncoder().float64(1.0))], 0)
    for level in (23, -101, 1.5, True, '1'):
        with pytest.raises(bag_writer.BagError, match=f'zstd_level={level!r} rejected'):
            bag_writer.BagWriter(tmp_path / 'y.mcap', zstd_level=level)


@pytest.mark.timeout(300)
@pytest.mark.parametrize('name', ['shell_robot', 'pump_cycle'])
def test_a_recorded_run_opens_in_rosbags_with_every_topic_and_matches_the_physics(
    tmp_path, name
):
    out = tmp_path / f'{name}.mcap'
    result = run_scene(load_scene(name), 0.5, out)
    assert result.fault is None
    store = get_typestore(Stores.ROS2_JAZZY)
    decoded: dict[str, list] = {}
    with AnyReader([out], default_typestore=store) as reader:
        types_ = {c.topic: c.msgtype for c in reader.connections}
        for conn, _, raw in reader.messages():
            decoded.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    expected = {('/' + t if not t.startswith('/') else t): TOPIC_TYPES[t]
                for t in cdr.RECORDED_TOPICS}
    assert types_ == expected
    assert all(decoded[t] for t in expected)
    # values: the same physics stepped without recording gives the recorded states, bit for bit
    observations = [obs for _, _, obs in Drive(load_scene(name), 0.5)]
    velocity = [m.twist.linear.x for m in decoded['/pulsejet/velocity']]
    assert velocity[1:] == [obs.velocity_m_s for obs in observations]
    volume = [m.data for m in decoded['/pulsejet/volume']]
    assert volume[1:] == [obs.volume_m3 for obs in observations]
    odom = decoded['/odom'][-1]
    assert odom.pose.pose.position.x == observations[-1].position_m
    assert odom.pose.pose.orientation.w == 1.0
    last = decoded['/pulsejet/mantle_profile'][-1].polygon.points
    r_m, z_m = result.sim.profile()
    assert np.array_equal([p.y for p in last], np.float32(r_m))
    assert np.array_equal([p.x for p in last], np.float32(z_m))
    ledger = decoded['/pulsejet/energy_ledger'][-1].status[0]
    assert {kv.key: float(kv.value) for kv in ledger.values} == result.sim.energy_ledger()
    # and the project's own reader decodes the same values
    info = bag_info(out)
    assert info.topics == expected and not info.damaged
    assert info.counts == {t: len(decoded[t]) for t in expected}
    own = [m.twist.linear.x for topic, _, _, m in read_bag(out) if topic == '/pulsejet/velocity']
    assert own == velocity
    # the rosbag2 metadata record (YAML in its JSON subset) reads as YAML: names, types, counts
    import yaml
    from mcap.reader import make_reader

    with open(out, 'rb') as fh:
        (record,) = [m for m in make_reader(fh).iter_metadata() if m.name == 'rosbag2']
    rosbag2 = yaml.safe_load(record.metadata['serialized_metadata'])['rosbag2_bagfile_information']
    assert rosbag2['version'] == 9 and rosbag2['storage_identifier'] == 'mcap'
    assert {t['topic_metadata']['name']: (t['topic_metadata']['type'], t['message_count'])
            for t in rosbag2['topics_with_message_count']} == {
        t: (expected[t], info.counts[t]) for t in expected}
    assert rosbag2['message_count'] == sum(info.counts.values())


def mcap_messages(path: Path) -> list[tuple]:
    """(topic, log time, publish time, sequence, bytes) of every message, in file order."""
    from mcap.reader import make_reader

    with open(path, 'rb') as fh:
        return [
            (channel.topic, m.log_time, m.publish_time, m.sequence, m.data)
            for _, channel, m in make_reader(fh).iter_messages(log_time_order=False)
        ]


def mcap_summary(path: Path):
    from mcap.reader import make_reader

    with open(path, 'rb') as fh:
        return make_reader(fh).get_summary()


@pytest.mark.timeout(300)
@pytest.mark.parametrize('name, duration_s', [('shell_robot', 4.0), ('pump_cycle', 3.0)])
def test_run_scene_records_the_messages_one_write_records_per_publication_writes(
    tmp_path, name, duration_s
):
    """
    The laid-out chunks (bag.publications) hold the per-message encoder's messages, in order.

    Same topics, log and publish times, sequences and bytes (TopicEncoder's, which test_cdr holds
    to rclpy's), the same schemas and channels; several chunks, each with its message indexes.
    """
    (tmp_path / 'a').mkdir()
    (tmp_path / 'b').mkdir()
    from benchmarks.performance.bench_recording import write_per_publication

    reference, recorded = tmp_path / 'a' / 'run.mcap', tmp_path / 'b' / 'run.mcap'
    write_per_publication(reference, name, duration_s)
    result = run_scene(load_scene(name), duration_s, recorded)
    expected = mcap_messages(reference)
    assert mcap_messages(recorded) == expected
    assert len(expected) > 11 * result.publications  # commands, state, profile; ledgers
    want, got = mcap_summary(reference), mcap_summary(recorded)
    assert got.schemas == want.schemas and got.channels == want.channels
    assert got.statistics.message_count == len(expected)
    assert got.statistics.channel_message_counts == want.statistics.channel_message_counts
    assert got.statistics.chunk_count > 1
    chunks = got.chunk_indexes
    assert [c.message_start_time for c in chunks] == sorted(c.message_start_time for c in chunks)
    assert all(c.compression == 'zstd' and c.message_index_offsets for c in chunks)
    # the message indexes point at every message (mcap's indexed reader goes through them)
    from mcap.reader import make_reader

    with open(recorded, 'rb') as fh:
        indexed = [
            (channel.topic, m.log_time, m.sequence, m.data)
            for _, channel, m in make_reader(fh).iter_messages(log_time_order=True)
        ]
    assert sorted(indexed, key=lambda m: (m[1], m[0], m[2])) == sorted(
        ((t, log, seq, data) for t, log, _, seq, data in expected),
        key=lambda m: (m[1], m[0], m[2]),
    )


def test_column_encoder_rows_are_the_per_message_bytes():
    rng = np.random.default_rng(7)
    n = 9
    times = np.sort(rng.uniform(0.0, 3e4, n))
    times[0] = 0.0
    ns = cdr.stamps_ns(times)
    assert ns.tolist() == [cdr.stamp_ns(t) for t in times]
    values = {f: rng.normal(size=n) * 10.0 ** rng.integers(-9, 3) for f in (
        'mantle_radius_m', 'volume_m3', 'velocity_m_s', 'thrust_n', 'fluid_mass_kg', 'position_m')}
    commands = np.abs(rng.normal(size=(n, 3)))
    r_m, z_m = rng.normal(size=(n, 13)), rng.normal(size=(n, 13))
    columns, per = cdr.ColumnEncoder(), cdr.TopicEncoder()
    state = dict(columns.state(ns, values))
    applied = columns.applied_commands(ns, commands)
    profiles = columns.profiles(ns, r_m, z_m)
    command_rows = dict(columns.commands(commands))
    for i in range(n):
        from pulsejet_sim.core.model_io import Command, Observation

        obs = Observation(**{**dict.fromkeys(Observation.__dataclass_fields__, 0.0),
                             **{k: float(v[i]) for k, v in values.items()},
                             'time_s': float(times[i])})
        for topic, data in per.observation(obs, int(ns[i])):
            assert state[topic][i].tobytes() == data, topic
        cmd = Command(*map(float, commands[i]))
        for topic, data in per.commands(cmd):
            assert command_rows[topic][i].tobytes() == data, topic
        assert applied[i].tobytes() == per.applied_command(cmd, int(ns[i]))
        assert profiles[i].tobytes() == per.profile(r_m[i], z_m[i], int(ns[i]))
    with pytest.raises(ValueError, match='time_s=-1.0'):
        cdr.stamps_ns([0.0, -1.0])
    with pytest.raises(ValueError, match='allowed: two'):
        columns.profiles(ns[:2], r_m[:2], z_m[:3])


CHILD_RUN = """
import sys
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies import runner

runner._RunColumns.PUBLICATIONS_PER_CHUNK = 10**5  # none reach the writer before close
count = 0
iterate = runner.Drive.__iter__


def counted(self):
    global count
    for item in iterate(self):
        count += 1
        if count == 200:
            print('running', flush=True)
        yield item


runner.Drive.__iter__ = counted
try:
    runner.run_scene(load_scene('shell_robot'), 1e5, sys.argv[1])
except KeyboardInterrupt:
    print(count, flush=True)
"""


@pytest.mark.timeout(120)
def test_ctrl_c_mid_run_writes_every_publication_collected(tmp_path):
    """The messages still held as columns are handed over when a signal closes the file."""
    import signal
    import subprocess
    import sys

    script = tmp_path / 'child.py'
    script.write_text(CHILD_RUN)
    out = tmp_path / 'run.mcap'
    # the child takes SIGINT as a terminal's Ctrl-C does: a suite started as a background job
    # (nohup make test &) passes SIGINT on ignored, and the writer leaves an ignored signal alone
    proc = subprocess.Popen(
        [sys.executable, str(script), str(out)], stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[1],
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.stdout.readline().strip() == 'running', proc.stderr.read()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    count = int(stdout.split()[-1])
    info = bag_info(out)
    assert not info.damaged and not info.truncated
    states = {info.counts[f'/{t}' if not t.startswith('/') else t] for t in cdr.STATE_TOPICS}
    assert len(states) == 1  # whole publications
    (state_count,) = states
    assert state_count >= count >= 200  # the initial state and every publication yielded
    assert info.counts['/pulsejet/cmd/cable_force'] in (state_count - 1, state_count)


def write_layout_file(out: Path, compression: str, zstd_level: int = 1) -> tuple[list, list]:
    """
    Write 12 publications of every kind with bag.publications + write_chunk, in two chunks.

    Publications without commands (the initial state), with the applied command (the first and
    on a change), with a ledger. Returns the (topic, log time, bytes) TopicEncoder writes for them
    and the applied commands' positions.
    """
    from pulsejet_sim.bag.publications import PublicationLayout, STATE_FIELDS, STATE_ORDER
    from pulsejet_sim.core.model_io import Command, Observation
    from pulsejet_sim.core.topics import (
        COMMAND_TOPICS, TOPIC_APPLIED_COMMAND, TOPIC_ENERGY_LEDGER, TOPIC_MANTLE_PROFILE,
    )

    rng = np.random.default_rng(3)
    n, points = 12, 5
    times = np.arange(n) * 0.01 + 0.01
    commands = np.abs(rng.normal(size=(n, 3)))
    commands[4] = commands[3]  # held: no applied command at row 4
    commands[:, 1] = 1.0
    states = rng.normal(size=(n, len(STATE_FIELDS)))
    r_m, z_m = rng.normal(size=(n, points)), rng.normal(size=(n, points))
    command_ns = cdr.stamps_ns(times - 0.01)
    command_ns[0] = -1  # the initial state: no commands
    state_ns = cdr.stamps_ns(times)
    encoder = cdr.TopicEncoder()
    ledgers = {row: encoder.ledger({'stored_elastic': float(row), 'closure_relative': 0.0},
                                   int(state_ns[row])) for row in (0, 5, 11)}
    applied = np.ones(n, dtype=bool)
    applied[4] = False
    with bag_writer.BagWriter(out, compression=compression, zstd_level=zstd_level) as bag:
        bag.add_metadata('pulsejet', {'scene': 'test'})
        topics = [*STATE_ORDER, TOPIC_MANTLE_PROFILE, TOPIC_ENERGY_LEDGER, *COMMAND_TOPICS,
                  TOPIC_APPLIED_COMMAND]
        layout = PublicationLayout(bag.channel_ids(topics), points, encoder)
        for part in (slice(0, 7), slice(7, n)):
            rows = range(n)[part]
            stretch = layout.records(
                command_ns[part], commands[part], applied[part], state_ns[part], states[part],
                (r_m[part], z_m[part]),
                {row - rows.start: data for row, data in ledgers.items() if row in rows},
            )
            layout.counts = stretch.counts
            bag.write_chunk(stretch)
    expected = []
    for i in range(n):
        if command_ns[i] >= 0:
            cmd = Command(*map(float, commands[i]))
            ns = int(command_ns[i])
            expected += [(t, ns, data) for t, data in encoder.commands(cmd)]
            if applied[i]:
                expected.append((TOPIC_APPLIED_COMMAND, ns, encoder.applied_command(cmd, ns)))
        obs = Observation(**{**dict.fromkeys(Observation.__dataclass_fields__, 0.0),
                             **dict(zip(STATE_FIELDS, map(float, states[i]))),
                             'time_s': float(times[i])})
        ns = int(state_ns[i])
        expected += [(t, ns, data) for t, data in encoder.observation(obs, ns)]
        expected.append((TOPIC_MANTLE_PROFILE, ns, encoder.profile(r_m[i], z_m[i], ns)))
        if i in ledgers:
            expected.append((TOPIC_ENERGY_LEDGER, ns, ledgers[i]))
    positions = [list(commands[i]) for i in range(n) if command_ns[i] >= 0 and applied[i]]
    return expected, positions


@pytest.mark.parametrize('compression, fast', [('zstd', True), ('lz4', True), ('none', True),
                                               ('zstd', False)])
def test_publication_layout_writes_the_per_message_encoders_bytes(
    tmp_path, monkeypatch, compression, fast
):
    """bag.publications + write_chunk: each message the bytes TopicEncoder writes, read back."""
    from pulsejet_sim.core.topics import APPLIED_COMMAND_NAMES

    if not fast:
        monkeypatch.setattr(bag_writer._FastChunk, 'attach', classmethod(lambda c, w, s: None))
    out = tmp_path / 'layout.mcap'
    expected, applied = write_layout_file(out, compression)
    got = mcap_messages(out)
    assert [(t, log, data) for t, log, _, _, data in got] == [
        ('/' + t if not t.startswith('/') else t, ns, data) for t, ns, data in expected]
    sequences: dict[str, int] = {}
    for topic, log, publish, sequence, _ in got:
        sequences[topic] = sequences.get(topic, 0) + 1
        assert sequence == sequences[topic] and publish == log
    summary = mcap_summary(out)
    assert summary.statistics.chunk_count == 2
    with AnyReader([out], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        decoded = [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in
                   reader.messages()]
    assert len(decoded) == len(expected)
    positions = [list(m.position) for t, m in decoded if t == '/pulsejet/applied_command']
    assert positions == applied and len(applied) == 10  # 11 with commands, one of them held
    assert APPLIED_COMMAND_NAMES == ('pump_flow_m3_s', 'valve_opening', 'cable_force_n')


# mcap's writer compresses a chunk with zstandard.compress (level 3) and lz4.frame.compress
@pytest.mark.parametrize('compression, zstd_level', [('zstd', 3), ('lz4', 1), ('none', 1)])
def test_write_chunk_writes_the_file_mcaps_writer_writes(
    tmp_path, fixed_close_time, monkeypatch, compression, zstd_level
):
    """
    write_chunk's chunk, message indexes, chunk index and statistics, byte for byte.

    Against the same records through mcap's add_message and a flush after each stretch (the
    writer's path for an mcap library that does not look as expected): the same file.
    """
    fast = tmp_path / 'fast' / 'run.mcap'  # same name: the rosbag2 metadata has it
    write_layout_file(fast, compression, zstd_level)
    monkeypatch.setattr(bag_writer._FastChunk, 'attach', classmethod(lambda c, w, s: None))
    public = tmp_path / 'public' / 'run.mcap'
    write_layout_file(public, compression, zstd_level)
    assert mcap_summary(fast).statistics.chunk_count == 2
    assert fast.read_bytes() == public.read_bytes()
