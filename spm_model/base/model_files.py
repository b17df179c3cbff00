"""Model files and the estimator boundary: one ``.npz`` per model (a JSON header and
named arrays, no pickle), and the input checks every estimator shares."""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from spm_data.errors import one_line
from spm_data.io.files import write_npz_atomic
from spm_model.base.estimator import ModelError

MODEL_FORMAT = 1


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


def save_model_file(path, kind: str, params: dict, arrays: dict, extra: dict | None = None) -> Path:
    """One ``.npz``: a JSON header (format, kind, parameters) and named arrays; no pickle."""
    path = Path(path)
    header = {"format": MODEL_FORMAT, "kind": kind, "params": params, **(extra or {})}
    return write_npz_atomic(path, header=np.array(json.dumps(header)), **arrays)


def need(ok: bool, what: str) -> None:
    """A loaded model's consistency check: ValueError(what) unless ``ok``."""
    if not ok:
        raise ValueError(what)


def need_finite(*arrays) -> None:
    need(all(np.isfinite(np.asarray(a, dtype=np.float64)).all() for a in arrays), "arrays hold NaN or inf")


def load_model_file(path, kind: str | None = None) -> tuple[dict, dict]:
    """(header, arrays) of a model file; ModelError naming the file for a missing, truncated,
    corrupt, foreign or newer one."""
    retrain = "retrain it with spm train"
    foreign = "give the model.npz or reference-model.npz that spm train wrote, or retrain with spm train"
    magic = b""
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ModelError(f"model file not found: {path}; train one with spm train") from None
    except IsADirectoryError:
        raise ModelError(f"{path}: is a folder, not a model file; {foreign}") from None
    except PermissionError as exc:
        raise ModelError(f"{path}: cannot read the model file ({exc.strerror}); check its permissions") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        if not magic:
            raise ModelError(f"{path}: damaged spm model file (an empty file); {retrain}") from None
        if magic.startswith(b"PK"):  # a zip (every .npz is one) that cannot be read
            raise ModelError(f"{path}: damaged spm model file (truncated or corrupt: {type(exc).__name__}: "
                             f"{one_line(exc)}); {retrain}") from None
        raise ModelError(f"{path}: not an spm model file (not an .npz archive); {foreign}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ModelError(f"{path}: not an spm model file (a single numpy array, not an .npz archive); {foreign}")
    with z:
        if "header" not in z.files:
            raise ModelError(f"{path}: not an spm model file (an .npz archive without spm's header); {foreign}")
        try:
            header = json.loads(str(z["header"]))
            arrays = {k: z[k] for k in z.files if k != "header"}
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ModelError(f"{path}: damaged spm model file (truncated or corrupt: "
                             f"{type(exc).__name__}: {one_line(exc)}); {retrain}") from None
    if not isinstance(header, dict) or not isinstance(header.get("format", 0), int):
        raise ModelError(f"{path}: damaged spm model file (its header is not spm's); {retrain}")
    if header.get("format", 0) > MODEL_FORMAT or (kind is not None and header.get("kind") != kind):
        raise ModelError(f"{path}: model format {header.get('format')} of kind {header.get('kind')} is not one "
                         f"this spm reads here ({kind or 'any'}, format {MODEL_FORMAT}); retrain or upgrade spm")
    return header, arrays
