"""The meshes a shard folder's frames were drawn from, named by their content: ``FOLDER/meshes/``.

Every render writes the exact mesh (geometry, texture, symmetries) of each target and 3-D
distractor it draws as ``meshes/SHA256.npz``, and each frame names its target's digest in the
shard field ``mesh`` (distractors: the shard attribute ``distractor_mesh_digests``, parallel to
``distractor_meshes``). ``merge`` and ``occlude`` carry the entries their frames name into the
new folder, verifying each, so an export of any folder finds the very mesh every frame was
rendered from, with no spec, seed or mesh file needed.

The digest (:func:`mesh_digest`) is the SHA-256 of the mesh's arrays and symmetries, not of
its name: one mesh under two names is one mesh, two meshes under one name are two. An entry
proves what it is: :func:`load_mesh` recomputes the digest and refuses a file whose content
does not match its name.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
from pathlib import Path

import numpy as np

from spm_data.errors import MeshError
from spm_data.core.meshes import TexturedMesh
from spm_data.core.symmetries import Symmetries
from spm_data.io.files import atomic_file, read_regular_file

STORE = "meshes"      # the store's folder inside a shard folder
DIGEST = re.compile(r"[0-9a-f]{64}")
MAX_MESH_BYTES = 1 << 30  # an entry over 1 GiB is refused before reading
_ARRAYS = (("vertices", np.float64), ("faces", np.int64), ("normals", np.float64), ("uv", np.float64),
           ("texture", np.uint8))


def _canonical(mesh: TexturedMesh) -> dict:
    """The arrays that make a mesh what it is, in fixed dtypes (its name left out)."""
    out = {key: np.ascontiguousarray(getattr(mesh, key), dtype=dtype) for key, dtype in _ARRAYS}
    out["sym_discrete"] = np.ascontiguousarray(np.reshape(mesh.symmetries.discrete, (-1, 3, 3)), np.float64)
    out["sym_continuous"] = np.ascontiguousarray(np.reshape(mesh.symmetries.continuous, (-1, 3)), np.float64)
    return out


def _digest_of(arrays: dict) -> str:
    h = hashlib.sha256(b"spm-mesh-1")
    for key in sorted(arrays):
        a = arrays[key]
        h.update(json.dumps([key, a.dtype.str, a.shape]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def mesh_digest(mesh: TexturedMesh) -> str:
    """64 hex digits: SHA-256 of ``mesh``'s vertices, faces, normals, uv, texture and symmetries."""
    return _digest_of(_canonical(mesh))


def store_path(folder, digest: str) -> Path:
    return Path(folder) / STORE / f"{digest}.npz"


def save_mesh(folder, mesh: TexturedMesh) -> str:
    """Put ``mesh`` in ``folder``'s store (written whole under a temporary name, so workers that
    store the same mesh at once each rename a complete file); returns its digest."""
    arrays = _canonical(mesh)
    digest = _digest_of(arrays)
    path = store_path(folder, digest)
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
        npz = io.BytesIO()
        np.savez_compressed(npz, name=np.asarray(mesh.name), **arrays)   # textures compress 3-10x
        with atomic_file(path, tmp) as partial, open(partial, "wb") as fh:
            fh.write(npz.getbuffer())
    return digest


def load_mesh(folder, digest: str) -> TexturedMesh:
    """The mesh ``digest`` from ``folder``'s store; MeshError (one line, naming the file) when it is
    missing, unreadable or its content is not the mesh its name says."""
    if not DIGEST.fullmatch(str(digest)):
        raise MeshError(f"{digest!r} is not a mesh digest (64 hex digits)")
    path = store_path(folder, digest)
    try:
        with np.load(io.BytesIO(read_regular_file(path, MAX_MESH_BYTES)), allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
    except FileNotFoundError:
        raise MeshError(f"{path}: missing from the folder's mesh store; the folder is not whole "
                        "(copy its meshes/ folder back, or merge/render it again)") from None
    except (OSError, ValueError) as exc:   # a folder, a FIFO, over the limit, unreadable
        raise MeshError(f"{path}: cannot be read ({exc}); render or merge again") from None
    except Exception as exc:  # noqa: BLE001 - a damaged zip or .npy fails in many ways (zlib, header syntax...)
        raise MeshError(f"{path}: not a mesh store entry ({type(exc).__module__}.{type(exc).__name__}); it is damaged: "
                        "render or merge again") from None
    name = str(arrays.pop("name", "mesh"))
    if _digest_of({k: arrays.get(k, np.zeros(0)) for k in _canonical_keys()}) != digest:
        raise MeshError(f"{path}: its content is not the mesh its name says (damaged); "
                        "render or merge the folder again")
    return TexturedMesh(name=name, **{key: arrays[key] for key, _ in _ARRAYS},
                        symmetries=Symmetries(tuple(arrays["sym_discrete"]), tuple(arrays["sym_continuous"])))


def _canonical_keys() -> tuple:
    return tuple(key for key, _ in _ARRAYS) + ("sym_discrete", "sym_continuous")


def has_mesh(folder, digest: str) -> bool:
    return bool(digest) and store_path(folder, digest).is_file()


def carry_meshes(digests, sources, folder) -> int:
    """Copy the entries ``digests`` (an iterable; "" skipped) from the first of ``sources`` (shard
    folders) whose store has each into ``folder``'s store, verifying each; returns how many were
    new. MeshError when no source has one."""
    new = 0
    for digest in sorted(set(digests) - {""}):
        if has_mesh(folder, digest):
            continue
        found = next((src for src in sources if has_mesh(src, digest)), None)
        if found is None:
            raise MeshError(f"mesh {digest[:12]}… is named by a frame but is in no source's {STORE}/ "
                            f"({', '.join(str(s) for s in sources)}); the source folder is not whole")
        save_mesh(folder, load_mesh(found, digest))
        new += 1
    return new
