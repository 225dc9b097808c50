"""
Run the property tests' generators at a larger example count; write the reliability table.

The table of docs/dev/reliability.md (inputs tried, faults injected, survived, data lost), with
date, machine and command.

    .venv/bin/python -m benchmarks.reliability.reliability_table [--examples N] [--kills K]
                                                                 [--out docs/dev/reliability.md]

The generators and checks are those of input_fuzz.py, recording_damage.py and killed_writer.py
beside this file, which test/test_fuzz_inputs.py, test/test_mcap_corruption.py and
test/test_repair.py run too (so the table and `make test` exercise the same code);
here every example runs to the end and its outcome is counted instead of stopping at the first
failure. "Survived" = the property held: a clear error naming what is wrong, or a run / the
readable part of the file, and no traceback, hang or non-finite value.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import os
from pathlib import Path
import platform
import signal
import sys
import tempfile
import time

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st

REPO = Path(__file__).resolve().parents[2]
# also step lumped scenes with other terms (read when input_fuzz is imported, inside the runs)
os.environ.setdefault('PULSEJET_FUZZ_ALL_FLAGS', '1')

MARKER_START = '<!-- reliability-table:start -->'
MARKER_END = '<!-- reliability-table:end -->'


class Tally:

    def __init__(self) -> None:
        self.outcomes: collections.Counter = collections.Counter()
        self.failures: list[str] = []
        self.extra: dict[str, float] = {}

    def run(self, fn, *args) -> str | None:
        try:
            outcome = fn(*args)
        except Exception as exc:  # the property failed: count it, keep going
            self.outcomes['FAILED'] += 1
            if len(self.failures) < 5:
                self.failures.append(f'{type(exc).__name__}: {str(exc)[:300]}')
            return None
        self.outcomes[str(outcome)] += 1
        return outcome

    @property
    def tried(self) -> int:
        return sum(self.outcomes.values())

    @property
    def survived(self) -> int:
        return (
            self.tried
            - self.outcomes['FAILED']
            - sum(n for k, n in self.outcomes.items() if k.startswith('known'))
        )


def _settings(n: int):
    return settings(
        max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck)
    )


def fuzz_scenes(n: int, tmp: Path) -> Tally:
    from benchmarks.reliability import input_fuzz as F

    tally = Tally()

    @_settings(n)
    @given(case=F.scene_texts())
    def run(case):
        text, _, mutations = case
        tally.run(F.check_scene_text, text, mutations, tmp)

    run()
    return tally


def fuzz_commands(n: int) -> Tally:
    from benchmarks.reliability import input_fuzz as F

    tally = Tally()
    counts = collections.Counter()

    def check(name, commands, steps):
        applied, rejected, outcome = F.check_command_sequence(name, commands, steps)
        counts['applied'] += applied
        counts['rejected'] += rejected
        return outcome

    @_settings(n)
    @given(
        name=st.sampled_from(['escape', 'pump_cycle', 'shell_robot', 'shell_cone']),
        commands=st.lists(F.COMMANDS, min_size=1, max_size=12),
        steps=st.sampled_from([1, 2, 5]),
    )
    def run(name, commands, steps):
        tally.run(check, name, commands, steps)

    run()
    tally.extra.update(counts)
    return tally


def fuzz_sweeps(n: int, tmp: Path) -> Tally:
    from benchmarks.reliability import input_fuzz as F

    tally = Tally()

    @_settings(n)
    @given(text=F.sweep_texts())
    def run(text):
        tally.run(F.check_sweep_text, text, tmp)

    run()
    return tally


def fuzz_mcap(n: int, tmp: Path) -> tuple[Tally, dict[str, Tally], float]:
    from benchmarks.reliability import recording_damage as M

    rec = M.Recording(M.make_recording(tmp / 'run.mcap'))
    cut_tally = Tally()
    recovered: list[float] = []

    def cut(fraction, tools):
        c = int(fraction * len(rec.data))
        outcome = M.check_truncation(rec, c, tmp, tools=tools)
        if c > 200:
            n_read = len(M.read_messages(tmp / 'cut.mcap')[0])
            complete = sum(1 for end in rec.chunk_ends if end <= c)
            bound = M.read_messages_count_until(rec, complete) if complete else 0
            recovered.append(n_read - bound)  # >= 0: beyond the complete chunks' messages
        return outcome

    @_settings(n)
    @given(fraction=st.floats(0.0, 1.0), tools=st.booleans())
    def run_cut(fraction, tools):
        cut_tally.run(cut, fraction, tools)

    run_cut()
    cut_tally.extra['min_extra_messages'] = min(recovered) if recovered else 0
    kinds = {}
    for kind in ('flip', 'overwrite', 'zero', 'length', 'insert', 'delete'):
        tally = kinds[kind] = Tally()
        lost_fraction: list[float] = []

        def corrupt(seed, tools, kind=kind):
            outcome = M.check_corruption(rec, seed, kind, tmp, tools=tools)
            try:
                got = len(M.read_messages(tmp / 'bad.mcap')[0])
                lost_fraction.append(1 - got / len(rec.messages))
            except Exception:
                lost_fraction.append(1.0)
            return outcome

        @_settings(max(n // 3, 10))
        @given(seed=st.integers(0, 2**32 - 1), tools=st.booleans())
        def run_corrupt(seed, tools):
            tally.run(corrupt, seed, tools)

        run_corrupt()
        ordered = sorted(lost_fraction) or [0.0]
        tally.extra['median_lost'] = ordered[len(ordered) // 2]
        tally.extra['max_lost'] = ordered[-1]
    return cut_tally, kinds


def kill_runs(k: int, tmp: Path) -> tuple[Tally, list[float], Tally]:
    from benchmarks.reliability import killed_writer as R

    busy, idle = Tally(), Tally()
    lost: list[float] = []

    def one_busy(i):
        d = tmp / f'kill{i}'
        d.mkdir()
        proc, path = R.start_writer(d, 'busy')
        time.sleep(0.5 + 0.1 * i)
        t_kill = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=10)
        from pulsejet_sim.bag.reader import bag_info, iter_bag
        from pulsejet_sim.bag.repair import repair_file

        stamps = [m.msg.data for m in iter_bag(path, topics=['pulsejet/volume'])]
        lost.append(t_kill - stamps[-1])
        info = bag_info(path)
        result = repair_file(path)
        assert R.channel_metadata(result.out_path) == info.channel_metadata
        assert not bag_info(result.out_path).damaged
        return 'repaired'

    def one_idle(i):
        d = tmp / f'idle{i}'
        d.mkdir()
        proc, path = R.start_writer(d, 'idle')
        assert proc.stdout.readline().strip() == 'idle'
        time.sleep(R.FLUSH_S + 0.3)
        proc.kill()
        proc.communicate(timeout=10)
        from pulsejet_sim.bag.reader import bag_info

        info = bag_info(path)
        assert info.counts['/pulsejet/volume'] == 1000, info.counts
        return 'nothing lost'

    for i in range(k):
        busy.run(one_busy, i)
        idle.run(one_idle, i)
    return busy, lost, idle


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in open('/proc/cpuinfo'):
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f'{platform.node()}: {cpu}, {os.cpu_count()} cores, '
        f'{platform.system()} {platform.release()}, '
        f'Python {platform.python_version()}'
    )


def fmt_outcomes(t: Tally) -> str:
    return ', '.join(f'{k} {v}' for k, v in sorted(t.outcomes.items()))


def _stored(name: str):
    """Return the JSON a live run stored in benchmarks/results (None if it was not run)."""
    import json

    path = REPO / 'benchmarks' / 'results' / f'{name}.json'
    return json.loads(path.read_text()) if path.exists() else None


def live_fuzz_row() -> tuple:
    """
    Return the live fuzz row from benchmarks/reliability/live_fuzz.py's stored run.

    Not rerun here: it takes minutes of wall time.
    """
    what = (
        'live fuzz of sim_node topics, services and parameters'
        ' (`benchmarks/reliability/live_fuzz.py`)'
    )
    stored = _stored('live_fuzz')
    if stored is None:
        return (what, 'not yet run', 'not yet run', 'not yet run', 'not yet run')
    runs = stored['results']
    sent = sum(r['messages_sent'] for r in runs)
    calls = sum(r['sent']['service'] + r['sent']['parameter'] for r in runs)
    seconds = sum(r['seconds'] for r in runs)
    bad = sum(
        r['nan_published'] + r['restarts_needed'] + r['tracebacks_in_log'] + (r['exit_code'] != 0)
        for r in runs
    )
    rss = ', '.join(f"{r['scene']} {r['rss_growth']:+.1%}" for r in runs)
    return (
        what + f"; `{stored['command']}`",
        f'{sent} commands + {calls} service/parameter calls in {seconds / 60:.0f} min',
        f"scenes {', '.join(r['scene'] for r in runs)} at >= "
        f"{min(r['rate_hz'] for r in runs):.0f} messages/s: "
        'NaN, inf, 1e308, negative values, unknown names, stamps out of order, duplicates, '
        'random pause/step/reset, live parameter changes',
        f"{len(runs) - bad}/{len(runs)} runs: {sum(r['nan_published'] for r in runs)} "
        f"non-finite values published, {sum(r['restarts_needed'] for r in runs)} restarts, "
        f'RSS {rss}',
        'none (commands past the subscription depth are superseded by later ones; '
        'see live_fuzz.md)',
    )


def soak_row() -> tuple:
    """From benchmarks/reliability/soak.py's stored run."""
    what = (
        'soak: 1 kHz publication, closed-loop controller, recorder'
        ' (`benchmarks/reliability/soak.py`)'
    )
    stored = _stored('soak')
    if stored is None:
        return (what, 'not yet run', 'not yet run', 'not yet run', 'not yet run')
    r = stored['result']
    growth = ', '.join(f'{name} {g[0]:+.2%}' for name, g in r['rss'].items())
    rec = r.get('recording', {})
    return (
        what + f"; `{stored['command']}`",
        f"{r['minutes']:g} min",
        f"1 kHz of state with {r.get('controller', 'every_state')} closed-loop control; "
        'a parameter dump (list + get) every second',
        ('met' if not stored['misses'] else 'MISSED: ' + '; '.join(stored['misses']))
        + f": RTF {r['rtf']:.4f}, watchdog trips {r['watchdog_trips']}, memory {growth}, "
        f"parameter rounds {r['param_services']['rounds']} "
        f"(max {r['param_services']['max_ms']:.0f} ms)",
        rec.get('error')
        or (
            f"none: {sum(rec.get('messages', {}).values())} messages read back with rosbags"
            if rec
            else 'not recorded'
        ),
    )


def table(examples: int, kills: int) -> str:
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        started = time.perf_counter()
        scenes = fuzz_scenes(examples, tmp)
        commands = fuzz_commands(examples)
        sweeps = fuzz_sweeps(examples, tmp)
        cut, kinds = fuzz_mcap(examples, tmp)
        busy, lost, idle = kill_runs(kills, tmp)
        wall = time.perf_counter() - started
    rows = [
        (
            'scene files (valid and mutated: wrong types, NaN/inf/1e308, missing and unknown '
            'keys, non-mapping sections, not-a-mapping or invalid YAML)',
            scenes.tried,
            f'0-3 mutations per file; outcomes: {fmt_outcomes(scenes)}',
            f'{scenes.survived}/{scenes.tried}',
            'n/a',
        ),
        (
            'command sequences into Simulation '
            '(any float, NaN, +-inf, 1e308, negative, subnormal)',
            commands.tried,
            f'{int(commands.extra.get("applied", 0))} commands applied, '
            f'{int(commands.extra.get("rejected", 0))} rejected; runs: {fmt_outcomes(commands)}',
            f'{commands.survived}/{commands.tried}',
            'none (no non-finite observation)',
        ),
        (
            'sweep files (mutated)',
            sweeps.tried,
            f'outcomes: {fmt_outcomes(sweeps)}',
            f'{sweeps.survived}/{sweeps.tried}',
            'n/a',
        ),
        (
            'MCAP cut at a random byte (reader, summary, resim, replay loading)',
            cut.tried,
            f'outcomes: {fmt_outcomes(cut)}',
            f'{cut.survived}/{cut.tried}',
            'only messages after the last complete chunk',
        ),
    ]
    what = {
        'flip': '1-8 bit flips',
        'overwrite': '1-512 random bytes overwritten',
        'zero': 'up to 4 kB zeroed',
        'length': 'a record length set to 2^40, 2^63 or 2^64-1',
        'insert': '1-64 random bytes inserted',
        'delete': '1-256 bytes deleted',
    }
    for kind, t in kinds.items():
        rows.append(
            (
                f'MCAP corrupted ({what[kind]}; reader, summary, resim, replay loading)',
                t.tried,
                f'outcomes: {fmt_outcomes(t)}',
                f'{t.survived}/{t.tried}',
                f'median {t.extra["median_lost"]:.1%}, max {t.extra["max_lost"]:.0%} '
                'of the messages; '
                'never a message that was not recorded',
            )
        )
    rows += [
        (
            'writer process SIGKILLed mid-write, then `pulsejet repair`',
            busy.tried,
            f'SIGKILL after 0.5-{0.5 + 0.1 * kills:.1f} s of writing at ~1 kHz',
            f'{busy.survived}/{busy.tried}',
            f'max {max(lost) if lost else float("nan"):.3f} s of messages (flush period 0.25 s); '
            'repaired files keep every channel metadata key',
        ),
        (
            'idle writer SIGKILLed',
            idle.tried,
            'SIGKILL 0.55 s after the last write',
            f'{idle.survived}/{idle.tried}',
            'none',
        ),
        live_fuzz_row(),
        soak_row(),
    ]
    failures = [
        ('scene', scenes),
        ('commands', commands),
        ('sweeps', sweeps),
        ('cut', cut),
        *kinds.items(),
        ('kill', busy),
        ('idle kill', idle),
    ]
    lines = [
        MARKER_START,
        f'Generated {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC} '
        f'on {machine()} by',
        f'`{Path(sys.executable).name} -m benchmarks.reliability.reliability_table '
        f'--examples {examples} --kills {kills}` '
        f'({wall:.0f} s).',
        '',
        '| inputs | tried | faults injected | survived | data lost |',
        '|---|---|---|---|---|',
    ]
    lines += [f'| {a} | {b} | {c} | {d} | {e} |' for a, b, c, d, e in rows]
    notes = [f'- {name}: {msg}' for name, t in failures for msg in t.failures]
    if notes:
        lines += ['', 'Failures (first of each kind):', *notes]
    lines.append(MARKER_END)
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument(
        '--examples', type=int, default=300, help='examples per generator (default 300)'
    )
    parser.add_argument(
        '--kills', type=int, default=5, help='SIGKILL runs of each kind (default 5)'
    )
    parser.add_argument(
        '--out',
        default=str(REPO / 'docs' / 'dev' / 'reliability.md'),
        help='markdown file whose table (between the markers) is replaced',
    )
    args = parser.parse_args(argv)
    text = table(args.examples, args.kills)
    out = Path(args.out)
    if out.exists() and MARKER_START in out.read_text():
        doc = out.read_text()
        head, rest = doc.split(MARKER_START, 1)
        tail = rest.split(MARKER_END, 1)[1] if MARKER_END in rest else ''
        out.write_text(head + text + tail)
    else:
        out.write_text(text + '\n')
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
