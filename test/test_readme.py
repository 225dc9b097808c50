"""The README and the user docs: their examples run as written (real sim_node, real DDS)."""

from pathlib import Path
import re

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / 'README.md'
ROS_DOC = REPO / 'docs' / 'user' / 'ros.md'


def python_block(path: Path, needle: str) -> str:
    blocks = re.findall(r'```python\n(.*?)```', path.read_text(), re.S)
    return next(b for b in blocks if needle in b)


@pytest.mark.timeout(180)
def test_ros_doc_harness_example_runs(capsys):
    example = python_block(ROS_DOC, 'SimHarness')
    exec(compile(example, str(ROS_DOC), 'exec'), {})
    printed = capsys.readouterr().out
    assert 'SimState' in printed or 'time_s' in printed


@pytest.mark.timeout(300)
def test_readme_python_quickstart_runs(capsys):
    # the quickstart names the modules of the layered package (core/, engine/, scene/)
    example = python_block(README, 'Simulation(')
    namespace = {}
    exec(compile(example, str(README), 'exec'), namespace)
    obs, sim = namespace['obs'], namespace['sim']
    assert obs.time_s == pytest.approx(2.0) and obs.velocity_m_s > 0.0
    ledger = sim.energy_ledger()
    assert ledger['in_actuation_work'] > 0.0 and abs(ledger['closure_relative']) < 1e-6
    assert 'closure_relative' in capsys.readouterr().out


def test_readme_opens_with_the_two_set_up_commands():
    text = README.read_text()
    first_block = re.search(r'```sh\n(.*?)```', text, re.S).group(1)
    commands = [line.split('#')[0].strip() for line in first_block.splitlines() if line.strip()]
    assert commands == ['make demo', 'make test']
    assert 'make test' in (README.parent / '.ci' / 'run').read_text()


def test_readme_stays_short():
    assert len(README.read_text().splitlines()) <= 200
