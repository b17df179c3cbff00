"""Model files and the estimator boundary: one ``.npz`` per model (a JSON header, named
arrays and a SHA-256 seal over both; no pickle), and the input checks every estimator shares.

A model file is trusted as a shard is: it is read only if it is a regular file of at most
MAX_MODEL_BYTES (a FIFO, a device or a folder is refused without reading or waiting), and
used only if its seal matches what it holds (format 2; a format-1 file has no seal and is
refused with the advice to retrain). The header names the spm version that wrote it."""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from spm_data.version import __version__
from spm_data.errors import one_line
from spm_data.io.files import read_regular_file, write_npz_atomic
from spm_model.base.estimator import ModelError

MODEL_FORMAT = 2   # 2: sealed (SHA-256 over header and arrays) and the writer's spm version
MAX_MODEL_BYTES = 4 * 2**30   # a model over 4 GiB is refused before it is read (the default set's is ~0.2 GB)


def check_xy(X, y=None, dims=None):
    """Validate (n, d) finite features and (n, 6) labels at the estimator boundary."""
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or (dims is not None and X.shape[1] != dims):
        want = f"(n, {dims})" if dims else "(n, d)"
        raise ModelError(f"expected features of shape {want}, got {X.shape}; extract them with "
                         "spm_model.spm.features (the same feature configuration as in training)")
    if not np.isfinite(X).all():
        raise ModelError("features contain NaN/inf; drop frames whose feature extraction failed")
    if y is None:
        return X
    y = np.asarray(y, dtype=np.float64)
    if y.shape != (len(X), 6) or not np.isfinite(y).all():
        raise ModelError(f"expected finite labels of shape ({len(X)}, 6) (rx, ry, rz degrees, t metres), "
                         f"got {y.shape}")
    return X, y


def model_seal(header_json: str, arrays: dict) -> str:
    """The SHA-256 (hex) of a model's header (its JSON text) and arrays (each one's name, dtype,
    shape and C-order bytes, by name): what its file must still hold to be used."""
    h = hashlib.sha256(header_json.encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_model_file(path, kind: str, params: dict, arrays: dict, extra: dict | None = None) -> Path:
    """One ``.npz``: a JSON header (format, kind, spm version, parameters), named arrays and
    their ``seal`` (:func:`model_seal`); no pickle. Written to a temporary name, then renamed."""
    path = Path(path)
    header = json.dumps({"format": MODEL_FORMAT, "kind": kind, "spm_version": __version__, "params": params,
                         **(extra or {})})
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    return write_npz_atomic(path, header=np.array(header), seal=np.array(model_seal(header, arrays)), **arrays)


def need(ok: bool, what: str) -> None:
    """A loaded model's consistency check: ValueError(what) unless ``ok``."""
    if not ok:
        raise ValueError(what)


def need_finite(*arrays) -> None:
    need(all(np.isfinite(np.asarray(a, dtype=np.float64)).all() for a in arrays), "arrays hold NaN or inf")


def load_model_file(path, kind: str | None = None) -> tuple[dict, dict]:
    """(header, arrays) of a model file; ModelError naming the file for a missing, unreadable,
    irregular (FIFO, device, folder), oversized, truncated, corrupt, unsealed, foreign or newer one."""
    retrain = "retrain it with spm train"
    foreign = "give the model.npz or reference-model.npz that spm train wrote, or retrain with spm train"
    try:
        data = read_regular_file(path, MAX_MODEL_BYTES)
    except FileNotFoundError:
        raise ModelError(f"model file not found: {path}; train one with spm train") from None
    except OSError as exc:
        raise ModelError(f"{path}: cannot read the model file ({exc.strerror or exc}); check its permissions") from None
    except ValueError as exc:
        reason = f"{exc} (spm_model.base.model_files.MAX_MODEL_BYTES)" if "limit" in str(exc) else f"{exc}"
        raise ModelError(f"{path}: {reason}, not a model file; {foreign}") from None
    if not data:
        raise ModelError(f"{path}: damaged spm model file (an empty file); {retrain}")
    header_json, arrays = _read_npz(path, data, retrain, foreign)
    try:
        header = json.loads(header_json)
    except ValueError:
        header = None
    if not isinstance(header, dict) or not isinstance(header.get("format", 0), int):
        raise ModelError(f"{path}: damaged spm model file (its header is not spm's); {retrain}")
    if header.get("format", 0) > MODEL_FORMAT or (kind is not None and header.get("kind") != kind):
        raise ModelError(f"{path}: model format {header.get('format')} of kind {header.get('kind')} is not one "
                         f"this spm reads here ({kind or 'any'}, format {MODEL_FORMAT}); retrain or upgrade spm")
    seal = arrays.pop("seal", None)
    if seal is None or header.get("format", 0) < MODEL_FORMAT:
        raise ModelError(f"{path}: model format {header.get('format')} has no SHA-256 seal, so it cannot be "
                         f"verified; {retrain} (spm {__version__} writes format {MODEL_FORMAT})")
    if str(seal) != model_seal(header_json, arrays):
        raise ModelError(f"{path}: damaged spm model file (what it holds differs from its SHA-256 seal); {retrain}")
    return header, arrays


def _read_npz(path, data: bytes, retrain: str, foreign: str) -> tuple[str, dict]:
    """(header JSON text, {name: array}) of an spm ``.npz`` held in ``data``; ModelError otherwise."""
    try:
        z = np.load(io.BytesIO(data), allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        if data.startswith(b"PK"):  # a zip (every .npz is one) that cannot be read
            raise ModelError(f"{path}: damaged spm model file (truncated or corrupt: {type(exc).__name__}: "
                             f"{one_line(exc)}); {retrain}") from None
        raise ModelError(f"{path}: not an spm model file (not an .npz archive); {foreign}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ModelError(f"{path}: not an spm model file (a single numpy array, not an .npz archive); {foreign}")
    with z:
        if "header" not in z.files:
            raise ModelError(f"{path}: not an spm model file (an .npz archive without spm's header); {foreign}")
        try:
            return str(z["header"]), {k: z[k] for k in z.files if k != "header"}
        except Exception as exc:  # noqa: BLE001 - numpy parses each .npy header with Python's tokenizer:
            # a flipped byte there raises SyntaxError or TokenError, not only the errors of a bad zip
            raise ModelError(f"{path}: damaged spm model file (truncated or corrupt: "
                             f"{type(exc).__name__}: {one_line(exc)}); {retrain}") from None
