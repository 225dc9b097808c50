"""Names in the package say what they are by physics, not by the history of the studies."""

from __future__ import annotations

from pathlib import Path
import re

ROOT = Path(__file__).resolve().parent.parent
# "experiment E", "Experiments I and J": the study's letters live in docs/validation/papers.md
EXPERIMENT_LETTER = re.compile(r'\b[Ee]xperiments? [A-K]\b')
# pointers to documents that moved (docs/theory, docs/validation, docs/dev hold them now)
OLD_DOCS = re.compile(
    r'docs/(PHYSICS_LUMPED|PHYSICS_SHELL|CALIBRATION|ARCHITECTURE|RELIABILITY)\.md'
)


def package_lines():
    for package in ('pulsejet_sim', 'pulsejet_ctrl'):
        for path in sorted((ROOT / package).rglob('*.py')):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                yield f'{path.relative_to(ROOT)}:{number}', line


def test_no_experiment_letters_in_the_package():
    found = [f'{where}: {line.strip()}' for where, line in package_lines()
             if EXPERIMENT_LETTER.search(line)]
    assert not found, 'name the physics instead:\n' + '\n'.join(found)


def test_no_pointers_to_moved_documents():
    found = [
        f'{where}: {line.strip()}' for where, line in package_lines() if OLD_DOCS.search(line)
    ]
    assert not found, '\n'.join(found)


def test_the_patterns_catch_what_they_are_for():
    assert EXPERIMENT_LETTER.search('# experiment K: the momentum')
    assert EXPERIMENT_LETTER.search('see "Experiment E"')
    assert not EXPERIMENT_LETTER.search('the experiment of Weymouth et al.')
    assert OLD_DOCS.search('see docs/PHYSICS_SHELL.md')


def test_every_import_of_pulsejet_names_a_module_that_exists():
    """Scripts, tests and lazy imports too: a moved module leaves no import behind."""
    import ast
    import importlib.util

    missing = []
    for folder in ('pulsejet_sim', 'pulsejet_ctrl', 'benchmarks', 'test', 'examples', 'launch'):
        for path in sorted((ROOT / folder).rglob('*.py')):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                elif isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                else:
                    continue
                for name in names:
                    if name.split('.')[0] in ('pulsejet_sim', 'pulsejet_ctrl', 'benchmarks'):
                        if importlib.util.find_spec(name) is None:
                            missing.append(f'{path.relative_to(ROOT)}:{node.lineno}: {name}')
    assert not missing, 'imports of modules that do not exist:\n' + '\n'.join(missing)
