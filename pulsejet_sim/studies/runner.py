"""
Offline runner: the same model, Simulation.step and routine as the live nodes, without DDS.

It runs as fast as the machine allows and writes the same topics to MCAP (log time = simulation
time).

`Drive` is the loop itself (no ROS): the MCAP runner and `pulsejet sweep` both iterate it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import operator
from pathlib import Path
import struct
import threading
import time
from typing import Iterator

from pulsejet_sim.core.model_io import Command, Observation, SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.routines import routine_from_scene
from pulsejet_sim.scene import Scene

LEDGER_PERIOD_S = 0.2  # energy ledger messages at 5 Hz, as sim_node publishes them
#: MCAP chunk size of a recorded run: rosbag2's default (mcap's C++ writer, 768 KiB); fewer
#: chunks than the writer's default cost less per run (benchmarks/results/recording.md)
RUN_CHUNK_BYTES = 768 * 1024
#: zstd level of a recorded run's chunks: mcap's C++ CompressionLevel::Fast (rosbag2's default is
#: 1): a third less compression CPU for files about 12 % larger (benchmarks/results/recording.md)
RUN_ZSTD_LEVEL = -3


def steps_per_publication(scene: Scene) -> int:
    return max(1, int(round(1.0 / (scene.publish_rate_hz * scene.model.dt_s))))


@dataclass
class Drive:
    """
    Steps a scene in publication-sized batches, like sim_node + controller_node at an ideal rate.

    Each command comes from the scene's routine (or the scene's initial command). Iterating yields
    (time_s at the batch start, command held, observation after the batch); a blow-up ends the
    iteration and is kept in `fault`.
    """

    scene: Scene
    duration_s: float
    sim: Simulation = field(init=False)
    fault: str | None = field(init=False, default=None)

    def __post_init__(self):
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(
                f'duration_s={self.duration_s!r} rejected; allowed: a positive finite number of '
                'seconds'
            )
        self.sim = Simulation(self.scene.model)
        self.routine = routine_from_scene(self.scene.routine)
        self.batch = steps_per_publication(self.scene)
        self.batches = int(
            math.ceil(self.duration_s / (self.batch * self.scene.model.dt_s) - 1e-9)
        )

    def __iter__(self) -> Iterator[tuple[float, Command, Observation]]:
        obs = self.sim.observe()
        for _ in range(self.batches):
            start_s = self.sim.time_s
            command = (
                self.routine.command(start_s, obs.volume_m3) if self.routine else self.sim.command
            )
            try:
                obs = self.sim.step(self.batch, command)
            except SimulationBlowUp as err:  # stop, keep what was good
                self.fault = str(err)
                return
            yield start_s, command, obs


@dataclass
class RunResult:
    path: Path | None
    sim: Simulation
    publications: int
    fault: str | None


def run_scene(
    scene: Scene,
    duration_s: float | None = None,
    out: str | Path | None = None,
    *,
    chunk_size_bytes: int = RUN_CHUNK_BYTES,
) -> RunResult:
    """
    Run `scene` for duration_s of simulated time (default: the scene's), writing MCAP to `out`.

    The file is written only if `out` is given, in MCAP chunks of about chunk_size_bytes
    (uncompressed; small chunks for tests that cut a file between chunks). A blow-up ends the
    run early: the file keeps everything before it, and the fault is returned (never a NaN
    message).
    """
    drive = Drive(scene, scene.duration_s if duration_s is None else float(duration_s))
    if out is None:
        published = sum(1 for _ in drive)
        return RunResult(path=None, sim=drive.sim, publications=published, fault=drive.fault)
    return _record(drive, Path(out), chunk_size_bytes)


def _record(drive: Drive, out: Path, chunk_size_bytes: int) -> RunResult:
    from pulsejet_sim.bag.writer import BagWriter, install_signal_handlers
    from pulsejet_sim.core.schema import dump_yaml

    sim, scene = drive.sim, drive.scene
    ledger_every = max(1, int(round(LEDGER_PERIOD_S / (drive.batch * scene.model.dt_s))))
    # no fsync at close: a killed run's writes are with the OS already, and an offline run
    # reruns bit for bit from its scene (the sync cost ~5 % of a 10 s shell_robot run)
    writer = BagWriter(
        out, chunk_size_bytes=chunk_size_bytes, sync_on_close=False, zstd_level=RUN_ZSTD_LEVEL
    )
    # the scene travels with the recording, so `pulsejet resim FILE` needs nothing else
    writer.add_metadata(
        'pulsejet',
        {
            'scene': scene.name,
            'scene_yaml': dump_yaml(dict(scene.data, name=scene.name)),
        },
    )
    columns = _RunColumns(writer, sim)
    writer.on_close(columns.flush)
    # Ctrl-C or SIGTERM during a long offline run still leaves a complete, readable file
    restore_signals = (
        install_signal_handlers(writer)
        if threading.current_thread() is threading.main_thread()
        else None
    )
    published = 0
    try:
        columns.add(None, sim.observe())
        published = columns.record(drive, ledger_every)
        if drive.fault is not None:
            columns.add(None, sim.observe())
    finally:
        writer.close()  # hands the last columns over first (on_close)
        if restore_signals is not None:
            restore_signals()
    return RunResult(path=out, sim=sim, publications=published, fault=drive.fault)


class _RunColumns:
    """
    The run's publications, written a chunk at a time (bag.publications).

    Per publication only references and one copy: the (start, command, observation) the drive
    yields, appended to a list (the publication counts from that one store on, so a signal
    handler that closes the writer mid-run hands over whole publications), the bytes of the
    model's profile sample (the state changes in place) and, every LEDGER_PERIOD_S, a copy of
    the state for its energy ledger. flush() turns a chunk's publications into columns, books
    their ledgers, lays out their records with numpy (PublicationLayout.records) and writes them
    as one MCAP chunk (BagWriter.write_chunk). Between physics steps a publication costs two
    appends and a copy; packing its values into rows is done a chunk at a time.
    """

    #: publications per chunk; None: as many as fill the writer's chunk size
    PUBLICATIONS_PER_CHUNK: int | None = None

    def __init__(self, writer, sim: Simulation) -> None:
        from pulsejet_sim.bag.cdr import TopicEncoder
        from pulsejet_sim.bag.publications import PublicationLayout, STATE_FIELDS, STATE_ORDER
        from pulsejet_sim.core.topics import (
            APPLIED_COMMAND_NAMES, COMMAND_TOPICS, TOPIC_APPLIED_COMMAND, TOPIC_ENERGY_LEDGER,
            TOPIC_MANTLE_PROFILE,
        )
        import numpy as np

        self.writer, self.sim = writer, sim
        model = sim.model
        profile = sim.profile()
        sample = getattr(model, 'profile_sample', None)
        if profile is None:
            self.sample = self.profiles_of = None
        elif sample is not None and hasattr(model, 'profiles_of_samples'):
            self.sample, self.profiles_of = sample, model.profiles_of_samples
        else:  # a model without the array methods: its profile() each time, r then z
            points = len(profile[0])

            def sample(state):
                return np.concatenate(model.profile(state))

            self.sample = sample
            self.profiles_of = lambda samples: (samples[:, :points], samples[:, points:])
        # channels in the order a write_records call per publication adds them
        topics = [*STATE_ORDER, *([TOPIC_MANTLE_PROFILE] if profile is not None else []),
                  TOPIC_ENERGY_LEDGER, *COMMAND_TOPICS, TOPIC_APPLIED_COMMAND]
        self.encoder = TopicEncoder()
        self.layout = PublicationLayout(
            writer.channel_ids(topics), None if profile is None else len(profile[0]),
            self.encoder,
        )
        per_publication = self.layout.command.width + self.layout.state.width
        self.capacity = self.PUBLICATIONS_PER_CHUNK or max(
            1, writer.chunk_size_bytes // per_publication
        )
        command_values = operator.attrgetter(*APPLIED_COMMAND_NAMES)
        no_command = (0.0,) * len(APPLIED_COMMAND_NAMES)
        state_values = operator.attrgetter('time_s', *STATE_FIELDS)
        # a row per publication: the commands' time (-1: none), the command values in
        # APPLIED_COMMAND_NAMES' order, the state's time and STATE_FIELDS
        row = struct.Struct(f'={2 + len(APPLIED_COMMAND_NAMES) + len(STATE_FIELDS)}d').pack

        def rows(publications) -> np.ndarray:
            data = b''.join([
                row(start_s, *(command_values(command) if command is not None else no_command),
                    *state_values(obs))
                for start_s, command, obs in publications
            ])
            return np.frombuffer(data).reshape(len(publications), -1)

        self.rows = rows
        self.command_columns = slice(1, 1 + len(APPLIED_COMMAND_NAMES))
        self.sample_values = (
            None if self.sample is None else len(self.sample(sim.state))
        )
        self.publications: list[tuple[float, Command | None, Observation]] = []
        self.samples: list[bytes] = []  # each publication's profile sample, its bytes
        # publication -> the state whose energy ledger it carries, booked at flush(): the
        # ledger is a function of the state alone (Simulation.energy_ledger), and computing a
        # stretch's ledgers back to back costs about half of doing it between physics steps
        self.ledgers: dict[int, np.ndarray] = {}
        self.last_command: np.ndarray | None = None
        self.period_s = 0.5 * writer.flush_period_s
        self.since = time.monotonic()

    def add(self, command: Command | None, obs: Observation, start_s: float = -1.0) -> None:
        """Add a publication, its ledger: the command sent at start_s (None: none), the state."""
        if self.sample is not None:
            self.samples.append(self.sample(self.sim.state).tobytes())
        self.ledgers[len(self.publications)] = self.sim.state.copy()
        self.publications.append((start_s, command, obs))
        self.flush_if_due()

    def record(self, drive: Drive, ledger_every: int) -> int:
        """
        Add the publications of a drive (the ledger every ledger_every and with the last).

        Returns how many it yielded. The loop of add() with its lookups hoisted: it runs once
        per publication, next to the physics it records.
        """
        import numpy as np

        publications, samples, sim, sample = self.publications, self.samples, self.sim, self.sample
        append, add_sample = publications.append, samples.append
        # the profile sample: a view of the state (the physics changes it in place) whose bytes
        # are taken per publication, or the model's sample of each state
        state = sim.state
        view = None if sample is None else sample(state)
        if view is not None and not np.shares_memory(view, state):
            view = None
        capacity, monotonic, last = self.capacity, time.monotonic, drive.batches
        period_s = self.period_s
        # a chunk handed over this many publications before the end: its compression (in the
        # writer's worker) overlaps the last ones, and close() compresses only a short tail
        tail = last - max(1, capacity // 3)
        published = 0
        for publication in drive:
            published += 1
            if view is not None and sim.state is state:
                add_sample(view.tobytes())
            elif sample is not None:  # not a view, or reset() replaced the state
                add_sample(sample(sim.state).tobytes())
            if published % ledger_every == 0 or published == last:
                self.ledgers[len(publications)] = sim.state.copy()
            append(publication)  # the publication counts from here on (a signal's flush takes it)
            if (len(publications) == capacity or published == tail
                    or monotonic() - self.since >= period_s):
                self.flush()
        return published

    def flush_if_due(self) -> None:
        if (len(self.publications) >= self.capacity
                or time.monotonic() - self.since >= self.period_s):
            self.flush()

    def flush(self) -> None:
        """Lay out the publications added since the last flush and write them as one chunk."""
        from pulsejet_sim.bag.cdr import stamps_ns
        from pulsejet_sim.bag.publication_kernel import stamps_and_changes
        import numpy as np

        n = len(self.publications)
        if not n:
            return
        rows = self.rows(self.publications[:n])
        stop = self.command_columns.stop  # the state's time
        sent, times = rows[:, 0], rows[:, stop]
        if not (sent.max() < 2.0**31 and times.min() >= 0.0 and times.max() < 2.0**31):
            stamps_ns(times)  # ValueError naming a time that is no ROS stamp (or a NaN)
            stamps_ns(sent[sent >= 0.0])
        # the stamps, and the applied command published when the held command changes (sim_node)
        last = self.last_command
        command_ns, state_ns, applied, held, has_held = stamps_and_changes(
            rows, stop, np.zeros(stop - 1) if last is None else last, last is not None
        )
        last = held if has_held else None
        commands = rows[:, self.command_columns]
        states = rows[:, stop:]
        profiles = None
        if self.sample is not None:
            samples = np.frombuffer(b''.join(self.samples[:n])).reshape(n, self.sample_values)
            profiles = self.profiles_of(samples)
        booked = sorted(row for row in self.ledgers if row < n)
        model = self.sim.model
        if not booked:
            values = []
        elif hasattr(model, 'energy_ledgers'):  # the model books them at once (the shell)
            values = model.energy_ledgers(np.array([self.ledgers[row] for row in booked]))
        else:
            values = [model.energy_ledger(self.ledgers[row]) for row in booked]
        ledger = self.encoder.ledger
        stretch = self.layout.records(
            command_ns, commands, applied, state_ns, states[:, 1:], profiles,
            {row: ledger(value, int(state_ns[row])) for row, value in zip(booked, values)},
        )
        # the publications are in the stretch: a signal closing the file from here on finds
        # none left (a sample or ledger of a publication not yet appended goes with it)
        del self.publications[:n]
        del self.samples[:]
        self.layout.counts = stretch.counts
        self.ledgers, self.last_command = {}, last
        self.since = time.monotonic()
        self.writer.write_chunk(stretch)


def default_output(scene: Scene) -> Path:
    import datetime

    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
    return Path('runs') / f'{scene.name}-{stamp}.mcap'
