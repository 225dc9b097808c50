"""
Complete ROS 2 message definitions (`ros2msg` schema text) built the way rosbag2 builds them.

rosbag2 (rosbag2_cpp LocalMessageDefinitionSource) stores, per type, the type's own .msg text
followed by every dependency, depth first in sorted order, each preceded by a line of 80 `=` and
`MSG: <name as written in the referencing .msg>`. Readers without the ROS packages (rosbags,
Foxglove, mcap_ros2) decode messages from this text alone, so it must be complete.

The .msg files come from the installed ROS packages' share directories; no rclpy is imported.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
import re
import sys

DELIMITER = '=' * 80 + '\n'

# Same pattern as rosbag2: the first word of each field line
# ("foo_msgs/Bar" in "foo_msgs/Bar[] bar").
_FIELD_TYPE_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset(
    {
        'bool',
        'byte',
        'char',
        'float32',
        'float64',
        'int8',
        'uint8',
        'int16',
        'uint16',
        'int32',
        'uint32',
        'int64',
        'uint64',
        'string',
    }
)
_NAME = r'[a-zA-Z][a-zA-Z0-9_]*'
_TYPE_RE = re.compile(rf'^({_NAME})/(?:({_NAME})/)?({_NAME})$')


class MessageDefinitionError(LookupError):
    """
    A message type whose .msg definition cannot be found or parsed.

    The message names the type and where we looked.
    """


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """
    Split 'pkg/msg/Type' or 'pkg/Type' into ('pkg', 'msg', 'Type').

    Raises ValueError naming a bad name.
    """
    match = _TYPE_RE.match(type_name) if isinstance(type_name, str) else None
    if match is None:
        raise ValueError(
            f'message type name {type_name!r} not understood; expected "package/msg/Type"'
        )
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def _prefixes() -> list[Path]:
    """
    Return the install prefixes to search: AMENT_PREFIX_PATH first, then this Python's prefix.

    AMENT_PREFIX_PATH is set by a sourced ROS; the PyPI ROS wheels install share/<pkg> under the
    venv and do not always set AMENT_PREFIX_PATH.
    """
    found: list[Path] = []
    for entry in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if entry:
            found.append(Path(entry))
    for entry in (sys.prefix, sys.base_prefix):
        found.append(Path(entry))
    unique: list[Path] = []
    for p in found:
        if p not in unique:
            unique.append(p)
    return unique


@functools.lru_cache(maxsize=None)
def find_share_dir(package: str) -> Path:
    """
    Return the share directory of an installed ROS package.

    Raises MessageDefinitionError naming the package.
    """
    searched = []
    for prefix in _prefixes():
        share = prefix / 'share' / package
        searched.append(str(share))
        if share.is_dir():
            return share
    raise MessageDefinitionError(
        f'ROS package {package!r} not found; looked in {", ".join(searched)} '
        '(install the package or set AMENT_PREFIX_PATH)'
    )


def _definition_file(type_name: str, extension: str) -> Path:
    package, namespace, name = split_type_name(type_name)
    return find_share_dir(package) / namespace / f'{name}{extension}'


@functools.lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    path = _definition_file(type_name, '.msg')
    try:
        return path.read_text(encoding='utf-8')
    except OSError as exc:
        raise MessageDefinitionError(
            f'no .msg definition for {type_name!r}: {path} ({exc.strerror})'
        ) from None


def _dependencies(text: str, package: str) -> list[str]:
    """
    Return the non-primitive field types of a .msg text, sorted like rosbag2's std::set.

    Same-package short names get the package prefix ("Twist" in geometry_msgs ->
    "geometry_msgs/Twist").
    """
    deps: set[str] = set()
    for match in _FIELD_TYPE_RE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        deps.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(deps)


@functools.lru_cache(maxsize=None)
def full_text(type_name: str) -> str:
    """
    Return the complete `ros2msg` definition of type_name.

    type_name is e.g. 'geometry_msgs/msg/TwistStamped'.
    """
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise MessageDefinitionError(
                f'definition of {type_name!r} nests deeper than 50 levels'
            )
        text = _msg_text(name)
        package = split_type_name(name)[0]
        out = text
        for dep in _dependencies(text, package):
            if dep in seen:
                continue
            seen.add(dep)
            out += '\n' + DELIMITER + f'MSG: {dep}\n' + append(dep, depth - 1)
        return out

    split_type_name(type_name)  # reject a malformed name before touching the file system
    return append(type_name, 50)


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """
    Return the RIHS01 type description hash generated with the package.

    The hash comes from share/<pkg>/msg/<Type>.json; rosbag2 stores it as the channel's
    `topic_type_hash`. '' when the package ships no .json.
    """
    try:
        path = _definition_file(type_name, '.json')
        data = json.loads(path.read_text(encoding='utf-8'))
    except (MessageDefinitionError, OSError, ValueError):
        return ''
    package, namespace, name = split_type_name(type_name)
    canonical = f'{package}/{namespace}/{name}'
    for entry in data.get('type_hashes', []):
        if entry.get('type_name') == canonical:
            return str(entry.get('hash_string', ''))
    return ''
