"""
A small declarative checker for scene sections: every key known, every value typed and in range.

Errors name the key (dotted path), the bad value and what is allowed, so a user can fix a scene
file from the message alone. Values are shown shortened (show()): a message never carries a
whole file back.

safe_load_yaml() is the one way pulsejet reads a YAML file it did not write (scenes, sweeps, fits,
the scene stored in a recording): yaml.SafeLoader only (no Python tags, nothing executed), at most
MAX_YAML_BYTES, and refused when its aliases expand to more than MAX_YAML_NODES values, nest deeper
than MAX_YAML_DEPTH levels or refer to themselves (a "billion laughs" file would otherwise hang or
exhaust memory in whatever walks the data).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import re
import reprlib
from typing import Any, Mapping

from pulsejet_sim.core.model_io import ModelError
import yaml

MAX_YAML_BYTES = 1 << 20  # 1 MiB: a scene is a few kB, a sweep or fit some tens of kB
MAX_YAML_NODES = 100_000  # values after alias expansion
MAX_YAML_DEPTH = 64  # nesting levels

_SHOW = reprlib.Repr()
_SHOW.maxstring = 60
_SHOW.maxother = 60
_SHOW.maxlist = _SHOW.maxtuple = _SHOW.maxdict = _SHOW.maxset = 6
_SHOW.maxlevel = 3


def show(value: Any) -> str:
    """
    Return repr() of a value, shortened to a line.

    Shortens long strings, big or nested containers, recursion.
    """
    try:
        return _SHOW.repr(value)
    except Exception:  # a value whose repr fails
        return f'<{type(value).__name__}>'


class YAMLInputError(ValueError):
    """
    A YAML text that is not valid, too large or too deeply aliased.

    The message names the file.
    """


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _check_graph(root: yaml.Node, what: str) -> None:
    """Refuse a composed YAML graph whose expansion is too big, too deep or cyclic."""
    memo: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, int, bool]] = [(root, 1, False)]
    while stack:
        node, depth, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            memo[key] = min(1 + sum(memo[id(c)] for c in _children(node)), MAX_YAML_NODES + 1)
            if memo[key] > MAX_YAML_NODES:
                raise YAMLInputError(
                    f'{what}: expands to more than {MAX_YAML_NODES} values through its '
                    f'aliases; allowed: a plain scene/sweep file (a YAML bomb is refused)'
                )
            continue
        if key in memo:
            continue
        if key in on_path:
            raise YAMLInputError(
                f'{what}: an alias refers to a value containing itself (line '
                f'{node.start_mark.line + 1}); allowed: non-recursive YAML'
            )
        if depth > MAX_YAML_DEPTH:
            raise YAMLInputError(
                f'{what}: nested deeper than {MAX_YAML_DEPTH} levels (line '
                f'{node.start_mark.line + 1}); allowed: at most {MAX_YAML_DEPTH}'
            )
        on_path.add(key)
        stack.append((node, depth, True))
        for child in _children(node):
            if id(child) in on_path:
                raise YAMLInputError(
                    f'{what}: an alias refers to a value containing itself (line '
                    f'{child.start_mark.line + 1}); allowed: non-recursive YAML'
                )
            if id(child) not in memo:
                stack.append((child, depth + 1, False))


class _SafeLoader(yaml.SafeLoader):
    """
    yaml.SafeLoader that also reads ``1e-3``, ``4e4`` and ``4.0e4`` as numbers.

    PyYAML follows YAML 1.1, whose floats need a dot and a signed exponent, so an unquoted ``1e-3``
    or ``4.0e4`` was text ('1e-3' was refused as "not a number" by the lumped model's number
    rule; the shell converted it); YAML 1.2, and other readers of a scene file, read them as
    numbers. Plain integers stay integers (their resolver comes first) and quoted text stays text.
    """


_SafeLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$'),
    list('-+0123456789.'),
)


def safe_load_yaml(text: str | bytes, what: str) -> Any:
    """
    Parse one YAML document with the safe loader (exponents without a dot are numbers too).

    The limits above apply; YAMLInputError names `what`.
    """
    if isinstance(text, bytes):
        if len(text) > MAX_YAML_BYTES:
            raise YAMLInputError(
                f'{what}: {len(text)} bytes; allowed: at most {MAX_YAML_BYTES} bytes of YAML'
            )
        try:
            text = text.decode('utf-8')
        except UnicodeDecodeError as err:
            raise YAMLInputError(
                f'{what}: not UTF-8 text (byte {err.start}); allowed: a UTF-8 YAML file'
            ) from None
    if not isinstance(text, str):
        raise YAMLInputError(f'{what}: {type(text).__name__} given; allowed: YAML text')
    if len(text) > MAX_YAML_BYTES:
        raise YAMLInputError(
            f'{what}: {len(text)} characters; allowed: at most {MAX_YAML_BYTES} of YAML'
        )
    try:
        loader = _SafeLoader(text)
    except yaml.YAMLError as err:  # the reader refuses control characters up front
        detail = ' '.join(str(err).split())
        raise YAMLInputError(
            f'{what}: not valid YAML ({detail[:300]}); allowed: one well-formed YAML document'
        ) from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_graph(node, what)
        return loader.construct_document(node)
    except yaml.YAMLError as err:
        detail = ' '.join(str(err).split())
        raise YAMLInputError(
            f'{what}: not valid YAML ({detail[:300]}); allowed: one well-formed YAML document'
        ) from None
    except RecursionError:
        raise YAMLInputError(
            f'{what}: nested too deeply to parse; allowed: at most {MAX_YAML_DEPTH} levels'
        ) from None
    finally:
        loader.dispose()


def read_yaml_file(path: Any, what: str | None = None) -> Any:
    """safe_load_yaml() of a file, refusing one larger than MAX_YAML_BYTES before reading it."""
    from pathlib import Path

    p = Path(path)
    what = what or f'file {str(p)!r}'
    try:
        size = p.stat().st_size
        if size > MAX_YAML_BYTES:
            raise YAMLInputError(
                f'{what}: {size} bytes; allowed: at most {MAX_YAML_BYTES} bytes of YAML'
            )
        with open(p, 'rb') as fh:
            data = fh.read(MAX_YAML_BYTES + 1)
    except (OSError, ValueError) as err:
        if isinstance(err, YAMLInputError):
            raise
        reason = getattr(err, 'strerror', None) or str(err)
        raise YAMLInputError(
            f'{what}: cannot be read ({reason}); allowed: a readable YAML file'
        ) from None
    return safe_load_yaml(data, what)


#: libyaml's emitter and parser when PyYAML was built with it (5-10x faster; the same safe subset)
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)
_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def dump_yaml(data: Any) -> str:
    """Return YAML text of plain data (keys in their order), as yaml.safe_dump writes it."""
    return yaml.dump(data, Dumper=_DUMPER, sort_keys=False)


def load_own_yaml(text: str) -> Any:
    """
    Parse YAML that pulsejet wrote itself (e.g. QoS profiles kept by the bag writer).

    The safe loader; for text from outside use safe_load_yaml(), which also bounds its size.
    """
    return yaml.load(text, Loader=_LOADER)


class NumberRejected(ValueError):
    """Why a value is not an allowed number: ``reason`` is 'not a number' or 'out of range'."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class Number:
    """
    A finite number in [low, high] ((low, high] with low_open), in `unit`.

    The one rule every input reader applies to a number (scene sections, sweep, fit and
    optimisation files, ROS parameters, command-line options): a bool is never a number, NaN and
    infinities are out of range. Each reader words its message its own way through check() (scene
    keys), accept() ("<where>: <value> rejected; allowed: <what>") or value() (the bare rule).
    """

    default: float | None  # None: required
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False  # True: value must be > low (not >=)
    unit: str = ''
    integer: bool = False  # with from_text: the text must read as an integer (a count)

    def value(self, value: Any, from_text: bool = False) -> float:
        """
        Return value as a float (an int with `integer` and from_text) if this rule allows it.

        from_text: also take what float() (int()) reads, e.g. '2.5' from a command line or a
        string parameter. Raises NumberRejected with its reason.
        """
        if isinstance(value, bool):
            raise NumberRejected('not a number')
        if from_text:
            try:
                v = (int if self.integer else float)(value)
            except (TypeError, ValueError):
                raise NumberRejected('not a number') from None
            except OverflowError:
                raise NumberRejected('out of range') from None
        elif not isinstance(value, (int, float)):
            raise NumberRejected('not a number')
        else:
            try:
                v = float(value)
            except OverflowError:  # an int beyond the floats
                raise NumberRejected('out of range') from None
        too_low = v <= self.low if self.low_open else v < self.low
        if not math.isfinite(v) or too_low or v > self.high:
            raise NumberRejected('out of range')
        return v

    def check(
        self, key: str, value: Any, *, from_text: bool = False, allowed: str | None = None
    ) -> float:
        """Return value() or raise ModelError '<key>: <value> is <reason>; allowed: <what>'."""
        try:
            return self.value(value, from_text)
        except NumberRejected as why:
            raise ModelError(
                f'{key}: {show(value)} is {why.reason}; allowed: {allowed or self.allowed()}'
            ) from None

    def accept(
        self,
        value: Any,
        where: str,
        *,
        error: type[Exception] = ModelError,
        allowed: str | None = None,
        sep: str = ': ',
        from_text: bool = False,
    ) -> float:
        """
        Return value() or raise `error` '<where><sep><value> rejected; allowed: <what>'.

        sep '=' words it as a parameter (name=value), sep '' for argparse (which names the
        option itself); `allowed` replaces the generated range text.
        """
        try:
            return self.value(value, from_text)
        except NumberRejected:
            raise error(
                f'{where}{sep}{show(value)} rejected; allowed: {allowed or self.allowed()}'
            ) from None

    def allowed(self) -> str:
        lo = '(' if self.low_open else '['
        unit = f' {self.unit}' if self.unit else ''
        return f'a finite number in {lo}{self.low:g}, {self.high:g}]{unit}'


@dataclass(frozen=True)
class Flag:
    default: bool | None

    def check(self, key: str, value: Any) -> bool:
        if not isinstance(value, bool):
            raise ModelError(f'{key}: {show(value)} is not a boolean; allowed: true or false')
        return value

    def accept(
        self,
        value: Any,
        where: str,
        *,
        error: type[Exception] = ModelError,
        sep: str = ': ',
        from_text: bool = False,
    ) -> bool:
        """
        Return the boolean or raise `error` '<where><sep><value> rejected; allowed: true or false'.

        from_text: also take the words true and false (any case, spaces around), as a string
        parameter gives them.
        """
        if isinstance(value, bool):
            return value
        if from_text and isinstance(value, str) and value.strip().lower() in ('true', 'false'):
            return value.strip().lower() == 'true'
        raise error(f'{where}{sep}{show(value)} rejected; allowed: true or false')


@dataclass(frozen=True)
class Choice:
    default: str | None
    choices: tuple[str, ...]

    def check(self, key: str, value: Any) -> str:
        if not isinstance(value, str) or value not in self.choices:
            raise ModelError(
                f'{key}: {show(value)} is not allowed; allowed: one of {", ".join(self.choices)}'
            )
        return value


@dataclass(frozen=True)
class Text:
    default: str | None

    def check(self, key: str, value: Any) -> str:
        if not isinstance(value, str):
            raise ModelError(f'{key}: {show(value)} is not a string; allowed: text')
        return value


def mapping(
    value: Any, where: str, allowed: str, error: type[Exception] = ModelError
) -> Mapping[str, Any]:
    """
    Return the mapping a section holds ({} when absent).

    Anything else raises `error` '<where>: <value> is not a mapping; allowed: <allowed>'.
    """
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise error(f'{where}: {show(value)} is not a mapping; allowed: {allowed}')
    return value


def check_section(section: str, given: Any, spec: Mapping[str, Any]) -> dict[str, Any]:
    """Validate one mapping against its spec, filling defaults. Raises ModelError."""
    if given is None:
        given = {}
    if not isinstance(given, Mapping):
        raise ModelError(
            f'{section}: {show(given)} is not a mapping; allowed keys: {", ".join(spec)}'
        )
    unknown = [k for k in given if k not in spec]
    if unknown:
        raise ModelError(
            f'{section}.'
            f'{show(unknown[0]) if not isinstance(unknown[0], str) else unknown[0][:60]}: '
            f'unknown key (value {show(given[unknown[0]])}); allowed keys: {", ".join(spec)}'
        )
    out: dict[str, Any] = {}
    for key, rule in spec.items():
        path = f'{section}.{key}'
        if key in given:
            out[key] = rule.check(path, given[key])
        elif rule.default is None:
            raise ModelError(
                f'{path}: missing; allowed: '
                f'{rule.allowed() if hasattr(rule, "allowed") else "required"}'
            )
        else:
            out[key] = rule.default
    return out
