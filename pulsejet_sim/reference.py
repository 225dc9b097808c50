"""
Write the reference tables of the docs (docs/user/reference.md) from the code's declarations.

    python -m pulsejet_sim.reference            # rewrite docs/user/reference.md
    python -m pulsejet_sim.reference --check    # exit 1 when the file differs from the code

The tables are read from what the code declares as data, never copied: topic and service names,
types and units (`pulsejet_sim.core.topics`), actuator limits (`Command.LIMITS`), the parameters of
sim_node and controller_node (their `ParamSpec` tables) and the scene keys the models declare with
`pulsejet_sim.core.schema` (Number, Choice, Flag; the shell's in its scene_keys module, each with
its meaning). Needs no rclpy: the parameter tables import
without ROS. test/test_reference_docs.py fails when the stored file drifts from the code.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import sys

REFERENCE_PATH = Path(__file__).resolve().parent.parent / 'docs' / 'user' / 'reference.md'
REGENERATE = 'python -m pulsejet_sim.reference'


def _num(x) -> str:
    if isinstance(x, float) and math.isinf(x):
        return '-inf' if x < 0 else 'inf'
    return f'{x:g}'


def _cell(text) -> str:
    return str(text).replace('|', '\\|').replace('\n', ' ')


def _table(header: tuple[str, ...], rows) -> list[str]:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(_cell(c) for c in row) + ' |' for row in rows]
    return lines + ['']


def _rule_cells(rule) -> tuple[str, str, str]:
    """Return (default, allowed, unit) of a schema rule: Number, Choice, Flag, Text or alias."""
    from pulsejet_sim.core.schema import Choice, Flag, Number

    default = getattr(rule, 'default', None)
    if isinstance(rule, Number):
        lo = '(' if rule.low_open else '['
        return (
            'required' if default is None else f'`{_num(default)}`',
            f'{lo}{_num(rule.low)}, {_num(rule.high)}]',
            rule.unit,
        )
    if isinstance(rule, Flag):
        return ('required' if default is None else f'`{str(default).lower()}`',
                'true, false', '')
    if isinstance(rule, Choice):
        return ('required' if default is None else f'`{default}`', ', '.join(rule.choices), '')
    if hasattr(rule, 'of'):  # a deprecated alias of another key
        return ('', ', '.join(rule.choices), f'deprecated name of `{rule.of}`')
    return ('required' if default is None else f'`{default}`', 'text', '')


def _param_rows(specs) -> list[tuple[str, ...]]:
    rows = []
    for spec in specs:
        default = spec.default
        if isinstance(default, bool):
            shown = str(default).lower()
        elif isinstance(default, (list, tuple)):
            shown = '[' + ', '.join(default) + ']'
        elif isinstance(default, float):
            shown = repr(default)
        else:
            shown = repr(default) if default == '' else str(default)
        rows.append((
            f'`{spec.name}`',
            spec.type_name(),
            f'`{shown}`',
            'no' if spec.read_only else 'yes',
            spec.allowed_text(),
            spec.description,
        ))
    return rows


def topics_section() -> list[str]:
    from pulsejet_sim.core import topics as names
    from pulsejet_sim.core.model_io import Command

    types = dict(names.TOPIC_TYPES, **names.VIEW_TOPIC_TYPES)
    subscribed = set(names.COMMAND_TOPICS) | {names.TOPIC_CMD_COMMAND}
    rows = []
    for topic in sorted(types, key=lambda t: (t in subscribed, t.lstrip('/'))):
        field = names.COMMAND_FIELDS.get(topic)
        allowed = ''
        if field:
            low, high = Command.LIMITS[field]
            allowed = f'[{_num(low)}, {_num(high)}]'
        elif topic == names.TOPIC_CMD_COMMAND:
            allowed = ', '.join(
                f'{n} [{_num(Command.LIMITS[n][0])}, {_num(Command.LIMITS[n][1])}]'
                for n in names.APPLIED_COMMAND_NAMES
            )
        rows.append((
            f'`{topic}`',
            types[topic],
            'subscribes' if topic in subscribed else 'publishes',
            names.TOPIC_UNITS[topic],
            allowed,
        ))
    out = ['## Topics of sim_node', '']
    out.append(
        'Names without a leading `/` are relative: the node namespace applies. A command outside '
        'its range, NaN or infinite is rejected with a warning naming it; the held command stays.'
    )
    out.append('')
    out += _table(('topic', 'type', 'sim_node', 'unit / content', 'allowed'), rows)
    out += ['## Services of sim_node', '']
    out += _table(
        ('service', 'type', 'what it does'),
        [(f'`{s}`', t, names.SERVICE_MEANINGS[s]) for s, t in names.SERVICE_TYPES.items()],
    )
    return out


def parameters_section() -> list[str]:
    from pulsejet_sim.ros import controller_params, sim_node_params

    header = ('parameter', 'type', 'default', 'live', 'allowed', 'meaning')
    out = ['## Parameters of sim_node', '']
    out.append(
        'Besides these, every `scene.<section>.<key>` parameter given at start-up overrides that '
        'scene key (read-only; allowed: what the scene keys below allow).'
    )
    out.append('')
    out += _table(header, _param_rows(sim_node_params.PARAMETERS))
    out += ['## Parameters of controller_node', '']
    out.append(
        "The node's own, then the routine's: their defaults here are the routine's; a scene's "
        "`routine:` block replaces them. rclpy's `use_sim_time` defaults to true on this node "
        '(false with `closed_loop`).'
    )
    out.append('')
    out += _table(header, _param_rows(controller_params.NODE_PARAMETERS))
    for kind in controller_params.ROUTINE_SPECS:
        out += [f'### Routine `{kind}`', '']
        out += _table(header, _param_rows(controller_params.routine_parameters(kind, {})))
    return out


def scene_section() -> list[str]:
    from pulsejet_sim.models.lumped import model as lumped
    from pulsejet_sim.ros.controller_params import ROUTINE_SPECS

    header = ('key', 'default', 'allowed', 'unit')
    out = ['## Scene keys', '']
    out.append(
        'A key missing from a scene takes its default; `required` keys have none. An unknown key '
        'or a value outside its range is refused with the key, the value and what is allowed.'
    )
    out.append('')
    out += ['### Lumped model (`model: lumped`)', '']
    for section, spec in lumped.SECTION_SPECS.items():
        out += [f'#### `{section}:`', '']
        out += _table(header, [(f'`{k}`', *_rule_cells(r)) for k, r in spec.items()])
    out += ['### Routine (`routine:`, both models)', '']
    for kind, spec in ROUTINE_SPECS.items():
        out += [f'#### `kind: {kind}`', '']
        out += _table(header, [(f'`{k}`', *_rule_cells(r)) for k, r in spec.items()])
    out += shell_scene_section()
    return out


def _key_row(name: str, key) -> tuple[str, ...]:
    """Return the row of a shell scene key (scene_keys.Key): its words replace derived values."""
    default, allowed, unit = _rule_cells(key.rule)
    if key.default:
        default = key.default
    return (f'`{name}`', default, key.allowed or allowed, unit, key.doc)


def shell_scene_section() -> list[str]:
    from pulsejet_sim.models.shell import scene_keys as keys

    header = ('key', 'default', 'allowed', 'unit', 'meaning')

    def table(spec) -> list[str]:
        return _table(header, [_key_row(name, key) for name, key in spec.items()])

    out = ['### Shell model (`model: shell`)', '']
    out.append(
        'A default or a bound in words is computed from other keys of the scene; a refusal '
        'prints the value it takes there.'
    )
    out.append('')
    out += ['#### Top level', '']
    out += table(keys.TOP_SPEC)
    sections = list(keys.SECTION_SPECS.items())
    for section, spec in sections[:1]:
        out += [f'#### `{section}:`', '']
        out += table(spec)
    out += ['#### `geometry:`', '']
    out += table(keys.GEOMETRY_KIND_SPEC)
    for kind, spec in keys.GEOMETRY_SPECS.items():
        out += [f'`kind: {kind}`:', '']
        out += table(spec)
    out += ['`kind: points`:', '']
    out += _table(header, [('`points`', 'required', 'a list', 'm', keys.GEOMETRY_POINTS_DOC)])
    for section, spec in sections[1:]:
        out += [f'#### `{section}:`', '']
        if section == 'actuation':
            out.append(
                '; '.join(f'`kind: {kind}` takes {", ".join(f"`{k}`" for k in names)}'
                          for kind, names in keys.ACTUATION_KIND_KEYS.items())
                + '; `kind: none` uses none of them.'
            )
            out.append('')
        out += table(spec)
    return out


def render() -> str:
    """Return the text of docs/user/reference.md."""
    lines = [
        '# Reference tables',
        '',
        f'<!-- Generated from the code by `{REGENERATE}`; do not edit by hand. -->',
        '',
        'Topics, services, node parameters and scene keys as the code declares them. '
        f'Regenerate with `{REGENERATE}` after changing a declaration; '
        '`test/test_reference_docs.py` fails while this file differs from the code.',
        '',
    ]
    lines += topics_section() + parameters_section() + scene_section()
    return '\n'.join(lines).rstrip('\n') + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m pulsejet_sim.reference', description=__doc__
                                     .split('\n\n')[0])
    parser.add_argument('--check', action='store_true',
                        help='exit 1 if the stored file differs from the code, write nothing')
    parser.add_argument('--out', type=Path, default=REFERENCE_PATH, help='file to write or check')
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        stored = args.out.read_text() if args.out.is_file() else None
        if stored != text:
            print(f'{args.out} differs from the code; regenerate it with `{REGENERATE}`',
                  file=sys.stderr)
            return 1
        print(f'{args.out} matches the code')
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
