"""
Scenes: YAML files under config/ naming the model, geometry, material, actuation and terms.

Scene files are untrusted input: they are read with schema.read_yaml_file (yaml.SafeLoader, size,
alias-expansion and depth limits) and every value is validated before a model is built; a bad
scene raises SceneError naming the key, the value and what is allowed, never another exception.
A scene stored in a recording is parsed with the same loader (scene_from_stored).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
from typing import Any

from pulsejet_sim.core.model_io import Command, ModelError
from pulsejet_sim.core.schema import Number, read_yaml_file, safe_load_yaml, show, YAMLInputError
from pulsejet_sim.models import build_model
from pulsejet_sim.scene.paths import config_dirs

DEFAULT_SCENE = 'shell_robot'  # the design card's default: the shell mantle


class SceneError(ValueError):
    """A scene that cannot be found or read or that a model refuses (the message says why)."""


def available_scenes() -> list[str]:
    return sorted({p.stem for d in config_dirs() for p in d.glob('*.yaml')})


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):  # a name the OS cannot look up (NUL byte, too long)
        return False


def resolve_scene_path(name_or_path: str | os.PathLike) -> Path:
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise SceneError(
            f'scene {show(name_or_path)} is not a name; allowed: a YAML file path or one of '
            f'{", ".join(available_scenes())}'
        )
    text = str(name_or_path)
    if not text.strip() or '\x00' in text:
        raise SceneError(
            f'scene {show(text)} is not a name; allowed: a YAML file path or one of '
            f'{", ".join(available_scenes())}'
        )
    candidate = Path(text).expanduser()
    if candidate.suffix in ('.yaml', '.yml') or os.sep in text:
        if _is_file(candidate):
            return candidate
        raise SceneError(
            f'scene file {text!r} does not exist; allowed: a YAML file path or one of '
            f'{", ".join(available_scenes())}'
        )
    for d in config_dirs():
        path = d / f'{text}.yaml'
        if _is_file(path):
            return path
    raise SceneError(
        f'scene {show(text)} not found; allowed: a YAML file path or one of '
        f'{", ".join(available_scenes())}'
    )


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
    """Return the raw mapping of a scene file (not validated yet) and its path."""
    path = resolve_scene_path(name_or_path)
    try:
        data = read_yaml_file(path, f'scene file {str(path)!r}')
    except YAMLInputError as err:
        raise SceneError(str(err)) from None
    if not isinstance(data, dict):
        raise SceneError(
            f'scene file {str(path)!r}: {type(data).__name__} {show(data)} at top level; allowed: '
            'a '
            f'mapping with keys model, simulation, geometry, material, ...'
        )
    return data, path


def load_scene(
    name_or_path: str | os.PathLike = DEFAULT_SCENE,
    overrides: dict | None = None,
    command_driven: bool = False,
    replace: tuple[str, ...] = (),
) -> Scene:
    """
    Read, validate and compile a scene.

    `overrides` is merged section by section (tests, sweeps); the sections named in `replace` are
    replaced by the override's instead.

    command_driven=True is how the live nodes load a scene: actuation the model would otherwise
    drive itself from its built-in routine (the shell's cable) comes from commands instead, and
    `scene.routine` describes the same routine for controller_node to send.
    """
    data, path = load_scene_data(name_or_path)
    if overrides is not None and not isinstance(overrides, dict):
        raise SceneError(
            f'scene overrides {show(overrides)} are not a mapping; allowed: a mapping merged into '
            f'the scene, e.g. {{material: {{stiffness_n_m: 200}}}}'
        )
    data = {k: v for k, v in data.items() if k not in replace}
    data = merge(data, overrides or {})
    if command_driven:
        data = command_driven_data(data)
    return scene_from_dict(data, name=_scene_name(data.pop('name', path.stem)), path=path)


def _scene_name(name: Any) -> str:
    if isinstance(name, bool) or not isinstance(name, (str, int, float)) or not str(name).strip():
        raise SceneError(f'name: {show(name)} is not a scene name; allowed: text')
    return str(name)[:200]


def command_driven_data(data: dict[str, Any]) -> dict[str, Any]:
    """
    Turn a shell scene whose cable follows its built-in routine into a command-driven one.

    The result's cable follows commands, with a `routine:` block of the same shape for the
    controller (pulsejet_ctrl.CableRoutine).
    """
    actuation = data.get('actuation')
    if (
        data.get('model') != 'shell'
        or not isinstance(actuation, dict)
        or actuation.get('kind') != 'cable'
        or actuation.get('source', 'routine') != 'routine'
        or 'routine' in data
    ):
        return data
    routine = {'kind': 'cable', 'amplitude_n': actuation.get('amplitude', 0.0)}
    for key in ('frequency_hz', 'contraction_s', 'release_s', 'start_delay_s', 'pulse'):
        if key in actuation:
            routine[key] = actuation[key]
    return dict(data, actuation=dict(actuation, source='command'), routine=routine)


# Scene-level keys every model shares (the models check their own; these are used by the runner and
# nodes).
DURATION = Number(10.0, 0.0, 1e6, low_open=True, unit='s')
PUBLISH_RATE = Number(100.0, 1.0, 10000.0, unit='Hz')


def scene_from_dict(data: dict[str, Any], name: str = 'scene', path: Path | None = None) -> Scene:
    """
    Validate a scene mapping and compile its model.

    SceneError names the key, value and what is allowed.
    """
    if not isinstance(data, dict):
        raise SceneError(
            f'scene {name!r}: {type(data).__name__} {show(data)}; allowed: a mapping with keys '
            'model, '
            f'simulation, geometry, material, ...'
        )
    data = dict(data)
    meta = {k: data.pop(k) for k in ('description', 'routine', 'name') if k in data}
    if 'description' in meta and not isinstance(meta['description'], str):
        raise SceneError(
            f'scene {name!r}: description: {show(meta["description"])} is not text; allowed: text'
        )
    from pulsejet_sim.models import MODEL_BUILDERS

    kind = data.get('model')
    if not isinstance(kind, str) or kind not in MODEL_BUILDERS:
        raise SceneError(
            f'scene {name!r}: model: {show(kind)} is not a known model; allowed: one of '
            f'{", ".join(MODEL_BUILDERS)}'
        )
    try:
        model = build_model(data)
    except ModelError as err:
        raise SceneError(f'scene {name!r}: {err}') from None
    except (TypeError, ValueError, ArithmeticError, LookupError, AttributeError) as err:
        # a value the model's own checks let through: still a refusal with the key path where known
        raise SceneError(
            f'scene {name!r}: refused by the {show(data.get("model"))} model '
            f'({type(err).__name__}: '
            f'{show(str(err))}); this value combination is not validated yet, please report it'
        ) from None
    sim = data.get('simulation') or {}
    try:
        duration = DURATION.check('simulation.duration_s', sim.get('duration_s', DURATION.default))
        rate = PUBLISH_RATE.check(
            'simulation.publish_rate_hz', sim.get('publish_rate_hz', PUBLISH_RATE.default)
        )
    except ModelError as err:
        raise SceneError(f'scene {name!r}: {err}') from None
    routine = meta.get('routine')
    if routine is not None and not isinstance(routine, dict):
        raise SceneError(
            f'scene {name!r}: routine: {show(routine)} is not a mapping; allowed: routine '
            'parameters'
        )
    if routine is not None:
        from pulsejet_sim.core.model_io import check_command_value, CommandError
        from pulsejet_sim.routines import routine_from_scene  # pure, no ROS

        try:
            routine_from_scene(routine)
            # what the routine will command must pass Command validation too (e.g. no pin-hole
            # valve)
            for key, (low, high) in Command.LIMITS.items():
                if key in routine:
                    try:
                        check_command_value(key, routine[key], low, high)
                    except CommandError as err:
                        raise ModelError(f'routine.{err}') from None
        except ModelError as err:
            raise SceneError(f'scene {name!r}: {err}') from None
        except (TypeError, ValueError, ArithmeticError, LookupError, AttributeError) as err:
            raise SceneError(
                f'scene {name!r}: routine: {show(routine)} refused ({type(err).__name__}: '
                f'{show(str(err))}); allowed: the parameters of pulsejet_sim.routines'
            ) from None
    return Scene(
        name=name,
        path=path or Path(name),
        data=data,
        model=model,
        duration_s=duration,
        publish_rate_hz=rate,
        routine=routine,
    )


def scene_from_stored(text: str, fallback_name: str = 'stored') -> Scene:
    """
    Return the scene a recording carries as YAML text (`pulsejet` metadata, key scene_yaml).

    It is safe-loaded and validated like a scene file; it is data only (nothing in it is executed
    or opened).
    """
    try:
        data = safe_load_yaml(text, 'scene stored in the recording')
    except YAMLInputError as err:
        raise SceneError(str(err)) from None
    if not isinstance(data, dict):
        raise SceneError(
            f'scene stored in the recording: {type(data).__name__} {show(data)} at top level; '
            'allowed: a mapping with keys model, simulation, geometry, material, ...'
        )
    data = dict(data)
    name = _scene_name(data.pop('name', fallback_name))
    return scene_from_dict(data, name=name, path=Path(name))


def is_project_scene_name(name: Any) -> bool:
    """Tell if a bare scene name exists under config/ (no path, nothing outside the project)."""
    return (
        isinstance(name, str)
        and bool(name)
        and name == os.path.basename(name)
        and '/' not in name
        and '\\' not in name
        and not name.startswith('.')
        and name in available_scenes()
    )


def merge(base: dict, override: dict) -> dict:
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out
