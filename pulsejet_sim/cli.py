"""
`pulsejet`: offline tools.

`pulsejet run SCENE`, `pulsejet summary FILE.mcap`, `pulsejet plot FILE.mcap`, `pulsejet animate
FILE.mcap`, `pulsejet resim FILE.mcap`, `pulsejet repair FILE.mcap`, `pulsejet sweep SWEEP`,
`pulsejet fit FIT`, `pulsejet optimize OPT`, `pulsejet validate [CASE...]`, `pulsejet view SCENE`,
`pulsejet scenes`.
"""

from __future__ import annotations

import argparse
import sys
import time


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog='pulsejet run', description='Run a scene offline (no DDS) and record it to MCAP.'
    )
    parser.add_argument('scene', help='scene name under config/ or a YAML path')
    parser.add_argument(
        '--duration', type=float, default=None, help="simulated seconds (default: the scene's)"
    )
    parser.add_argument(
        '--out', default=None, help='output MCAP (default: runs/<scene>-<time>.mcap)'
    )
    parser.add_argument(
        '--dt', type=float, default=None, help='physics step in s (overrides the scene)'
    )
    parser.add_argument('--no-plot', action='store_true', help='do not write the PNG plot')
    args = parser.parse_args(argv)
    from pulsejet_sim import analysis
    from pulsejet_sim.scene import load_scene, SceneError
    from pulsejet_sim.studies.runner import default_output, run_scene

    try:
        overrides = {'simulation': {'dt_s': args.dt}} if args.dt is not None else None
        scene = load_scene(args.scene, overrides)
        out = args.out or default_output(scene)
        wall = time.perf_counter()
        result = run_scene(scene, args.duration, out)
        wall = time.perf_counter() - wall
    except (SceneError, ValueError) as err:
        print(f'pulsejet run: {err}', file=sys.stderr)
        return 2
    sim_s = result.sim.time_s
    print(
        f'{scene.name}: {sim_s:.3f} s simulated in {wall:.3f} s wall '
        f'({sim_s / max(wall, 1e-9):.1f}x real time) -> {out}'
    )
    if result.fault:
        print(f'pulsejet run: FAULT: {result.fault}', file=sys.stderr)
    print(analysis.format_summary(analysis.summarize(out)))
    if not args.no_plot:
        print(f'plot: {analysis.plot(out)}')
    return 1 if result.fault else 0


def _scenes(argv: list[str]) -> int:
    from pulsejet_sim.scene import available_scenes

    print('\n'.join(available_scenes()))
    return 0


def _lazy(module: str, function: str):
    """Import a sub-command's module only when it runs (sweep workers must not pull in rclpy)."""

    def call(argv: list[str]) -> int:
        import importlib

        return getattr(importlib.import_module(f'pulsejet_sim.{module}'), function)(argv)

    return call


#: command -> (what it does, its entry point); each entry point parses its own options (argparse)
COMMANDS = {
    'run': ('run a scene offline (no DDS) and record it to MCAP', _run),
    'summary': (
        'key numbers of a recording (live or offline)',
        _lazy('analysis.summary', 'main_summary'),
    ),
    'plot': (
        'radius, volume, velocity and thrust of a recording as a PNG (+ mantle snapshots over a '
        'cycle for shell runs)',
        _lazy('analysis.summary', 'main_plot'),
    ),
    'animate': (
        'the mantle section of a shell recording as a GIF or MP4',
        _lazy('analysis.profiles', 'main_animate'),
    ),
    'resim': (
        're-simulate a recording from its applied commands and compare',
        _lazy('studies.resim', 'main_resim'),
    ),
    'repair': (
        'write a complete copy of a damaged recording, metadata kept',
        _lazy('bag.repair', 'main_repair'),
    ),
    'sweep': (
        'a grid of scenes on a process pool or Dask', _lazy('studies.sweep', 'main_sweep')
    ),
    'fit': (
        'calibrate scene parameters to figures or a recording', _lazy('studies.fit', 'main_fit')
    ),
    'optimize': (
        'search scene parameters (differential evolution) on a process pool or Dask',
        _lazy('studies.optimize', 'main_optimize'),
    ),
    'validate': (
        'predicted against measured figures of real robots: docs/validation/ report',
        _lazy('studies.validation', 'main_validate'),
    ),
    'view': (
        'run a scene in real time, served live to the Foxglove app (WebSocket; no ROS)',
        _lazy('view.foxglove_live', 'main_view'),
    ),
    'scenes': ('list the scenes under config/', _scenes),
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(
        prog='pulsejet',
        description='pulsejet offline tools (no DDS). `pulsejet COMMAND -h` shows the options '
        'of a command.',
    )
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, (text, _) in COMMANDS.items():
        # the command's own argparse parses the rest (and answers its -h with every option)
        sub.add_parser(name, help=text, add_help=False)
    try:
        args, _ = parser.parse_known_args(argv[:1])
    except SystemExit as exit_:
        return int(exit_.code or 0)
    return int(COMMANDS[args.command][1](argv[1:]) or 0)


if __name__ == '__main__':
    sys.exit(main())
