"""Scenes: YAML files under config/ naming the model, geometry, material, actuation and terms."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pulsejet_sim.models import build_model
from pulsejet_sim.models.base import Command, ModelError

DEFAULT_SCENE = 'shell_robot'   # the design card's default: the shell mantle


class SceneError(ValueError):
    """A scene that cannot be found or read or that a model refuses (the message says why)."""


def config_dirs() -> list[Path]:
    """Where scene names are looked up: the source tree, then the installed share directory."""
    dirs = [Path(__file__).resolve().parent.parent / 'config']
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory('pulsejet_sim')) / 'config')
    except Exception:   # not installed through colcon: the source tree is enough
        pass
    return [d for d in dirs if d.is_dir()]


def available_scenes() -> list[str]:
    return sorted({p.stem for d in config_dirs() for p in d.glob('*.yaml')})


def resolve_scene_path(name_or_path: str | os.PathLike) -> Path:
    text = str(name_or_path)
    candidate = Path(text).expanduser()
    if candidate.suffix in ('.yaml', '.yml') or os.sep in text:
        if candidate.is_file():
            return candidate
        raise SceneError(f'scene file {text!r} does not exist; allowed: a YAML file path or one of '
                         f'{", ".join(available_scenes())}')
    for d in config_dirs():
        path = d / f'{text}.yaml'
        if path.is_file():
            return path
    raise SceneError(f'scene {text!r} not found; allowed: a YAML file path or one of {", ".join(available_scenes())}')


@dataclass
class Scene:
    name: str
    path: Path
    data: dict[str, Any]
    model: Any
    duration_s: float
    publish_rate_hz: float
    routine: dict[str, Any] | None = field(default=None)

    @property
    def initial_command(self) -> Command:
        return getattr(self.model, 'initial_command', Command())


def load_scene_data(name_or_path: str | os.PathLike) -> tuple[dict[str, Any], Path]:
    """The raw mapping of a scene file (not validated yet) and its path."""
    path = resolve_scene_path(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise SceneError(f'scene file {path}: not valid YAML ({err})') from None
    if not isinstance(data, dict):
        raise SceneError(f'scene file {path}: {type(data).__name__} at top level; allowed: a mapping with '
                         f'keys model, simulation, geometry, material, ...')
    return data, path


def load_scene(name_or_path: str | os.PathLike = DEFAULT_SCENE, overrides: dict | None = None,
               command_driven: bool = False, replace: tuple[str, ...] = ()) -> Scene:
    """Read, validate and compile a scene. `overrides` is merged section by section (tests, sweeps);
    the sections named in `replace` are replaced by the override's instead.

    command_driven=True is how the live nodes load a scene: actuation the model would otherwise
    drive itself from its built-in routine (the shell's cable) comes from commands instead, and
    `scene.routine` describes the same routine for controller_node to send."""
    data, path = load_scene_data(name_or_path)
    data = {k: v for k, v in data.items() if k not in replace}
    data = merge(data, overrides or {})
    if command_driven:
        data = command_driven_data(data)
    return scene_from_dict(data, name=str(data.pop('name', path.stem)), path=path)


def command_driven_data(data: dict[str, Any]) -> dict[str, Any]:
    """A shell scene whose cable follows its built-in routine becomes one whose cable follows
    commands, with a `routine:` block of the same shape for the controller (pulsejet_ctrl.CableRoutine)."""
    actuation = data.get('actuation')
    if data.get('model') != 'shell' or not isinstance(actuation, dict) or actuation.get('kind') != 'cable' \
            or actuation.get('source', 'routine') != 'routine' or 'routine' in data:
        return data
    routine = {'kind': 'cable', 'amplitude_n': actuation.get('amplitude', 0.0)}
    for key in ('frequency_hz', 'contraction_s', 'release_s', 'start_delay_s'):
        if key in actuation:
            routine[key] = actuation[key]
    return dict(data, actuation=dict(actuation, source='command'), routine=routine)


def scene_from_dict(data: dict[str, Any], name: str = 'scene', path: Path | None = None) -> Scene:
    data = dict(data)
    meta = {k: data.pop(k) for k in ('description', 'routine', 'name') if k in data}
    try:
        model = build_model(data)
    except ModelError as err:
        raise SceneError(f'scene {name!r}: {err}') from None
    sim = data.get('simulation') or {}
    routine = meta.get('routine')
    if routine is not None and not isinstance(routine, dict):
        raise SceneError(f'scene {name!r}: routine: {routine!r} is not a mapping; allowed: routine parameters')
    return Scene(name=name, path=path or Path(name), data=data, model=model,
                 duration_s=float(sim.get('duration_s', 10.0)),
                 publish_rate_hz=float(sim.get('publish_rate_hz', 100.0)), routine=routine)


def merge(base: dict, override: dict) -> dict:
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out
