"""
Node parameters and command lines.

One table entry per parameter (default, description, range, read-only), the check that a live
change must pass, and the `--ros-args` form of a value.

Shared by sim_node, controller_node, recorder and replay (declaration and on-set validation) and by
everything that starts a node as a process (the demo, the harness, tests, benchmarks).

Structured scene overrides: sim_node takes every parameter named `scene.<section>.<key>` (from
`-p scene.geometry.nozzle_radius_m:=0.01` or a params file, where a nested `scene:` mapping is
flattened by rcl to the same names) as an override of that scene key (`scene_overrides` below).
"""

from __future__ import annotations

import dataclasses
import sys
from typing import TYPE_CHECKING

from pulsejet_sim.core.schema import Number

if TYPE_CHECKING:  # rclpy's types are imported where used: the tables import without ROS
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """
    One parameter: its default, description, type and allowed values.

    Declared from this table.
    """

    name: str
    default: object
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    allowed: str | None = None  # wording of the allowed values when the range alone is not enough
    dynamic: bool = False  # any type accepted by rclpy: the node checks the value itself

    def allowed_text(self) -> str:
        if self.allowed:
            return self.allowed
        if self.choices:
            return 'one of ' + ', '.join(self.choices)
        if isinstance(self.default, (list, tuple)):
            return 'a list of strings'
        if self.low is not None:
            kind = (
                'a whole number'
                if isinstance(self.default, int) and not isinstance(self.default, bool)
                else 'a number'
            )
            return f'{kind} in [{self.low:g}, {self.high:g}]'
        if isinstance(self.default, bool):
            return 'true or false'
        return 'a string'

    def type_name(self) -> str:
        """Return the ROS parameter type the default declares: bool, integer, double, string..."""
        if isinstance(self.default, bool):
            return 'bool'
        if isinstance(self.default, int):
            return 'integer'
        if isinstance(self.default, float):
            return 'double'
        if isinstance(self.default, (list, tuple)):
            return 'string[]'
        return 'string'

    def descriptor(self) -> ParameterDescriptor:
        from rcl_interfaces.msg import (
            FloatingPointRange,
            IntegerRange,
            ParameterDescriptor,
            ParameterType,
        )

        d = ParameterDescriptor(
            description=f'{self.description}; allowed: {self.allowed_text()}',
            read_only=self.read_only,
        )
        if isinstance(self.default, bool):
            d.type = ParameterType.PARAMETER_BOOL
        elif isinstance(self.default, int):
            d.type = ParameterType.PARAMETER_INTEGER
            d.integer_range = [
                IntegerRange(from_value=int(self.low), to_value=int(self.high), step=0)
            ]
        elif isinstance(self.default, float):
            # statically typed, as rclcpp and rclpy type a declared double: a live set with an
            # integer is refused by rclpy with its reason (`declare` converts an integer given at
            # start-up, saying so); the range is applied by rclpy too
            d.type = ParameterType.PARAMETER_DOUBLE
            d.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high), step=0.0)
            ]
        elif isinstance(self.default, (list, tuple)):
            d.type = ParameterType.PARAMETER_STRING_ARRAY
        else:
            d.type = ParameterType.PARAMETER_STRING
            if self.choices:
                d.additional_constraints = 'one of: ' + ', '.join(self.choices)
        if self.dynamic:
            d.type = ParameterType.PARAMETER_NOT_SET
            d.dynamic_typing = True
            d.additional_constraints = d.additional_constraints or self.allowed_text()
        return d

    def check(self, value):
        """
        Return the value converted (float for doubles).

        Raises ValueError naming the value and what is allowed.
        """
        if isinstance(self.default, bool):
            ok = isinstance(value, bool)
        elif isinstance(self.default, int):
            ok = (
                isinstance(value, int)
                and not isinstance(value, bool)
                and self.low <= value <= self.high
            )
        elif isinstance(self.default, float):
            return check_number(self.name, value, self.low, self.high, self.allowed_text())
        elif isinstance(self.default, (list, tuple)):
            if value is None and not self.default:  # declared by type only (`declare`): empty
                return ()
            ok = isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)
        else:
            ok = isinstance(value, str) and (self.choices is None or value in self.choices)
        if not ok:
            raise ValueError(
                f'parameter {self.name}={value!r} rejected; allowed: {self.allowed_text()}'
            )
        return value


def declare(node, spec: ParamSpec):
    """
    Declare `spec` on `node` and return its checked value (ValueError: a bad one, named).

    A value given at start-up (command line or params file) is checked against the spec before
    rclpy sees it, so a wrong type is refused with the allowed values instead of rclpy's bare type
    error. A double given as an integer (`-p real_time_factor:=2`, `real_time_factor: 2` in a
    params file) is declared as that double and logged: the parameter stays a double, as
    `ros2 param describe` says, and a later `ros2 param set` with an integer is refused by rclpy
    ("Wrong parameter type, expected 'Type.DOUBLE' got 'Type.INTEGER'"), as on every ROS node.
    """
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import Parameter

    descriptor = spec.descriptor()
    # rclpy keeps the start-up values (command line, params files) only in this attribute
    override = node._parameter_overrides.get(spec.name)
    if override is not None and override.type_ != Parameter.Type.NOT_SET:
        spec.check(override.value)
        if (
            descriptor.type == ParameterType.PARAMETER_DOUBLE
            and override.type_ == Parameter.Type.INTEGER
        ):
            value = float(override.value)
            node.get_logger().info(
                f'parameter {spec.name}:={override.value} given as an integer; declared as the '
                f'double {value!r}'
            )
            node.declare_parameter(spec.name, value, descriptor, ignore_override=True)
            return spec.check(node.get_parameter(spec.name).value)
    if isinstance(spec.default, (list, tuple)) and not spec.default:
        # rclpy types an empty list as a byte array: declared by its type only, the parameter is
        # not set (`ros2 param get` says so) until given, and not set means empty
        node.declare_parameter(spec.name, Parameter.Type.STRING_ARRAY, descriptor)
        return spec.check(node.get_parameter_or(spec.name).value)
    node.declare_parameter(spec.name, spec.default, descriptor)
    return spec.check(node.get_parameter(spec.name).value)


def check_number(name, value, low, high, allowed=None) -> float:
    """
    Return value (an int or float parameter) as float if finite and in [low, high].

    Else ValueError 'parameter <name>=<value> rejected; allowed: ...'.
    """
    return Number(None, low, high).accept(
        value,
        f'parameter {name}',
        error=ValueError,
        allowed=allowed or f'a number in [{low:g}, {high:g}]',
        sep='=',
    )


def check_parameters(params, specs) -> tuple[dict, SetParametersResult | None]:
    """
    Check rclpy Parameters against their specs (unknown names pass through unchecked).

    Returns the converted values, or a rejection naming the first bad value and what is allowed.
    """
    from rcl_interfaces.msg import SetParametersResult

    checked = {}
    for param in params:
        spec = specs.get(param.name)
        if spec is None:
            continue
        try:
            checked[param.name] = spec.check(param.value)
        except ValueError as exc:
            return checked, SetParametersResult(successful=False, reason=str(exc))
    return checked, None


SCENE_PREFIX = 'scene.'


def scene_override_names(overrides) -> list[str]:
    """
    Return the `scene.<key>` names among a node's parameter overrides, sorted.

    The overrides are rclpy's `_parameter_overrides`: command line, params files and constructor
    overrides.
    """
    return sorted(name for name in overrides if name.startswith(SCENE_PREFIX))


def scene_override_descriptor(name: str) -> ParameterDescriptor:
    from rcl_interfaces.msg import ParameterDescriptor

    key = name[len(SCENE_PREFIX):]
    return ParameterDescriptor(
        description=f'scene override: the value of scene key {key} (merged over the scene file '
                    'and '
        'scene_overrides); allowed: what the scene schema allows for that key',
        read_only=True,
        dynamic_typing=True,
    )


def scene_overrides(values: dict) -> dict:
    """
    Nest the `scene.<key>` parameters into the mapping merged into the scene.

    {'scene.geometry.nozzle_radius_m': 0.01, ...} -> {'geometry': {'nozzle_radius_m': 0.01}} (the
    scene's own validation then refuses an unknown key or a bad value, naming it). ValueError for a
    name with an empty part or a key given both as a value and as a section.
    """
    out: dict = {}
    origin: dict = {}  # key path -> parameter that set it (for a conflict message)
    for name in sorted(values):
        parts = name[len(SCENE_PREFIX):].split('.')
        if not name.startswith(SCENE_PREFIX) or not all(parts):
            raise ValueError(
                f'parameter {name!r} rejected; allowed: scene.<section>.<key>, e.g. '
                'scene.geometry.nozzle_radius_m'
            )
        value = values[name]
        if not isinstance(value, (bool, int, float, str)):  # an rclpy array: a plain list
            value = list(value)
        node = out
        for i, part in enumerate(parts[:-1]):
            path = tuple(parts[: i + 1])
            if path in origin:
                raise ValueError(
                    f'parameter {name}={value!r} conflicts with {origin[path]}: '
                    f'{".".join(path)} cannot be both a value and a section'
                )
            node = node.setdefault(part, {})
        node[parts[-1]] = value  # sorted: a key's own value comes before its sub-keys
        origin[tuple(parts)] = name
    return out


def ros_value(value) -> str:
    """Format a --ros-args value: doubles always parse as doubles, strings as strings."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        s = repr(value)
        return format(value, '.12f') if ('e' in s or 'n' in s) else s
    if isinstance(value, str):
        return (
            value
            if value and all(c.isalnum() or c in '_./-' for c in value) and not value[0].isdigit()
            else "'" + value.replace("'", "\\'") + "'"
        )
    return str(value)


def node_command(module: str, params: dict) -> list[str]:
    """`python -m module --ros-args -p name:=value ...` with this interpreter."""
    cmd = [sys.executable, '-m', module, '--ros-args']
    for name, value in params.items():
        cmd += ['-p', f'{name}:={ros_value(value)}']
    return cmd
