"""A small declarative checker for scene sections: every key known, every value typed and in range.

Errors name the key (dotted path), the bad value and what is allowed, so a user can fix a scene
file from the message alone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from pulsejet_sim.models.base import ModelError


@dataclass(frozen=True)
class Number:
    default: float | None          # None: required
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False         # True: value must be > low (not >=)
    unit: str = ''

    def check(self, key: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ModelError(f'{key}: {value!r} is not a number; allowed: {self.allowed()}')
        v = float(value)
        too_low = v <= self.low if self.low_open else v < self.low
        if not math.isfinite(v) or too_low or v > self.high:
            raise ModelError(f'{key}: {value!r} is out of range; allowed: {self.allowed()}')
        return v

    def allowed(self) -> str:
        lo = '(' if self.low_open else '['
        unit = f' {self.unit}' if self.unit else ''
        return f'a finite number in {lo}{self.low:g}, {self.high:g}]{unit}'


@dataclass(frozen=True)
class Flag:
    default: bool | None

    def check(self, key: str, value: Any) -> bool:
        if not isinstance(value, bool):
            raise ModelError(f'{key}: {value!r} is not a boolean; allowed: true or false')
        return value


@dataclass(frozen=True)
class Choice:
    default: str | None
    choices: tuple[str, ...]

    def check(self, key: str, value: Any) -> str:
        if value not in self.choices:
            raise ModelError(f'{key}: {value!r} is not allowed; allowed: one of {", ".join(self.choices)}')
        return value


@dataclass(frozen=True)
class Text:
    default: str | None

    def check(self, key: str, value: Any) -> str:
        if not isinstance(value, str):
            raise ModelError(f'{key}: {value!r} is not a string; allowed: text')
        return value


def check_section(section: str, given: Any, spec: Mapping[str, Any]) -> dict[str, Any]:
    """Validate one mapping against its spec, filling defaults. Raises ModelError."""
    if given is None:
        given = {}
    if not isinstance(given, Mapping):
        raise ModelError(f'{section}: {given!r} is not a mapping; allowed keys: {", ".join(spec)}')
    unknown = [k for k in given if k not in spec]
    if unknown:
        raise ModelError(f'{section}.{unknown[0]}: unknown key; allowed keys: {", ".join(spec)}')
    out: dict[str, Any] = {}
    for key, rule in spec.items():
        path = f'{section}.{key}'
        if key in given:
            out[key] = rule.check(path, given[key])
        elif rule.default is None:
            raise ModelError(f'{path}: missing; allowed: {rule.allowed() if hasattr(rule, "allowed") else "required"}')
        else:
            out[key] = rule.default
    return out
