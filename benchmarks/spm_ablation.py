"""Ablation of the SPM pipeline's open choices, and a stage-by-stage probe.

Usage (from the repository root, in the venv; PYOPENGL_PLATFORM=egl for rendering):

    # once: render the subset (plus its 5-degree path neighbours) again at 512 px
    python benchmarks/spm_ablation.py render [/work/data/py/render]
           [--hires /work/data/ablation/render512] [--instances 2] [--azimuth-step 2] [--elevation-step 2]
    # the benchmark: prints two markdown tables, writes them (and JSON) to --out
    python benchmarks/spm_ablation.py run [/work/data/py/render]
           [--hires /work/data/ablation/render512] [--out /work/data/ablation/results]
           [--instances 2] [--azimuth-step 2] [--elevation-step 2] [--seed 0] [--no-hires] [--no-best]
           [--probe-only] [--measure docs/results/measures/spm-ablation.json]

Subset: every class in the shards folder, instances 0 .. --instances-1 of each, every
--azimuth-step-th azimuth and every --elevation-step-th elevation of the camera
grid. The training keypoint rule (RANSAC inliers against the frame's path
neighbours, spm_model/spm/features.py) uses the neighbours from the full render,
so the neighbours are read (and, for 512 px, rendered) too.

Table 1 sweeps one choice at a time from the default (FeatureConfig() and
SPMEstimator()): the training keypoint rule, the cluster order, unit
normalisation, PSO vs direct ellipse, appended ellipse parameters, gamma,
the regressor's kernel width and centres, and 128 vs 512 px renders (with
max_side 256, today's cap, and 512); then a "best" row combining the
per-choice winners (chosen on these same test splits: optimistic).
Protocols (the same splits as spm_model/bench/protocols.py): ``views`` (a seeded
20% of the (instance, view) groups held out) and ``instances`` (fold f tests
the f-th instance of every class, in a seeded order; every frame tested once).
Metrics per protocol, for 1-NN on the manifold vector and for the SPM
estimator (SPP + RBF regressor): the median geodesic error in degrees over all
test frames, a frame without a vector counted as 180 degrees, and the % of test
frames with every Euler angle within +-5 degrees (spm_model.bench.metrics; no
vector: a failure). Training frames without a vector are left out.

Table 2 (the probe): 1-NN median geodesic error when the descriptor is
(a) an 8x8 histogram of keypoint positions in the mask's bounding box, (b) the
EM cluster centres in box coordinates, in canonical_order, (c) the ellipse
(centre, semi-axes in box units, cos/sin of twice its angle), (d) the 16-d
manifold vector, (e) the SPP re-projection of (d) (SPMEstimator.transform of
the model fitted on the training split), and chance (a random training frame's
label, seeded). All on the frames that have a default
vector (training rule for the training side, query rule for the test side);
(a)-(c) are z-scored with training statistics.

Stage lines on stderr, and progress (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s,
default 10, elsewhere) while rendering, finding keypoints and running the variants.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import shlex
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from spm_data.jobs.progress import Progress  # noqa: E402
from spm_data.io.files import write_json_atomic  # noqa: E402
from spm_data.io.shards import list_shards, read_shard  # noqa: E402
from spm_model.spm.bunches import BunchError, fit_bunches  # noqa: E402
from spm_model.spm.ellipse import EllipseError, fit_ellipse  # noqa: E402
from spm_model.spm.estimator import SPMEstimator  # noqa: E402
from spm_model.spm.features import FeatureConfig, FeatureError, manifold_from_keypoints, working_image  # noqa: E402
from spm_model.spm.keypoints import homography_inliers, sift_keypoints  # noqa: E402
from spm_model.spm.manifold import canonical_order, ellipse_parameters, foci_distances  # noqa: E402
from spm_model.bench.metrics import pose_errors, tolerance_rate  # noqa: E402
from spm_model.spm.regressor import RBFPoseRegressor  # noqa: E402

LABELS = ("class_name", "instance_id", "instance_name", "path_index", "pose", "azimuth", "elevation")
FAIL_DEG = 180.0
PROJECTION_SAMPLES = 1000  # SPMEstimator's default; --projection-samples (smoke tests only)


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- subset

def read_labels(shards) -> dict:
    parts = []
    for s in shards:
        d = read_shard(s, LABELS)
        d["shard"] = np.array([str(s)] * len(d["pose"]), dtype=object)
        d["row"] = np.arange(len(d["pose"]))
        parts.append(d)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def subset_masks(labels: dict, instances: int, az_step: int, el_step: int, keys=None):
    """(subset, needed): the evaluated frames (those whose (class, instance id, path
    index) is in ``keys`` when given), and those plus their path neighbours."""
    if keys is None:
        az, el = labels["azimuth"], labels["elevation"]
        az_keep = np.isin(az, np.unique(az)[::az_step])
        el_keep = np.isin(el, np.unique(el)[::el_step])
        subset = (labels["instance_id"] < instances) & az_keep & el_keep
    else:
        subset = np.array([(str(c), int(i), int(p)) in keys for c, i, p in
                           zip(labels["class_name"], labels["instance_id"], labels["path_index"])])
    key = {(c, int(i), int(p)) for c, i, p in zip(labels["class_name"][subset], labels["instance_id"][subset],
                                                  labels["path_index"][subset])}
    near = {(c, i, p + d) for c, i, p in key for d in (-1, 1)}
    needed = np.array([(c, int(i), int(p)) in key or (c, int(i), int(p)) in near
                       for c, i, p in zip(labels["class_name"], labels["instance_id"], labels["path_index"])])
    return subset, needed


# ----------------------------------------------------------------------------- render (512 px)

def cmd_render(args) -> None:
    from spm_data.pipelines.render_jobs import ShardJob, effective_spec, plan_shards, render_shard
    from spm_data.core.specs import parse_spec

    labels = read_labels(list_shards(args.shards))
    _, needed = subset_masks(labels, args.instances, args.azimuth_step, args.elevation_step)
    out = Path(args.hires)
    # Shards already there are reused (a resume): only if made with these options (out_options.py).
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from out_options import claim

    claim(out, {"shards": str(Path(args.shards).resolve()), "--instances": args.instances,
                "--azimuth-step": args.azimuth_step, "--elevation-step": args.elevation_step, "--size": args.size},
          record="ablation-render-options.json", data=("specs",), script="spm_ablation.py render")
    (out / "specs").mkdir(parents=True, exist_ok=True)
    start = time.time()
    progress = Progress("frame", "spm_ablation: rendering", int(needed.sum()))
    for cls in sorted(set(labels["class_name"].tolist())):
        text = (ROOT / "render_specs" / f"{cls}.toml").read_text()
        text = re.sub(r"^width = \d+", f"width = {args.size}", text, flags=re.M)
        text = re.sub(r"^height = \d+", f"height = {args.size}", text, flags=re.M)
        spec_file = out / "specs" / f"{cls}.toml"
        if not spec_file.exists():   # never rewritten under its shards
            spec_file.write_text(text)
        spec = effective_spec(parse_spec(text, str(spec_file), base_dir=str(ROOT / "render_specs")),
                              renderer="pyrender")
        sel = needed & (labels["class_name"] == cls)
        inst, pidx = labels["instance_id"][sel].astype(np.int64), labels["path_index"][sel].astype(np.int64)
        order = np.lexsort((pidx, inst))
        inst, pidx = inst[order], pidx[order]
        key = plan_shards(spec, out)[0].plan_key
        per = 256
        for k, s in enumerate(range(0, len(inst), per)):
            name = f"{cls}-{k:05d}.h5"
            if (out / name).exists():
                progress(len(inst[s:s + per]))
                continue
            job = ShardJob(spec=spec, name=name, shard_index=k, instances=inst[s:s + per],
                           path_indices=pidx[s:s + per], plan_key=key, out_dir=str(out))
            render_shard(job, progress)
            log(f"rendered {name} ({len(job.instances)} frames, {time.time() - start:.0f} s)")
    progress.close()
    log(f"render done in {time.time() - start:.0f} s")


# ----------------------------------------------------------------------------- features

class FrameSet:
    """The subset's keypoints (training and query rule) of one render at one max_side,
    with lazily cached bunches and ellipses."""

    def __init__(self, folder, args, max_side: int, name: str, keys=None):
        t0 = time.time()
        self.name = name
        labels = read_labels(list_shards(folder))
        subset, needed = subset_masks(labels, args.instances, args.azimuth_step, args.elevation_step, keys)
        idx = np.flatnonzero(needed)
        sift, box = {}, {}
        progress = Progress("frame", f"spm_ablation: {name} keypoints", len(idx))
        for shard in sorted(set(labels["shard"][idx].tolist())):
            rows = idx[labels["shard"][idx] == shard]
            d = read_shard(shard, ("rgb", "mask"), frames=np.sort(labels["row"][rows]))
            for j, i in enumerate(rows[np.argsort(labels["row"][rows])]):
                small, mask = working_image(d["rgb"][j], d["mask"][j], max_side)
                sift[i] = sift_keypoints(small, mask)
                ys, xs = np.nonzero(mask)
                box[i] = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) if len(xs) else (0, 0, 1, 1)
                progress(1)
        progress.close()
        where = {(c, int(k), int(p)): i for i, (c, k, p) in enumerate(
            zip(labels["class_name"], labels["instance_id"], labels["path_index"])) if i in sift}
        sub = np.flatnonzero(subset)
        sub = sub[np.lexsort((labels["path_index"][sub], labels["instance_id"][sub], labels["class_name"][sub]))]
        self.keys = {(str(labels["class_name"][i]), int(labels["instance_id"][i]), int(labels["path_index"][i]))
                     for i in sub}
        self.train_pts, self.query_pts, self.neighbours = [], [], []
        for i in sub:
            loc, desc = sift[i]
            c, k, p = labels["class_name"][i], int(labels["instance_id"][i]), int(labels["path_index"][i])
            nb = [where[q] for q in ((c, k, p - 1), (c, k, p + 1)) if q in where]
            keep = np.zeros(len(loc), bool) if nb else np.ones(len(loc), bool)
            for j in nb:
                keep |= homography_inliers(loc, desc, *sift[j])
            self.train_pts.append(loc[keep])
            self.query_pts.append(loc)
            self.neighbours.append(len(nb))
        self.box = np.array([box[i] for i in sub], dtype=np.float64)
        self.class_name = labels["class_name"][sub].astype(str)
        self.instance = np.char.add(np.char.add(self.class_name, "/"), labels["instance_name"][sub].astype(str))
        self.path_index = labels["path_index"][sub].astype(np.int64)
        self.pose = labels["pose"][sub].astype(np.float64)
        self.n = len(sub)
        self._bunches, self._ellipses = {}, {}
        log(f"{name}: {self.n} subset frames ({len(idx)} with neighbours) keypoints in {time.time() - t0:.0f} s; "
            f"median keypoints train {np.median([len(x) for x in self.train_pts]):.0f}, "
            f"query {np.median([len(x) for x in self.query_pts]):.0f}")

    def points(self, rule):
        return self.train_pts if rule == "train" else self.query_pts

    def bunches(self, rule, gamma, seed=0):
        key = (rule, gamma)
        if key not in self._bunches:
            out = []
            for pts in self.points(rule):
                try:
                    out.append(fit_bunches(pts, gamma=gamma, seed=seed).means)
                except BunchError:
                    out.append(None)
            self._bunches[key] = out
        return self._bunches[key]

    def ellipses(self, rule, cfg: FeatureConfig):
        key = (rule, cfg.gamma, cfg.ellipse, cfg.lam)
        if key not in self._ellipses:
            out = []
            for means in self.bunches(rule, cfg.gamma, cfg.seed):
                try:
                    out.append(None if means is None else fit_ellipse(means, method=cfg.ellipse, lam=cfg.lam,
                                                                      seed=cfg.seed))
                except EllipseError:
                    out.append(None)
            self._ellipses[key] = out
        return self._ellipses[key]

    def vectors(self, rule, cfg: FeatureConfig) -> np.ndarray:
        """(n, cfg.dims), NaN rows where the frame has no vector; equal to
        features.manifold_from_keypoints (checked on a sample by ``check``)."""
        X = np.full((self.n, cfg.dims), np.nan)
        for i, (means, e) in enumerate(zip(self.bunches(rule, cfg.gamma, cfg.seed), self.ellipses(rule, cfg))):
            if e is not None:
                v = foci_distances(means, e, order=cfg.order, normalise=cfg.normalise)
                X[i] = np.concatenate([v, ellipse_parameters(e)]) if cfg.append_ellipse else v
        return X

    def check(self, rule, cfg, X, sample=25):
        """The cached stages give bit-for-bit the library's vector (features.manifold_from_keypoints)."""
        for i in np.random.default_rng(1).choice(self.n, min(sample, self.n), replace=False):
            try:
                ref = manifold_from_keypoints(self.points(rule)[i], cfg)[0]
            except FeatureError:
                ref = np.full(cfg.dims, np.nan)
            if not np.array_equal(ref, X[i], equal_nan=True):
                raise AssertionError(f"{self.name} {rule} {cfg}: cached vector differs from the library's")


# ----------------------------------------------------------------------------- splits and scoring

def splits(fs: FrameSet, protocol: str, seed: int, held_out: float = 0.2):
    """spm_model.bench.protocols.splits on a FrameSet (it has the class_name, instance and
    path_index arrays the splits read): [(name, train index, test index)]."""
    from spm_model.bench.protocols import splits as protocol_splits

    return protocol_splits(fs, protocol, seed, held_out)


def score(pred: np.ndarray, true: np.ndarray) -> dict:
    e = pose_errors(pred, true)
    g = np.where(np.isfinite(e["geodesic"]), e["geodesic"], FAIL_DEG)
    return {"median_deg": float(np.median(g)), "tol5_pct": tolerance_rate(e["rotation_max"]),
            "frames": int(len(pred)), "estimated": int(np.isfinite(pred).all(axis=1).sum())}


def nearest(train_X, train_y, test_X) -> np.ndarray:
    """1-NN labels (Euclidean); NaN for test rows with NaN."""
    ok_tr = np.isfinite(train_X).all(axis=1)
    A, yA = train_X[ok_tr], train_y[ok_tr]
    out = np.full((len(test_X), 6), np.nan)
    ok = np.isfinite(test_X).all(axis=1)
    B = test_X[ok]
    d2 = (B ** 2).sum(1)[:, None] + (A ** 2).sum(1)[None] - 2 * B @ A.T
    out[ok] = yA[np.argmin(d2, axis=1)]
    return out


def fit_spm(X, y, cfg, reg, cache, key):
    """SPMEstimator(features=cfg).fit(X, y); regressor variants (reg: width_scale,
    landmarks) reuse the projection of the default fit on the same data (the
    projection does not depend on the regressor)."""
    if key not in cache:
        cache[key] = SPMEstimator(features=cfg, projection_samples=PROJECTION_SAMPLES).fit(X, y)
    base = cache[key]
    if not reg:
        return base
    model = SPMEstimator(features=cfg, projection_samples=base.projection_samples,
                         landmarks=reg.get("landmarks", base.landmarks))
    model.projection_ = base.projection_
    model.regressor_ = RBFPoseRegressor(alpha=base.alpha, noise=base.noise, noise_copies=base.noise_copies,
                                        landmarks=reg.get("landmarks", base.landmarks), seed=base.seed,
                                        width_scale=reg.get("width_scale", 1.0)).fit(base.transform(X), y)
    return model


def evaluate_variant(fs, rule, cfg, reg, seed, cache, vkey):
    Xtr_all = fs.vectors(rule, cfg)
    Xq_all = fs.vectors("query", cfg)
    out = {}
    for protocol in ("views", "instances"):
        nn_pred, spm_pred, truth = [], [], []
        for name, tr, te in splits(fs, protocol, seed):
            Xtr, ytr = Xtr_all[tr], fs.pose[tr]
            ok = np.isfinite(Xtr).all(axis=1)
            nn_pred.append(nearest(Xtr, ytr, Xq_all[te]))
            model = fit_spm(Xtr[ok], ytr[ok], cfg, reg, cache, (vkey, protocol, name))
            pred = np.full((len(te), 6), np.nan)
            okq = np.isfinite(Xq_all[te]).all(axis=1)
            pred[okq] = model.predict(Xq_all[te][okq])
            spm_pred.append(pred)
            truth.append(fs.pose[te])
        truth = np.concatenate(truth)
        out[protocol] = {"nn": score(np.concatenate(nn_pred), truth), "spm": score(np.concatenate(spm_pred), truth)}
    out["train_coverage_pct"] = 100.0 * float(np.isfinite(Xtr_all).all(axis=1).mean())
    out["query_coverage_pct"] = 100.0 * float(np.isfinite(Xq_all).all(axis=1).mean())
    return out


# ----------------------------------------------------------------------------- the probe

def box_coords(points, box):
    x0, y0, x1, y1 = box
    side = max(x1 - x0, y1 - y0, 1.0)
    return (np.asarray(points) - [(x0 + x1) / 2, (y0 + y1) / 2]) / side


def stage_descriptors(fs, rule, cfg):
    """{stage: (n, d)} descriptors of (a)-(d), NaN where the default vector is missing."""
    pts, means, ells = fs.points(rule), fs.bunches(rule, cfg.gamma, cfg.seed), fs.ellipses(rule, cfg)
    n = fs.n
    out = {k: np.full((n, d), np.nan) for k, d in (("a", 64), ("b", 2 * cfg.gamma), ("c", 6))}
    for i in range(n):
        if ells[i] is None:
            continue
        p = box_coords(pts[i], fs.box[i]) + 0.5  # the box's longer side spans [0, 1]
        h, _, _ = np.histogram2d(p[:, 0], p[:, 1], bins=8, range=[[0, 1], [0, 1]])
        out["a"][i] = h.ravel() / max(len(p), 1)
        m = means[i][canonical_order(means[i], ells[i])]
        out["b"][i] = box_coords(m, fs.box[i]).ravel()
        e = ells[i]
        side = max(fs.box[i][2] - fs.box[i][0], fs.box[i][3] - fs.box[i][1], 1.0)
        out["c"][i] = np.concatenate([box_coords(e.centre[None], fs.box[i])[0], [e.a / side, e.b / side],
                                      ellipse_parameters(e)[1:]])
    out["d"] = fs.vectors(rule, cfg)
    return out


def probe(fs, seed, cache):
    cfg = FeatureConfig()
    train_d, query_d = stage_descriptors(fs, "train", cfg), stage_descriptors(fs, "query", cfg)
    result = {}
    rng = np.random.default_rng(seed)
    for protocol in ("views", "instances"):
        preds = {k: [] for k in "abcdez"}
        truth = []
        for name, tr, te in splits(fs, protocol, seed):
            tr = tr[np.isfinite(train_d["d"][tr]).all(axis=1)]
            te = te[np.isfinite(query_d["d"][te]).all(axis=1)]
            truth.append(fs.pose[te])
            for k in "abcd":
                A, B = train_d[k][tr], query_d[k][te]
                if k in "abc":
                    mu, sd = A.mean(axis=0), A.std(axis=0) + 1e-9
                    A, B = (A - mu) / sd, (B - mu) / sd
                preds[k].append(nearest(A, fs.pose[tr], B))
            preds["z"].append(fs.pose[rng.choice(tr, len(te))])  # chance: a random training label
            model = cache[("default", protocol, name)]
            preds["e"].append(nearest(model.transform(train_d["d"][tr]), fs.pose[tr],
                                      model.transform(query_d["d"][te])))
        truth = np.concatenate(truth)
        result[protocol] = {k: score(np.concatenate(v), truth) for k, v in preds.items()}
    return result


# ----------------------------------------------------------------------------- run

def results_doc():
    """scripts/results_doc.py: the tables (table_spm_ablation*, what docs/spm-ablation.md shows) and made_block."""
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "scripts" / "results_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def measure_of(lo: FrameSet, args, rows: list, stages: dict, needed: int, shards_frames: int) -> dict:
    """The figures as docs/results/measures/spm-ablation.json holds them (without its made block)."""
    keep = ("train_coverage_pct", "query_coverage_pct", "views", "instances", "rule", "features", "regressor")
    return {"subset": {"frames": lo.n, "with_neighbours": needed, "shards_frames": shards_frames,
                       "classes": len(set(lo.class_name.tolist())), "instances": args.instances,
                       "azimuth_step": args.azimuth_step, "elevation_step": args.elevation_step, "seed": args.seed},
            "variants": [[name, {k: r[k] for k in keep}] for name, r in rows], "probe": stages}


def cmd_run(args) -> None:
    global PROJECTION_SAMPLES
    PROJECTION_SAMPLES = args.projection_samples
    start = time.time()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lo = FrameSet(args.shards, args, max_side=256, name="128 px")
    D = FeatureConfig()
    # (row name, frame set, training rule, FeatureConfig, regressor options, vector key)
    variants = [("default (train rule, sign order, unit, PSO, gamma 8, 128 px)", lo, "train", D, {}),
                ("keypoints: query rule for training too", lo, "query", D, {}),
                ("order: angle around centroid from +x", lo, "train", replace(D, order="angle"), {}),
                ("order: distance from ellipse centre", lo, "train", replace(D, order="distance"), {}),
                ("no unit normalisation", lo, "train", replace(D, normalise=False), {}),
                ("ellipse: direct fit", lo, "train", replace(D, ellipse="direct"), {}),
                ("+ ellipse parameters (b/a, cos 2θ, sin 2θ)", lo, "train", replace(D, append_ellipse=True), {}),
                ("gamma 6", lo, "train", replace(D, gamma=6), {}),
                ("gamma 12", lo, "train", replace(D, gamma=12), {}),
                ("regressor: width x10", lo, "train", D, {"width_scale": 10.0}),
                ("regressor: 4000 centres", lo, "train", D, {"landmarks": 4000}),
                ("regressor: width x10, 4000 centres", lo, "train", D, {"width_scale": 10.0, "landmarks": 4000})]
    hi = {}
    if args.probe_only:
        variants, args.no_hires, args.no_best = variants[:1], True, True
    if not args.no_hires:
        hi[256] = FrameSet(args.hires, args, max_side=256, name="512 px, max_side 256", keys=lo.keys)
        hi[512] = FrameSet(args.hires, args, max_side=512, name="512 px, max_side 512", keys=lo.keys)
        for fs in hi.values():
            if fs.n != lo.n or not np.allclose(fs.pose, lo.pose, atol=1e-9):
                raise SystemExit(f"{fs.name}: not the same frames as the 128 px subset; re-run `render`")
        variants += [("512 px renders, max_side 256 (today's cap)", hi[256], "train", D, {}),
                     ("512 px renders, max_side 512", hi[512], "train", replace(D, max_side=512), {})]
    cache, rows, results = {}, [], {}

    def run_variant(name, fs, rule, cfg, reg):
        t0 = time.time()
        vkey = "default" if (fs is lo and rule == "train" and cfg == D) else f"{fs.name}|{rule}|{cfg.key()}"
        for r in {rule, "query"}:
            fs.check(r, cfg, fs.vectors(r, cfg))
        res = evaluate_variant(fs, rule, cfg, reg, args.seed, cache, vkey)
        res.update({"rule": rule, "features": asdict(cfg), "regressor": reg, "frames": fs.name,
                    "seconds": time.time() - t0})
        rows.append((name, res))
        results[name] = res
        log(f"{name}: views SPM {res['views']['spm']['median_deg']:.1f} deg, instances SPM "
            f"{res['instances']['spm']['median_deg']:.1f} deg ({time.time() - t0:.0f} s)")
        return res

    progress = Progress("variant", "spm_ablation: variants", len(variants) + (not args.no_best))
    for v in variants:
        run_variant(*v)
        progress(1)

    if not args.no_best:
        def mean_spm(name):
            r = results[name]
            return (r["views"]["spm"]["median_deg"] + r["instances"]["spm"]["median_deg"]) / 2

        def pick(names):
            return min(names, key=mean_spm)

        n = [v[0] for v in variants]
        best_rule = "query" if pick([n[0], n[1]]) == n[1] else "train"
        best_order = {n[0]: "sign", n[2]: "angle", n[3]: "distance"}[pick([n[0], n[2], n[3]])]
        best = replace(D, order=best_order, normalise=pick([n[0], n[4]]) == n[0],
                       ellipse="direct" if pick([n[0], n[5]]) == n[5] else "pso",
                       append_ellipse=pick([n[0], n[6]]) == n[6],
                       gamma={n[0]: 8, n[7]: 6, n[8]: 12}[pick([n[0], n[7], n[8]])])
        reg = {n[0]: {}, n[9]: variants[9][4], n[10]: variants[10][4], n[11]: variants[11][4]}[
            pick([n[0], n[9], n[10], n[11]])]
        fs = lo
        if hi:
            res_names = [n[0], variants[-2][0], variants[-1][0]]
            choice = pick(res_names)
            fs = {res_names[0]: lo, res_names[1]: hi[256], res_names[2]: hi[512]}[choice]
            if fs is hi[512]:
                best = replace(best, max_side=512)
        label = (f"best of each (on these splits): {best_rule} rule, {best.order} order, "
                 f"{'unit' if best.normalise else 'raw'}, {best.ellipse}, "
                 f"{'+ellipse, ' if best.append_ellipse else ''}gamma {best.gamma}, {fs.name}, "
                 f"regressor {reg or 'default'}")
        run_variant(label, fs, best_rule, best, reg)
        progress(1)
    progress.close()

    log("probe")
    stages = probe(lo, args.seed, cache)
    seconds = time.time() - start
    doc = results_doc()
    labels = read_labels(list_shards(args.shards))
    found = {"summary": measure_of(lo, args, rows, stages, int(subset_masks(labels, args.instances, args.azimuth_step,
                                                                           args.elevation_step)[1].sum()),
                                   len(labels["pose"]))}
    t1, t2 = doc.table_spm_ablation(found), doc.table_spm_ablation_probe(found)
    text = (f"Subset: {lo.n} frames ({args.instances} instances per class, every {args.azimuth_step}. azimuth, "
            f"every {args.elevation_step}. elevation), seed {args.seed}; run time {seconds / 60:.1f} min\n\n"
            f"{t1}\n\n{t2}\n")
    print(text)
    (out / "tables.md").write_text(text)
    (out / "results.json").write_text(json.dumps({"args": vars(args), "seconds": seconds, "variants": results,
                                                  "probe": stages}, indent=1, default=str))
    if args.measure:
        found["made"] = doc.made_block(shlex.join(["python", "benchmarks/spm_ablation.py", *args.argv]), seconds,
                                       cpu_s=doc.cpu_seconds())
        Path(args.measure).parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.measure, found, sort_keys=False)
    log(f"done in {seconds:.0f} s; wrote {out / 'tables.md'} and results.json")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in ("render", "run"):
        p = sub.add_parser(name)
        p.add_argument("shards", nargs="?", default="/work/data/py/render",
                       help="128-px pyrender shards of the default specs (default: /work/data/py/render)")
        p.add_argument("--shards", dest="old_shards", help=argparse.SUPPRESS)
        p.add_argument("--hires", default="/work/data/ablation/render512", help="the 512-px subset's shards")
        p.add_argument("--instances", type=int, default=2, help="instances 0..N-1 of every class")
        p.add_argument("--azimuth-step", type=int, default=2, help="every k-th azimuth of the grid")
        p.add_argument("--elevation-step", type=int, default=2, help="every k-th elevation of the grid")
        if name == "render":
            p.add_argument("--size", type=int, default=512, help="image width and height")
        else:
            p.add_argument("--out", default="/work/data/ablation/results", help="where tables.md / results.json go")
            p.add_argument("--seed", type=int, default=0, help="split seed")
            p.add_argument("--no-hires", action="store_true", help="skip the 512-px rows")
            p.add_argument("--no-best", action="store_true", help="skip the combined row")
            p.add_argument("--probe-only", action="store_true", help="only the default row and table 2")
            p.add_argument("--projection-samples", type=int, default=1000,
                           help="SPMEstimator's projection_samples (1000, its default; less only for smoke tests)")
            p.add_argument("--measure", help="also write the tables' figures and how they were made to this JSON "
                                             "(docs/results/measures/spm-ablation.json: docs/spm-ablation.md's tables)")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv
    if args.old_shards:  # the old spelling, kept for one release
        print("warning: --shards is deprecated; give the folder as the first argument", file=sys.stderr)
        args.shards = args.old_shards
    (cmd_render if args.command == "render" else cmd_run)(args)


if __name__ == "__main__":
    main()
