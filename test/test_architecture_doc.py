"""docs/dev/architecture.md's layer table matches the code and the layer contract (test_layers)."""

from __future__ import annotations

from pathlib import Path
import re

from test_layers import layer_of

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / 'docs' / 'dev' / 'architecture.md'


def layer_rows() -> list[tuple[str, str]]:
    """(layer name, path) of every row of the '## Layers' table, top first."""
    text = DOC.read_text()
    section = text.split('## Layers', 1)[1].split('\n## ', 1)[0]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if len(cells) >= 3 and cells[1].startswith('`'):
            rows.append((cells[0], cells[1].strip('`')))
    return rows


def module_of(path: str) -> str:
    return path.rstrip('/').removesuffix('.py').replace('/', '.')


def test_every_row_names_a_place_that_exists():
    rows = layer_rows()
    assert len(rows) >= 10
    missing = [p for _, p in rows if not (ROOT / p).exists()]
    assert not missing, f'architecture.md names what is not there: {missing}'


def test_rows_run_down_the_layers_of_the_contract():
    # a folder's row stands for the modules inside it
    layers = [layer_of(module_of(p) + ('.m' if p.endswith('/') else '')) for _, p in layer_rows()]
    assert layers == sorted(layers), list(zip([p for _, p in layer_rows()], layers))


def test_every_part_of_the_package_has_a_row():
    named = {module_of(p) for _, p in layer_rows()}
    parts = {
        f'pulsejet_sim.{p.stem}' for p in (ROOT / 'pulsejet_sim').iterdir()
        if (p.is_dir() and (p / '__init__.py').exists())
        or (p.suffix == '.py' and p.name != '__init__.py')
    }
    assert not parts - named, f'parts of pulsejet_sim with no row: {sorted(parts - named)}'
    assert re.search(r'`pulsejet_ctrl/`', DOC.read_text())
