"""Every shipped scene says, in a comment above its first key, which physics it uses and why."""

from pathlib import Path

import pytest
import yaml

CONFIG = Path(__file__).resolve().parent.parent / 'config'
SCENES = sorted(CONFIG.glob('*.yaml'))


def header_comment(path: Path) -> str:
    """Return the comment block above the scene's first key, without the '#' marks."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith('#'):
            break
        lines.append(line.lstrip('#').strip())
    return ' '.join(lines)


def test_the_shipped_scenes_are_found():
    assert {p.stem for p in SCENES} >= {'shell_robot', 'pump_cycle', 'escape'}


@pytest.mark.parametrize('path', SCENES, ids=[p.stem for p in SCENES])
def test_scene_states_its_physics_and_its_optional_terms(path):
    text = header_comment(path)
    assert 'Physics used:' in text, f'{path.name}: no "Physics used:" comment above its first key'
    used = text.split('Physics used:', 1)[1].lower().replace('-', ' ').replace('_', ' ')
    model = yaml.safe_load(path.read_text())['model']
    assert 'coupling' in used, f'{path.name}: the comment does not name the coupling'
    # each optional term the model offers: whether the scene uses it
    optional = {
        'shell': ('starting jet', 'internal inertia'),
        'lumped': ('starting jet', 'spring'),
    }[model]
    for term in optional:
        assert term in used, f'{path.name}: the comment does not say whether it uses {term!r}'
