"""The toolkit's error types.

The library raises these; the CLI prints ``error: <message>`` on one line and
exits with status 1. Anything else escaping is a bug.
"""


def one_line(text) -> str:
    """``text`` (or an exception's message) with every run of whitespace one space:
    messages from other libraries may span lines, ours are one."""
    return " ".join(str(text).split())


class SpmError(Exception):
    """Base class of every error the toolkit raises on purpose."""


class SpecError(SpmError):
    """A render spec (TOML) has an unknown key, a wrong type or a bad value."""


class MeshError(SpmError):
    """A mesh file cannot be read, is empty, or has no faces."""


class ShardError(SpmError):
    """A shard or output folder is missing, corrupt, or of another schema."""


class RenderError(SpmError):
    """A renderer is missing, failed to start, or failed on a frame."""


class LockError(SpmError):
    """An output folder is locked by another run (spm_data.io.locking)."""


class SpmWarning(UserWarning):
    """Something the user should know that does not stop the command (the CLI
    prints ``warning: <message>`` on one line)."""


class ImageError(SpmError):
    """An image file cannot be read or decoded (the message is the reason alone)."""
