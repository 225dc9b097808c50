"""
The layer contract of the code base, read from the source with the `ast` module.

Layers, top to bottom (docs/dev/architecture.md): an import may point down or sideways inside its
own layer, never up; no import cycle between modules or between top-level packages; only the ROS
adapters (pulsejet_sim.ros, pulsejet_ctrl) import rclpy or ROS message packages. Lazy imports
inside functions count: they are dependencies all the same.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ('pulsejet_sim', 'pulsejet_ctrl')

# Top first. Modules of one layer may import each other (without cycles).
LAYERS: list[tuple[str, ...]] = [
    ('pulsejet_ctrl', 'pulsejet_sim.reference'),
    ('pulsejet_sim.ros',),
    ('pulsejet_sim.cli',),
    ('pulsejet_sim.studies', 'pulsejet_sim.view'),
    ('pulsejet_sim.envs',),
    ('pulsejet_sim.analysis',),
    ('pulsejet_sim.engine', 'pulsejet_sim.bag'),
    ('pulsejet_sim.scene',),
    ('pulsejet_sim.routines', 'pulsejet_sim.models'),
    ('pulsejet_sim.core',),
]
ROS_ADAPTERS = ('pulsejet_sim.ros', 'pulsejet_ctrl')
ROS_MODULES = (
    'rclpy', 'rcl_interfaces', 'rosidl_runtime_py', 'rosgraph_msgs', 'builtin_interfaces'
)
ROS_SUFFIXES = ('_msgs', '_srvs', '_interfaces')


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def source_modules() -> dict[str, Path]:
    found = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob('*.py')):
            found[module_name(path)] = path
    return found


def imports_of(path: Path, name: str, known: set[str]) -> set[str]:
    """Every module this file imports (top-level or lazy), resolved to known modules if ours."""
    tree = ast.parse(path.read_text(), str(path))
    out: set[str] = set()
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                anchor = package.split('.')
                anchor = anchor[: len(anchor) - node.level + 1]
                base = '.'.join(anchor + ([base] if base else []))
            for alias in node.names:
                full = f'{base}.{alias.name}'
                out.add(full if full in known else base)
    return out


def own(target: str, known: set[str]) -> str | None:
    """Return the module of ours that `target` names (a module, or a name inside one), or None."""
    while target:
        if target in known:
            return target
        target = target.rpartition('.')[0]
    return None


def layer_of(module: str) -> int:
    if module in PACKAGES:  # a bare package face (docstring only): imports nothing
        return len(LAYERS)
    for i, group in enumerate(LAYERS):
        if any(module == g or module.startswith(g + '.') for g in group):
            return i
    raise AssertionError(f'{module} is in no layer of LAYERS: add it where it belongs')


@pytest.fixture(scope='module')
def graph() -> dict[str, set[str]]:
    modules = source_modules()
    known = set(modules)
    edges: dict[str, set[str]] = {}
    for name, path in modules.items():
        edges[name] = imports_of(path, name, known)
    return edges


def test_every_module_has_a_layer(graph):
    for module in graph:
        layer_of(module)
    for package in PACKAGES:
        imported = {t for t in graph[package] if t != '__future__'}
        assert not imported, f'{package}/__init__.py imports {imported}'


def test_no_import_points_up(graph):
    known = set(graph)
    upward = []
    for module, targets in graph.items():
        for t in targets:
            mine = own(t, known)
            if mine is None or mine == module:
                continue
            # a package's __init__ may import its own modules (its public face)
            if mine.startswith(module + '.'):
                continue
            if layer_of(mine) < layer_of(module):
                upward.append(f'{module} -> {mine}')
    assert not upward, 'imports that point up the layers:\n' + '\n'.join(sorted(upward))


def _cycles(nodes: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in nodes.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_between_modules(graph):
    known = set(graph)
    nodes = {}
    for module, targets in graph.items():
        deps = {own(t, known) for t in targets} - {None, module}
        # importing a package runs its __init__; a package face importing its own modules is not
        # a cycle with a module that imports one of them
        nodes[module] = {d for d in deps if not d.startswith(module + '.')}
    assert not _cycles(nodes), f'import cycles: {_cycles(nodes)}'


def test_no_import_cycles_between_packages(graph):
    known = set(graph)
    top: dict[str, set[str]] = {}
    for module, targets in graph.items():
        here = module.split('.')[0]
        for t in targets:
            mine = own(t, known)
            if mine is not None and mine.split('.')[0] != here:
                top.setdefault(here, set()).add(mine.split('.')[0])
    assert not _cycles(top), f'packages that import each other: {_cycles(top)}'


def test_only_ros_adapters_import_ros(graph):
    offenders = []
    for module, targets in graph.items():
        if any(module == a or module.startswith(a + '.') for a in ROS_ADAPTERS):
            continue
        for t in targets:
            root = t.split('.')[0]
            if root in ROS_MODULES or root.endswith(ROS_SUFFIXES):
                offenders.append(f'{module} imports {t}')
    assert not offenders, 'ROS imported outside the adapters:\n' + '\n'.join(sorted(offenders))


def test_contract_catches_an_upward_import(tmp_path):
    """The checker itself: a core module importing the engine is reported."""
    path = tmp_path / 'x.py'
    path.write_text('from pulsejet_sim.engine.simulation import Simulation\n')
    known = {'pulsejet_sim.engine.simulation', 'pulsejet_sim.core.x'}
    deps = imports_of(path, 'pulsejet_sim.core.x', known)
    assert own(next(iter(deps)), known) == 'pulsejet_sim.engine.simulation'
    assert layer_of('pulsejet_sim.engine.simulation') < layer_of('pulsejet_sim.core.x')
    assert _cycles({'a': {'b'}, 'b': {'a'}, 'c': {'a'}}) == [['a', 'b']]
