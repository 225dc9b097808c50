"""
Benchmark (not a test): what recording costs an offline run.

For the default shell scene (shell_robot) and the lumped default (pump_cycle), timed side by side
in one process, repeats interleaved:

- physics: runner.run_scene without an output (Simulation.step per publication period, the
  observation after each; no recording);
- record: runner.run_scene with an MCAP output (what `pulsejet run` times: physics, the run's
  messages collected as columns, encoded a stretch at a time by bag.cdr.ColumnEncoder and
  written by BagWriter.write_batch, the file closed);
- per publication: the same file written with one BagWriter.write_records call per publication
  (the runner before columns; test_recording checks the two files are identical);
- rclpy record (only when rclpy imports): the same topics written the way the runner did before,
  an rclpy message per sample (ros/messages.py) serialised by rclpy, for comparison;
- summary: analysis.summarize of the recording (the read-back `pulsejet run` prints after the run;
  not part of the ratio).

Prints a markdown table and writes benchmarks/results/recording.md (date, machine, command,
medians, the ratio physics/record of the medians). With --profile it adds the cProfile of one
recorded run per scene (the functions with the most own time).

    .venv/bin/python -m benchmarks.performance.bench_recording [--repeats 7] [--duration 10]
        [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import io
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
from pulsejet_sim.studies.runner import Drive, LEDGER_PERIOD_S, run_scene

SCENES = ('shell_robot', 'pump_cycle')
TARGET_RATIO = 0.7  # issue: `pulsejet run` at >= 0.7x the speed of the physics with observations


def physics(name: str, duration_s: float) -> float:
    scene = load_scene(name)
    start = time.perf_counter()
    run_scene(scene, duration_s)
    return time.perf_counter() - start


def record(name: str, duration_s: float, out: Path) -> float:
    scene = load_scene(name)
    start = time.perf_counter()
    run_scene(scene, duration_s, out)
    return time.perf_counter() - start


def record_without_appending(name: str, duration_s: float, out: Path) -> float:
    """
    Time run_scene with BagWriter.write_batch a no-op: everything but laying out the messages.

    The collection per publication (the model's profile and ledger), opening and closing the
    file: what bounds the ratio however fast the encoding and the MCAP appends get.
    """
    from pulsejet_sim.bag.writer import BagWriter

    original = BagWriter.write_batch
    BagWriter.write_batch = lambda self, batch: None
    try:
        return record(name, duration_s, out)
    finally:
        BagWriter.write_batch = original


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
        out = Path(tmp) / 'run.mcap'
        for name in SCENES:
            record(name, 0.2, out)  # compile / load the numba cache, import everything
            if with_rclpy:
                record_with_rclpy(name, 0.2, out)
            times: dict[str, list[float]] = {'physics': [], 'record': [], 'rclpy': [],
                                             'summary': [], 'no_append': [], 'per_pub': []}
            for _ in range(args.repeats):  # interleaved: the machine's load hits all alike
                times['physics'].append(physics(name, args.duration))
                times['record'].append(record(name, args.duration, out))
                times['summary'].append(summary(out))
                times['no_append'].append(record_without_appending(name, args.duration, out))
                times['per_pub'].append(record_per_publication(name, args.duration, out))
                if with_rclpy:
                    times['rclpy'].append(record_with_rclpy(name, args.duration, out))
            med = {k: statistics.median(v) for k, v in times.items() if v}
            rows.append((name, med, out.stat().st_size))
            if args.profile:
                profiles.append(profile_text(name, args.duration, out))
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
        '(wall s, real-time factor in brackets). physics: runner.run_scene without an output '
        '(observation per publication, no recording); record: runner.run_scene to MCAP (the '
        "run's messages as columns, encoded a stretch at a time, zstd chunks); per "
        'publication: the same file with one write_records call per publication (the runner '
        'before columns); rclpy record: the same topics built as rclpy messages and '
        'serialised by rclpy (the runner before bag.cdr); without writing: run_scene with '
        "write_batch a no-op (the collection per publication with the model's profile and "
        'ledger, file open and close: the bound on the ratio however fast the encoding and the '
        'MCAP appends get); summary: analysis.summarize reading the file back (printed by '
        '`pulsejet run` after the timed run, not in the ratio). Ratio = physics / '
        f'record (target >= {TARGET_RATIO}).\n\n'
        '| scene | physics | record | ratio | per publication | ratio | rclpy record | ratio '
        '| without writing | ratio | summary | MCAP size |\n'
        '|---|---|---|---|---|---|---|---|---|---|---|---|\n'
    )

    def cell(seconds):
        return f'{seconds:.3f} s ({args.duration / seconds:.0f}x)'

    for name, med, size in rows:
        rclpy_cells = (
            f'{cell(med["rclpy"])} | {med["physics"] / med["rclpy"]:.2f}'
            if 'rclpy' in med else 'n/a | n/a'
        )
        text += (
            f'| {name} | {cell(med["physics"])} | {cell(med["record"])} | '
            f'{med["physics"] / med["record"]:.2f} | {cell(med["per_pub"])} | '
            f'{med["physics"] / med["per_pub"]:.2f} | {rclpy_cells} | {cell(med["no_append"])} | '
            f'{med["physics"] / med["no_append"]:.2f} | {med["summary"]:.3f} s | '
            f'{size / 1e6:.2f} MB |\n'
        )
    if profiles:
        text += '\n' + '\n'.join(profiles)
    bench_common.write('recording', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
