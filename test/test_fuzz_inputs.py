"""
Property-based tests (hypothesis) of the inputs a user hands pulsejet.

Scene files, command sequences into Simulation, sweep files. The generators and the `check_*`
properties are in benchmarks/reliability/input_fuzz.py (its docstring states each property), which
benchmarks/reliability/reliability_table.py also runs at a larger example count to tabulate the
outcomes (docs/dev/reliability.md). Example counts here are bounded to keep `make test` fast.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
import re
from typing import Any

from benchmarks.reliability.input_fuzz import (
    BASES,
    check_command_sequence,
    check_scene_text,
    check_sweep_text,
    COMMANDS,
    EXAMPLES,
    FUZZ_SETTINGS,
    reset_simulation,
    scene_texts,
    SWEEP_BASE,
    sweep_texts,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from pulsejet_sim.core.model_io import Command, CommandError
from pulsejet_sim.scene import load_scene, SceneError
import pytest
import yaml


@pytest.mark.timeout(120)
@FUZZ_SETTINGS
@given(case=scene_texts())
def test_scene_files_run_or_are_refused_clearly(case, tmp_path_factory) -> None:
    text, _, mutations = case
    check_scene_text(text, mutations, tmp_path_factory.mktemp('scene'))


@pytest.mark.parametrize(
    'text, key',
    [
        ('model: lumped\n', 'geometry.rest_minor_semi_axis_m'),
        ('- 1\n- 2\n', 'list'),
        ('', 'NoneType'),
        ('model: [lumped]\n', 'model'),
        ('model: shell\nsimulation: 3\n', 'simulation'),
    ],
)
def test_scene_refusals_name_the_key(tmp_path: Path, text: str, key: str) -> None:
    path = tmp_path / 's.yaml'
    path.write_text(text)
    with pytest.raises(SceneError, match=re.escape(key)) as err:
        load_scene(path)
    assert 'allowed' in str(err.value)


def test_publish_rate_and_duration_are_validated_for_every_model(tmp_path: Path) -> None:
    for base in ('shell_robot', 'escape'):
        for key, value in (
            ('publish_rate_hz', 'fast'),
            ('publish_rate_hz', -5),
            ('duration_s', 0),
        ):
            data = copy.deepcopy(BASES[base])
            data['simulation'][key] = value
            path = tmp_path / 's.yaml'
            path.write_text(yaml.safe_dump(data))
            with pytest.raises(SceneError, match=f'simulation.{key}: .*allowed'):
                load_scene(path)


def test_bad_routine_is_refused_at_load(tmp_path: Path) -> None:
    data = copy.deepcopy(BASES['pump_cycle'])
    data['routine'] = {'kind': 'pump_valve', 'hold_s': 'long'}
    path = tmp_path / 's.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SceneError, match="routine.hold_s: 'long' is not a number; allowed"):
        load_scene(path)


@pytest.mark.timeout(120)
@FUZZ_SETTINGS
@given(
    name=st.sampled_from(['escape', 'pump_cycle', 'shell_robot', 'shell_cone']),
    commands=st.lists(COMMANDS, min_size=1, max_size=12),
    steps=st.sampled_from([1, 2, 5]),
)
def test_command_sequences_are_applied_or_rejected(
    name: str, commands: list[Command], steps: int
) -> None:
    check_command_sequence(name, commands, steps)


@pytest.mark.timeout(60)
@settings(max_examples=max(EXAMPLES // 2, 10), deadline=None)
@given(name=st.sampled_from(['pump_cycle', 'shell_robot']), period=st.sampled_from([1, 2, 3]))
def test_rapid_toggling_between_extremes(name: str, period: int) -> None:
    """
    Toggle full pump / shut valve / full cable against off / open every `period` steps.

    At the top of the model's own ranges (the pump's and the cable's ratings) every command is
    applied and the physics keeps running.
    """
    limits = reset_simulation(name).command_limits
    high = Command(limits['pump_flow_m3_s'][1], 0.0, limits['cable_force_n'][1])
    low = Command(0.0, 1.0, 0.0)
    commands = [high if (i // period) % 2 == 0 else low for i in range(60)]
    applied, rejected, outcome = check_command_sequence(name, commands, 1)
    assert rejected == 0 and outcome == 'ran', (rejected, outcome)


@pytest.mark.parametrize(
    'command',
    [Command(5e-324, 5e-324, 5e-324), Command(1e-154, 1e-154, 0.0), Command(0.05, 1e-300, 1000.0)],
)
def test_pin_hole_valve_is_rejected_not_simulated(command: Command) -> None:
    """
    A pin-hole valve opening is refused instead of overflowing the orifice loss.

    Found by this file's fuzzing: a valve opening below ~1e-150 made the lumped model's orifice
    loss overflow (cavity pressure NaN in the observation). Such openings are now refused.
    """
    with pytest.raises(
        CommandError, match=r'valve_opening=.*allowed: 0 \(shut\) or a finite value in \[0.0015'
    ):
        command.validate()
    applied, rejected, _ = check_command_sequence(
        'pump_cycle', [command, Command(0.01, 0.0, 0.0)], 2
    )
    assert (applied, rejected) == (1, 1)


def test_pin_hole_initial_valve_is_refused_in_scenes(tmp_path: Path) -> None:
    for section, key in (('actuator', 'initial_valve_opening'), ('routine', 'valve_opening')):
        data = copy.deepcopy(BASES['pump_cycle'])
        data[section][key] = 5e-324
        path = tmp_path / 's.yaml'
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(SceneError, match=f'{section}.{key}.*allowed: 0 \\(shut\\)'):
            load_scene(path)


@pytest.mark.parametrize(
    'field, value, allowed',
    [
        ('pump_flow_m3_s', math.nan, '[0.0, 0.05]'),
        ('valve_opening', math.inf, '[0.0, 1.0]'),
        ('cable_force_n', -1e308, '[0.0, 1000.0]'),
        ('pump_flow_m3_s', '0.01', '[0.0, 0.05]'),
        ('valve_opening', True, '[0.0, 1.0]'),
        ('cable_force_n', None, '[0.0, 1000.0]'),
    ],
)
def test_command_validation_names_value_and_range(field: str, value: Any, allowed: str) -> None:
    with pytest.raises(CommandError) as err:
        Command(**{field: value}).validate()
    assert f'{field}={value!r}' in str(err.value) and allowed in str(err.value)


@pytest.mark.timeout(120)
@FUZZ_SETTINGS
@given(text=sweep_texts())
def test_sweep_files_load_or_are_refused(text: str, tmp_path_factory) -> None:
    """Any exception other than SweepError / YAML error fails."""
    check_sweep_text(text, tmp_path_factory.mktemp('sweep'))


@pytest.mark.parametrize('axis', [1, {'a': 1}, {'a': 'text'}])
def test_sweep_axis_that_is_not_a_mapping_is_refused(tmp_path: Path, axis: Any) -> None:
    from pulsejet_sim.studies.sweep import load_sweep, SweepError

    data = copy.deepcopy(SWEEP_BASE)
    data['studies']['s']['axes']['k'] = axis
    path = tmp_path / 'sweep.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SweepError, match='allowed'):
        load_sweep(path)
