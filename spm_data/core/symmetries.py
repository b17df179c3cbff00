"""Shape symmetries: the rotations that map an object's shape onto itself.

Built-in classes state theirs in their generators (meshes.py); for mesh files a
spec declares them (``mesh.symmetries``, parsed here). The BOP export writes them
to ``models_info.json`` (bop_models.py).
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
        raise MeshError(f"symmetry {text!r}: the turn must divide 360 degrees (such as 180, 120, 90), got {degrees}")
    return axis, value


def declared_symmetries(entries) -> Symmetries:
    """Symmetries from a spec's ``mesh.symmetries`` strings (parse_symmetry): an
    n-fold turn contributes all n - 1 of its rotations."""
    unit = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
    discrete, continuous = [], []
    for text in entries:
        axis, degrees = parse_symmetry(text)
        if degrees is None:
            continuous.append(np.array(unit[axis]))
        else:
            discrete += [rotation(unit[axis], k * degrees) for k in range(1, int(round(360 / degrees)))]
    return Symmetries(tuple(discrete), tuple(continuous))
