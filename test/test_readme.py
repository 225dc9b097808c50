"""The README's harness example runs as written (real sim_node, real DDS)."""

from pathlib import Path
import re

import pytest

README = Path(__file__).resolve().parent.parent / 'README.md'


@pytest.mark.timeout(180)
def test_readme_harness_example_runs(capsys):
    blocks = re.findall(r'```python\n(.*?)```', README.read_text(), re.S)
    example = next(b for b in blocks if 'SimHarness' in b)
    exec(compile(example, 'README.md', 'exec'), {})
    printed = capsys.readouterr().out
    assert 'SimState' in printed or 'time_s' in printed


def test_readme_opens_with_the_two_set_up_commands():
    text = README.read_text()
    first_block = re.search(r'```sh\n(.*?)```', text, re.S).group(1)
    commands = [line.split('#')[0].strip() for line in first_block.splitlines() if line.strip()]
    assert commands == ['make demo', 'make test']
    assert 'make test' in (README.parent / '.ci' / 'run').read_text()
