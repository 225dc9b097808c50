"""
Which valve openings the lumped model can hold, and whether a closing valve faults on its way shut.

    .venv/bin/python -m benchmarks.validation.valve_seat_probe [--code DIR] [--no-write]

For each shipped lumped scene and each valve opening, from three starts (at rest; inflated for 0.2
s and for 1 s by the pump with the valve shut) and seven pump flows (0 to the command limit 0.05
m^3/s):
  - hold: the opening is commanded and held for 0.3 s;
  - close: the opening plus 1e-5 (not a multiple of the valve's stroke per step) is held for 30 ms,
    then the valve is commanded shut for 0.2 s (its stroke passes the openings below).
Counts the runs that fault (SimulationBlowUp) and the commands refused (CommandError). `--code DIR`
probes the model of another pulsejet checkout (e.g. a `git worktree` of an older commit) with this
script. Writes benchmarks/results/valve_seat.md (appends a section per run). Not a test.
"""

from __future__ import annotations

import argparse
import datetime
import os
from pathlib import Path
import platform
import subprocess
import sys

from benchmarks.common import append, RESULTS as RESULTS_DIR

REPO = Path(__file__).resolve().parents[2]
RESULTS = RESULTS_DIR / 'valve_seat.md'
OPENINGS = (1e-9, 1e-6, 1e-4, 3e-4, 1e-3, 1.5e-3, 2e-3, 3e-3, 1e-2, 0.1, 0.5, 1.0)
FLOWS_M3_S = (0.0, 1e-4, 1e-3, 2.5e-3, 6e-3, 0.02, 0.05)
INFLATE_S = (0.0, 0.2, 1.0)
INFLATE_FLOW_M3_S = 2.5e-3
HOLD_S, CLOSE_HOLD_S, CLOSE_S = 0.3, 0.03, 0.2
SCENES = ('pump_cycle', 'escape')


def probe(scene_name: str) -> list[dict]:
    from pulsejet_sim.core.model_io import Command, CommandError, SimulationBlowUp
    from pulsejet_sim.engine.simulation import Simulation
    from pulsejet_sim.scene import load_scene

    scene = load_scene(scene_name, command_driven=True)
    sim = Simulation(scene.model)
    dt = scene.model.dt_s

    def steps(seconds):
        return int(round(seconds / dt))

    def run(phases):
        sim.reset()
        try:
            for seconds, q, v in phases:
                sim.step(steps(seconds), Command(pump_flow_m3_s=q, valve_opening=v))
        except CommandError:
            return 'refused'
        except SimulationBlowUp:
            return 'fault'
        return 'ran'

    rows = []
    for opening in OPENINGS:
        hold, close = [], []
        for inflate_s in INFLATE_S:
            pre = [(inflate_s, INFLATE_FLOW_M3_S, 0.0)] if inflate_s else []
            for q in FLOWS_M3_S:
                hold.append(run(pre + [(HOLD_S, q, opening)]))
                if opening + 1e-5 <= 1.0:
                    close.append(run(pre + [(CLOSE_HOLD_S, q, opening + 1e-5), (CLOSE_S, q, 0.0)]))
        rows.append({'opening': opening, 'hold': hold, 'close': close})
    return rows


def table(scene: str, rows: list[dict]) -> str:
    lines = [
        f'{scene}: runs per opening: {len(INFLATE_S)} starts x {len(FLOWS_M3_S)} pump flows',
        '',
        '| valve opening | hold 0.3 s: fault / refused / ran | opening + 1e-5, then shut:'
        ' fault / refused / ran |',
        '|---:|---|---|',
    ]
    for r in rows:

        def count(outcomes):
            if not outcomes:
                return 'n/a'
            return ' / '.join(str(outcomes.count(k)) for k in ('fault', 'refused', 'ran'))

        lines.append(f"| {r['opening']:g} | {count(r['hold'])} | {count(r['close'])} |")
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--code', type=Path, default=REPO, help='pulsejet checkout to probe')
    ap.add_argument('--no-write', action='store_true')
    args = ap.parse_args(argv)
    code = args.code.resolve()
    if not (code / 'pulsejet_sim' / '__init__.py').is_file():
        ap.error(f'--code {args.code}: not a pulsejet checkout (no pulsejet_sim package there)')
    import pulsejet_sim

    if Path(pulsejet_sim.__file__).resolve().parents[1] != code:
        # another checkout's model: run this probe again in a process started in that checkout,
        # whose directory comes first on sys.path, so pulsejet_sim is imported from there
        if os.environ.get('PULSEJET_PROBE_RERUN'):
            ap.error(f'--code {code}: no pulsejet_sim package imported from there')
        env = dict(os.environ, PULSEJET_PROBE_RERUN='1')
        env['PYTHONPATH'] = os.pathsep.join(p for p in (str(REPO), env.get('PYTHONPATH')) if p)
        rerun = [sys.executable, '-m', 'benchmarks.validation.valve_seat_probe']
        rerun += sys.argv[1:] if argv is None else list(argv)
        return subprocess.run(rerun, cwd=code, env=env).returncode
    commit = subprocess.run(
        ['git', '-C', str(code), 'rev-parse', '--short', 'HEAD'],
        capture_output=True,
        text=True,
    ).stdout.strip()
    dirty = subprocess.run(
        ['git', '-C', str(code), 'status', '--porcelain', '--', 'pulsejet_sim'],
        capture_output=True,
        text=True,
    ).stdout.strip()
    from pulsejet_sim.core.model_io import VALVE_MIN_OPENING

    now = datetime.datetime.now(datetime.timezone.utc)
    modified = ' (pulsejet_sim/ modified)' if dirty else ''
    text = (
        f'## {now:%Y-%m-%d %H:%M UTC}, model of commit {commit}{modified}'
        f'\n\nmachine: {platform.machine()}, {os.cpu_count()} cores, Python'
        f' {platform.python_version()}; command: `python -m benchmarks.validation.valve_seat_probe'
        f'{" --code " + str(args.code) if code != REPO else ""}`;'
        f' smallest valve opening a command may ask for: {VALVE_MIN_OPENING:g}\n\n'
        + '\n\n'.join(table(s, probe(s)) for s in SCENES)
        + '\n'
    )
    print(text)
    if not args.no_write:
        append(
            RESULTS,
            '# Valve openings the lumped model can hold\n\nProduced by'
            ' `benchmarks/validation/valve_seat_probe.py`; newest last. A fault is a'
            ' SimulationBlowUp'
            ' (reported, never published as NaN); refused: the command was refused'
            ' (CommandError).\n\n',
            text,
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
