"""Shapes: seeded procedural meshes for the paper's six classes, with their exact symmetries.

Instance ``i`` of a class is drawn from its own generator (meshes.instance_rng), so
the same (seed, class, instance) gives the same mesh on every machine.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import trimesh

from spm_data.errors import MeshError
from spm_data.core.meshes import TexturedMesh, instance_rng, to_textured
from spm_data.core.symmetries import NO_SYMMETRY, Symmetries, rotation

CLASSES = ("box", "car", "motorcycle", "ball", "animal4", "cup")


def _rot(axis, degrees):
    return trimesh.transformations.rotation_matrix(np.radians(degrees), axis)


def _box(extents, centre):
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def _rod(p0, p1, radius, sections=16):
    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], dtype=float), sections=sections)


def _ellipsoid(radii, centre, subdivisions=3):
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    m.apply_scale(radii)
    m.apply_translation(centre)
    return m


def _wheel(radius, width, centre, torus=False):
    if torus:
        m = trimesh.creation.torus(major_radius=radius - width / 2, minor_radius=width / 2,
                                   major_sections=32, minor_sections=12)
    else:
        m = trimesh.creation.cylinder(radius=radius, height=width, sections=32)
    m.apply_transform(_rot([1, 0, 0], 90))  # axle along y
    m.apply_translation(centre)
    return m


# --------------------------------------------------------------------------- the six classes
# Each generator returns (parts, Symmetries). A symmetry is stated about the parts' bounding-box
# centre, which normalise() moves to the origin; the bounding box of a symmetric shape is
# symmetric too, so its centre lies on every symmetry axis.

_HALF_TURN_X, _HALF_TURN_Y, _HALF_TURN_Z = (rotation(a, 180.0) for a in np.eye(3))

def _make_box(rng):
    ex = np.array([rng.uniform(0.6, 1.4), rng.uniform(0.5, 1.2), rng.uniform(0.35, 1.0)])
    parts = [_box(ex, [0, 0, ex[2] / 2])]
    lid, handle = rng.random() < 0.6, None
    if lid:  # a lid overhanging the body
        lid_h = ex[2] * rng.uniform(0.12, 0.25)
        parts.append(_box([ex[0] * 1.06, ex[1] * 1.06, lid_h], [0, 0, ex[2] + lid_h / 2 - 0.01]))
    handle = rng.random() < 0.5
    if handle:  # a carrying handle on top, in the x-z plane
        top = ex[2] * 1.25
        half = ex[0] * 0.25
        parts += [_rod([-half, 0, ex[2]], [-half, 0, top], 0.03), _rod([half, 0, ex[2]], [half, 0, top], 0.03),
                  _rod([-half, 0, top], [half, 0, top], 0.03)]
    # Every part is centred on the z axis and mirrored in x and y: a half turn about z maps the
    # box onto itself; a bare box (no lid, no handle) also turns over about x and y.
    turns = (_HALF_TURN_Z,) if lid or handle else (_HALF_TURN_X, _HALF_TURN_Y, _HALF_TURN_Z)
    return parts, Symmetries(discrete=turns)


def _make_car(rng):
    length, width = 1.0, rng.uniform(0.38, 0.5)
    wheel_r = rng.uniform(0.1, 0.15)
    body_h = rng.uniform(0.16, 0.26)
    z0 = wheel_r * 0.9
    parts = [_box([length, width, body_h], [0, 0, z0 + body_h / 2])]
    cab_len = rng.uniform(0.35, 0.6)
    cab_x = rng.uniform(-0.2, 0.15)
    cab_h = rng.uniform(0.14, 0.24)
    parts.append(_box([cab_len, width * 0.9, cab_h], [cab_x, 0, z0 + body_h + cab_h / 2]))
    axle = length * rng.uniform(0.3, 0.36)
    for x in (-axle, axle):
        for y in (-width / 2, width / 2):
            parts.append(_wheel(wheel_r, 0.08, [x, y, wheel_r]))
    if rng.random() < 0.5:  # rear spoiler on two posts
        top = z0 + body_h + 0.08
        parts += [_rod([-0.45, -0.12, z0 + body_h], [-0.45, -0.12, top], 0.012),
                  _rod([-0.45, 0.12, z0 + body_h], [-0.45, 0.12, top], 0.012),
                  _box([0.1, width * 0.95, 0.02], [-0.46, 0, top])]
    return parts, NO_SYMMETRY  # an off-centre part (cab, handle, head, fork) breaks every turn


def _make_motorcycle(rng):
    r = rng.uniform(0.18, 0.24)
    tyre = rng.uniform(0.09, 0.13)
    base = rng.uniform(0.42, 0.55)
    front, rear = np.array([base, 0, r]), np.array([-base, 0, r])
    seat_z = r * 2 + rng.uniform(0.05, 0.15)
    bar = np.array([base * 0.8, 0, seat_z + rng.uniform(0.1, 0.25)])
    parts = [_wheel(r, tyre, front, torus=True), _wheel(r, tyre, rear, torus=True),
             _rod(front, bar, 0.035), _rod(rear, [0, 0, seat_z - 0.05], 0.045),
             _rod([-base * 0.3, 0, seat_z - 0.04], bar - [0.1, 0, 0.05], 0.06),
             _rod(bar + [0, -0.2, 0], bar + [0, 0.2, 0], 0.03),
             _box([rng.uniform(0.35, 0.5), 0.22, rng.uniform(0.22, 0.32)], [0, 0, r * 1.1]),  # engine
             _ellipsoid([rng.uniform(0.2, 0.28), 0.14, 0.11], [base * 0.3, 0, seat_z + 0.03]),  # tank
             _box([rng.uniform(0.3, 0.45), 0.2, 0.07], [-base * 0.35, 0, seat_z])]  # seat
    if rng.random() < 0.5:  # exhaust
        parts.append(_rod([-0.05, 0.1, r * 0.8], [-base * 1.1, 0.1, r * 1.1], 0.025))
    return parts, NO_SYMMETRY  # an off-centre part (cab, handle, head, fork) breaks every turn


def _make_ball(rng):
    flat = rng.uniform(0.85, 1.0)
    parts = [_ellipsoid([1.0, 1.0, flat], [0, 0, 0], subdivisions=4)]
    if rng.random() < 0.5:  # a raised seam round the equator
        parts.append(trimesh.creation.torus(major_radius=1.0, minor_radius=0.03,
                                            major_sections=64, minor_sections=8))
    # A spheroid about z, with or without its equator seam: every turn about z, and turned over.
    return parts, Symmetries(discrete=(_HALF_TURN_X,), continuous=(np.array([0.0, 0.0, 1.0]),))


def _make_animal4(rng):
    body_l, body_w, body_h = rng.uniform(0.9, 1.2), rng.uniform(0.4, 0.55), rng.uniform(0.4, 0.55)
    leg = rng.uniform(0.3, 0.6)
    neck = rng.uniform(0.1, 0.4)
    body_z = leg + body_h * 0.35
    parts = [_ellipsoid([body_l / 2, body_w / 2, body_h / 2], [0, 0, body_z])]
    for x in (-body_l * 0.32, body_l * 0.32):
        for y in (-body_w * 0.28, body_w * 0.28):
            parts.append(_rod([x, y, body_z], [x, y, 0], rng.uniform(0.06, 0.09)))
    shoulder = np.array([body_l * 0.42, 0, body_z + body_h * 0.2])
    head = shoulder + [0.12, 0, neck]
    parts += [_rod(shoulder, head, 0.09), _ellipsoid([0.2, 0.13, 0.13], head + [0.08, 0, 0]),
              _rod([-body_l / 2, 0, body_z], [-body_l / 2 - 0.25, 0, body_z + rng.uniform(-0.2, 0.25)], 0.04)]
    if rng.random() < 0.6:  # ears
        for y in (-0.05, 0.05):
            ear = trimesh.creation.cone(radius=0.035, height=0.1)
            ear.apply_translation(head + [0.02, y, 0.07])
            parts.append(ear)
    return parts, NO_SYMMETRY  # an off-centre part (cab, handle, head, fork) breaks every turn


def _make_cup(rng):
    r_bot = rng.uniform(0.3, 0.4)
    r_top = r_bot * rng.uniform(1.0, 1.35)
    h = rng.uniform(0.6, 1.1)
    wall = 0.04
    profile = [[0, 0], [r_bot, 0], [r_top, h], [r_top - wall, h], [r_bot - wall, wall], [0, wall]]
    parts = [trimesh.creation.revolve(np.array(profile), sections=48)]
    # Handle: a half torus in the x-z plane, opening towards the cup on its +x side.
    hr = h * rng.uniform(0.22, 0.32)
    circle = np.array([[hr + 0.05 * np.cos(a), 0.05 * np.sin(a)] for a in np.linspace(0, 2 * np.pi, 13)])
    handle = trimesh.creation.revolve(circle, angle=np.pi, sections=24)
    handle.apply_transform(_rot([1, 0, 0], 90))  # half ring now spans x in [-hr, hr], z >= 0 side
    handle.apply_transform(_rot([0, 1, 0], 90))  # opening faces -x
    r_mid = (r_bot + r_top) / 2
    handle.apply_translation([r_mid - 0.02, 0, h * rng.uniform(0.45, 0.6)])
    parts.append(handle)
    if rng.random() < 0.4:  # saucer
        parts.append(trimesh.creation.cylinder(radius=r_top * 1.5, height=0.03, sections=48))
    return parts, NO_SYMMETRY  # an off-centre part (cab, handle, head, fork) breaks every turn


_GENERATORS = {"box": _make_box, "car": _make_car, "motorcycle": _make_motorcycle,
               "ball": _make_ball, "animal4": _make_animal4, "cup": _make_cup}


def procedural_mesh(class_name: str, instance: int, seed: int = 0, size: float = 0.25) -> TexturedMesh:
    """Instance ``instance`` of a built-in class (one of CLASSES), seeded, textured."""
    if class_name not in _GENERATORS:
        raise MeshError(f"unknown procedural class {class_name!r}; expected one of {', '.join(CLASSES)}")
    rng = instance_rng(seed, class_name, instance)
    parts, symmetries = _GENERATORS[class_name](rng)
    mesh = to_textured(trimesh.util.concatenate(parts), f"{class_name}-{instance:03d}", size, rng)
    return replace(mesh, symmetries=symmetries)
