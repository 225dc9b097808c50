"""
Damaged MCAP recordings and the checks that every file consumer handles them.

A real offline run (`escape`, the scene stored in the file so `resim` needs nothing else) written
in small chunks, so that a cut or a flipped byte lands in one of many chunks; truncation and
corruption of it; `check_*` functions that feed the damaged file to the reader, `pulsejet
summary`, `plot`, `resim` and replay's file loading and assert a clear error or the part that can
be read, never a hang or a traceback, returning an outcome label. test/test_mcap_corruption.py
runs them under hypothesis; benchmarks/reliability/reliability_table.py at a larger count.
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path
import random

from hypothesis import HealthCheck, settings
from pulsejet_sim import analysis
from pulsejet_sim.bag.reader import BagInfo, BagReadError, iter_bag
from pulsejet_sim.ros import replay
from pulsejet_sim.studies import resim

EXAMPLES = int(os.environ.get('PULSEJET_FUZZ_EXAMPLES', '40'))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
CHUNK_BYTES = 2048


def make_recording(path: Path, duration_s: float = 0.3) -> Path:
    """Make an offline run of `escape` (scene stored in the file), chunked every CHUNK_BYTES."""
    from pulsejet_sim.scene import load_scene
    from pulsejet_sim.studies.runner import run_scene

    run_scene(load_scene('escape'), duration_s, path, chunk_size_bytes=CHUNK_BYTES)
    return path


def read_messages(path: Path) -> tuple[list[tuple[str, int, bytes]], BagInfo]:
    info = BagInfo(path)
    return [
        (m.topic, m.log_time_ns, bytes(m.msg)) for m in iter_bag(path, info=info, decode=False)
    ], info


class Recording:

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.messages, self.info = read_messages(path)
        from mcap.reader import make_reader

        with open(path, 'rb') as fh:
            summary = make_reader(fh).get_summary()
        self.chunk_ends = sorted(
            c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes
        )
        assert len(self.chunk_ends) >= 10, 'the fixture should have many chunks'


def run_quietly(fn, *args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = fn(*args)
    return code, out.getvalue(), err.getvalue()


def check_tools(path: Path, plot: bool = False) -> dict[str, str]:
    """
    Run every file consumer on `path`.

    Each must return a clear exit code or error, not raise.
    """
    outcomes = {}
    code, out, err = run_quietly(analysis.main_summary, [str(path)])
    assert code in (0, 2), (code, err)
    assert code == 0 or (err.startswith('pulsejet summary: error:') and err.count('\n') == 1), err
    outcomes['summary'] = 'ok' if code == 0 else 'refused'
    if plot:
        code, out, err = run_quietly(
            analysis.main_plot, [str(path), '--out', str(path.with_suffix('.png'))]
        )
        assert code in (0, 2), err
        outcomes['plot'] = 'ok' if code == 0 else 'refused'
    code, out, err = run_quietly(resim.main_resim, [str(path)])
    assert code in (0, 1, 2), err
    assert code != 2 or err.startswith('pulsejet resim: '), err
    outcomes['resim'] = {0: 'ok', 1: 'mismatch', 2: 'refused'}[code]
    try:
        rec = replay.load_recording(path)
        replay.build_schedule(rec, replay.ReplayConfig(bag=path))
        outcomes['replay'] = 'ok'
    except (BagReadError, replay.ConfigError) as exc:
        assert str(exc)
        outcomes['replay'] = 'refused'
    return outcomes


def check_truncation(rec: Recording, cut: int, tmp_dir: Path, tools: bool = True) -> str:
    """
    Check a file cut at byte `cut`.

    It gives a prefix of the messages, at least every complete chunk's.
    """
    path = tmp_dir / 'cut.mcap'
    path.write_bytes(rec.data[:cut])
    try:
        messages, info = read_messages(path)
    except BagReadError as exc:
        assert cut < 200, f'a cut at byte {cut} (after the header) must still be readable: {exc}'
        return 'refused'
    assert messages == rec.messages[: len(messages)], 'not a prefix of the recording'
    complete = sum(1 for end in rec.chunk_ends if end <= cut)
    if complete:
        needed = read_messages_count_until(rec, complete)
        assert (
            len(messages) >= needed
        ), f'cut at {cut}: {len(messages)} < {needed} messages of complete chunks'
    assert info.valid_bytes <= cut and info.bytes_dropped == cut - info.valid_bytes
    assert info.damaged == (cut < len(rec.data)) == info.truncated
    if tools:
        check_tools(path)
    return 'partial' if len(messages) < len(rec.messages) else 'complete'


_PREFIX_COUNTS: dict[int, int] = {}


def read_messages_count_until(rec: Recording, chunks: int) -> int:
    if chunks not in _PREFIX_COUNTS:
        end = rec.chunk_ends[chunks - 1]
        path = rec.path.with_name(f'prefix{chunks}.mcap')
        path.write_bytes(rec.data[:end])
        _PREFIX_COUNTS[chunks] = len(read_messages(path)[0])
    return _PREFIX_COUNTS[chunks]


def corrupt(data: bytes, seed: int, kind: str) -> bytes:
    rnd = random.Random(seed)
    buf = bytearray(data)
    if kind == 'flip':
        for _ in range(rnd.randint(1, 8)):
            i = rnd.randrange(8, len(buf))
            buf[i] ^= 1 << rnd.randrange(8)
    elif kind == 'overwrite':
        i = rnd.randrange(8, len(buf))
        n = rnd.randint(1, 512)
        buf[i:i + n] = bytes(rnd.randrange(256) for _ in range(min(n, len(buf) - i)))
    elif kind == 'zero':
        i = rnd.randrange(8, len(buf))
        buf[i:i + rnd.randint(1, 4096)] = b'\0' * min(4096, len(buf) - i)
    elif kind == 'length':  # a record length field set to something huge
        i = rnd.randrange(9, len(buf) - 8)
        buf[i:i + 8] = rnd.choice(
            [b'\xff' * 8, (1 << 40).to_bytes(8, 'little'), (2**63).to_bytes(8, 'little')]
        )
    elif kind == 'insert':
        i = rnd.randrange(8, len(buf))
        buf[i:i] = bytes(rnd.randrange(256) for _ in range(rnd.randint(1, 64)))
    elif kind == 'delete':
        i = rnd.randrange(8, len(buf))
        del buf[i:i + rnd.randint(1, 256)]
    return bytes(buf)


def check_corruption(
    rec: Recording, seed: int, kind: str, tmp_dir: Path, tools: bool = True
) -> str:
    """
    Check a damaged file: only messages of the recording come out, or a clear BagReadError.

    A damaged chunk is skipped, never returned as garbage.
    """
    path = tmp_dir / 'bad.mcap'
    path.write_bytes(corrupt(rec.data, seed, kind))
    try:
        messages, info = read_messages(path)
    except BagReadError as exc:
        assert str(exc).startswith(repr(str(path))), exc
        outcome = 'refused'
    else:
        original = set(rec.messages)
        foreign = [m for m in messages if m not in original]
        assert not foreign, f'{len(foreign)} messages not in the recording, e.g. {foreign[0][:2]}'
        outcome = 'partial' if len(messages) < len(rec.messages) else 'complete'
    if tools:
        check_tools(path)
    return outcome
