"""
Benchmark (not a test): what recording costs an offline run.

For the default shell scene (shell_robot) and the lumped default (pump_cycle), timed side by side
in one process, repeats interleaved, each recording to a new file (the previous one deleted
outside the timing, as `pulsejet run` writes a new file), the garbage collected before each
timed run:

- physics: runner.run_scene without an output (Simulation.step per publication period, the
  observation after each; no recording);
- record: runner.run_scene with an MCAP output (what `pulsejet run` times: physics, each
  publication kept as the drive yields it with its profile sample's bytes, the state every
  LEDGER_PERIOD_S for its energy ledger; at each flush the rows packed, the ledgers booked (the
  shell's at once: energy_ledgers), a chunk of publications laid out in one call by
  bag.publications and written by BagWriter.write_chunk, compressed in the writer's worker
  thread; the file closed);
  its main-thread CPU time (time.thread_time) against the physics' is given too: the ratio a
  machine with a free core for the compression would see, whatever the load;
- per publication: the same messages written with one BagWriter.write_records call per
  publication (the runner before columns; test_recording checks the runner records the same
  messages);
- rclpy record (only when rclpy imports): the same topics written the way the runner did before,
  an rclpy message per sample (ros/messages.py) serialised by rclpy, for comparison;
- without writing: run_scene with the collected publications dropped at every flush (the
  collection per publication: the drive's tuple, the profile sample's bytes and, for the
  ledger, a copy of the state; the file opened and closed; no rows packed, no ledger booked, no
  layout, compression or chunk): the bound on the ratio however fast the flush gets;
- without ledgers: record with no energy ledger booked (not the same file: what the 5 Hz
  ledgers cost, the model's and their CDR text);
- summary: analysis.summarize of the recording (the read-back `pulsejet run` prints after the run;
  not part of the ratio).

Prints a markdown table and writes benchmarks/results/recording.md (date, machine, command,
medians, the ratio physics/record of the medians; the earlier runs kept below it). With --profile
it adds the cProfile of one recorded run per scene (the functions with the most own time).

    .venv/bin/python -m benchmarks.performance.bench_recording [--repeats 7] [--duration 10]
        [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import itertools
import os
from pathlib import Path
import pstats
import statistics
import sys
import tempfile
import threading
import time


from benchmarks import common as bench_common
from pulsejet_sim import analysis
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies import runner
from pulsejet_sim.studies.runner import Drive, LEDGER_PERIOD_S, run_scene

SCENES = ('shell_robot', 'pump_cycle')
TARGET_RATIO = 0.7  # issue: `pulsejet run` at >= 0.7x the speed of the physics with observations


def physics(name: str, duration_s: float) -> tuple[float, float]:
    """Return (wall s, this thread's CPU s) of run_scene without an output."""
    scene = load_scene(name)
    start, cpu = time.perf_counter(), time.thread_time()
    run_scene(scene, duration_s)
    return time.perf_counter() - start, time.thread_time() - cpu


def record(name: str, duration_s: float, out: Path) -> tuple[float, float]:
    """Return (wall s, this thread's CPU s) of run_scene recording to out."""
    scene = load_scene(name)
    start, cpu = time.perf_counter(), time.thread_time()
    run_scene(scene, duration_s, out)
    return time.perf_counter() - start, time.thread_time() - cpu


def record_without_writing(name: str, duration_s: float, out: Path) -> float:
    """
    Time run_scene with the collected rows dropped at each flush: everything but the writing.

    The collection per publication (the model's profile sample and ledger), opening and closing
    the file: what bounds the ratio however fast the layout and the MCAP chunks get.
    """
    original = runner._RunColumns.flush

    def drop(columns):
        del columns.publications[:], columns.samples[:]
        columns.ledgers = {}

    runner._RunColumns.flush = drop
    try:
        return record(name, duration_s, out)[0]
    finally:
        runner._RunColumns.flush = original


def record_without_ledgers(name: str, duration_s: float, out: Path) -> float:
    """
    Time run_scene with no energy ledger booked (not the same file: no ledger messages).

    Against record, what the ledgers cost: the model's (the shell's energy_ledgers) and their
    CDR text.
    """
    original = runner._RunColumns.flush

    def without_ledgers(columns):
        columns.ledgers = {}
        original(columns)

    runner._RunColumns.flush = without_ledgers
    try:
        return record(name, duration_s, out)[0]
    finally:
        runner._RunColumns.flush = original


def write_per_publication(path: Path, name: str, duration_s: float) -> None:
    """Record a scene with one write_records call per publication: the runner before columns."""
    from pulsejet_sim.bag import cdr
    from pulsejet_sim.bag.writer import BagWriter
    from pulsejet_sim.core.schema import dump_yaml

    scene = load_scene(name)
    drive = Drive(scene, duration_s)
    sim, encoder = drive.sim, cdr.TopicEncoder()
    ledger_every = max(1, int(round(LEDGER_PERIOD_S / (drive.batch * scene.model.dt_s))))
    with BagWriter(path) as bag:
        bag.add_metadata('pulsejet', {
            'scene': scene.name, 'scene_yaml': dump_yaml(dict(scene.data, name=scene.name)),
        })

        def state(obs, ledger):
            ns = cdr.stamp_ns(obs.time_s)
            records = encoder.observation(obs, ns)
            profile = sim.profile()
            if profile is not None:
                records.append((cdr.TOPIC_MANTLE_PROFILE, encoder.profile(*profile, ns)))
            if ledger:
                records.append((cdr.TOPIC_ENERGY_LEDGER, encoder.ledger(sim.energy_ledger(), ns)))
            bag.write_records(records, ns)

        state(sim.observe(), True)
        last, published = None, 0
        for start_s, command, obs in drive:
            ns = cdr.stamp_ns(start_s)
            records = encoder.commands(command)
            if command != last:
                records.append((cdr.TOPIC_APPLIED_COMMAND, encoder.applied_command(command, ns)))
                last = command
            bag.write_records(records, ns)
            published += 1
            state(obs, published % ledger_every == 0 or published == drive.batches)


def record_per_publication(name: str, duration_s: float, out: Path) -> float:
    start = time.perf_counter()
    write_per_publication(out, name, duration_s)
    return time.perf_counter() - start


def record_with_rclpy(name: str, duration_s: float, out: Path) -> float:
    """Record as the runner did before bag.cdr: an rclpy message per sample, rclpy-serialised."""
    from pulsejet_sim.bag.writer import BagWriter
    from pulsejet_sim.ros import messages
    from pulsejet_sim.ros.bag_messages import write_message

    scene = load_scene(name)
    start = time.perf_counter()
    drive = Drive(scene, duration_s)
    sim = drive.sim
    ledger_every = max(1, int(round(LEDGER_PERIOD_S / (drive.batch * scene.model.dt_s))))
    writer = BagWriter(out)

    def write_state(obs, ledger):
        ns = messages.stamp_ns(obs.time_s)
        for topic, msg in messages.observation_messages(obs):
            write_message(writer, topic, msg, ns)
        profile = sim.profile()
        if profile is not None:
            msg = messages.profile_message(*profile, obs.time_s)
            write_message(writer, messages.TOPIC_MANTLE_PROFILE, msg, ns)
        if ledger:
            write_message(
                writer, messages.TOPIC_ENERGY_LEDGER,
                messages.ledger_message(sim.energy_ledger(), obs.time_s),
                ns,
            )

    published, last = 0, None
    write_state(sim.observe(), True)
    for start_s, command, obs in drive:
        ns = messages.stamp_ns(start_s)
        for topic, msg in messages.command_messages(command):
            write_message(writer, topic, msg, ns)
        if command != last:
            write_message(
                writer, messages.TOPIC_APPLIED_COMMAND,
                messages.applied_command_message(command, start_s),
                ns,
            )
            last = command
        published += 1
        write_state(obs, published % ledger_every == 0 or published == drive.batches)
    writer.close()
    return time.perf_counter() - start


def summary(out: Path) -> float:
    start = time.perf_counter()
    analysis.summarize(out)
    return time.perf_counter() - start


def profile_text(name: str, duration_s: float, out: Path, lines: int = 14) -> str:
    prof = cProfile.Profile()
    prof.enable()
    run_scene(load_scene(name), duration_s, out)
    prof.disable()
    stream = io.StringIO()
    pstats.Stats(prof, stream=stream).sort_stats('tottime').print_stats(lines)
    body = stream.getvalue()
    body = body[body.index('ncalls'):] if 'ncalls' in body else body
    return f'cProfile of one recorded run of {name} ({duration_s:g} s simulated):\n\n```\n' + \
        body.rstrip() + '\n```\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=7)
    parser.add_argument('--duration', type=float, default=10.0, help='simulated s per run')
    parser.add_argument('--profile', action='store_true')
    parser.add_argument('--no-rclpy', action='store_true', help='skip the rclpy comparison')
    args = parser.parse_args(argv)
    with_rclpy = not args.no_rclpy
    if with_rclpy:
        try:
            import rclpy.serialization  # noqa: F401
        except ImportError:
            with_rclpy = False
    assert threading.current_thread() is threading.main_thread()
    load_before = os.getloadavg()
    rows, profiles = [], []
    with tempfile.TemporaryDirectory() as tmp:
        files = itertools.count()

        def fresh() -> Path:
            """
            Return a new file to record to, the previous ones deleted (not timed).

            The garbage of the run before is collected too: the rclpy record leaves enough that
            a collection would otherwise land in whichever run comes next (the physics one).
            """
            for old in Path(tmp).glob('*.mcap'):
                old.unlink()
            gc.collect()
            return Path(tmp) / f'run{next(files)}.mcap'

        for name in SCENES:
            record(name, 0.2, fresh())  # compile / load the numba cache, import everything
            if with_rclpy:
                record_with_rclpy(name, 0.2, fresh())
            times: dict[str, list[float]] = {
                'physics': [], 'record': [], 'physics_cpu': [], 'record_cpu': [], 'rclpy': [],
                'summary': [], 'no_writing': [], 'per_pub': [], 'no_ledgers': [],
            }
            for _ in range(args.repeats):  # interleaved: the machine's load hits all alike
                gc.collect()
                wall, cpu = physics(name, args.duration)
                times['physics'].append(wall)
                times['physics_cpu'].append(cpu)
                out = fresh()
                wall, cpu = record(name, args.duration, out)
                times['record'].append(wall)
                times['record_cpu'].append(cpu)
                size = out.stat().st_size
                times['summary'].append(summary(out))
                times['no_ledgers'].append(record_without_ledgers(name, args.duration, fresh()))
                times['no_writing'].append(record_without_writing(name, args.duration, fresh()))
                times['per_pub'].append(record_per_publication(name, args.duration, fresh()))
                if with_rclpy:
                    times['rclpy'].append(record_with_rclpy(name, args.duration, fresh()))
            med = {k: statistics.median(v) for k, v in times.items() if v}
            rows.append((name, med, size))
            if args.profile:
                profiles.append(profile_text(name, args.duration, fresh()))
    text = bench_common.header(
        'Offline recording: `pulsejet run` against the same physics without recording',
        'python -m benchmarks.performance.bench_recording '
        + ' '.join(argv if argv is not None else sys.argv[1:]),
    )
    load_after = os.getloadavg()
    text += (
        f'Load average (1, 5, 15 min) before: {load_before[0]:.2f}, {load_before[1]:.2f}, '
        f'{load_before[2]:.2f}; after: {load_after[0]:.2f}, {load_after[1]:.2f}, '
        f'{load_after[2]:.2f} (on {os.cpu_count()} cores: above it, the repeats compete with '
        'other jobs and single medians move; the interleaving keeps the ratios side by side).'
        '\n\n'
    )
    text += (
        f'{args.duration:g} s simulated per run, median of {args.repeats} interleaved repeats '
        '(wall s, real-time factor in brackets), each recording to a new file, the garbage '
        'collected before each timed run. physics: '
        'runner.run_scene without an output (observation per publication, no recording); '
        "record: runner.run_scene to MCAP (per publication the drive's tuple and the profile "
        "sample's bytes kept; at each flush the rows packed, the ledgers booked and a 768 KiB "
        "chunk laid out by bag.publications' numba kernel, zstd level -3 in "
        "the writer's worker thread); CPU: "
        "the same two runs' main-thread CPU time (time.thread_time), physics / record: the "
        'ratio with a core free for the compression, whatever the load; per publication: the '
        'same messages with one write_records call per publication (the runner before '
        'columns); rclpy record: the same topics built as rclpy messages and serialised by '
        'rclpy (the runner before bag.cdr); without writing: run_scene with the collected '
        'publications dropped at each flush (the collection per publication with the profile '
        'sample and a copy of the state for the ledger, file open and close: the bound on the '
        'ratio however fast the flush gets); without ledgers: record with no energy ledger '
        'booked (no ledger messages: what the 5 Hz ledgers cost); summary: analysis.summarize '
        'reading the file back (printed by `pulsejet run` after the timed run, not in the '
        'ratio). Ratio = physics / record '
        f'(target >= {TARGET_RATIO}).\n\n'
        '| scene | physics | record | ratio | CPU ratio | per publication | ratio | rclpy record '
        '| ratio | without ledgers | ratio | without writing | ratio | summary | MCAP size |\n'
        '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n'
    )

    def cell(seconds):
        return f'{seconds:.3f} s ({args.duration / seconds:.0f}x)'

    verdicts = []
    for name, med, size in rows:
        rclpy_cells = (
            f'{cell(med["rclpy"])} | {med["physics"] / med["rclpy"]:.2f}'
            if 'rclpy' in med else 'n/a | n/a'
        )
        ratio = med['physics'] / med['record']
        cpu_ratio = med['physics_cpu'] / med['record_cpu']
        text += (
            f'| {name} | {cell(med["physics"])} | {cell(med["record"])} | {ratio:.2f} | '
            f'{cpu_ratio:.2f} | {cell(med["per_pub"])} | '
            f'{med["physics"] / med["per_pub"]:.2f} | {rclpy_cells} | '
            f'{cell(med["no_ledgers"])} | {med["physics"] / med["no_ledgers"]:.2f} | '
            f'{cell(med["no_writing"])} | {med["physics"] / med["no_writing"]:.2f} | '
            f'{med["summary"]:.3f} s | {size / 1e6:.2f} MB |\n'
        )
        verdicts.append(
            f'{name} {ratio:.2f} ('
            + ('meets' if ratio >= TARGET_RATIO else 'below')
            + f' the target; CPU ratio {cpu_ratio:.2f})'
        )
    text += f'\nVerdict against {TARGET_RATIO} (wall ratio of this run): ' + '; '.join(verdicts)
    text += '.\n'
    if profiles:
        text += '\n' + '\n'.join(profiles)
    bench_common.write('recording', with_history(text))
    return 0


def with_history(text: str) -> str:
    """
    Return this run's text followed by the earlier runs stored in recording.md, newest first.

    The stored file's latest run (its text between the title and '## Earlier runs') becomes the
    first earlier run, under a heading of its date line.
    """
    path = bench_common.RESULTS / 'recording.md'
    if not path.exists():
        return text
    stored = path.read_text()
    body = stored.split('\n', 1)[1].lstrip('\n') if stored.startswith('# ') else stored
    latest, _, earlier = body.partition('## Earlier runs (newest first)\n')
    first_line, _, rest = latest.strip().partition('\n')
    return (
        text.rstrip('\n') + '\n\n## Earlier runs (newest first)\n\n'
        + f'### {first_line}\n{rest}\n\n' + earlier.lstrip('\n')
    ).rstrip('\n') + '\n'


if __name__ == '__main__':
    sys.exit(main())
