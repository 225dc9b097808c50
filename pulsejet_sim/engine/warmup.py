"""
Warm numba's on-disk compile cache for the shipped scenes.

So a fresh install's first start is fast.

    pulsejet_warmup [SCENE ...] [--quiet]          (or: python -m pulsejet_sim.engine.warmup)

The physics kernels are ``@njit(cache=True)``: the first process that calls a kernel signature
compiles it (the shell kernels take ~20 s) and writes the machine code to the cache
(NUMBA_CACHE_DIR when set, else the ``__pycache__`` next to the kernel's source file when it is
writable, else the user cache directory); later processes load it in milliseconds.  A cache entry
is keyed by the function (module, name, line), a hash of its source file, its type signature -- for
the lumped model's ``numba.literally`` specialisations that includes the literal term-flag value --
and the host CPU.  So the cache must be filled by the *installed* copy of the package, on the
machine that runs it, with exactly the signatures ``sim_node`` calls.  This module does that by
loading every shipped scene (config/*.yaml) the way sim_node does (``command_driven=True``),
building its model and doing what sim_node's ``_warm_up`` and the first publication do: one step,
an observation, the energy ledger, the stable step and the mantle profile, then a reset.  Both
models and the couplings and integrators the shipped scenes use are covered because the scenes are.

``setup.py install`` / ``setup.py develop`` (what ``colcon build`` runs for ament_python, with and
without --symlink-install) run this in a subprocess against the installed tree after installing.
Exit status: 0 when every scene compiled (or loaded from the cache), 1 when one failed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import time

# The modules of the njit(cache=True) physics kernels whose cache this warms and lists.
KERNEL_MODULES = ('pulsejet_sim.models.lumped.kernels', 'pulsejet_sim.models.shell.kernels')


def shipped_scenes(config_dir: str | os.PathLike | None = None) -> list[Path]:
    """
    Return the scene files sim_node can be started with by name: config/*.yaml.

    Not the sweeps/optimize/params/fits sub-directories, which are not scenes; from ``config_dir``
    or the first config directory the package finds (source tree, then the installed share
    directory).
    """
    if config_dir is None:
        from pulsejet_sim.scene.paths import config_dirs

        dirs = config_dirs()
        if not dirs:
            return []
        config_dir = dirs[0]
    return sorted(Path(config_dir).glob('*.yaml'))


def kernel_signatures() -> tuple[set, set]:
    """
    Return (loaded, compiled): the kernel signatures loaded from numba's cache and compiled.

    These are the signatures this process has so far loaded from numba's cache and compiled itself,
    as sets of (function, signature), over every dispatcher of the kernel modules (numba's
    ``dispatcher.stats.cache_hits`` against ``dispatcher.overloads``). A ``numba.literally`` kernel
    also records a cache miss for its non-literal signature on every first call; that is not a
    compilation and is not counted.
    """
    from numba.core.dispatcher import Dispatcher

    loaded, compiled = set(), set()
    for name in KERNEL_MODULES + ('pulsejet_sim.models.lumped.batch',):
        mod = sys.modules.get(name)
        if mod is None:
            continue
        for attr, obj in vars(mod).items():
            if not isinstance(obj, Dispatcher):
                continue
            hits = obj.stats.cache_hits
            for sig in obj.overloads:
                (loaded if hits.get(sig, 0) else compiled).add((f'{name}.{attr}', sig))
    return loaded, compiled


def warm_scene(scene: str | os.PathLike) -> dict:
    """
    Build one scene's model as sim_node does and take one step; return what happened.

    That is: scene, model, seconds, the number of kernel signatures it loaded from numba's cache
    and compiled (``kernel_signatures``; those an earlier scene of this process already needed are
    not counted), error (or None).
    """
    from pulsejet_sim.core.model_io import SimulationBlowUp
    from pulsejet_sim.engine.simulation import Simulation
    from pulsejet_sim.scene import load_scene

    l0, c0 = kernel_signatures()
    t0 = time.perf_counter()
    result = {'scene': str(scene), 'model': '?', 'error': None}
    try:
        loaded = load_scene(scene, command_driven=True)
        result['scene'] = loaded.name
        result['model'] = loaded.data.get('model', '?')
        sim = Simulation(loaded.model)
        try:
            sim.step(1, sim.command)  # sim_node._warm_up
            sim.energy_ledger()
            sim.stable_step_s()
            sim.profile()  # the first publication: observation, ledger, profile
        except SimulationBlowUp:  # a blow-up after compiling still warmed the kernels
            pass
        sim.reset()
    except Exception as exc:  # report and go on with the next scene
        result['error'] = f'{type(exc).__name__}: {exc}'
    l1, c1 = kernel_signatures()
    result.update(seconds=time.perf_counter() - t0, loaded=len(l1 - l0), compiled=len(c1 - c0))
    return result


def warm_compile_cache(scenes=None, *, log=None) -> list[dict]:
    """
    Compile (or load from numba's cache) every kernel signature the given scenes use.

    scenes: scene names or YAML paths; default: the shipped scenes (``shipped_scenes()``).
    log: called with one line per scene (default: nothing).  Returns warm_scene's dict per scene.
    """
    if scenes is None:
        scenes = shipped_scenes()
    results = []
    for scene in scenes:
        r = warm_scene(scene)
        results.append(r)
        if log is not None:
            status = (
                f'FAILED ({r["error"]})'
                if r['error']
                else f'{r["compiled"]} kernel signatures compiled, {r["loaded"]} loaded from the '
                     'cache'
            )
            log(f'  {r["scene"]:<24s} {r["model"]:<7s} {r["seconds"]:6.1f} s  {status}')
    return results


def cache_files(package_dir: str | os.PathLike) -> list[Path]:
    """
    Return the numba cache files (index .nbi and data .nbc) of the kernel modules.

    These are the files found for the package at package_dir, wherever this process's numba
    configuration puts them (NUMBA_CACHE_DIR, the in-tree __pycache__ or the user cache directory).
    """
    from numba.core.dispatcher import Dispatcher

    files: set[Path] = set()
    for name in KERNEL_MODULES:
        mod = sys.modules.get(name)
        if mod is None or not Path(mod.__file__).resolve().is_relative_to(
            Path(package_dir).resolve()
        ):
            continue
        stem = Path(mod.__file__).stem
        for obj in vars(mod).values():
            if isinstance(obj, Dispatcher) and getattr(obj, '_cache', None) is not None:
                impl = getattr(obj._cache, 'cache_path', None)
                if impl:
                    files.update(p for p in Path(impl).glob(f'{stem}.*.nb[ic]'))
    return sorted(files)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='pulsejet_warmup',
        description='Compile the physics kernels every shipped scene uses into '
        "numba's on-disk cache, so that sim_node's first start does not wait for the compiler.",
    )
    parser.add_argument(
        'scenes', nargs='*', help='scene names or YAML paths (default: config/*.yaml)'
    )
    parser.add_argument('--config-dir', help='take the shipped scenes from this directory')
    parser.add_argument(
        '--expect-root',
        help='fail unless pulsejet_sim is imported from under this directory '
        '(the install hook checks that it warms the installed copy)',
    )
    parser.add_argument(
        '--list-cache-files',
        action='store_true',
        help='print the cache files of the kernel modules afterwards, one per line',
    )
    parser.add_argument('--quiet', action='store_true', help='only the summary line')
    args = parser.parse_args(argv)

    import pulsejet_sim

    package_dir = Path(pulsejet_sim.__file__).resolve().parent
    where = Path(
        pulsejet_sim.__file__
    ).parent  # as imported (a symlinked build dir stays as it is)
    if args.expect_root is not None:
        root = Path(args.expect_root).absolute()
        if not (where.is_relative_to(root) or package_dir.is_relative_to(root.resolve())):
            print(
                f'pulsejet_warmup: pulsejet_sim imported from {where}, not from under {root}',
                file=sys.stderr,
            )
            return 2
    if os.environ.get('NUMBA_DISABLE_JIT', '0') not in ('', '0'):
        print('pulsejet_warmup: NUMBA_DISABLE_JIT is set: nothing to compile')
        return 0
    scenes = args.scenes or [str(p) for p in shipped_scenes(args.config_dir)]
    if not scenes:
        print('pulsejet_warmup: no scenes found', file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    results = warm_compile_cache(scenes, log=None if args.quiet else print)
    failed = [r for r in results if r['error']]
    compiled = sum(r['compiled'] for r in results)
    loaded = sum(r['loaded'] for r in results)
    print(
        f'pulsejet_warmup: {len(results) - len(failed)}/{len(results)} scenes warmed in '
        f'{time.perf_counter() - t0:.1f} s ({compiled} kernel signatures compiled, {loaded} '
        'loaded from the '
        f'cache) for {where}',
        flush=True,
    )
    if args.list_cache_files:
        for path in cache_files(package_dir):
            print(path)
    for r in failed:
        print(f'pulsejet_warmup: scene {r["scene"]} failed: {r["error"]}', file=sys.stderr)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
