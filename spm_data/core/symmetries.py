"""Shape symmetries: the rotations that map an object's shape onto itself.

Built-in classes state theirs in their generators (meshes.py); for mesh files a
spec declares them (``mesh.symmetries``, parsed here). The BOP export writes them
to ``models_info.json`` (bop/models.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from spm_data.errors import MeshError


@dataclass(frozen=True)
class Symmetries:
    """Rotations about the object-frame origin that map a mesh's shape onto itself
    (the shape only: textures are not considered, as in BOP's MSSD and MSPD).

    discrete: tuple of (3, 3) float64 rotations, the identity left out;
    continuous: tuple of (3,) float64 unit axes through the origin (every angle).
    """

    discrete: tuple = ()
    continuous: tuple = ()


NO_SYMMETRY = Symmetries()


def rotation(axis, degrees: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``degrees`` about ``axis`` (3,) (right hand)."""
    return trimesh.transformations.rotation_matrix(np.radians(degrees), np.asarray(axis, dtype=np.float64))[:3, :3]


def parse_symmetry(text: str) -> tuple[str, float | None]:
    """``"z"`` (every angle about z) -> ("z", None); ``"x/180"`` (an n-fold turn
    about x, 360 / degrees a whole number) -> ("x", 180.0); MeshError otherwise."""
    axis, slash, degrees = str(text).strip().partition("/")
    if axis not in ("x", "y", "z"):
        raise MeshError(f"symmetry {text!r}: expected an axis x, y or z, alone (every angle) "
                        "or with a turn in degrees such as \"z/180\"")
    if not slash:
        return axis, None
    try:
        value = float(degrees)
    except ValueError:
        value = float("nan")
    if not (0 < value < 360) or abs(360 / value - round(360 / value)) > 1e-9:
        raise MeshError(f"symmetry {text!r}: the turn must be less than 360 degrees and divide it "
                        f"(such as 180, 120, 90), got {degrees}")
    return axis, value


MAX_GROUP = 120  # rotations a declared set may generate (the icosahedral group has 60)


def _group(generators: list) -> list:
    """Every rotation the ``generators`` (3, 3) make by composition, the identity first:
    BOP lists each symmetry, and bop_toolkit does not compose them (x/180 with y/180
    is also z/180). MeshError when they make no finite group (at most MAX_GROUP)."""
    found = [np.eye(3)]
    frontier = list(generators)
    while frontier:
        R = frontier.pop()
        if any(np.allclose(R, F, atol=1e-9) for F in found):
            continue
        found.append(R)
        if len(found) > MAX_GROUP:
            raise MeshError(f"the declared symmetries generate more than {MAX_GROUP} rotations; "
                            "declare the turns of one finite symmetry group (for example z/90 and x/180)")
        frontier += [R @ G for G in generators]
    return found


def declared_symmetries(entries) -> Symmetries:
    """Symmetries from a spec's ``mesh.symmetries`` strings (parse_symmetry): every rotation
    the declared turns generate, each once; a continuous axis absorbs the turns about it."""
    unit = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
    turns, continuous = [], []
    for text in entries:
        axis, degrees = parse_symmetry(text)
        if degrees is None:
            if not any(np.array_equal(unit[axis], c) for c in continuous):
                continuous.append(np.array(unit[axis]))
        else:
            turns.append(rotation(unit[axis], degrees))
    discrete = [R for R in _group(turns)[1:] if not any(_about(R, c) for c in continuous)]
    return Symmetries(tuple(discrete), tuple(continuous))


def _about(R: np.ndarray, axis: np.ndarray) -> bool:
    """Whether the rotation ``R`` turns about ``axis`` (leaves it where it is)."""
    return bool(np.allclose(R @ axis, axis, atol=1e-9))
