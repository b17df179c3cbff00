"""Our shards out as a BOP dataset (Hodaň et al.): one scene per target object.

``camera.json``, ``models/`` and ``models_eval/`` (bop/models.py, from the folder's mesh
store), ``objects.json`` (obj_id -> class, instance, mesh digest), ``test_targets_bop19.json``,
and per scene (bop/scene.py) ``scene_camera.json``, ``scene_gt.json``, ``scene_gt_info.json``
and the masks (bop/gt.py: what bop_toolkit's calc_gt_info and calc_gt_masks compute from the
export, every object in the frame: the target and its 3-D distractors), ``scene_gt_coco.json``;
rgb as JPEG in ``*_pbr`` splits, PNG otherwise; written to ``OUT.partial`` and renamed.

Object ids, scenes and image ids: bop/ids.py (the rule the results file shares).

K: BOP counts the principal point from the pixel corner (cx = W / 2 for a centred
camera), our shards from the first pixel's centre (OpenCV): export adds 0.5 to cx and
cy (poses.K_to_corner_origin). docs/datasets.md compares the conventions.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.core.meshes import TexturedMesh
from spm_data.core.poses import K_to_corner_origin, intrinsics_from_fov
from spm_data.core.specs import parse_spec
from spm_data.formats.bop.ids import folder_objects, save_objects
from spm_data.formats.bop.gt import DEPTH_SCALES
from spm_data.formats.bop.models import save_bop_model, save_models_info
from spm_data.formats.bop.scene import SceneWriter
from spm_data.io.outputs import check_creatable, check_out_name, space_fix, top_created
from spm_data.io.shards import read_attrs, read_shard

SPLIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")  # one folder inside the dataset, never a path
RGB_SUFFIX = {True: ".jpg", False: ".png"}  # keyed by "a PBR split": BOP stores PBR renders as JPEG
JPEG_QUALITY = 95  # BlenderProc's BOP writer's setting


def _encode(path: Path, array: np.ndarray) -> None:
    import cv2

    img = cv2.cvtColor(array, cv2.COLOR_RGB2BGR) if array.ndim == 3 else array
    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if path.suffix == ".jpg" else []
    ok, data = cv2.imencode(path.suffix, img, params)
    if not ok:
        raise SpmError(f"could not encode {path}")
    path.write_bytes(data.tobytes())  # an OSError (disk full, read-only) names its errno, unlike cv2.imwrite


def _check_out(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise SpmError(f"{out_dir} is a file; give --out a new folder to export into")
    if out_dir.exists() and any(out_dir.iterdir()):
        raise SpmError(f"{out_dir} exists and is not empty; export into a new folder")
    check_creatable(out_dir, "create", "give --out a new folder to export into",
                    "give --out a folder in a writable place")


def nominal_camera(shards) -> tuple[np.ndarray, tuple[int, int]]:
    """camera.json's camera, (K (3, 3) OpenCV, (H, W)): the spec's own (its field of view at its
    image size, never a frame's randomised K) of the first shard rendered from a spec; for
    imported or merged shards, the K most frames share (the first frame's when none is shared)."""
    size = read_shard(shards[0], ["rgb"], frames=slice(0, 1))["rgb"].shape[1:3]
    for path in shards:
        text = read_attrs(path).get("spec")
        if text:
            try:
                spec = parse_spec(str(text), "the shard's spec")
            except SpmError:
                continue   # a spec this spm no longer accepts: the frames' K below
            return intrinsics_from_fov(spec.image.fov, spec.image.width, spec.image.height), \
                (spec.image.height, spec.image.width)
    counts: dict[bytes, list] = {}
    for path in shards:
        for K in read_shard(path, ["K"])["K"]:
            counts.setdefault(K.tobytes(), [K, 0])[1] += 1
    K = max(counts.values(), key=lambda kc: kc[1])[0]   # max keeps the first of equals: frame 0's on a tie
    return K, size


class _Export:
    """The BOP dataset being written into ``root`` (OUT.partial): one scene per object."""

    def __init__(self, root: Path, split: str, found, meshes):
        self.root, self.split, self.found, self.meshes = root, split, found, meshes
        self.ids = found.ids
        self.rgb_suffix = RGB_SUFFIX[split.endswith("_pbr")]
        self.models: dict[int, object] = {}   # obj_id -> its mesh (None: no mesh, image-only ground truth)
        self.models_info, self.no_model, self.frames, self.scales = {}, set(), 0, {DEPTH_SCALES[0]}
        self.writer = SceneWriter(root / split, self.rgb_suffix, _encode, self.scales)   # bop/scene.py
        self.scenes = self.writer.scenes
        self.names: dict[int, dict] = {}
        for sub in ("models", "models_eval"):
            (root / sub).mkdir(parents=True)

    def object_id(self, identity: tuple) -> int:
        """The obj_id of ``identity`` (bop/ids.py), its model written the first time it is met."""
        obj_id = self.ids[identity]
        if obj_id not in self.models:
            entry = dict(self.found.entries[identity])
            mesh = self.models[obj_id] = self._mesh(identity)
            if mesh is None:
                entry["ground_truth"] = "image-only"   # no model: px_count_all etc. from the image alone
                self.no_model.add(f"{entry['class']}/{entry['instance']}")
            else:
                unit, size = (self.meshes.mesh(identity[1]), identity[2]) if identity[0] == "distractor" else (None,
                                                                                                               1.0)
                self.models_info[obj_id] = save_bop_model(self.root, obj_id, mesh, unit, size)
            self.names[obj_id] = entry
        return obj_id

    def _mesh(self, identity: tuple):
        if identity[0] == "name":
            return None
        mesh = self.meshes.mesh(identity[1])
        if identity[0] == "distractor":   # drawn at its own size: that size is the model's
            size = identity[2]
            mesh = TexturedMesh(mesh.name, mesh.vertices * size, mesh.faces, mesh.normals, mesh.uv, mesh.texture,
                                mesh.symmetries)
        return mesh

    def add_frame(self, data: dict, i: int, obj_id: int) -> None:
        """Frame ``i`` of ``data`` with its target ``obj_id`` and its 3-D distractors (those the
        scan found: found.distractors, empty without include_distractors) to the scene writer."""
        objects = [(obj_id, self.models[obj_id], data["R"][i], data["t"][i])]
        for identity, k, _ in (self.found.distractors[self.frames] if self.found.distractors else ()):
            other = self.object_id(identity)
            objects.append((other, self.models[other], data["distractor_R"][i][k], data["distractor_t"][i][k]))
        self.writer.add_frame(data, i, objects)
        self.frames += 1

    def finish(self, shards) -> None:
        self.writer.finish(self.ids.values())   # COCO files list every category of the dataset, as bop_toolkit's
        K, (h, w) = nominal_camera(shards)
        K = K_to_corner_origin(K)
        (self.root / "camera.json").write_text(json.dumps({"cx": K[0, 2], "cy": K[1, 2], "fx": K[0, 0],
                                                           "fy": K[1, 1], "width": int(w), "height": int(h),
                                                           "depth_scale": max(self.scales)}))
        save_objects(self.root, self.names)
        save_models_info(self.root / "models" / "models_info.json", self.models_info)
        save_models_info(self.root / "models_eval" / "models_info.json", self.models_info)


def export_bop(in_dir, out_dir, *, split="train", progress=None, allow_partial=False, meshes_from=None,
               ids_from=None, include_distractors=True) -> dict:
    """Write the shards of ``in_dir`` as a BOP dataset at ``out_dir``. Returns counts.
    split: one folder name (BOP's: train, train_pbr, val, test...). meshes_from: the folder
    a mesh-file spec's paths start from, when not the spec folder its shards recorded
    (spm_data.core.instances.shard_mesh). ids_from: a previous export (or its objects.json)
    whose obj_ids to keep (the module's docstring). include_distractors: a frame's 3-D distractors
    are objects of its own in it (scene_gt, masks, scene_gt_info, COCO), numbered after the targets."""
    out_dir = check_out_name(out_dir)
    if not SPLIT_NAME.fullmatch(str(split)):
        raise SpmError(f"--split {split!r}: expected one folder name of letters, digits, '_' or '-' "
                       "(BOP's are train, train_pbr, val, test)")
    if meshes_from is not None and not Path(meshes_from).is_dir():
        raise SpmError(f"--meshes-from {meshes_from}: no such folder; give the folder the spec file is in")
    _check_out(out_dir)
    # Every shard read below is verified as it is read; the export is built in OUT.partial, so a
    # corrupt shard (or a full disk) leaves nothing behind.
    shards, meshes, found = folder_objects(in_dir, ids_from, allow_partial=allow_partial, spec_dir=meshes_from,
                                           distractors=include_distractors)
    tmp = out_dir.with_name(out_dir.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    made = top_created(tmp / "models")  # what this export creates: removed on failure
    try:
        export = _Export(tmp, split, found, meshes)
        if progress is not None:
            progress.total = len(found.targets)
        frame = 0
        for path in shards:
            data = read_shard(path)
            if "depth" not in data:   # an import without depth: zeros, no surface (BOP's depth PNG of 0)
                data["depth"] = read_shard(path, ["depth"])["depth"]
            for i in range(len(data["pose"])):
                export.add_frame(data, i, export.object_id(found.targets[frame]))
                frame += 1
                if progress:
                    progress(1)
        export.finish(shards)
        from spm_data.formats.bop.results import write_test_targets   # what eval_bop19_pose.py scores against
        write_test_targets(tmp, split)
        if out_dir.exists():
            out_dir.rmdir()
        os.replace(tmp, out_dir)
    except BaseException as exc:
        shutil.rmtree(made, ignore_errors=True)
        if isinstance(exc, OSError):
            fix = space_fix(exc, "give --out a folder in a writable place")
            raise SpmError(f"could not export to {out_dir}: {exc.strerror or exc}; nothing was written; "
                           f"{fix}") from None
        raise
    return {"frames": export.frames, "objects": len(export.names), "scenes": len(export.scenes),
            "distractors": sum(e.get("role") == "distractor" for e in export.names.values()),
            "without_model": sorted(export.no_model)}
