"""What tests in several files share: waiting for a state, reaping processes, small
specs, shard arrays, a flipped stored byte, COIL-100 images, transforms.json captures,
ellipse points, estimator inputs, posed splits of rendered views, and the repository's scripts as
modules. Fixtures are in
tests/conftest.py; import these as ``from tests.helpers import ...``."""

import contextlib
import importlib.util
import json
import time
from pathlib import Path

import cv2
import h5py
import numpy as np

from spm_data.core.poses import K_to_corner_origin, cv_to_gl_camera_to_world
from spm_data.io.shards import FIELDS


# --------------------------------------------------------------------------- processes

def wait_for(predicate, what, *, timeout=120.0, interval=0.05, proc=None):
    """Poll ``predicate()`` until it is truthy and return its value: tests wait for a
    state (a shard on disk, a lock taken), never a fixed time, so a loaded machine only
    makes them slower. AssertionError naming ``what`` after ``timeout`` seconds, or as
    soon as ``proc`` (a Popen) exits without the state reached (with its output)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            value = predicate()  # reached just before it exited
            if value:
                return value
            output = proc.communicate()[0] if proc.stdout is not None else ""
            raise AssertionError(f"the process exited with status {proc.returncode} before {what}:\n{output}")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(interval)


@contextlib.contextmanager
def reaped(proc, kill=None):
    """Yield ``proc`` (a Popen); on the way out a run still alive (a test that failed
    midway) is killed (``kill()``, default ``proc.kill``) and waited for, so no test
    leaves a process behind."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            (kill or proc.kill)()
            proc.communicate()


# --------------------------------------------------------------------------- render specs

SMALL_SPEC = """
class = "{cls}"
seed = {seed}
[mesh]
instances = 2
[camera]
azimuth = [0, 25, 5]
elevation = [0, 10, 5]
distances = [0.6, 0.7]
[image]
width = 64
height = 64
[render]
renderer = "pyrender"
frames_per_shard = 8
"""


def write_small_specs(folder):
    """``folder`` made, with SMALL_SPEC for cup and box (18 views x 2 instances each); returns it."""
    folder.mkdir(parents=True)
    for cls in ("cup", "box"):
        (folder / f"{cls}.toml").write_text(SMALL_SPEC.format(cls=cls, seed=3))
    return folder


# One instance at 128x128 over azimuth 0..AZ_STOP x two elevations (EL, EL + 5):
# enough keypoints for the SPM pipeline (model tests) and quick to render (executor tests).
PYRENDER_128_SPEC = """
class = "{cls}"
seed = {seed}
[mesh]
instances = {instances}
[camera]
azimuth = [0, {az_stop}, 5]
elevation = [{el}, {el_stop}, 5]
distances = [0.6]
[image]
width = 128
height = 128
[render]
renderer = "pyrender"
frames_per_shard = {per_shard}
"""


def write_pyrender_128_spec(folder, cls, *, seed, az_stop, el, per_shard, instances=1):
    (folder / f"{cls}.toml").write_text(PYRENDER_128_SPEC.format(cls=cls, seed=seed, az_stop=az_stop, el=el,
                                                                 el_stop=el + 5, per_shard=per_shard,
                                                                 instances=instances))


# --------------------------------------------------------------------------- shards

def make_arrays(n=3, h=8, w=10, seed=0):
    """Random arrays of every shard field (FIELDS) for ``n`` frames of ``h`` x ``w``;
    string fields are ``"<field>-<i>"``."""
    rng = np.random.default_rng(seed)
    arrays = {}
    for name, (dtype, shape) in FIELDS.items():
        shape = (n,) + tuple({"H": h, "W": w, "R": 1}.get(d, d) for d in shape)
        if dtype == "str":
            arrays[name] = [f"{name}-{i}" for i in range(n)]
        elif dtype == "bool":
            arrays[name] = rng.random(shape) > 0.5
        else:
            arrays[name] = (rng.random(shape) * 100).astype(dtype)
    return arrays


def flip_stored_byte(path, field, chunk=0):
    """Flip one bit in the middle of a stored chunk of ``field`` (file size unchanged)."""
    with h5py.File(path, "r") as f:
        info = f[field].id.get_chunk_info(chunk)
    at = info.byte_offset + info.size // 2
    with open(path, "r+b") as fh:
        fh.seek(at)
        byte = fh.read(1)[0]
        fh.seek(at)
        fh.write(bytes([byte ^ 0x10]))


def payload_positions(path) -> set:
    """Byte positions of a shard that hold a chunk's stored data (everything else is metadata)."""
    inside = set()
    with h5py.File(path, "r") as f:
        for ds in f.values():
            for i in range(ds.id.get_num_chunks()):
                info = ds.id.get_chunk_info(i)
                inside.update(range(info.byte_offset, info.byte_offset + info.size))
    return inside


# --------------------------------------------------------------------------- COIL-100 images

OBJECTS = (7, 12)  # the objects of the coil_folder fixture (tests/conftest.py)


def coil_image(obj, angle):
    img = np.zeros((128, 128, 3), np.uint8)
    cv2.circle(img, (64, 64), 20 + obj % 10, (obj * 2 % 255, 100, angle % 255), -1)
    return img


def png_bytes(img):
    return cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))[1].tobytes()


def ppm16(img, comment=b"# converted by a scanner tool\n"):
    """A 16-bit binary PPM with a comment and odd whitespace in its header."""
    data = (img.astype(">u2") * 257).tobytes()
    return b"P6\n" + comment + b"128  128\n\n65535\n" + data


# --------------------------------------------------------------------------- transforms.json captures

SCALE, CENTER = 0.25, np.array([0.4, -1.2, 2.0])   # metres per world unit; the object's origin in the world


def write_capture(root, rgb, mask, K, R, t, *, per_frame=False, alpha=True, depth=None, suffix=".png"):
    """Frames as a capture app writes them: RGBA PNGs (alpha = mask; ``alpha`` False: RGB images of
    ``suffix``, e.g. a phone's ".jpg") and transforms.json with each frame's OpenGL camera-to-world
    matrix in a world frame where X_world = X_obj / SCALE + CENTER, and nerfstudio's pixel-corner
    intrinsics."""
    (root / "images").mkdir(parents=True)
    frames = []
    for i in range(len(rgb)):
        image = np.dstack([rgb[i], mask[i].astype(np.uint8) * 255]) if alpha else rgb[i]
        cv2.imwrite(str(root / "images" / f"frame_{i:05d}{suffix}"),
                    cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA if alpha else cv2.COLOR_RGB2BGR))
        M = cv_to_gl_camera_to_world(R[i], t[i])
        M[:3, 3] = M[:3, 3] / SCALE + CENTER
        frame = {"file_path": f"images/frame_{i:05d}{suffix}", "transform_matrix": M.tolist()}
        if depth is not None:
            cv2.imwrite(str(root / "images" / f"depth_{i:05d}.png"), np.round(depth[i] * 1000).astype(np.uint16))
            frame["depth_file_path"] = f"images/depth_{i:05d}.png"
        Kc = K_to_corner_origin(K[i])
        camera = {"fl_x": Kc[0, 0], "fl_y": Kc[1, 1], "cx": Kc[0, 2], "cy": Kc[1, 2]}
        frames.append({**frame, **camera} if per_frame else frame)
    h, w = rgb.shape[1:3]
    top = {"camera_model": "OPENCV", "w": w, "h": h, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
    if not per_frame:
        Kc = K_to_corner_origin(K[0])
        top.update(fl_x=Kc[0, 0], fl_y=Kc[1, 1], cx=Kc[0, 2], cy=Kc[1, 2])
    (root / "transforms.json").write_text(json.dumps({**top, "frames": frames}, indent=1))
    return root


# --------------------------------------------------------------------------- ellipses

def ellipse_points(centre=(40.0, 70.0), a=30.0, b=18.0, degrees=30.0, n=8, phase=0.3):
    """``n`` points on a known ellipse, and that ellipse (spm_model.spm.ellipse.Ellipse)."""
    from spm_model.spm.ellipse import Ellipse

    u = np.array([np.cos(np.radians(degrees)), np.sin(np.radians(degrees))])
    v = np.array([-u[1], u[0]])
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + phase
    return np.asarray(centre) + a * np.cos(t)[:, None] * u + b * np.sin(t)[:, None] * v, Ellipse(
        np.asarray(centre), a, b, u)


# --------------------------------------------------------------------------- estimator inputs (no rendering)

N = 24


class CachedFrames(list):
    """Frames whose features are cached (as spm_model.base.frames.Frames serves them): ``frames``
    (frame dicts with images) and ``columns``; without ``frames``, dicts of K alone."""

    def __init__(self, columns: dict, frames=None):
        super().__init__(frames if frames is not None else ({"K": k} for k in columns["K"]))
        self.columns = columns

    def column(self, name):
        return self.columns.get(name)


def labels(n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-180, 180, (n, 3)), rng.normal(0, 0.05, (n, 2)), rng.uniform(0.5, 1, n)])


def vectors(n, seed, d=16):
    x = np.abs(np.random.default_rng(seed).normal(size=(n, d))) + 0.1
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def frames(n, seed):
    from spm_model.methods.descriptors import HOG_SIZE

    rng = np.random.default_rng(seed)
    K = np.tile(np.array([[60.0, 0, 31.5], [0, 60, 31.5], [0, 0, 1]]), (n, 1, 1))
    geometry = np.column_stack([rng.uniform(20, 40, (n, 2)), rng.uniform(10, 50, n), K[:, 0, 0], K[:, 1, 1],
                                K[:, 0, 2], K[:, 1, 2]])
    template = np.hstack([rng.uniform(0, 1, (n, HOG_SIZE)), geometry]).astype(np.float32)
    return CachedFrames({"train_vector": vectors(n, seed), "query_vector": vectors(n, seed + 1),
                         "raw": rng.integers(0, 255, (n, 64)).astype(np.uint8), "template": template, "K": K})


FAST_SPM = {"projection_samples": 16, "projection": "knn", "neighbours": 8}


# The plug-in estimators of the plugin_module fixture (tests/conftest.py), written as my_pose.py.
PLUGIN = '''
import json
import os

import numpy as np

class MeanPose:
    """Predicts the mean training label; notes what it was given (in the file SPM_TEST_NOTES names:
    it runs in a process of its own)."""

    def __init__(self, *, shift=0.0):
        self.shift = shift

    def fit(self, frames, poses):
        f = frames[0]
        seen = dict(rgb=[list(f["rgb"].shape), str(f["rgb"].dtype)], mask=str(f["mask"].dtype),
                    K=list(f["K"].shape), n=len(frames), poses=list(np.asarray(poses).shape))
        if os.environ.get("SPM_TEST_NOTES"):
            with open(os.environ["SPM_TEST_NOTES"], "a") as fh:
                fh.write(json.dumps(seen) + "\\n")
        self.mean_ = np.asarray(poses).mean(axis=0) + self.shift
        return self

    def predict(self, frames):
        return np.tile(self.mean_, (len(frames), 1))

class WrongShape(MeanPose):
    def predict(self, frames):
        return np.zeros((len(frames), 5))
'''


def note(value) -> None:
    """For a test's plug-in (it runs in a process of its own): ``value`` as one JSON line in the
    file SPM_TEST_NOTES names (the ``notes`` fixture sets it), if any."""
    import json
    import os

    if os.environ.get("SPM_TEST_NOTES"):
        with open(os.environ["SPM_TEST_NOTES"], "a") as fh:
            fh.write(json.dumps(value) + "\n")


def sealed_model(path, header: dict, arrays: dict):
    """A model file as spm writes one (format 2: header, arrays and their SHA-256 seal) from any
    header and arrays, so a test reaches the checks behind the seal; returns ``path``."""
    import json

    from spm_model.base.model_files import model_seal

    text = json.dumps(header)
    np.savez(path, header=np.array(text), seal=np.array(model_seal(text, arrays)), **arrays)
    return path


# --------------------------------------------------------------------------- posed renders (N3M, SIFT + PnP)

def grid_split(folder):
    """N3M's and SIFT + PnP's data from the model_shards fixture: training frames (even path
    steps: a 10-degree grid) with depth and "sequence", and test frames (odd steps 1, 7, 13,
    ...: 5 degrees off every training view) with only rgb, mask, K. Returns (train, poses,
    test, truth)."""
    from spm_data.io.shards import read_shard

    train, train_poses, test, test_poses = [], [], [], []
    for s, path in enumerate(sorted(folder.glob("*.h5"))):
        data = read_shard(path, ("rgb", "mask", "depth", "K", "pose", "path_index"))
        for i, step in enumerate(data["path_index"]):
            frame = {"rgb": data["rgb"][i], "mask": data["mask"][i] > 0, "K": data["K"][i]}
            if step % 2 == 0:
                train.append({**frame, "depth": data["depth"][i], "sequence": s})
                train_poses.append(data["pose"][i])
            elif step % 6 == 1:
                test.append(frame)
                test_poses.append(data["pose"][i])
    return train, np.array(train_poses), test, np.array(test_poses)


def within_5_degrees(pred, truth) -> np.ndarray:
    """(n,) bool: a pose estimated (no NaN) and each Euler angle within 5 degrees of the truth."""
    from spm_data.core.poses import wrap_degrees

    found = np.all(np.isfinite(pred), axis=1)
    err = np.abs(wrap_degrees(np.nan_to_num(pred[:, :3]) - truth[:, :3]))
    return found & np.all(err <= 5.0, axis=1)


def load_script(path: str, name: str):
    """A script of the repository (``path`` from its root: benchmarks/..., scripts/...) as a module."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
