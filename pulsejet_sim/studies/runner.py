"""
Offline runner: the same model, Simulation.step and routine as the live nodes, without DDS.

It runs as fast as the machine allows and writes the same topics to MCAP (log time = simulation
time).

`Drive` is the loop itself (no ROS): the MCAP runner and `pulsejet sweep` both iterate it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
import threading
from typing import Iterator

from pulsejet_sim.core.model_io import Command, Observation, SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.routines import routine_from_scene
from pulsejet_sim.scene import Scene

LEDGER_PERIOD_S = 0.2  # energy ledger messages at 5 Hz, as sim_node publishes them


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
    from pulsejet_sim.bag.cdr import stamp_ns, TopicEncoder
    from pulsejet_sim.bag.writer import BagWriter, install_signal_handlers
    from pulsejet_sim.core.topics import TOPIC_APPLIED_COMMAND, TOPIC_ENERGY_LEDGER
    from pulsejet_sim.core.topics import TOPIC_MANTLE_PROFILE
    import yaml

    sim, scene = drive.sim, drive.scene
    ledger_every = max(1, int(round(LEDGER_PERIOD_S / (drive.batch * scene.model.dt_s))))
    writer = BagWriter(out)
    # the scene travels with the recording, so `pulsejet resim FILE` needs nothing else
    writer.add_metadata(
        'pulsejet',
        {
            'scene': scene.name,
            'scene_yaml': yaml.safe_dump(dict(scene.data, name=scene.name), sort_keys=False),
        },
    )
    # Ctrl-C or SIGTERM during a long offline run still leaves a complete, readable file
    restore_signals = (
        install_signal_handlers(writer)
        if threading.current_thread() is threading.main_thread()
        else None
    )
    # CDR straight from the values (bag.cdr): the bytes sim_node's rclpy messages serialise to
    encoder = TopicEncoder()
    write = writer.write_records

    def write_state(obs: Observation, ledger: bool) -> None:
        ns = stamp_ns(obs.time_s)
        records = encoder.observation(obs, ns)
        profile = sim.profile()
        if profile is not None:
            records.append((TOPIC_MANTLE_PROFILE, encoder.profile(*profile, ns)))
        if ledger:
            records.append((TOPIC_ENERGY_LEDGER, encoder.ledger(sim.energy_ledger(), ns)))
        write(records, ns)

    published = 0
    last_applied = None
    try:
        write_state(sim.observe(), ledger=True)
        for start_s, command, obs in drive:
            ns = stamp_ns(start_s)
            records = encoder.commands(command)
            if command != last_applied:
                records.append((TOPIC_APPLIED_COMMAND, encoder.applied_command(command, ns)))
                last_applied = command
            write(records, ns)
            published += 1
            write_state(obs, ledger=published % ledger_every == 0 or published == drive.batches)
        if drive.fault is not None:
            write_state(sim.observe(), ledger=True)
    finally:
        writer.close()
        if restore_signals is not None:
            restore_signals()
    return RunResult(path=out, sim=sim, publications=published, fault=drive.fault)


def default_output(scene: Scene) -> Path:
    import datetime

    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
    return Path('runs') / f'{scene.name}-{stamp}.mcap'
