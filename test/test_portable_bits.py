"""
Every shipped scene steps to the same bits whichever SIMD kernels numpy picks on this CPU.

numpy runs some float64 functions (arctan2, exp, log, power, arcsin, ...) on CPUs with AVX-512
through kernels whose last bits differ from the C library's. A model that used them while it
builds or steps would rerun a stored study an ulp off on another CPU, as the paper 000 study did
until the reference geometry took the C library's atan2 (docs/theory/shell.md, "Paper 000 against
the model"). Here each shipped scene is built and stepped in two child processes, one with numpy's
AVX-512 kernels turned off (NPY_DISABLE_CPU_FEATURES); state, observation and ledger must agree bit
for bit. On a CPU without AVX-512 both take the same path, so the test is skipped and says why.
"""

import json
import os
import subprocess
import sys

from pulsejet_sim.scene import available_scenes
import pytest

try:  # numpy 2
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
except ImportError:  # numpy 1
    from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__

# numpy's x86-64 dispatch targets above AVX2 (numpy 2.x names)
AVX512_TARGETS = [t for t in ('X86_V4', 'AVX512_ICL', 'AVX512_SPR') if t in __cpu_dispatch__]

CHILD = r"""
import hashlib, json, sys
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene

out = {}
for name in sys.argv[1:]:
    sim = Simulation(load_scene(name).model)
    obs = None
    for _ in range(4):  # a few batches: the shell's implicit steps cost ~1 ms, the lumped ~us
        obs = sim.step(25 if sim.model.dt_s > 2e-4 else 250)
    out[name] = {
        'state': hashlib.sha256(sim.state.tobytes()).hexdigest(),
        'observation': repr(obs),
        'ledger': {k: repr(v) for k, v in sim.energy_ledger().items()},
    }
print(json.dumps(out))
"""


def run_child(env_extra: dict) -> dict:
    env = dict(os.environ, **env_extra)
    done = subprocess.run(
        [sys.executable, '-c', CHILD, *available_scenes()],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.timeout(900)
def test_every_scene_steps_to_the_same_bits_with_and_without_numpys_avx512_kernels():
    if not any(__cpu_features__.get(f) for f in ('AVX512F', 'AVX512_SKX')) or not AVX512_TARGETS:
        pytest.skip('this CPU has no AVX-512: numpy takes the same kernels in both runs')
    default = run_child({})
    without = run_child({'NPY_DISABLE_CPU_FEATURES': ' '.join(AVX512_TARGETS)})
    assert sorted(default) == sorted(available_scenes())
    for name in default:
        assert default[name] == without[name], name
