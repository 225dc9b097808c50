"""
The offline recording path: batched CDR records, the same file, readable by rosbags and our reader.

`pulsejet run` writes bag.cdr bytes through BagWriter.write_records (one lock per batch, the
Message records appended to mcap's open chunk directly). These tests hold that path to the file
the public per-message path writes, byte for byte, and the recording of both default scenes to
what a ROS reader and the project's reader decode, value for value against the physics.
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
