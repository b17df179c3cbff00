"""Plug-ins named, never imported where labels are: ``--estimator MODULE:CLASS`` is imported in a
process of its own (spm_model/bench/isolation.py) that reports what the benchmark needs to know
of the class (``NEEDS``, ``DETERMINISTIC``, whether it imports and pickles by its module path);
the command, its workers and the scoring carry a :class:`PluginRef` (plain data), and only a
split's method process imports the module (:func:`resolve`). So a plug-in's module-level code
(an import-time hook, a patched library) never runs in a process that holds a test label."""

from __future__ import annotations

import re
from dataclasses import dataclass

from spm_model.errors import ModelError
from spm_model.base.estimator import Needs

SPEC = re.compile(r"([A-Za-z_][\w.]*):([A-Za-z_]\w*)")


@dataclass(frozen=True)
class PluginRef:
    """A plug-in class by name, with what its class declares (read in a process of its own).
    ``NEEDS`` and ``DETERMINISTIC`` are read as a class's are (needs_of, protocols)."""

    spec: str
    NEEDS: Needs = Needs()
    DETERMINISTIC: bool = False
    unpicklable: str | None = None   # why pickle refused the class, if it did (check-estimator says so)
    needs_error: str | None = None   # why its NEEDS is refused (describe(strict=False) only)

    @property
    def __name__(self) -> str:   # noqa: A003 - what a class would answer, for messages
        return self.spec.split(":")[1]


def check_spec(spec: str) -> str:
    """``spec`` when it has the form MODULE:CLASS; ModelError otherwise (nothing imported)."""
    if not SPEC.fullmatch(spec or ""):
        raise ModelError(f"--estimator expects MODULE:CLASS (for example my_pose:MyEstimator), got {spec!r}")
    return spec


def resolve(plugin):
    """The class of a PluginRef (imported here: only in a method's process), or ``plugin`` itself."""
    if isinstance(plugin, PluginRef):
        from spm_model.methods.registry import load_estimator_class

        return load_estimator_class(plugin.spec)
    return plugin


def describe(specs, timeout: float | None = None, strict: bool = True) -> dict:
    """{spec: PluginRef} of every 'MODULE:CLASS' in ``specs``, each imported in a process of its own
    (not this one); ModelError (one line, the first refused) for one that cannot be imported, is
    not such a class, or (``strict``) declares a wrong NEEDS; or whose import takes longer than
    ``timeout``."""
    from spm_model.bench.isolation import EstimatorProcess, Lost

    specs = [check_spec(s) for s in dict.fromkeys(specs or ())]
    if not specs:
        return {}
    child = EstimatorProcess("spm_model.bench.isolated_child:serve_describe")
    out = {}
    try:
        child.send(specs)
        for spec in specs:
            try:
                header, _ = child.reply(spec, "", timeout)
            except Lost as lost:
                raise ModelError(f"--estimator {spec}: importing it: {lost.why}") from None
            why = header.get("error") or (header.get("needs_error") if strict else None)
            if why:
                raise ModelError(str(why))
            needs = Needs(**header["needs"]) if header.get("needs") else Needs()
            out[spec] = PluginRef(spec, needs, header["deterministic"] is True, header.get("unpicklable"),
                                  header.get("needs_error"))
    finally:
        child.close()
    return out
