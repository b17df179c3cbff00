"""PLY meshes as BOP's models are stored: ``save_ply`` and ``load_ply``.

Vertex properties, all optional but x, y, z: ``nx ny nz`` (normals),
``red green blue`` (uchar colours), ``texture_u texture_v`` (UVs, v = 0 at the
texture image's bottom row); faces as ``vertex_indices`` lists; a texture image
named by a ``comment TextureFile NAME`` header line, as bop_toolkit's
``inout.load_ply`` reads it. Written binary little-endian; read binary
little-endian or ASCII.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_data.errors import SpmError

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
          "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
          "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}
# array key -> (PLY properties, their type)
_VERTEX_PROPS = {"vertices": (("x", "y", "z"), "float"), "normals": (("nx", "ny", "nz"), "float"),
                 "colors": (("red", "green", "blue"), "uchar"),
                 "uv": (("texture_u", "texture_v"), "float")}


def save_ply(path, vertices, faces, *, normals=None, colors=None, uv=None, texture_file=None) -> None:
    """Write a mesh. vertices (V, 3) float (mm for BOP); faces (F, 3) int;
    normals (V, 3) float; colors (V, 3) uint8; uv (V, 2) float; texture_file: the
    texture image's file name, beside the PLY."""
    arrays = {"vertices": vertices, "normals": normals, "colors": colors, "uv": uv}
    columns, header = [], ["ply", "format binary_little_endian 1.0"]
    if texture_file:
        header.append(f"comment TextureFile {texture_file}")
    header.append(f"element vertex {len(vertices)}")
    for key, (names, kind) in _VERTEX_PROPS.items():
        if arrays[key] is None:
            continue
        values = np.asarray(arrays[key])
        if values.shape != (len(vertices), len(names)):
            raise SpmError(f"save_ply: {key} has shape {values.shape}, expected ({len(vertices)}, {len(names)})")
        header += [f"property {kind} {n}" for n in names]
        columns += [(n, _TYPES[kind], values[:, i]) for i, n in enumerate(names)]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    table = np.empty(len(vertices), dtype=[(n, t) for n, t, _ in columns])
    for name, _, column in columns:
        table[name] = column
    face_table = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_table["n"], face_table["idx"] = 3, np.asarray(faces)
    with open(path, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(table.tobytes())
        fh.write(face_table.tobytes())


def _header(data: bytes, path) -> tuple[list[str], int]:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise SpmError(f"{path}: not a PLY file (no 'ply' ... 'end_header' header)")
    body = data.index(b"\n", end) + 1
    return data[:end].decode("ascii", "replace").splitlines(), body


def _elements(lines, path) -> tuple[str, list, str | None]:
    """(format, [(element, count, [(property, dtype or ('list', count dtype, item dtype))])], texture)."""
    fmt, elements, texture = None, [], None
    for line in lines:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[:2] == ["comment", "TextureFile"] and len(words) > 2:
            texture = " ".join(words[2:])
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[4], ("list", _TYPES[words[2]], _TYPES[words[3]])))
            else:
                elements[-1][2].append((words[2], _TYPES[words[1]]))
    if fmt not in ("binary_little_endian", "ascii"):
        raise SpmError(f"{path}: PLY format {fmt!r} is not supported; expected binary_little_endian or ascii")
    return fmt, elements, texture


def _read_binary(data: bytes, pos: int, elements) -> dict:
    out = {}
    for name, count, props in elements:
        if all(not isinstance(t, tuple) for _, t in props):
            dtype = np.dtype([(p, t) for p, t in props])
            out[name] = np.frombuffer(data, dtype, count, pos)
            pos += dtype.itemsize * count
            continue
        (prop, (_, count_t, item_t)), = props  # faces: one list property (what BOP's models have)
        n = int(np.frombuffer(data, count_t, 1, pos)[0])
        dtype = np.dtype([("n", count_t), (prop, item_t, (n,))])
        out[name] = np.frombuffer(data, dtype, count, pos)
        pos += dtype.itemsize * count
    return out


def _read_ascii(text: str, elements) -> dict:
    rows, out = iter(text.split("\n")), {}
    for name, count, props in elements:
        values = [next(rows).split() for _ in range(count)]
        if all(not isinstance(t, tuple) for _, t in props):
            table = np.empty(count, dtype=[(p, t) for p, t in props])
            for i, (p, _) in enumerate(props):
                table[p] = [float(v[i]) for v in values]
        else:
            (prop, _), = props
            table = {prop: np.array([[int(x) for x in v[1:1 + int(v[0])]] for v in values], dtype=np.int64)}
        out[name] = table
    return out


def load_ply(path) -> dict:
    """Read a PLY mesh: ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64, and when
    present ``normals`` (V, 3) float64, ``colors`` (V, 3) uint8, ``uv`` (V, 2)
    float64, ``texture_file`` (str). SpmError naming the file if it cannot be read."""
    path = Path(path)
    try:
        data = path.read_bytes()
        lines, body = _header(data, path)
        fmt, elements, texture = _elements(lines, path)
        tables = _read_binary(data, body, elements) if fmt != "ascii" else \
            _read_ascii(data[body:].decode("ascii"), elements)
    except (OSError, ValueError, KeyError, IndexError, StopIteration) as exc:
        raise SpmError(f"{path}: unreadable PLY ({type(exc).__name__}: {exc})") from None
    vertex = tables.get("vertex")
    face = tables.get("face")
    if vertex is None:
        raise SpmError(f"{path}: PLY has no vertex element")
    out = {}
    for key, (names, _) in _VERTEX_PROPS.items():
        if all(n in vertex.dtype.names for n in names):
            out[key] = np.column_stack([vertex[n] for n in names]).astype(np.uint8 if key == "colors" else np.float64)
    faces = np.empty((0, 3), np.int64) if face is None else np.asarray(face["vertex_indices"], dtype=np.int64)
    out["faces"] = faces.reshape(-1, 3)
    if texture:
        out["texture_file"] = texture
    return out
