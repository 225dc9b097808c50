"""docs/user/reference.md is what `python -m pulsejet_sim.reference` writes from the code."""

import os
from pathlib import Path
import subprocess
import sys

from pulsejet_sim import reference
from test_offline_without_rclpy import BLOCKER

REPO = Path(__file__).resolve().parent.parent


def test_reference_tables_match_the_code():
    stored = reference.REFERENCE_PATH.read_text()
    assert stored == reference.render(), (
        f'{reference.REFERENCE_PATH} differs from the code: regenerate it with '
        f'`{reference.REGENERATE}` and commit it'
    )


def test_tables_name_every_declared_topic_service_and_parameter():
    from pulsejet_sim.core import topics
    from pulsejet_sim.models.lumped import model as lumped
    from pulsejet_sim.ros import controller_params, sim_node_params

    text = reference.render()
    names = (
        list(topics.TOPIC_TYPES) + list(topics.VIEW_TOPIC_TYPES)
        + list(topics.SERVICE_TYPES)
        + [p.name for p in sim_node_params.PARAMETERS]
        + [p.name for p in controller_params.NODE_PARAMETERS]
        + [k for spec in controller_params.ROUTINE_SPECS.values() for k in spec]
        + [k for spec in lumped.SECTION_SPECS.values() for k in spec]
    )
    missing = [n for n in names if f'| `{n}` |' not in text]
    assert not missing, missing


def test_the_shell_scene_keys_are_generated_from_their_declarations():
    """Every declared shell key has its row, with the default, range and meaning it declares."""
    from pulsejet_sim.models.shell import scene_keys as keys

    text = reference.render()
    shell = text[text.index('### Shell model (`model: shell`)'):]
    specs = [keys.TOP_SPEC, keys.GEOMETRY_KIND_SPEC, *keys.GEOMETRY_SPECS.values(),
             *keys.SECTION_SPECS.values()]
    rows = [reference._key_row(name, key) for spec in specs for name, key in spec.items()]
    assert len(rows) == sum(len(spec) for spec in specs) > 60
    missing = [row[0] for row in rows if '| ' + ' | '.join(row) + ' |' not in shell]
    assert not missing, missing
    # a changed declaration changes the generated row: the stored file then drifts
    assert '| `dt_s` | required | (0, 0.1] | s | the time step' in shell
    assert "| `outlet_radius_m` | half the ring's radius (paper_code: 12.5 mm) |" in shell
    for section in keys.SECTION_SPECS:
        assert f'#### `{section}:`' in shell


def test_check_runs_without_rclpy_and_fails_on_a_drifted_file(tmp_path):
    shim = tmp_path / 'shim'
    shim.mkdir()
    (shim / 'sitecustomize.py').write_text(BLOCKER)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(shim), str(REPO)]))

    def check(path):
        return subprocess.run(
            [sys.executable, '-m', 'pulsejet_sim.reference', '--check', '--out', str(path)],
            env=env, capture_output=True, text=True, timeout=300,
        )

    good = tmp_path / 'reference.md'
    good.write_text(reference.render())
    proc = check(good)
    assert proc.returncode == 0, proc.stderr[-3000:]
    drifted = tmp_path / 'drifted.md'
    drifted.write_text(reference.render().replace('| `real_time_factor` |', '| `rtf` |'))
    proc = check(drifted)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert 'python -m pulsejet_sim.reference' in proc.stderr
