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
import threading
import time
from typing import Iterator

from pulsejet_sim.core.model_io import Command, Observation, SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.routines import routine_from_scene
from pulsejet_sim.scene import Scene

LEDGER_PERIOD_S = 0.2  # energy ledger messages at 5 Hz, as sim_node publishes them
#: the Observation fields the state topics carry (bag.cdr.ColumnEncoder.state's names)
STATE_FIELDS = (
    'mantle_radius_m', 'volume_m3', 'velocity_m_s', 'thrust_n', 'fluid_mass_kg', 'position_m'
)


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
    scene: Scene, duration_s: float | None = None, out: str | Path | None = None
) -> RunResult:
    """
    Run `scene` for duration_s of simulated time (default: the scene's), writing MCAP to `out`.

    The file is written only if `out` is given. A blow-up ends the run early: the file keeps
    everything before it, and the fault is returned (never a NaN message).
    """
    drive = Drive(scene, scene.duration_s if duration_s is None else float(duration_s))
    if out is None:
        published = sum(1 for _ in drive)
        return RunResult(path=None, sim=drive.sim, publications=published, fault=drive.fault)
    return _record(drive, Path(out))


def _record(drive: Drive, out: Path) -> RunResult:
    from pulsejet_sim.bag.writer import BagWriter, install_signal_handlers
    from pulsejet_sim.core.schema import dump_yaml

    sim, scene = drive.sim, drive.scene
    ledger_every = max(1, int(round(LEDGER_PERIOD_S / (drive.batch * scene.model.dt_s))))
    writer = BagWriter(out)
    # the scene travels with the recording, so `pulsejet resim FILE` needs nothing else
    writer.add_metadata(
        'pulsejet',
        {
            'scene': scene.name,
            'scene_yaml': dump_yaml(dict(scene.data, name=scene.name)),
        },
    )
    columns = _RunColumns(writer)
    writer.on_close(columns.flush)
    # Ctrl-C or SIGTERM during a long offline run still leaves a complete, readable file
    restore_signals = (
        install_signal_handlers(writer)
        if threading.current_thread() is threading.main_thread()
        else None
    )
    published = 0
    try:
        columns.state(sim, sim.observe(), ledger=True)
        for start_s, command, obs in drive:
            columns.commands(start_s, command)
            published += 1
            columns.state(
                sim, obs, ledger=published % ledger_every == 0 or published == drive.batches
            )
        if drive.fault is not None:
            columns.state(sim, sim.observe(), ledger=True)
    finally:
        writer.close()  # hands the last columns over first (on_close)
        if restore_signals is not None:
            restore_signals()
    return RunResult(path=out, sim=sim, publications=published, fault=drive.fault)


class _RunColumns:
    """
    The run's messages as columns, written a stretch at a time (bag.batch, bag.cdr.ColumnEncoder).

    Per publication only one tuple is appended (one bytecode, so a signal handler that closes the
    writer mid-run sees whole publications); flush() encodes each topic's messages at once. The
    order keys put a publication's commands before its state, each group in the order sim_node
    publishes it, so the file is the one a write_records call per publication writes.
    """

    FLUSH_PUBLICATIONS = 250  # about 0.3 MB of messages per flush for the default shell scene
    # slots within a publication: commands, the applied command, state topics, profile, ledger
    SLOT_APPLIED, SLOT_STATE, SLOT_PROFILE, SLOT_LEDGER, SLOTS = 3, 4, 11, 12, 16

    def __init__(self, writer) -> None:
        from pulsejet_sim.bag.cdr import ColumnEncoder
        from pulsejet_sim.core.topics import APPLIED_COMMAND_NAMES

        self.writer = writer
        self.encoder = ColumnEncoder()
        self.command_values = operator.attrgetter(*APPLIED_COMMAND_NAMES)  # the encoder's columns
        self.state_values = operator.attrgetter(*STATE_FIELDS)
        self.publication = 0
        self.last_values: tuple | None = None
        self.command_rows: list[tuple] = []
        self.state_rows: list[tuple] = []
        self.since = time.monotonic()

    def commands(self, start_s: float, command: Command) -> None:
        """Add the command sent at start_s; the applied command too when it changed."""
        self.publication += 1
        values = self.command_values(command)
        self.command_rows.append((self.publication, start_s, values != self.last_values, values))
        self.last_values = values

    def state(self, sim: Simulation, obs: Observation, ledger: bool) -> None:
        """Add the state after a publication's steps (its profile, and the ledger if asked)."""
        from pulsejet_sim.bag.cdr import stamp_ns

        self.state_rows.append((
            self.publication, obs.time_s, self.state_values(obs), sim.profile(),
            self.encoder.encoder.ledger(sim.energy_ledger(), stamp_ns(obs.time_s))
            if ledger else None,
        ))
        if (
            len(self.state_rows) >= self.FLUSH_PUBLICATIONS
            or time.monotonic() - self.since >= 0.5 * self.writer.flush_period_s
        ):
            self.flush()

    def flush(self) -> None:
        """Encode what was added, topic by topic, and write it as one batch."""
        from pulsejet_sim.bag.batch import RecordBatch
        from pulsejet_sim.bag.cdr import stamps_ns
        from pulsejet_sim.core.topics import (
            TOPIC_APPLIED_COMMAND, TOPIC_ENERGY_LEDGER, TOPIC_MANTLE_PROFILE,
        )
        import numpy as np

        commands, self.command_rows = self.command_rows, []
        states, self.state_rows = self.state_rows, []
        self.since = time.monotonic()
        batch = RecordBatch()
        enc, slots = self.encoder, self.SLOTS
        if commands:
            keys = np.array([row[0] for row in commands]) * slots
            ns = stamps_ns([row[1] for row in commands])
            values = np.array([row[3] for row in commands], dtype=np.float64)
            for slot, (topic, rows) in enumerate(enc.commands(values)):
                batch.add(topic, keys + slot, ns, rows)
            applied = np.array([row[2] for row in commands], dtype=bool)
            batch.add(
                TOPIC_APPLIED_COMMAND, keys[applied] + self.SLOT_APPLIED, ns[applied],
                enc.applied_commands(ns[applied], values[applied]),
            )
        if states:
            keys = np.array([row[0] for row in states]) * slots
            ns = stamps_ns([row[1] for row in states])
            values = np.array([row[2] for row in states], dtype=np.float64)
            named = dict(zip(STATE_FIELDS, values.T))
            for slot, (topic, rows) in enumerate(enc.state(ns, named), start=self.SLOT_STATE):
                batch.add(topic, keys + slot, ns, rows)
            profiled = np.array([row[3] is not None for row in states], dtype=bool)
            if profiled.any():
                r_m = np.array([row[3][0] for row in states if row[3] is not None])
                z_m = np.array([row[3][1] for row in states if row[3] is not None])
                batch.add(
                    TOPIC_MANTLE_PROFILE, keys[profiled] + self.SLOT_PROFILE, ns[profiled],
                    enc.profiles(ns[profiled], r_m, z_m),
                )
            ledgers = [i for i, row in enumerate(states) if row[4] is not None]
            batch.add(
                TOPIC_ENERGY_LEDGER, keys[ledgers] + self.SLOT_LEDGER, ns[ledgers],
                [states[i][4] for i in ledgers],
            )
        self.writer.write_batch(batch)


def default_output(scene: Scene) -> Path:
    import datetime

    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
    return Path('runs') / f'{scene.name}-{stamp}.mcap'
