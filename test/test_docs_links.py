"""Every relative link in the README, the top-level docs and docs/ points at a file in the repo."""

from pathlib import Path
import re

REPO = Path(__file__).resolve().parent.parent
LINK = re.compile(r'\[[^\]]*\]\(([^)\s]+)\)')
FENCE = re.compile(r'```.*?```', re.S)


def documents() -> list[Path]:
    top = [REPO / name for name in ('README.md', 'CONTRIBUTING.md', 'CHANGELOG.md')]
    return [p for p in top if p.is_file()] + sorted((REPO / 'docs').rglob('*.md'))


def slug(heading: str) -> str:
    """Return the GitHub anchor of a heading: lower case, no punctuation, spaces to hyphens."""
    text = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return text.replace(' ', '-')


def anchors(path: Path) -> set[str]:
    text = FENCE.sub('', path.read_text())
    return {slug(m.group(1)) for m in re.finditer(r'^#+\s+(.*)$', text, re.M)}


def broken_links(path: Path) -> list[str]:
    text = FENCE.sub('', path.read_text())
    text = re.sub(r'`[^`\n]*`', '', text)  # inline code is not a link
    broken = []
    for target in LINK.findall(text):
        if re.match(r'[a-z][a-z0-9+.-]*:', target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition('#')
        dest = (path.parent / file_part).resolve() if file_part else path
        if REPO not in dest.parents and dest != REPO:
            broken.append(f'{target} (outside the repository)')
        elif not dest.exists():
            broken.append(f'{target} (no such file)')
        elif anchor and dest.suffix == '.md' and anchor not in anchors(dest):
            broken.append(f'{target} (no heading #{anchor} in {dest.name})')
    return broken


def test_the_docs_exist():
    names = {str(p.relative_to(REPO)) for p in documents()}
    assert {'README.md', 'CONTRIBUTING.md', 'CHANGELOG.md', 'docs/user/reference.md'} <= names


def test_every_relative_link_resolves():
    problems = {
        str(p.relative_to(REPO)): bad for p in documents() if (bad := broken_links(p))
    }
    assert not problems, problems


def test_the_checker_sees_a_broken_link(tmp_path):
    doc = REPO / 'docs' / 'user' / 'reference.md'
    bad = tmp_path / 'bad.md'
    bad.write_text(f'[a]({doc}) [b](missing.md) [c]({doc}#no-such-heading) [d](https://x.org)\n')
    found = broken_links(bad)
    assert any('missing.md' in b for b in found) and any('no-such-heading' in b for b in found)
    assert not any('x.org' in b for b in found)
