"""
Hard kills (SIGKILL) of a process writing a recording, and `pulsejet repair`.

- a writer process (BagWriter with the recorder's QoS metadata and a `pulsejet` metadata record)
  killed mid-write: the project's reader reads the file up to its last complete chunk, losing at
  most the messages of the last flush period; `pulsejet repair` writes a file rosbags reads
  (rosbags.rosbag2.Reader and AnyReader on the repaired .mcap) with every channel's metadata
  (offered_qos_profiles, topic_type_hash) and the metadata records preserved; `pulsejet summary`
  says what was cut (messages recovered, time span, bytes dropped);
- an idle writer (no message after a burst) killed: the background flush put everything on disk;
- the offline runner (`pulsejet run`) killed mid-run: repaired, and `pulsejet resim` re-simulates
  the repaired file bit-identically.
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess
import sys
import time

from benchmarks.reliability.killed_writer import channel_metadata, FLUSH_S, start_writer
from mcap.reader import make_reader
from pulsejet_sim.bag.reader import bag_info, BagReadError, read_metadata
from pulsejet_sim.bag.repair import repair_file
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader

REPO = Path(__file__).resolve().parents[1]


def pulsejet(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'pulsejet_sim.cli', *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.timeout(60)
def test_sigkill_mid_write_then_repair_keeps_data_and_metadata(tmp_path: Path) -> None:
    proc, path = start_writer(tmp_path, 'busy')
    time.sleep(1.0)
    kill_time = time.monotonic()
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=10)
    assert proc.returncode == -signal.SIGKILL

    # the damaged file: refused by the indexed readers, read by ours up to the last complete chunk
    with pytest.raises(Exception):
        with AnyReader([path]) as reader:
            list(reader.messages())
    info = bag_info(path)
    assert info.truncated and info.bytes_dropped >= 0
    n = info.counts['/pulsejet/volume']
    assert n > 500
    from pulsejet_sim.bag.reader import iter_bag

    stamps = [m.msg.data for m in iter_bag(path, topics=['pulsejet/volume'])]
    assert stamps == sorted(stamps) and len(stamps) == n
    lost_s = kill_time - stamps[-1]
    assert (
        lost_s <= FLUSH_S + 0.15
    ), f'{lost_s:.3f} s of messages lost; allowed: one flush period ({FLUSH_S} s)'
    assert read_metadata(path, 'pulsejet') == {'scene': 'escape', 'note': 'killed on purpose'}

    # `pulsejet summary` says what was cut
    summary = pulsejet('summary', str(path))
    assert summary.returncode == 0, summary.stderr
    total = sum(info.counts.values())
    assert f'{total} messages recovered' in summary.stdout
    assert f'{info.bytes_dropped} of {info.file_size} bytes dropped' in summary.stdout
    assert 'log time 0 s to' in summary.stdout

    # `pulsejet repair FILE`
    done = pulsejet('repair', str(path))
    assert done.returncode == 0, done.stderr
    fixed = path.with_name('killed.repaired.mcap')
    assert f'{total} messages' in done.stdout and str(fixed) in done.stdout
    assert pulsejet('repair', str(path)).returncode == 2  # will not overwrite without --force

    original = info.channel_metadata
    assert channel_metadata(fixed) == original
    assert original['/pulsejet/volume']['offered_qos_profiles'].startswith('- history: keep_last')
    assert original['/pulsejet/volume']['topic_type_hash'].startswith('RIHS01_')
    with Reader(fixed) as reader:
        assert reader.message_count == total
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        assert (
            qos['/pulsejet/volume'][0].depth == 1000
            and qos['/pulsejet/volume'][0].reliability.name == 'RELIABLE'
        )
        assert qos['/clock'][0].reliability.name == 'BEST_EFFORT'
    with AnyReader([fixed]) as reader:
        values = [
            reader.deserialize(raw, c.msgtype).data
            for c, _, raw in reader.messages()
            if c.topic == '/pulsejet/volume'
        ]
    assert values == stamps
    with open(fixed, 'rb') as fh:
        names = [m.name for m in make_reader(fh).iter_metadata()]
    assert sorted(names) == ['pulsejet', 'rosbag2']
    assert read_metadata(fixed, 'pulsejet') == {'scene': 'escape', 'note': 'killed on purpose'}
    assert not bag_info(fixed).damaged


@pytest.mark.timeout(60)
def test_sigkill_of_idle_writer_loses_nothing(tmp_path: Path) -> None:
    proc, path = start_writer(tmp_path, 'idle')
    assert proc.stdout.readline().strip() == 'idle'
    time.sleep(FLUSH_S + 0.3)  # the background flusher closes the open chunk
    proc.kill()
    proc.communicate(timeout=10)
    info = bag_info(path)
    assert (
        info.truncated and info.counts['/pulsejet/volume'] == 1000 and info.counts['/clock'] == 100
    )
    result = repair_file(path)
    assert result.messages == 1100 and not bag_info(result.out_path).damaged


@pytest.mark.timeout(120)
def test_killed_offline_run_repairs_and_resimulates_bit_identically(tmp_path: Path) -> None:
    out = tmp_path / 'run.mcap'
    proc = subprocess.Popen(
        [
            sys.executable,
            '-m',
            'pulsejet_sim.cli',
            'run',
            'escape',
            '--duration',
            '100000',
            '--out',
            str(out),
            '--no-plot',
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while (not out.exists() or out.stat().st_size < 20_000) and time.monotonic() < deadline:
        assert proc.poll() is None, proc.stderr.read()
        time.sleep(0.1)
    time.sleep(1.2)  # > the runner's flush period: several chunks on disk
    proc.kill()
    proc.communicate(timeout=10)
    info = bag_info(out)
    assert info.truncated and info.counts.get('/pulsejet/velocity', 0) > 50
    done = pulsejet('repair', str(out), '--out', str(tmp_path / 'fixed.mcap'))
    assert done.returncode == 0, done.stderr
    assert 'pulsejet' in dict(bag_info(tmp_path / 'fixed.mcap').metadata)
    again = pulsejet('resim', str(tmp_path / 'fixed.mcap'), timeout=120)
    assert again.returncode == 0, again.stdout + again.stderr
    assert 'OK, bit-identical' in again.stdout


def test_repair_refuses_bad_input(tmp_path: Path) -> None:
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'not an mcap at all')
    done = pulsejet('repair', str(junk))
    assert (
        done.returncode == 2
        and 'not an MCAP file' in done.stderr
        and 'Traceback' not in done.stderr
    )
    missing = pulsejet('repair', str(tmp_path / 'missing.mcap'))
    assert missing.returncode == 2 and 'no such file' in missing.stderr
    with pytest.raises(BagReadError, match='other than the input'):
        repair_file(junk, junk)


@pytest.mark.timeout(90)
def test_real_recorder_sigkilled_then_repaired(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """
    A recorder killed with SIGKILL has flushed its messages; repair keeps the QoS.

    The recorder node as a process over DDS, killed with SIGKILL after the messages arrived: an
    idle recorder has flushed them within its flush period; the repaired file keeps the QoS its
    publishers offered.
    """
    from test_recorder import domain_id, N_STEPS, Publisher, start_recorder

    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    domain = domain_id(7)
    topics = ['pulsejet/velocity', 'pulsejet/volume']
    proc, out = start_recorder(tmp_path, domain, topics)
    pub = Publisher(domain, topics)
    try:
        pub.wait_matched()
        pub.publish_run()
        time.sleep(1.0 + 0.8)  # the recorder's flush period (1 s) and some slack
    finally:
        pub.close()
        proc.kill()
        proc.communicate(timeout=15)
    info = bag_info(out)
    assert info.truncated and info.counts == {
        '/pulsejet/velocity': N_STEPS,
        '/pulsejet/volume': N_STEPS,
    }
    qos = info.channel_metadata['/pulsejet/volume']['offered_qos_profiles']
    assert (
        qos.startswith('- history:') and 'reliability: reliable' in qos
    )  # DDS does not carry the depth
    done = pulsejet('repair', str(out))
    assert done.returncode == 0, done.stderr
    fixed = out.with_name('rec.repaired.mcap')
    assert channel_metadata(fixed) == info.channel_metadata
    with Reader(fixed) as reader:
        assert reader.message_count == 2 * N_STEPS
        assert all(
            c.ext.offered_qos_profiles[0].reliability.name == 'RELIABLE'
            for c in reader.connections
        )
