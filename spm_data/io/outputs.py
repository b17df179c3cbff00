"""Where an output may go: checked before any work, so a bad ``--out`` is one line and nothing
is made; and, if writing fails after all, nothing half-made is left."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from pathlib import Path


def nearest_existing(path) -> Path:
    """``path`` itself if it exists, else its closest existing ancestor (the folder a
    new output would be created in; what must be a writable folder)."""
    base = Path(path)
    while not os.path.lexists(base) and base != base.parent:
        base = base.parent
    return base


def unwritable(path) -> tuple[Path, str] | None:
    """None when ``path`` is, or can be made as, something inside a writable folder;
    else ``(the existing ancestor in the way, "file" or "read-only")``."""
    base = nearest_existing(path)
    if not base.is_dir():
        return base, "file"
    if not os.access(base, os.W_OK | os.X_OK):
        return base, "read-only"
    return None


def top_created(path) -> Path | None:
    """The outermost folder that creating ``path``'s parent folders would make (to remove
    on failure), or None when the parent already exists."""
    parent = Path(path).parent
    base = nearest_existing(parent)
    return None if base == parent else base / parent.relative_to(base).parts[0]


@contextlib.contextmanager
def removing_created(path):
    """Run the block; if it fails, remove the folders that creating ``path``'s parents made."""
    made = top_created(path)
    try:
        yield
    except BaseException:
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
        raise


def space_fix(exc: OSError, otherwise: str) -> str:
    """What to tell the user to do about a failed write: free space, or ``otherwise``."""
    return "free space there" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else otherwise
