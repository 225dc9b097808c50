"""
Re-simulation of recordings from their applied commands.

Bit-identical for `pulsejet run` files, and a perturbed command is detected.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from pulsejet_sim.bag import BagInfo, BagWriter, iter_bag
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.resim import (
    main_resim,
    read_applied_commands,
    read_recorded_states,
    ResimError,
    resimulate,
)
from pulsejet_sim.studies.runner import run_scene
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

DURATION_S = 5.0
TOPICS = ('pulsejet/velocity', 'pulsejet/volume', 'pulsejet/mantle_radius')


@pytest.fixture(scope='module')
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('resim') / 'pump_cycle.mcap'
    result = run_scene(load_scene('pump_cycle'), DURATION_S, path)
    assert result.fault is None
    return path


def rewrite(
    src: Path,
    dst: Path,
    transform: Callable[[str, int, bytes], tuple[int, bytes]],
    metadata: dict[str, str] | None = None,
    keep: Callable[[str, int], bool] = lambda topic, index: True,
) -> Path:
    """
    Copy a recording message by message through transform.

    transform(topic, log_ns, cdr) -> (log_ns, cdr); keep(topic, index within the topic) -> bool.
    """
    info = BagInfo(src)
    msgs = list(iter_bag(src, info=info, decode=False))
    with BagWriter(dst) as bag:
        for topic, type_name in info.topics.items():
            bag.add_topic(topic, type_name, definition=info.definitions[type_name])
        seen: dict[str, int] = {}
        for m in msgs:
            index = seen[m.topic] = seen.get(m.topic, -1) + 1
            if not keep(m.topic, index):
                continue
            log_ns, cdr = transform(m.topic, m.log_time_ns, m.msg)
            bag.write(m.topic, cdr, log_ns)
        if metadata:
            bag.add_metadata('pulsejet', metadata)
    return dst


def test_runner_recording_resimulates_bit_identically(recording: Path) -> None:
    result = resimulate(recording, 'pump_cycle')
    assert set(result.topics) == set(TOPICS)
    for topic in TOPICS:
        comparison = result.topics[topic]
        assert comparison.recorded == comparison.compared == int(DURATION_S * 100) + 1
        assert comparison.max_abs_error == 0.0, (topic, comparison)
    assert result.max_error == 0.0 and result.bit_identical and result.fault is None
    assert result.time_source == 'log time'
    assert result.steps == int(round(DURATION_S / result.dt_s))
    assert len(result.commands) >= 3  # inflate, hold, jet within 5 s: the commands do change
    assert not result.warnings
    # a Scene object works the same
    assert resimulate(recording, load_scene('pump_cycle')).bit_identical


def test_perturbed_command_list_is_detected(recording: Path) -> None:
    commands = read_applied_commands(recording)
    assert commands[0][0] == 0.0
    i = 1  # the second command (hold or jet)
    t, cmd = commands[i]
    perturbed = list(commands)
    perturbed[i] = (
        t,
        dataclasses.replace(
            cmd,
            valve_opening=min(1.0, cmd.valve_opening + 0.05) if cmd.valve_opening < 1.0 else 0.95,
        ),
    )
    result = resimulate(recording, 'pump_cycle', commands=perturbed)
    assert result.max_error > 0.0 and not result.bit_identical
    assert result.topics['pulsejet/velocity'].max_abs_error > 0.0
    assert result.topics['pulsejet/velocity'].worst_time_s >= t
    # held one step late
    shifted = list(commands)
    shifted[i] = (t + result.dt_s, cmd)
    assert resimulate(recording, 'pump_cycle', commands=shifted).max_error > 0.0


def test_perturbed_bag_is_detected_and_cli_exit_codes(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    seen = []

    def bump_first_pump_flow(topic: str, log_ns: int, cdr: bytes) -> tuple[int, bytes]:
        if topic == '/pulsejet/applied_command' and not seen:
            msg = deserialize_message(cdr, JointState)
            msg.position = [msg.position[0] * 1.001, *msg.position[1:]]
            seen.append(msg)
            cdr = serialize_message(msg)
        return log_ns, cdr

    modified = rewrite(recording, tmp_path / 'modified.mcap', bump_first_pump_flow)
    assert seen and seen[0].position[0] > 0.0

    result = resimulate(modified, 'pump_cycle')
    assert all(result.topics[t].max_abs_error > 0.0 for t in TOPICS)

    assert main_resim([str(recording), '--scene', 'pump_cycle']) == 0
    out = capsys.readouterr().out
    assert 'OK, bit-identical' in out and 'pulsejet/velocity' in out
    assert main_resim([str(modified), '--scene', 'pump_cycle']) == 1
    assert 'MISMATCH' in capsys.readouterr().out
    big = result.max_error * 2
    assert main_resim([str(modified), '--scene', 'pump_cycle', '--tolerance', repr(big)]) == 0
    assert main_resim([str(recording)]) == 0  # the runner stored its scene
    capsys.readouterr()
    anonymous = rewrite(recording, tmp_path / 'anonymous.mcap', lambda topic, ns, cdr: (ns, cdr))
    assert main_resim([str(anonymous)]) == 2  # this copy does not name its scene
    assert 'does not name its scene' in capsys.readouterr().err
    assert main_resim([str(tmp_path / 'missing.mcap'), '--scene', 'pump_cycle']) == 2
    assert main_resim([str(recording), '--scene', 'no_such_scene']) == 2
    with pytest.raises(SystemExit) as exit_info:
        main_resim([str(recording), '--scene', 'pump_cycle', '--tolerance', '-1'])
    assert exit_info.value.code == 2

    # --out writes the re-simulated run; it re-simulates bit-identically itself
    out_path = tmp_path / 'resim.mcap'
    assert main_resim([str(recording), '--scene', 'pump_cycle', '--out', str(out_path)]) == 0
    recorded = read_recorded_states(recording).values
    assert read_recorded_states(out_path).values == recorded
    assert resimulate(out_path, 'pump_cycle').bit_identical


def test_live_style_recording_with_receive_times_and_stored_scene(
    recording: Path, tmp_path: Path
) -> None:
    """
    A live-style recording: states placed through /clock, the stored scene used.

    Log times = wall-clock receive times (as the recorder writes them, with jitter): Float64 states
    are placed through /clock, and the scene named in the file's metadata is used.
    """
    epoch_ns = 1_764_000_000_000_000_000
    counter = [0]

    def receive_time(topic: str, log_ns: int, cdr: bytes) -> tuple[int, bytes]:
        counter[0] += 1
        return (
            epoch_ns + log_ns + 200_000 + (counter[0] * 7919) % 3_000_000,
            cdr,
        )  # 0.2 .. 3.2 ms late

    live = rewrite(
        recording, tmp_path / 'live.mcap', receive_time, metadata={'scene': 'pump_cycle'}
    )
    result = resimulate(live)
    assert result.scene_name == 'pump_cycle'
    assert result.time_source == 'publication order'  # every state there: k-th is k-th
    assert result.bit_identical, result.format_table()

    # one volume lost: that topic is placed through /clock instead, still on the right states
    gap = rewrite(
        live,
        tmp_path / 'gap.mcap',
        lambda topic, ns, cdr: (ns, cdr),
        metadata={'scene': 'pump_cycle'},
        keep=lambda topic, index: not (topic == '/pulsejet/volume' and index == 3),
    )
    result = resimulate(gap)
    assert result.time_source == 'clock-mapped and publication order'
    assert result.topics['pulsejet/volume'].compared == int(DURATION_S * 100)
    assert result.topics['pulsejet/volume'].max_abs_error == 0.0, result.format_table()


def test_live_recording_states_placed_by_publication_order(
    recording: Path, tmp_path: Path
) -> None:
    """
    Float64 states received 1.5 periods late are still the right states (a fast live run).

    Receive times then name the wrong observation through /clock; publication order does not.
    """

    def late_floats(topic: str, log_ns: int, cdr: bytes) -> tuple[int, bytes]:
        late = 15_000_000 if topic in ('/pulsejet/volume', '/pulsejet/mantle_radius') else 0
        return 1_764_000_000_000_000_000 + log_ns + late, cdr

    live = rewrite(recording, tmp_path / 'late.mcap', late_floats)
    result = resimulate(live, 'pump_cycle')
    assert result.time_source == 'publication order'
    assert result.bit_identical, result.format_table()


def test_missing_applied_commands_is_an_error(recording: Path, tmp_path: Path) -> None:
    info = BagInfo(recording)
    msgs = [
        m
        for m in iter_bag(recording, info=info, decode=False)
        if m.topic != '/pulsejet/applied_command'
    ]
    stripped = tmp_path / 'no_commands.mcap'
    with BagWriter(stripped) as bag:
        for topic, type_name in info.topics.items():
            if topic != '/pulsejet/applied_command':
                bag.add_topic(topic, type_name, definition=info.definitions[type_name])
        for m in msgs:
            bag.write(m.topic, m.msg, m.log_time_ns)
    with pytest.raises(ResimError, match='applied_command'):
        resimulate(stripped, 'pump_cycle')
