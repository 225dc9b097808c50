"""
Truncated and corrupted MCAP recordings: a clear error or what can be read.

Truncated and corrupted MCAP recordings into the reader, `pulsejet summary`, `plot`, `resim` and
replay's file loading (hypothesis): a clear error or the part that can be read, never a hang, never
a traceback.

The recording and the `check_*` properties are in benchmarks/reliability/recording_damage.py,
which benchmarks/reliability/reliability_table.py also runs at a larger example count.
"""

from __future__ import annotations

from pathlib import Path

from benchmarks.reliability.recording_damage import (
    check_corruption,
    check_tools,
    check_truncation,
    corrupt,
    FUZZ,
    make_recording,
    read_messages,
    Recording,
    run_quietly,
)
from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from pulsejet_sim import analysis
from pulsejet_sim.bag.reader import BagReadError
from pulsejet_sim.studies import resim
import pytest


@pytest.fixture(scope='module')
def recording(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    return Recording(make_recording(tmp_path_factory.mktemp('corrupt') / 'run.mcap'))


@pytest.mark.timeout(180)
@FUZZ
@given(fraction=st.floats(min_value=0.0, max_value=1.0), tools=st.booleans())
def test_truncated_file_reads_complete_chunks(
    recording: Recording, fraction: float, tools: bool, tmp_path_factory
) -> None:
    cut = int(fraction * len(recording.data))
    check_truncation(recording, cut, tmp_path_factory.mktemp('cut'), tools=tools)


@pytest.mark.timeout(60)
def test_every_chunk_boundary(recording: Recording, tmp_path: Path) -> None:
    for k, end in enumerate(recording.chunk_ends[:12], start=1):
        for cut in (end - 1, end, end + 5):
            check_truncation(recording, cut, tmp_path, tools=False)


@pytest.mark.timeout(180)
@FUZZ
@given(
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(['flip', 'overwrite', 'zero', 'length', 'insert', 'delete']),
    tools=st.booleans(),
)
def test_corrupted_file_gives_clear_error_or_readable_part(
    recording: Recording, seed: int, kind: str, tools: bool, tmp_path_factory
) -> None:
    check_corruption(recording, seed, kind, tmp_path_factory.mktemp('bad'), tools=tools)


@pytest.mark.timeout(120)
@settings(
    max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(['flip', 'overwrite', 'length']))
def test_plot_of_damaged_file(
    recording: Recording, seed: int, kind: str, tmp_path_factory
) -> None:
    path = tmp_path_factory.mktemp('plot') / 'bad.mcap'
    path.write_bytes(corrupt(recording.data, seed, kind))
    outcomes = check_tools(path, plot=True)
    assert outcomes['plot'] in ('ok', 'refused')


@pytest.mark.parametrize(
    'content, expected',
    [
        (b'', 'empty file'),
        (b'\x89MC', 'cut short'),
        (b'\x89MCAP1\r\n' + b'\0' * 40, "major version '1'"),
        (b'PK\x03\x04zipfile', 'not an MCAP file'),
        (b'\x89MCAP0\r\n', 'no readable'),
    ],
)
def test_tiny_and_foreign_files_are_refused_clearly(
    tmp_path: Path, content: bytes, expected: str
) -> None:
    path = tmp_path / 'x.mcap'
    path.write_bytes(content)
    if expected == 'no readable':
        messages, info = read_messages(path)
        assert messages == [] and info.truncated
        code, _, err = run_quietly(analysis.main_summary, [str(path)])
        assert code == 2 and 'no pulsejet topics' in err
        return
    with pytest.raises(BagReadError, match=expected):
        read_messages(path)
    for main in (analysis.main_summary, resim.main_resim):
        code, _, err = run_quietly(main, [str(path)])
        assert code == 2 and expected in err, err


def test_damage_is_reported_by_summary(recording: Recording, tmp_path: Path) -> None:
    path = tmp_path / 'cut.mcap'
    cut = recording.chunk_ends[len(recording.chunk_ends) // 2] + 100
    path.write_bytes(recording.data[:cut])
    code, out, _ = run_quietly(analysis.main_summary, [str(path)])
    assert code == 0
    messages, info = read_messages(path)
    assert f'{len(messages)} messages recovered' in out
    assert f'{len(recording.data[:cut]) - info.valid_bytes} of {cut} bytes dropped' in out
    assert 'log time 0 s to' in out and 'pulsejet repair' in out
