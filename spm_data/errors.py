"""The toolkit's error types.

The library raises these; the CLI prints ``error: <message>`` on one line and
exits with status 1. Anything else escaping is a bug.
"""


def one_line(text) -> str:
    """``text`` (or an exception's message) with every run of whitespace one space:
    messages from other libraries may span lines, ours are one."""
    return " ".join(str(text).split())


class Option(str):
    """An option named in a library message by its key (occlude's ``min``, ``max``, ``copies``,
    ``rects``, ``seed``): the message shows the key, the command line its flag (SpmError.named,
    with spm_cli/support.py's table)."""


def said(parts, names: dict | None = None) -> str:
    """Message ``parts`` (text, and Option keys) as one string, each Option as ``names`` has it
    (one it lacks as its key)."""
    names = names or {}
    return "".join(names.get(p, p) if isinstance(p, Option) else str(p) for p in parts)


def joined(*parts) -> tuple:
    """``parts`` with each run of plain text made one string: an error of one part where no Option
    is among them (a message as before), text and Option keys apart where one is."""
    out: list = []
    for part in parts:
        if out and not isinstance(part, Option) and not isinstance(out[-1], Option):
            out[-1] += str(part)
        else:
            out.append(part if isinstance(part, Option) else str(part))
    return tuple(out)


class SpmError(Exception):
    """Base class of every error the toolkit raises on purpose. Its message may come in parts, some
    of them Option keys: ``SpmError(Option("min"), " 0.7 is above ", Option("max"), " 0.6")`` reads
    "min 0.7 is above max 0.6", and names the flags instead where the command line says it (``named``)."""

    def __str__(self) -> str:
        return said(self.args) if _names_options(self.args) else super().__str__()

    def named(self, names: dict) -> str:
        """The message with each Option key in it written as ``names`` has it (a face's flags)."""
        return said(self.args, names) if _names_options(self.args) else str(self)


def _names_options(args: tuple) -> bool:
    return any(isinstance(a, Option) for a in args)


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
