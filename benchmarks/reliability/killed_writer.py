"""
A process writing a recording, to be killed (SIGKILL) mid-write or idle; its channels read back.

The writer is a BagWriter with the recorder's QoS metadata and a `pulsejet` metadata record,
flushing every FLUSH_S; it prints `ready` after 500 messages (and, in `idle` mode, `idle` after
1000, then sleeps). test/test_repair.py and benchmarks/reliability/reliability_table.py kill it.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys
import textwrap

from mcap.reader import make_reader

REPO = Path(__file__).resolve().parents[2]
FLUSH_S = 0.25

WRITER = textwrap.dedent("""
    import sys, time
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64
    from rosgraph_msgs.msg import Clock
    from pulsejet_sim.bag.writer import BagWriter, qos_profiles_yaml
    from pulsejet_sim.ros.messages import reliable_qos
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    path, mode, flush = sys.argv[1], sys.argv[2], float(sys.argv[3])
    # chunks close by age only
    bag = BagWriter(path, chunk_size_bytes=1 << 20, flush_period_s=flush)
    bag.add_metadata('pulsejet', {'scene': 'escape', 'note': 'killed on purpose'})
    bag.add_topic(
        'pulsejet/volume', 'std_msgs/msg/Float64',
        qos_profiles_yaml([reliable_qos('pulsejet/volume', 1000)]),
    )
    # a best-effort clock publisher (as a bag player's)
    bag.add_topic(
        '/clock', 'rosgraph_msgs/msg/Clock',
        qos_profiles_yaml([QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)]),
    )
    i = 0
    while True:
        # system-wide clock: the parent compares it with its kill time
        now = time.monotonic()
        bag.write('pulsejet/volume', serialize_message(Float64(data=now)), 1_000_000 * i)
        if i % 10 == 0:
            bag.write('/clock', serialize_message(Clock()), 1_000_000 * i)
        i += 1
        if i == 500:
            print('ready', flush=True)
        if mode == 'idle' and i >= 1000:
            print('idle', flush=True)
            time.sleep(3600)
        time.sleep(0.0005)
""")


def start_writer(tmp_path: Path, mode: str) -> tuple[subprocess.Popen, Path]:
    path = tmp_path / 'killed.mcap'
    script = tmp_path / 'writer.py'
    script.write_text(WRITER)
    proc = subprocess.Popen(
        [sys.executable, str(script), str(path), mode, str(FLUSH_S)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().strip() == 'ready', proc.stderr.read()
    return proc, path


def channel_metadata(path: Path) -> dict[str, dict[str, str]]:
    with open(path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    return {c.topic: dict(c.metadata) for c in summary.channels.values()}
