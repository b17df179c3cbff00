"""Where an output may go: checked before any work, so a bad ``--out`` is one line and nothing
is made; and, if writing fails after all, nothing half-made is left."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from pathlib import Path

from spm_data.errors import SpmError


NAME_MAX = 255  # bytes in one file name on common file systems (ext4, xfs, btrfs, APFS, NTFS in UTF-16 units)
PATH_MAX = 4096  # bytes in a whole path on Linux, when the file system does not say
INSIDE = 64  # bytes a command adds under --out: "/.motorcycle-00000-occ0.h5.partial" and the like


def check_out_name(path, option: str = "--out") -> Path:
    """SpmError unless every name in ``path`` fits the file system (with room for the
    hidden ``.NAME.partial`` a write goes through) and so does the whole path with a file
    inside it (PATH_MAX): checked before any work."""
    path = Path(path)
    try:
        limit = os.pathconf(nearest_existing(path.absolute()), "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = NAME_MAX
    for part in path.parts:
        size = len(os.fsencode(part))
        if size + len(".partial") + 1 > limit:
            raise SpmError(f"{option}: the name {part[:24]}... is {size} bytes, over the "
                           f"{limit - len('.partial') - 1} a file name can have here; give a shorter name")
    try:
        whole = os.pathconf(nearest_existing(path.absolute()), "PC_PATH_MAX")
    except (OSError, ValueError):
        whole = PATH_MAX
    # Room for what goes inside: a shard's partial name (.CLASS-00000.h5.partial) and the like.
    size = len(os.fsencode(str(path.absolute()))) + INSIDE
    if size > whole:
        raise SpmError(f"{option}: the path {str(path)[:24]}... is {size - INSIDE} bytes, and with the files "
                       f"written inside it would be over the {whole} a path can have here; give a shorter path")
    return path


def nearest_existing(path) -> Path:
    """``path`` itself if it exists, else its closest existing ancestor (the folder a
    new output would be created in; what must be a writable folder)."""
    base = Path(path)
    while not _lexists(base) and base != base.parent:
        base = base.parent
    return base


def _lexists(path) -> bool:
    try:
        os.lstat(path)
    except (OSError, ValueError):  # missing, or a name too long to exist
        return False
    return True


def unwritable(path) -> tuple[Path, str] | None:
    """None when ``path`` is, or can be made as, something inside a writable folder;
    else ``(the existing ancestor in the way, "file" or "read-only")``."""
    base = nearest_existing(path)
    if not base.is_dir():
        return base, "file"
    if not os.access(base, os.W_OK | os.X_OK):
        return base, "read-only"
    return None


def check_creatable(path, verb: str, fix_file: str, fix_read_only: str) -> None:
    """SpmError ``cannot VERB PATH: FOLDER is a file|is read-only; FIX`` unless ``path`` can be
    made inside a writable folder (its nearest existing ancestor): checked before any work."""
    problem = unwritable(Path(path).parent)
    if problem:
        state, fix = ("is a file", fix_file) if problem[1] == "file" else ("is read-only", fix_read_only)
        raise SpmError(f"cannot {verb} {path}: {problem[0]} {state}; {fix}")


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
