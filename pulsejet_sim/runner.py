"""Offline runner: the same model, Simulation.step and routine as the live nodes, as fast as the
machine allows, no DDS; writes the same topics to MCAP (log time = simulation time)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from pulsejet_ctrl.routines import routine_from_scene
from pulsejet_sim import messages
import threading

import yaml

from pulsejet_sim.bag.writer import BagWriter, install_signal_handlers
from pulsejet_sim.models.base import Command
from pulsejet_sim.scene import Scene
from pulsejet_sim.simulation import Simulation

LEDGER_PERIOD_S = 0.2   # energy ledger messages at 5 Hz, as sim_node publishes them


@dataclass
class RunResult:
    path: Path | None
    sim: Simulation
    publications: int
    fault: str | None


def steps_per_publication(scene: Scene) -> int:
    return max(1, int(round(1.0 / (scene.publish_rate_hz * scene.model.dt_s))))


def run_scene(scene: Scene, duration_s: float | None = None, out: str | Path | None = None,
              on_observation=None) -> RunResult:
    """Run `scene` for duration_s of simulated time (default: the scene's), writing MCAP to `out`
    if given. A blow-up ends the run early: the file keeps everything before it, and the fault is
    returned (never a NaN message)."""
    duration_s = scene.duration_s if duration_s is None else float(duration_s)
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f'duration_s={duration_s!r} rejected; allowed: a positive finite number of seconds')
    sim = Simulation(scene.model)
    routine = routine_from_scene(scene.routine)
    batch = steps_per_publication(scene)
    total_batches = int(math.ceil(duration_s / (batch * scene.model.dt_s) - 1e-9))
    ledger_every = max(1, int(round(LEDGER_PERIOD_S / (batch * scene.model.dt_s))))
    writer = BagWriter(out) if out is not None else None
    if writer is not None:
        # the scene travels with the recording, so `pulsejet resim FILE` needs nothing else
        writer.add_metadata('pulsejet', {'scene': scene.name, 'scene_yaml': yaml.safe_dump(
            dict(scene.data, name=scene.name), sort_keys=False)})
    # Ctrl-C or SIGTERM during a long offline run still leaves a complete, readable file
    restore_signals = (install_signal_handlers(writer)
                       if writer is not None and threading.current_thread() is threading.main_thread() else None)
    fault = None
    published = 0
    last_applied = None
    try:
        obs = sim.observe()
        _write_state(writer, obs, sim)
        for i in range(total_batches):
            command = routine.command(sim.time_s, obs.volume_m3) if routine else sim.command
            if writer is not None:
                ns = messages.stamp_ns(sim.time_s)
                for topic, msg in messages.command_messages(command):
                    writer.write_message(topic, msg, ns)
                if command != last_applied:
                    writer.write_message(messages.TOPIC_APPLIED_COMMAND,
                                         messages.applied_command_message(command, sim.time_s), ns)
                    last_applied = command
            try:
                obs = sim.step(batch, command)
            except Exception as err:   # SimulationBlowUp: stop, keep what was good
                fault = str(err)
                break
            published += 1
            if on_observation is not None:
                on_observation(obs)
            _write_state(writer, obs, sim, ledger=(i + 1) % ledger_every == 0 or i + 1 == total_batches)
    finally:
        if writer is not None:
            if fault is not None:
                writer.write_message(messages.TOPIC_ENERGY_LEDGER,
                                     messages.ledger_message(sim.energy_ledger(), sim.time_s),
                                     messages.stamp_ns(sim.time_s))
            writer.close()
        if restore_signals is not None:
            restore_signals()
    return RunResult(path=Path(out) if out is not None else None, sim=sim, publications=published, fault=fault)


def _write_state(writer, obs, sim: Simulation, ledger: bool = True) -> None:
    if writer is None:
        return
    ns = messages.stamp_ns(obs.time_s)
    for topic, msg in messages.observation_messages(obs):
        writer.write_message(topic, msg, ns)
    if ledger:
        writer.write_message(messages.TOPIC_ENERGY_LEDGER, messages.ledger_message(sim.energy_ledger(), obs.time_s), ns)


def default_output(scene: Scene) -> Path:
    import datetime
    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
    return Path('runs') / f'{scene.name}-{stamp}.mcap'


__all__ = ['run_scene', 'RunResult', 'steps_per_publication', 'default_output', 'Command']
