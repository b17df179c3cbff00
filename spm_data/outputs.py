"""Where an output may go: checked before any work, so a bad ``--out`` is one line and nothing is made."""

from __future__ import annotations

import os
from pathlib import Path


def nearest_existing(path) -> Path:
    """``path`` itself if it exists, else its closest existing ancestor (the folder a
    new output would be created in; what must be a writable folder)."""
    base = Path(path)
    while not os.path.lexists(base) and base != base.parent:
        base = base.parent
    return base


def top_created(path) -> Path | None:
    """The outermost folder that creating ``path``'s parent folders would make (to remove
    on failure), or None when the parent already exists."""
    parent = Path(path).parent
    base = nearest_existing(parent)
    return None if base == parent else base / parent.relative_to(base).parts[0]
