"""Physics models (no ROS). ``build_model(scene_dict)`` compiles what a scene asks for."""

from __future__ import annotations

from typing import Any, Mapping

from pulsejet_sim.core.model_io import ModelError


def _lumped(data):
    from pulsejet_sim.models.lumped.model import LumpedModel

    return LumpedModel.from_scene(data)


def _shell(data):
    from pulsejet_sim.models.shell.model import ShellModel

    return ShellModel.from_scene(data)


MODEL_BUILDERS = {'lumped': _lumped, 'shell': _shell}


def build_model(data: Mapping[str, Any]):
    kind = data.get('model')
    if kind not in MODEL_BUILDERS:
        raise ModelError(
            f'model: {kind!r} is not a known model; allowed: one of {", ".join(MODEL_BUILDERS)}'
        )
    return MODEL_BUILDERS[kind](data)
