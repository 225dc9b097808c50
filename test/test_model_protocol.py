"""Both models satisfy core.protocol.Model, method by method and parameter by parameter."""

from __future__ import annotations

import inspect

from pulsejet_sim.core.protocol import Model
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.models.lumped.model import LumpedModel
from pulsejet_sim.models.shell.model import ShellModel
from pulsejet_sim.scene import load_scene
import pytest

METHODS = [
    name for name, value in vars(Model).items()
    if callable(value) or isinstance(value, classmethod)
    if not name.startswith('_')
]


def test_protocol_names_the_engine_calls():
    assert set(METHODS) == {
        'from_scene', 'initial_state', 'advance', 'observe', 'energy_ledger', 'profile',
        'stable_step_s',
    }


@pytest.mark.parametrize('cls', [LumpedModel, ShellModel])
@pytest.mark.parametrize('name', METHODS)
def test_model_method_matches_the_protocol(cls, name):
    want = list(inspect.signature(getattr(Model, name)).parameters)
    have = inspect.signature(getattr(cls, name)).parameters
    # the protocol's parameters in its order; a model may add optional ones after them
    assert list(have)[: len(want)] == want, f'{cls.__name__}.{name}{list(have)}'
    extra = list(have.values())[len(want):]
    assert all(p.default is not inspect.Parameter.empty for p in extra), f'{cls.__name__}.{name}'


@pytest.mark.parametrize('scene', ['pump_cycle', 'shell_robot'])
def test_scene_models_are_models(scene):
    model = load_scene(scene).model
    assert isinstance(model, Model)
    sim = Simulation(model)
    assert sim.step(2).time_s == pytest.approx(2 * model.dt_s)


def test_protocol_refuses_an_object_without_the_methods():
    class Half:
        dt_s = 1e-3

        def initial_state(self):
            return None

    assert not isinstance(Half(), Model)
