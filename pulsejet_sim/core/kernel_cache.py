"""
Keep numba's on-disk cache of a kernel module honest about the modules it compiles in.

numba (`cache=True`) keys a cached kernel on the hash of the kernel's own source file only. A
kernel that calls or inlines a numba function of another module (the shell's kernels use
`models.starting_jet` and `models.cable_pulse`), or reads a constant from one, is compiled with
that module's code baked in; after an edit of that module alone, the next process would load the
stale machine code and run the old physics without a word.

`drop_stale_cache(kernel, dependencies)`, called once at the end of a kernel module, compares a
digest of the dependencies' sources with the one stored beside the module's cache entries and,
when it differs, removes that module's entries (numba then compiles afresh and stores new ones).
It only ever deletes numba's own files of that one module, in the directory numba reports for it
(`Dispatcher.stats.cache_path`).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from types import ModuleType
from typing import Any, Sequence

#: suffixes of numba's cache files: the index and the machine code of each function
CACHE_SUFFIXES = ('.nbi', '.nbc')


def sources_digest(dependencies: Sequence[ModuleType | str | os.PathLike]) -> str:
    """Return a sha256 hex digest of the dependencies' source files, in the order given."""
    digest = hashlib.sha256()
    for dependency in dependencies:
        path = Path(getattr(dependency, '__file__', dependency))
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def drop_stale_cache(
    kernel: Any, dependencies: Sequence[ModuleType | str | os.PathLike]
) -> bool:
    """
    Remove the cached kernels of kernel's module when a dependency's source changed.

    kernel: any `@njit(cache=True)` function of the module (its cache directory is the module's);
    dependencies: the modules (or source paths) whose code or constants the module compiles in.
    Returns True when entries were removed. A cache directory that cannot be written is left
    alone (numba then caches elsewhere or not at all).
    """
    cache_dir = Path(kernel.stats.cache_path)
    module = Path(kernel.py_func.__code__.co_filename).stem
    stamp = cache_dir / f'{module}.dependencies.sha256'
    current = sources_digest(dependencies)
    try:
        if stamp.read_text() == current:
            return False
    except OSError:
        pass  # no stamp yet: the entries (if any) were made without one
    removed = False
    try:
        for entry in cache_dir.glob(f'{module}.*'):
            if entry.suffix in CACHE_SUFFIXES:
                entry.unlink(missing_ok=True)
                removed = True
        cache_dir.mkdir(parents=True, exist_ok=True)
        temporary = stamp.with_suffix(f'.{os.getpid()}.tmp')
        temporary.write_text(current)
        os.replace(temporary, stamp)  # another process may race: either digest is the same
    except OSError:
        return removed
    return removed
