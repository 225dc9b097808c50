"""
Generators and checks of the inputs a user hands pulsejet: scene files, commands, sweep files.

test/test_fuzz_inputs.py runs them under hypothesis at a small example count (part of `make test`);
benchmarks/reliability/reliability_table.py runs the same generators at a larger count and counts
the outcomes. Each `check_*` returns an outcome label and asserts the property:

- scene files (valid and invalid: wrong types, missing keys, out-of-range, unknown keys, YAML that
  is not a mapping): either the scene runs with finite observations and a finite ledger that
  closes, or it is refused with a SceneError naming the key and what is allowed; never another
  exception.
- command sequences (any float, NaN, +-inf, 1e308, negative, rapid toggling) into `Simulation`:
  each command is validated (Command.validate) and applied or rejected with a CommandError naming
  the value and the allowed range; a rejected command changes nothing; no observation is ever
  non-finite (a blow-up stops the run at its last good, finite state).
- sweep files: loaded or refused with SweepError / a YAML error (what `pulsejet sweep` reports).
"""

from __future__ import annotations

import copy
from dataclasses import fields
import math
import os
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from pulsejet_sim.core.model_io import Command, CommandError, Observation, SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene, load_scene_data, SceneError
import yaml

EXAMPLES = int(os.environ.get('PULSEJET_FUZZ_EXAMPLES', '40'))
FUZZ_SETTINGS = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=False,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.function_scoped_fixture,
        HealthCheck.data_too_large,
    ],
)
BASE_NAMES = ('escape', 'pump_cycle', 'shell_robot', 'shell_cone', 'shell_ellipsoid')
BASES: dict[str, dict] = {name: load_scene_data(name)[0] for name in BASE_NAMES}
RUN_STEPS = 40  # physics steps a valid scene is run for (in batches of RUN_BATCH)
RUN_BATCH = 8
CLOSURE_TOL = 0.05  # |closure_relative| allowed after a short run (shell: Newton tolerance)
SAFETY_NET = 'please report'  # scene.loader's catch-all: a value the model's own validation missed
# every lumped terms/options combination compiles its own numba kernel (seconds each): the fast
# test steps only the bases' combinations; the reliability script sets PULSEJET_FUZZ_ALL_FLAGS=1
ALL_FLAGS = os.environ.get('PULSEJET_FUZZ_ALL_FLAGS') == '1'
_BASE_LUMPED_FLAGS = {
    load_scene(n).model.flags for n in BASE_NAMES if BASES[n]['model'] == 'lumped'
}

SPECIAL_FLOATS = [
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    -1e308,
    5e-324,
    -0.0,
    0.0,
    -1.0,
    1e-12,
    1e12,
]
WEIRD_VALUES = st.one_of(
    st.sampled_from(SPECIAL_FLOATS),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.text(max_size=12),
    st.none(),
    st.booleans(),
    st.lists(st.integers(-5, 5), max_size=3),
    st.dictionaries(st.text(max_size=4), st.integers(-5, 5), max_size=2),
)


def leaf_paths(data: Any, prefix: tuple = ()) -> list[tuple]:
    out = []
    if isinstance(data, dict):
        for k, v in data.items():
            out.append(prefix + (k,))
            out.extend(leaf_paths(v, prefix + (k,)))
    return out


def _set(data: dict, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        data = data[k]
    data[path[-1]] = value


def _delete(data: dict, path: tuple) -> None:
    for k in path[:-1]:
        data = data[k]
    data.pop(path[-1], None)


def _get(data: dict, path: tuple) -> Any:
    for k in path:
        data = data[k]
    return data


@st.composite
def scene_texts(draw) -> tuple[str, str, list]:
    """
    Draw a base scene with 0-3 mutations, or a non-mapping file.

    Gives (YAML text, base name, mutations).
    """
    base = draw(st.sampled_from(BASE_NAMES))
    if draw(st.integers(0, 9)) == 0:  # not a mapping at all, or not YAML
        text = draw(
            st.one_of(
                st.just(''),
                st.just('- a\n- b\n'),
                st.just('42\n'),
                st.just('"text"\n'),
                st.just('{a: [1, 2\n'),
                st.just('model: lumped\n  bad indent: 1\n'),
                st.just('!!python/object/apply:os.system ["true"]\n'),
                st.just('a: &x [*x]\n'),
                st.text(max_size=40),
            )
        )
        return text, base, [('file', text)]
    data = copy.deepcopy(BASES[base])
    paths = leaf_paths(data)
    mutations = []
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(['weird', 'scale', 'delete', 'unknown', 'section']))
        path = draw(st.sampled_from(paths))
        try:
            current = _get(data, path)
        except (KeyError, TypeError):
            continue
        if kind == 'weird':
            value = draw(WEIRD_VALUES)
            _set(data, path, value)
        elif (
            kind == 'scale' and isinstance(current, (int, float)) and not isinstance(current, bool)
        ):
            value = current * draw(
                st.sampled_from([-1.0, 0.0, 1e-3, 0.5, 0.9, 1.1, 2.0, 10.0, 1e3])
            )
            if isinstance(current, int):
                value = int(value)
            _set(data, path, value)
        elif kind == 'delete':
            value = None
            _delete(data, path)
        elif kind == 'unknown':
            parent = _get(data, path[:-1]) if len(path) > 1 else data
            if not isinstance(parent, dict):
                continue
            value = draw(st.sampled_from(['bogus_key', 'Duration_s', 'stiffness', 'dt']))
            parent[value] = draw(st.integers(0, 3))
        else:  # replace a whole section by something that is not a mapping
            value = draw(st.sampled_from([[], [1, 2], 'text', 0, True]))
            _set(data, path[:1], value)
            path = path[:1]
        mutations.append((kind, '.'.join(map(str, path)), value))
    return yaml.safe_dump(data, sort_keys=False), base, mutations


def _finite_observation(obs: Observation, where: str) -> None:
    bad = {
        f.name: getattr(obs, f.name)
        for f in fields(obs)
        if not math.isfinite(getattr(obs, f.name))
    }
    assert not bad, f'{where}: non-finite observation {bad}'


def _type_error(mutation: tuple) -> bool:
    kind, _, value = mutation
    if kind == 'unknown':
        return True
    if isinstance(value, bool):
        return False
    if isinstance(value, (int, float)):
        return not math.isfinite(value)
    return True


def _refusal_ok(message: str, mutations: list) -> None:
    assert SAFETY_NET not in message, f'validation gap (model raised a raw exception): {message}'
    assert (
        'allowed' in message or 'not found' in message
    ), f'refusal does not say what is allowed: {message}'
    assert 'Traceback' not in message
    assert len(message) < 2000, f'refusal message of {len(message)} characters'
    # a single wrong type, non-finite number or unknown key is reported at that key (a finite
    # number may be refused by a rule across keys, which names the other key)
    if (
        len(mutations) == 1
        and mutations[0][0] in ('weird', 'unknown')
        and _type_error(mutations[0])
    ):
        key = (
            mutations[0][1].split('.')[-1] if mutations[0][0] == 'weird' else str(mutations[0][2])
        )
        assert key in message or mutations[0][1].split('.')[0] in message, (mutations, message)


def run_scene_briefly(scene) -> str:
    """Step a built scene RUN_STEPS steps with its routine's commands; 'ran' or 'fault'."""
    from pulsejet_sim.routines import routine_from_scene

    sim = Simulation(scene.model)
    _finite_observation(sim.observe(), 'initial state')
    routine = routine_from_scene(scene.routine)
    for _ in range(RUN_STEPS // RUN_BATCH):
        obs = sim.observe()
        command = routine.command(sim.time_s, obs.volume_m3) if routine else sim.command
        command.validate()
        try:
            obs = sim.step(RUN_BATCH, command)
        except SimulationBlowUp as err:
            assert str(err), 'blow-up without a message'
            _finite_observation(sim.observe(), f'after blow-up {err}')
            return 'fault'
        _finite_observation(obs, f't={sim.time_s}')
    ledger = sim.energy_ledger()
    bad = {k: v for k, v in ledger.items() if not math.isfinite(v)}
    assert not bad, f'non-finite ledger entries {bad}'
    scale = max(
        abs(ledger.get('in_initial', 0.0)) + abs(ledger.get('in_actuation_work', 0.0)), 1e-9
    )
    if scale > 1e-6:
        assert (
            abs(ledger['closure_error']) <= CLOSURE_TOL * scale + 1e-9
        ), f'ledger does not close: closure_error {ledger["closure_error"]:g} J of {scale:g} J in'
    return 'ran'


def check_scene_text(text: str, mutations: list, tmp_dir: Path) -> str:
    """Outcome of one scene file: 'refused', 'built' (not stepped), 'ran' or 'fault'."""
    path = tmp_dir / 'fuzz_scene.yaml'
    path.write_text(text)
    try:
        scene = load_scene(path)
    except SceneError as err:
        _refusal_ok(str(err), mutations)
        return 'refused'
    for attr in ('duration_s', 'publish_rate_hz'):
        assert math.isfinite(getattr(scene, attr)) and getattr(scene, attr) > 0
    assert math.isfinite(scene.model.dt_s) and scene.model.dt_s > 0
    if (
        scene.model.name == 'lumped'
        and scene.model.flags not in _BASE_LUMPED_FLAGS
        and not ALL_FLAGS
    ):
        return 'built'
    return run_scene_briefly(scene)


# ---- commands into Simulation -------------------------------------------------------------------
COMMAND_VALUES = st.one_of(
    st.sampled_from(SPECIAL_FLOATS + [0.05, 0.0500001, 1.0, 1.0000001, 1000.0, 1000.5, 0.5, 1e-3]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=0.0, max_value=1.0),
    st.floats(min_value=0.0, max_value=0.05),
)
COMMANDS = st.builds(Command, COMMAND_VALUES, COMMAND_VALUES, COMMAND_VALUES)
_SIMS: dict[str, Simulation] = {}


def reset_simulation(name: str) -> Simulation:
    if name not in _SIMS:
        _SIMS[name] = Simulation(load_scene(name, command_driven=True).model)
    sim = _SIMS[name]
    sim.reset()
    return sim


def check_command_sequence(name: str, commands: list[Command], steps: int) -> tuple[int, int, str]:
    """
    Apply each command as sim_node does (validate against the model's ranges, then step).

    Returns (applied, rejected, outcome).
    """
    sim = reset_simulation(name)
    applied = rejected = 0
    for command in commands:
        before = (sim.state.copy(), sim.steps, sim.command)
        try:
            valid = command.validate(sim.command_limits)
        except CommandError as err:
            text = str(err)
            assert (
                'allowed' in text and '=' in text and any(f.name in text for f in fields(Command))
            ), text
            assert (sim.steps, sim.command) == before[1:] and (sim.state == before[0]).all()
            rejected += 1
            continue
        for f in fields(Command):
            v = getattr(valid, f.name)
            low, high = sim.command_limits[f.name]
            assert isinstance(v, float) and math.isfinite(v) and low <= v <= high, (f.name, v)
        try:
            obs = sim.step(steps, valid)
        except SimulationBlowUp as err:
            _finite_observation(sim.observe(), f'after blow-up {err}')
            return applied, rejected, 'fault'
        applied += 1
        _finite_observation(obs, f'{name} t={sim.time_s} after {valid}')
    ledger = sim.energy_ledger()
    assert all(math.isfinite(v) for v in ledger.values()), ledger
    return applied, rejected, 'ran'


# ---- sweep files --------------------------------------------------------------------------------
SWEEP_BASE = {
    'name': 'fuzz',
    'duration_s': 0.1,
    'metric': 'peak_speed_m_s',
    'studies': {
        's': {
            'base': 'escape',
            'axes': {
                'k': {
                    'a': {'material': {'stiffness_n_m': 1000}},
                    'b': {'material': {'stiffness_n_m': 2000}},
                }
            },
        }
    },
}


@st.composite
def sweep_texts(draw) -> str:
    if draw(st.integers(0, 7)) == 0:
        return draw(
            st.one_of(
                st.just(''),
                st.just('[1, 2]\n'),
                st.just('studies: {a: &x [*x]}\n'),
                st.text(max_size=30),
            )
        )
    data = copy.deepcopy(SWEEP_BASE)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(leaf_paths(data) or [('name',)]))
        kind = draw(st.sampled_from(['weird', 'delete', 'unknown']))
        try:
            if kind == 'weird':
                _set(data, path, draw(WEIRD_VALUES))
            elif kind == 'delete':
                _delete(data, path)
            else:
                parent = _get(data, path[:-1]) if len(path) > 1 else data
                if isinstance(parent, dict):
                    parent['bogus'] = 1
        except (KeyError, TypeError):
            continue
    return yaml.safe_dump(data, sort_keys=False)


def check_sweep_text(text: str, tmp_dir: Path) -> str:
    """
    Load a sweep text and tell whether it was refused or loaded.

    'refused' (SweepError / YAML error, what `pulsejet sweep` prints) or 'loaded'; every run of a
    loaded sweep then loads its scene or is refused with SceneError. Anything else raises.
    """
    from pulsejet_sim.studies.sweep import load_sweep, SweepError

    path = tmp_dir / 'fuzz_sweep.yaml'
    path.write_text(text)
    try:
        _, runs = load_sweep(path)
    except (SweepError, yaml.YAMLError) as err:
        assert str(err)
        return 'refused'
    for spec in runs[:4]:
        try:
            load_scene(spec.scene, dict(spec.overrides), replace=spec.replace)
        except SceneError as err:
            assert SAFETY_NET not in str(err), str(err)
    return 'loaded'
