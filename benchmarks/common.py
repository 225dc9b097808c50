"""Header (date, machine, CPU, Python, command) and writer of the stored benchmark tables."""

from __future__ import annotations

import datetime
import os
from pathlib import Path
import platform

RESULTS = Path(__file__).resolve().parent / 'results'


def cpu_model() -> str:
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown cpu'


def header(title: str, command: str) -> str:
    now = datetime.datetime.now(datetime.timezone.utc)
    return (
        f'# {title}\n\n{now:%Y-%m-%d %H:%M UTC}, {platform.machine()}, {cpu_model()},'
        f' {os.cpu_count()} cores (shared with other jobs), Python'
        f' {platform.python_version()}\n\ncommand: `.venv/bin/{command}`\n\n'
    )


def write(name: str, text: str) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f'{name}.md'
    path.write_text(text)
    print(text)
    print(f'written to {path}')
    return path


def append(path: Path, preamble: str, text: str) -> Path:
    """Append a run's section to a results file (newest last); a new file starts with preamble."""
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists()
    with open(path, 'a') as f:
        if new:
            f.write(preamble)
        f.write(text + '\n')
    return path
