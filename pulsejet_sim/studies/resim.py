"""
Re-simulate a recording from the commands the simulator applied, and compare the states.

A recording (offline `pulsejet run` or live sim_node + recorder) holds `pulsejet/applied_command`
(sensor_msgs/JointState, see messages.applied_command_message): each message is the command the
simulator held from its header stamp (simulation time) on. resimulate() converts those stamps to
step indices (round(t / dt)), runs a fresh `Simulation` of the scene holding each command from
its step on, steps exactly to the stamp of every recorded `pulsejet/velocity`, `pulsejet/volume`
and `pulsejet/mantle_radius` message (nothing is interpolated) and reports the largest absolute
difference per topic.

A recording made by the offline runner re-simulates bit-identically (every error exactly 0.0): it
drove the same Simulation with the same commands over the same step batches. A live recording
re-simulates exactly too when sim_node publishes `pulsejet/applied_command` for every new command
it holds, stamped with the simulation time from which it holds it.

Times of the recorded states: the header stamp where the message has one (TwistStamped). Float64
topics have none; their log time is used when it is simulation time (offline runner: log time ==
simulation time, detected from /clock or the velocity stamps). For a live recording (log time =
wall-clock receive time) whose topic holds as many messages as the stamped velocity, in strictly
increasing stamps, the k-th message is the k-th state (the simulator publishes every state topic
of one observation together, reliably); otherwise the log time is mapped onto simulation time
through the recorded /clock and snapped to the nearest stamped observation time, which can pick a
neighbouring state when states arrive a few ms apart. `ResimResult.time_source` says which was
used.

Scene: the `scene` argument, else one stored in the file (an MCAP metadata record `pulsejet` with
key `scene_yaml` = the complete scene as YAML, or `scene` = a scene name or path); else ResimError.

    pulsejet resim FILE.mcap --scene NAME [--dt S] [--out NEW.mcap] [--tolerance T]

prints the comparison table; exit 0 when every max error <= tolerance (default 0: bit-identical)
and every recorded state was re-simulated, 1 otherwise, 2 on bad input.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import math
from pathlib import Path
import sys
from typing import Any, Iterable, Sequence

import numpy as np
from pulsejet_sim.bag.reader import BagInfo, BagReadError, find_topic, iter_bag, stamp_to_s
from pulsejet_sim.core.model_io import Command, CommandError, SimulationBlowUp
from pulsejet_sim.core.topics import APPLIED_COMMAND_NAMES
from pulsejet_sim.core.topics import TOPIC_APPLIED_COMMAND as APPLIED_COMMAND
from pulsejet_sim.core.topics import TOPIC_MANTLE_RADIUS as MANTLE_RADIUS
from pulsejet_sim.core.topics import TOPIC_VELOCITY as VELOCITY
from pulsejet_sim.core.topics import TOPIC_VOLUME as VOLUME

COMPARED_TOPICS = (VELOCITY, VOLUME, MANTLE_RADIUS)
# topic -> Observation attribute it carries
OBSERVATION_FIELD = {
    VELOCITY: 'velocity_m_s',
    VOLUME: 'volume_m3',
    MANTLE_RADIUS: 'mantle_radius_m',
}
APPLIED_NAMES = APPLIED_COMMAND_NAMES  # the names sim_node and the runner write, in order
METADATA_NAME = 'pulsejet'  # MCAP metadata record that may name the scene of a recording


class ResimError(ValueError):
    """A recording that cannot be re-simulated (names the file or value and what is expected)."""


@dataclass
class TopicComparison:
    topic: str  # relative name, e.g. 'pulsejet/velocity'
    recorded: int = 0  # recorded messages
    compared: int = 0  # of those, re-simulated and compared
    max_abs_error: float = 0.0  # largest |resim - recorded| (inf for a non-finite value)
    worst_time_s: float | None = None

    @property
    def complete(self) -> bool:
        return self.compared == self.recorded


@dataclass
class ResimResult:
    bag_path: Path
    scene_name: str
    dt_s: float
    commands: list[tuple[int, Command]]  # (step index from which held, command)
    topics: dict[str, TopicComparison]  # relative topic -> comparison
    steps: int  # physics steps re-simulated
    time_source: str  # Float64 topics: 'log time' | 'publication order' | 'clock-mapped'
    fault: str | None = None  # SimulationBlowUp during re-simulation
    warnings: list[str] = field(default_factory=list)
    out_path: Path | None = None

    @property
    def max_abs_error(self) -> dict[str, float]:
        return {t: c.max_abs_error for t, c in self.topics.items()}

    @property
    def max_error(self) -> float:
        return max((c.max_abs_error for c in self.topics.values()), default=0.0)

    @property
    def bit_identical(self) -> bool:
        return self.within(0.0)

    def within(self, tolerance: float = 0.0) -> bool:
        """Every recorded state re-simulated and every max error <= tolerance."""
        return (
            self.fault is None
            and bool(self.topics)
            and all(
                c.complete and c.recorded > 0 and c.max_abs_error <= tolerance
                for c in self.topics.values()
            )
        )

    def format_table(self) -> str:
        lines = [
            f'resim {self.bag_path}: scene {self.scene_name}, dt {self.dt_s:g} s, '
            f'{len(self.commands)} applied commands, {self.steps} steps '
            f'({self.steps * self.dt_s:.4f} s), state times from {self.time_source}',
            f'{"topic":<26} {"recorded":>8} {"compared":>8} {"max |error|":>13} {"at t [s]":>10}',
        ]
        for c in self.topics.values():
            at = '-' if c.worst_time_s is None else f'{c.worst_time_s:.4f}'
            lines.append(
                f'{c.topic:<26} {c.recorded:>8d} {c.compared:>8d} {c.max_abs_error:>13.6g} '
                f'{at:>10}'
            )
        if self.fault:
            lines.append(f'FAULT during re-simulation: {self.fault}')
        lines.extend(f'warning: {w}' for w in self.warnings)
        if self.out_path is not None:
            lines.append(f're-simulated states written to {self.out_path}')
        return '\n'.join(lines)


# ---- reading ------------------------------------------------------------------------------------
def _command_from_joint_state(msg: Any) -> tuple[float, Command]:
    """messages.command_from_applied without importing rclpy message classes."""
    values = dict(zip(msg.name, msg.position))
    missing = [n for n in APPLIED_NAMES if n not in values]
    if missing:
        raise ResimError(
            f'applied command with names {list(msg.name)!r} lacks {missing}; '
            f'expected names {list(APPLIED_NAMES)}'
        )
    t = stamp_to_s(msg.header.stamp)
    try:
        command = Command(*(float(values[n]) for n in APPLIED_NAMES)).validate()
    except (CommandError, TypeError, ValueError) as err:
        raise ResimError(f'applied command at t={t:.9g} s refused: {err}') from None
    return t, command


def read_applied_commands(path: str | Path) -> list[tuple[float, Command]]:
    """
    Return (simulation time from which held, Command) of every `pulsejet/applied_command`.

    In file order.
    """
    info = BagInfo(Path(path))
    names = _topic_names(path)
    topic = find_topic(names, APPLIED_COMMAND)
    if topic is None:
        raise ResimError(
            f'{str(path)!r} has no {APPLIED_COMMAND} topic (topics: {sorted(names)}); expected '
            'a recording of `pulsejet run` or of a sim_node that publishes the applied command'
        )
    return [_command_from_joint_state(m.msg) for m in iter_bag(path, topics=[topic], info=info)]


def _topic_names(path: str | Path) -> list[str]:
    info = BagInfo(Path(path))
    for _ in iter_bag(path, info=info, decode=False, types=()):
        pass
    return list(info.topics)


@dataclass
class RecordedStates:
    """Recorded values per relative topic: list of (simulation time s, value)."""

    values: dict[str, list[tuple[float, float]]]
    time_source: str
    first_time_s: float | None


def read_recorded_states(path: str | Path) -> RecordedStates:
    names = _topic_names(path)
    topics = {rel: find_topic(names, rel) for rel in COMPARED_TOPICS}
    clock_topic = find_topic(names, 'clock') if '/clock' not in names else '/clock'
    wanted = [t for t in topics.values() if t] + ([clock_topic] if clock_topic else [])
    raw: dict[str, list[tuple[int, float | None, float]]] = {rel: [] for rel in COMPARED_TOPICS}
    clock: list[tuple[int, float]] = []
    by_name = {v: k for k, v in topics.items() if v}
    for m in iter_bag(path, topics=wanted):
        if m.topic == clock_topic:
            clock.append((m.log_time_ns, stamp_to_s(m.msg.clock)))
            continue
        rel = by_name[m.topic]
        header = getattr(m.msg, 'header', None)
        value = float(m.msg.twist.linear.x) if rel == VELOCITY else float(m.msg.data)
        raw[rel].append(
            (m.log_time_ns, stamp_to_s(header.stamp) if header is not None else None, value)
        )

    # Is the log time simulation time (offline runner) or a receive time (live recorder)?
    if clock:
        log_is_sim = all(abs(ns * 1e-9 - t) < 1e-9 for ns, t in clock)
    else:
        stamped = raw[VELOCITY]
        log_is_sim = all(abs(ns * 1e-9 - t) < 1e-9 for ns, t, _ in stamped if t is not None)
    stamps = np.array(
        sorted({t for t_list in raw.values() for _, t, _ in t_list if t is not None})
    )
    if log_is_sim:
        to_sim = None
    else:
        if not clock:
            raise ResimError(
                f'{str(path)!r}: log times are not simulation time and there is no /clock to map '
                'them; expected a recording with /clock or stamped state topics'
            )
        lx = np.array([c[0] * 1e-9 for c in clock])
        sx = np.array([c[1] for c in clock])
        order = np.argsort(lx, kind='stable')
        lx, sx = lx[order], sx[order]

        def to_sim(t_log: float) -> float:
            t = float(np.interp(t_log, lx, sx))
            if len(stamps):  # snap onto the nearest observation time of a stamped topic
                i = (
                    int(np.clip(np.searchsorted(stamps, t), 1, len(stamps) - 1))
                    if len(stamps) > 1
                    else 0
                )
                cands = stamps[max(i - 1, 0): i + 1]
                t = float(cands[np.argmin(np.abs(cands - t))])
            return t

    # A live recording that holds every state in order: the k-th message of an unstamped topic is
    # the k-th observation (sim_node publishes each state's topics together over reliable
    # transport), which is exact where a receive time mapped through /clock is not (at a high
    # real-time factor states arrive a few ms apart and receive times of topics interleave).
    velocity_stamps = [t for _, t, _ in raw[VELOCITY] if t is not None]
    in_order = (
        not log_is_sim
        and len(velocity_stamps) == len(raw[VELOCITY]) > 0
        and all(b > a for a, b in zip(velocity_stamps, velocity_stamps[1:]))
    )
    values: dict[str, list[tuple[float, float]]] = {}
    sources = set()
    for rel, items in raw.items():
        if topics[rel] is None:
            continue
        out = []
        by_order = in_order and len(items) == len(velocity_stamps)
        for k, (ns, t, v) in enumerate(items):
            if t is None:
                if log_is_sim:
                    t = ns * 1e-9
                elif by_order:
                    t = velocity_stamps[k]
                    sources.add('publication order')
                else:
                    t = to_sim(ns * 1e-9)
                    sources.add('clock-mapped')
            out.append((t, v))
        values[rel] = out
    first = min((t for items in values.values() for t, _ in items), default=None)
    source = 'log time' if log_is_sim else ' and '.join(sorted(sources)) or 'header stamps'
    return RecordedStates(values, source, first)


def stored_scene(path: str | Path) -> Any | None:
    """
    Return the scene stored in the file's `pulsejet` metadata record, or None.

    The record is untrusted data: `scene_yaml` is parsed with the safe YAML loader and validated
    like a scene file (nothing in it is executed, no file it names is opened); `scene` alone is
    used only when it is a bare scene name under config/ (a path, absolute or relative, is never
    followed). ResimError names what was refused.
    """
    from pulsejet_sim.bag.reader import read_metadata
    from pulsejet_sim.core.schema import show
    from pulsejet_sim.scene import is_project_scene_name, load_scene, scene_from_stored, SceneError

    found = read_metadata(path, METADATA_NAME)
    try:
        if 'scene_yaml' in found:
            name = found.get('scene', 'stored')
            return scene_from_stored(
                found['scene_yaml'], name if isinstance(name, str) and name else 'stored'
            )
        if 'scene' in found:
            if not is_project_scene_name(found['scene']):
                raise ResimError(
                    f'{str(path)!r}: stored scene {show(found["scene"])} is not a scene name '
                    'under '
                    'config/ (paths stored in a recording are not followed); pass --scene NAME or '
                    'a YAML path you trust'
                )
            return load_scene(found['scene'])
    except SceneError as err:
        raise ResimError(
            f'{str(path)!r}: the scene stored in the recording is refused: {err}; pass --scene'
        ) from None
    return None


# ---- re-simulation ------------------------------------------------------------------------------
def _resolve_scene(bag_path: Path, scene: Any, dt_s: float | None) -> Any:
    from pulsejet_sim.scene import load_scene, SceneError

    overrides = {'simulation': {'dt_s': float(dt_s)}} if dt_s is not None else None
    if scene is None:
        stored = stored_scene(bag_path)
        if stored is None:
            raise ResimError(
                f'{str(bag_path)!r} does not name its scene; pass one (--scene NAME or a YAML '
                'path)'
            )
        if overrides is None:
            return stored
        from pulsejet_sim.scene import merge, scene_from_dict

        try:
            return scene_from_dict(
                merge(stored.data, overrides), name=stored.name, path=stored.path
            )
        except SceneError as err:
            raise ResimError(str(err)) from None
    if isinstance(scene, (str, Path)):
        try:
            return load_scene(scene, overrides)
        except SceneError as err:
            raise ResimError(str(err)) from None
    if overrides is not None:
        raise ResimError(
            'dt_s cannot be combined with a Scene object; load the scene with the override'
        )
    return scene


def resimulate(
    bag_path: str | Path,
    scene: Any = None,
    *,
    commands: Iterable[tuple[float, Command]] | None = None,
    out: str | Path | None = None,
    dt_s: float | None = None,
) -> ResimResult:
    """
    Re-simulate `bag_path` and compare it against its recorded states.

    scene: a Scene, a scene name or YAML path, or None (the scene stored in the file).
    commands: (time_s, Command) to apply instead of the recorded applied commands (what-if runs).
    out: write the re-simulated states (same topics and stamps as the runner) to this MCAP.
    dt_s: physics step overriding the scene's (a recording made with `pulsejet run --dt`).
    Raises ResimError (or BagReadError) for an unreadable file or missing data.
    """
    from pulsejet_sim.engine.simulation import Simulation

    path = Path(bag_path)
    if dt_s is not None and not (
        isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and dt_s > 0
    ):
        raise ResimError(f'dt_s={dt_s!r} rejected; allowed: a positive finite step in s')
    scene_obj = _resolve_scene(path, scene, dt_s)
    recorded_commands = list(commands) if commands is not None else read_applied_commands(path)
    states = read_recorded_states(path)
    dt = float(scene_obj.model.dt_s)
    result = ResimResult(
        bag_path=path,
        scene_name=str(scene_obj.name),
        dt_s=dt,
        commands=[],
        topics={},
        steps=0,
        time_source=states.time_source,
    )
    if not recorded_commands:
        raise ResimError(
            f'{str(path)!r}: no applied commands to re-simulate; expected {APPLIED_COMMAND} '
            'messages'
        )

    # command step index -> command (the later message wins on the same step)
    cmd_at: dict[int, Command] = {}
    for t, cmd in recorded_commands:
        if not (math.isfinite(t) and t >= 0):
            raise ResimError(
                f'applied command time {t!r} rejected; allowed: a finite simulation time >= 0'
            )
        step = int(round(t / dt))
        if abs(step * dt - t) > 0.5e-6 + 1e-9 * t:
            result.warnings.append(
                f'applied command at t={t:.9f} s is not on the {dt:g} s step grid '
                f'(held from step {step}); wrong dt?'
            )
        cmd_at[step] = cmd
    result.commands = sorted(cmd_at.items())
    if result.commands[0][0] != 0:
        result.warnings.append(
            f'first applied command at t={result.commands[0][0] * dt:g} s; before it the '
            "scene's initial command is held"
        )
    if states.first_time_s is not None and states.first_time_s > 0.5 * dt:
        result.warnings.append(
            f'recorded states start at t={states.first_time_s:g} s; the recording may have '
            'missed the start of the run (the re-simulation starts at t=0)'
        )

    # step index -> [(topic, recorded value, time)]
    targets: dict[int, list[tuple[str, float, float]]] = {}
    for rel, items in states.values.items():
        result.topics[rel] = TopicComparison(rel, recorded=len(items))
        for t, v in items:
            if not (math.isfinite(t) and t >= 0):
                result.warnings.append(f'{rel} at t={t!r} s: not a simulation time; not compared')
                continue
            targets.setdefault(int(round(t / dt)), []).append((rel, v, t))
    _check_span(path, sorted(set(targets) | set(cmd_at)), dt)
    for rel in COMPARED_TOPICS:
        if rel not in result.topics:
            result.warnings.append(f'no {rel} recorded: not compared')

    writer = None
    if out is not None:
        from pulsejet_sim.bag.cdr import stamp_ns, TopicEncoder
        from pulsejet_sim.bag.writer import BagWriter

        encoder = TopicEncoder()  # the bytes sim_node's messages serialise to, without rclpy
        writer = BagWriter(out)
        result.out_path = Path(out)
    sim = Simulation(scene_obj.model)
    try:
        breakpoints = sorted(set(targets) | set(cmd_at))
        command = sim.command
        for step in breakpoints:
            if step > sim.steps:
                try:
                    sim.step(step - sim.steps, command)
                except SimulationBlowUp as err:
                    result.fault = str(err)
                    break
            obs = sim.observe()
            for rel, value, t in targets.get(step, ()):
                tc = result.topics[rel]
                err = abs(float(getattr(obs, OBSERVATION_FIELD[rel])) - value)
                if not math.isfinite(err):
                    err = math.inf
                tc.compared += 1
                if err > tc.max_abs_error:
                    tc.max_abs_error, tc.worst_time_s = err, t
            if writer is not None and step in targets:
                ns = stamp_ns(sim.time_s)
                writer.write_records(encoder.observation(obs, ns), ns)
            if step in cmd_at:  # held from this step on: after the state observed at it
                command = cmd_at[step]
                sim.command = command
                if writer is not None:
                    ns = stamp_ns(step * dt)
                    writer.write_records(
                        [(APPLIED_COMMAND, encoder.applied_command(command, ns))], ns
                    )
    finally:
        if writer is not None:
            writer.close()
    result.steps = sim.steps
    return result


MAX_GAP_S = 3600.0  # sim time between two recorded instants beyond which the file is refused
MAX_STEPS = 2_000_000_000  # physics steps a re-simulation may take


def _check_span(path: Path, steps: list[int], dt: float) -> None:
    """
    Refuse a recording whose times would make the re-simulation run for ever.

    That is a damaged stamp (e.g. t = 1e9 s in a 10 s run) far beyond the other recorded instants,
    or a span beyond MAX_STEPS.
    """
    if not steps:
        return
    if steps[-1] > MAX_STEPS:
        raise ResimError(
            f'{str(path)!r}: a recorded time of {steps[-1] * dt:.6g} s needs {steps[-1]} physics '
            'steps; '
            f'allowed: at most {MAX_STEPS} steps (dt {dt:g} s); the file looks damaged'
        )
    prev = 0
    for step in steps:
        if (step - prev) * dt > MAX_GAP_S:
            raise ResimError(
                f'{str(path)!r}: recorded time {step * dt:.6g} s follows {prev * dt:.6g} s with '
                'nothing '
                f'recorded in between; allowed: gaps up to {MAX_GAP_S:g} s of simulation time '
                '(a damaged stamp?)'
            )
        prev = step


# ---- CLI ----------------------------------------------------------------------------------------
def _float_above(low: float, inclusive: bool):
    """
    Return an argparse type: a finite float > low (>= low when inclusive).

    Otherwise the type reports a message saying what is allowed.
    """

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not (math.isfinite(v) and (v >= low if inclusive else v > low)):
            raise argparse.ArgumentTypeError(
                f'{text!r} rejected; allowed: a finite number {">=" if inclusive else ">"} {low:g}'
            )
        return v

    return parse


_nonneg_float = _float_above(0.0, inclusive=True)
_pos_float = _float_above(0.0, inclusive=False)


def main_resim(argv: Sequence[str] | None = None) -> int:
    """
    Run `pulsejet resim FILE.mcap [--scene NAME] [--dt S] [--out NEW.mcap] [--tolerance T]`.

    Exit code: 0 all errors <= tolerance, 1 otherwise (or a blow-up), 2 bad input.
    """
    parser = argparse.ArgumentParser(
        prog='pulsejet resim',
        description='Re-simulate a recording from its pulsejet/applied_command messages and '
                    'compare the '
        'recorded velocity, volume and mantle radius with the re-simulated ones.',
    )
    parser.add_argument('file', help='MCAP recording (.mcap) with pulsejet/applied_command')
    parser.add_argument(
        '--scene',
        default=None,
        help='scene name under config/ or a YAML path (default: the scene stored in the file)',
    )
    parser.add_argument(
        '--dt', type=_pos_float, default=None, help='physics step in s (if the run overrode it)'
    )
    parser.add_argument('--out', default=None, help='write the re-simulated states to this MCAP')
    parser.add_argument(
        '--tolerance',
        type=_nonneg_float,
        default=0.0,
        help='largest allowed max |error| per topic (default 0: bit-identical)',
    )
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    from pulsejet_sim.scene import SceneError

    if args.out is not None and Path(args.out).resolve() == Path(args.file).resolve():
        print(
            f'pulsejet resim: --out {args.out!r} rejected; allowed: a path other than the input '
            'file',
            file=sys.stderr,
        )
        return 2
    try:
        result = resimulate(args.file, args.scene, out=args.out, dt_s=args.dt)
    except (ResimError, BagReadError, SceneError) as err:
        print(f'pulsejet resim: {err}', file=sys.stderr)
        return 2
    print(result.format_table())
    ok = result.within(args.tolerance)
    what = 'bit-identical' if args.tolerance == 0 else f'within tolerance {args.tolerance:g}'
    print(f'result: {"OK, " + what if ok else "MISMATCH, not " + what}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main_resim())
