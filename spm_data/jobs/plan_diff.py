"""Why a shard already in the output folder is refused: the first thing it was made with that
differs from this run's plan, named with both values, in one line.

A job may offer ``plan_difference(attrs)``: given the attributes of the shard on disk, the
difference as ``(key, old, new)`` (a spec key such as ``camera.azimuth``, ``seed``, an option
such as ``--limit``, or an option by its key, an Option such as occlude's ``max``, which the
command line names by its flag), a phrase ("was made from ..."), or None if it cannot tell.
Without one, or when it cannot tell, the refusal says what kinds of thing may differ.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_data.errors import Option, SpmError, joined

GENERIC = "was made from another spec, input, seed or options"


def flatten(tree, prefix: str = "") -> dict:
    """``{"camera": {"azimuth": {"start": 0, "stop": 350, "step": 10}}}`` -> ``{"camera.azimuth":
    [0, 350, 10]}``: a range as the spec writes it, every other table down to its keys."""
    if not isinstance(tree, dict):
        return {prefix: tree}
    if list(tree) == ["start", "stop", "step"]:
        return {prefix: list(tree.values())}
    out = {}
    for key, value in tree.items():
        out.update(flatten(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def plain(value):
    """A value as it reads in a spec: numpy scalars and arrays as Python ones, whole floats as ints."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


def first_difference(old: dict, new: dict) -> tuple | None:
    """(key, old value, new value) of the first key (in ``new``'s order, then ``old``'s) whose
    values differ; a key one side lacks has the value None there."""
    for key in list(new) + [k for k in old if k not in new]:
        a, b = plain(old.get(key)), plain(new.get(key))
        if a != b:
            return key, a, b
    return None


def show(key: str, value) -> str:
    """``--limit 8`` for an option, ``camera.azimuth = [0, 340, 20]`` for a spec key."""
    value = plain(value)
    if value is None:
        text = "none"
    elif isinstance(value, str):
        text = f'"{value}"'
    elif isinstance(value, bool):
        text = str(value).lower()
    elif isinstance(value, list):
        text = "[" + ", ".join(show("", v).strip() for v in value) + "]"
    else:
        text = str(value)
    if not key:
        return text
    return f"{key} {text}" if key.startswith("--") else f"{key} = {text}"


def shown(key, value) -> tuple:
    """show() as message parts: an Option key apart (``max``, `` 0.6``), for the command line's flag."""
    return (key, f" {show('', value)}") if isinstance(key, Option) else (show(key, value),)


def refusal(job, target: Path, attrs: dict) -> tuple:
    """The one-line refusal of ``target`` (its attributes ``attrs``), which ``job`` would make
    from another plan, as an error's parts (spm_data.errors.joined: one string unless it names an
    Option)."""
    what: tuple = (GENERIC,)
    explain = getattr(job, "plan_difference", None)
    if explain is not None:
        try:
            found = explain(attrs)
        except (SpmError, KeyError, ValueError, TypeError, OSError):
            found = None   # an older shard without what it would take to tell: the generic line
        if isinstance(found, str):
            what = (found,)
        elif found is not None:
            key, old, new = found
            what = ("was made with ", *shown(key, old), ", not ", *shown(key, new))
    return joined(f"{target} ", *what, f"; write into a new --out folder or delete {target.parent}")
