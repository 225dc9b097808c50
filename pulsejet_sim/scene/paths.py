"""Where pulsejet's configuration files live: the source tree's config/, then the share."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pulsejet_sim.core.schema import read_yaml_file, YAMLInputError


def config_dirs() -> list[Path]:
    """Where scene names are looked up: the source tree, then the installed share directory."""
    dirs = [Path(__file__).resolve().parents[2] / 'config']
    try:
        from ament_index_python.packages import get_package_share_directory

        dirs.append(Path(get_package_share_directory('pulsejet_sim')) / 'config')
    except Exception:  # not installed through colcon: the source tree is enough
        pass
    return [d for d in dirs if d.is_dir()]


def read_config_file(path: Any, folder: str, what: str, error: type) -> tuple[Any, Any]:
    """
    Return (file path, parsed data) of a YAML file: a path or a name under config/<folder>/.

    The file is read with the bounded safe loader; raises `error` naming the file when it is
    missing or not valid YAML (sweeps, fits and optimisations share this).
    """
    p = Path(path)
    if not p.is_file():
        builtin = [d / folder / f'{path}.yaml' for d in config_dirs()]
        builtin = [b for b in builtin if b.is_file()]
        if not builtin:
            raise error(
                f'{what} {str(path)!r} not found; allowed: a YAML path or a name under '
                f'config/{folder}/'
            )
        p = builtin[0]
    try:
        return p, read_yaml_file(p, f'{what} {str(p)!r}')
    except YAMLInputError as err:
        raise error(str(err)) from None
