"""
numba's cache and the modules a kernel compiles in (core.kernel_cache).

numba keys a cached kernel on its own source file only. These tests build a small kernel module
that calls a numba function of another module, fill the cache in one process, change only the
other module, and read the kernel's result in a fresh process: without drop_stale_cache the stale
machine code runs (the hazard is real with the pinned numba), with it the new code does.
"""

from pathlib import Path
import subprocess
import sys

from pulsejet_sim.core.kernel_cache import drop_stale_cache, sources_digest
import pytest

DEPENDENCY = """
from numba import njit


@njit(cache=True)
def gain():
    return {value}
"""

KERNEL = """
from numba import njit
import dependency
from pulsejet_sim.core.kernel_cache import drop_stale_cache


@njit(cache=True)
def kernel(x):
    return dependency.gain() * x


if {guarded}:
    drop_stale_cache(kernel, (dependency,))
"""


def run(tmp: Path, cache: Path) -> float:
    out = subprocess.run(
        [sys.executable, '-c', 'import kernel; print(kernel.kernel(1.0))'],
        cwd=tmp, capture_output=True, text=True, timeout=300,
        env={'PATH': '/usr/bin:/bin', 'NUMBA_CACHE_DIR': str(cache),
             'PYTHONPATH': f'{tmp}:{Path(__file__).resolve().parents[1]}'},
    )
    assert out.returncode == 0, out.stderr
    return float(out.stdout.split()[-1])


@pytest.mark.timeout(600)
@pytest.mark.parametrize('guarded', [False, True])
def test_a_changed_dependency_recompiles_only_with_the_guard(tmp_path, guarded):
    cache = tmp_path / 'cache'
    (tmp_path / 'kernel.py').write_text(KERNEL.format(guarded=guarded))
    (tmp_path / 'dependency.py').write_text(DEPENDENCY.format(value=2.0))
    assert run(tmp_path, cache) == 2.0
    assert run(tmp_path, cache) == 2.0  # from the cache
    (tmp_path / 'dependency.py').write_text(DEPENDENCY.format(value=3.0))
    # without the guard numba loads the kernel compiled with the old gain: the hazard
    assert run(tmp_path, cache) == (3.0 if guarded else 2.0)


def test_the_shipped_kernel_modules_guard_what_they_compile_in():
    """Each kernel module that uses another module's code or constants names it."""
    from pulsejet_sim.core import model_io
    from pulsejet_sim.models import cable_pulse, starting_jet
    from pulsejet_sim.models.lumped import batch, kernels as lumped
    from pulsejet_sim.models.shell import kernels as shell

    for kernel, dependencies in (
        (shell.advance, (starting_jet, cable_pulse)),
        (lumped.advance, (model_io,)),
        (batch.advance_batch_exact, (lumped, model_io)),
    ):
        module = Path(kernel.py_func.__code__.co_filename).stem
        stamp = Path(kernel.stats.cache_path) / f'{module}.dependencies.sha256'
        assert stamp.read_text() == sources_digest(dependencies)
        assert drop_stale_cache(kernel, dependencies) is False  # up to date: nothing removed
