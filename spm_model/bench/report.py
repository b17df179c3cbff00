"""Reports of an evaluation: results.json (schema: docs/results-schema.md),
results.md (a plain summary first, then the paper's Table 1, Table 2 and Fig. 5
analogues and every method's errors), accuracy.png (accuracy against geodesic
threshold) and occlusion.png (success against occlusion)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.io.outputs import unwritable
from spm_data.io.files import atomic_file, write_json_atomic
from spm_model.methods.registry import METHOD_NAMES
from spm_model.bench.metrics import CURVE_THRESHOLDS

SCHEMA = "spm-results"
SCHEMA_VERSION = 2
PAPER_TABLE1 = {"box": (97.2, 0.9, 0.31, 0.09), "car": (95.6, 1.1, 0.44, 0.12), "motorcycle": (92.8, 1.6, 0.61, 0.11),
                "ball": (88.4, 2.5, 0.76, 0.08), "animal4": (87.9, 2.9, 0.84, 0.09), "cup": (86.6, 3.3, 0.87, 0.07)}
PAPER_TABLE2 = {"box": (94.7, 2.6, 94.2, 2.3), "car": (91.5, 3.2, 94.5, 3.0), "motorcycle": (92.0, 1.8, 95.5, 1.1),
                "ball": (86.2, 3.4, 86.1, 2.5), "animal4": (83.3, 3.7, 83.8, 2.9), "cup": (82.6, 3.4, 82.8, 3.2)}
DOF = (("azimuth_deg", "azimuth", "°"), ("azimuth_mod180_deg", "azimuth mod 180°", "°"),
       ("elevation_deg", "elevation", "°"), ("roll_deg", "in-plane roll", "°"), ("distance_mm", "distance", " mm"))
COUNTS = ("frames", "estimated")


def _mean_tree(items: list):
    """Mean over runs of every number in a list of same-shaped dicts (None where all are None)."""
    first = next((i for i in items if i is not None), None)
    if isinstance(first, dict):
        return {k: _mean_tree([i.get(k) if i else None for i in items]) for k in first}
    values = [v for v in items if v is not None]
    return float(np.mean(values)) if values else None


def _std_tree(items: list):
    first = next((i for i in items if i is not None), None)
    if isinstance(first, dict):
        return {k: _std_tree([i.get(k) if i else None for i in items]) for k in first if k not in COUNTS}
    values = [v for v in items if v is not None]
    return float(np.std(values)) if values else None


def _summary(per_run: list) -> dict:
    out = _mean_tree(per_run)
    for k in COUNTS:
        out[k] = per_run[0][k]
    out["std"] = _std_tree(per_run)
    return out


def aggregate(evaluation: dict) -> dict:
    """The ``summary`` of results.json: means over runs with σ (docs/results-schema.md)."""
    runs, names = evaluation["runs"], evaluation["methods"]
    overall = {m: _summary([r["overall"][m] for r in runs]) for m in names}
    classes = {}
    for c in evaluation["classes"]:
        per_run = [r["classes"][c] for r in runs if c in r["classes"]]
        if per_run:
            classes[c] = {m: _summary([p[m] for p in per_run]) for m in names}
    occlusion = {m: [{**{k: row[k] for k in ("low", "high", "frames")},
                      **_mean_tree([{k: r["occlusion"][m][b][k] for k in ("success_tol5", "success_sum5", "success_sum3")}
                                    for r in runs])}
                     for b, row in enumerate(runs[0]["occlusion"][m])] for m in names}
    curve = {"thresholds_deg": CURVE_THRESHOLDS.tolist(),
             **{m: (np.mean([r["accuracy_curve"][m] for r in runs], axis=0).tolist()
                    if all(r["accuracy_curve"][m] is not None for r in runs) else None) for m in names}}
    return {"protocol": evaluation["protocol"], "runs": len(runs),
            "methods": {m: overall[m] for m in names if m != "chance"}, "chance": overall.get("chance"),
            "classes": classes, "occlusion": occlusion, "accuracy_curve": curve}


def _fmt(value, digits=1):
    return "–" if value is None else f"{value:.{digits}f}"


def _name(m: str) -> str:
    return METHOD_NAMES.get(m, m)


def plain_summary(summary: dict) -> list[str]:
    """The first lines a newcomer reads: the best method, how far above chance,
    and which degrees of freedom it recovers (median error at most half of chance's)."""
    methods, chance = summary["methods"], summary["chance"] or {}
    best = max(methods, key=lambda m: (methods[m]["success_tol5"] or 0, methods[m]["auc_45"] or 0))
    b = methods[best]
    lines = [f"- **Best method, {summary['protocol']} protocol: {_name(best)}**, {_fmt(b['success_tol5'])}% within "
             f"±5° (chance {_fmt(chance.get('success_tol5'))}%), geodesic median {_fmt(b['geodesic_median_deg'])}° "
             f"(chance {_fmt(chance.get('geodesic_median_deg'))}°), AUC of accuracy to 45° {_fmt(b['auc_45'])} "
             f"(chance {_fmt(chance.get('auc_45'))})."]
    spm = methods.get("spm")
    if spm and best != "spm":
        lines.append(f"- SPM: {_fmt(spm['success_tol5'])}% within ±5°, geodesic median {_fmt(spm['geodesic_median_deg'])}°.")
    good, bad, constant = [], [], []
    for key, label, unit in DOF:
        mine, base = b["median_error"].get(key), (chance.get("median_error") or {}).get(key)
        if mine is None or base is None:
            continue
        if base < 0.5:  # a random training pose gets it right: the data does not vary it
            constant.append(label)
            continue
        text = f"{label} {_fmt(mine)}{unit} (chance {_fmt(base)}{unit})"
        (good if mine <= 0.5 * base else bad).append(text)
    if good:
        lines.append(f"- Recovered by {_name(best)} (median error at most half of chance's): " + "; ".join(good) + ".")
    if bad:
        lines.append("- Not recovered (median error above half of chance's): " + "; ".join(bad) + ".")
    if constant:
        lines.append("- Not varied in this data (a random training pose has a median error under 0.5): "
                     + ", ".join(constant) + ".")
    return lines


def _surface_cell(s, key, digits=1):
    return _fmt((s.get("surface") or {}).get(key), digits)


def markdown(evaluation: dict, summary: dict, context: dict) -> str:
    names = list(summary["methods"]) + (["chance"] if summary["chance"] else [])
    return "\n".join(_intro(summary, context) + _paper_tables(evaluation, summary) + _method_tables(summary, names)
                     + _class_and_occlusion_tables(summary, names) + [
        "", "Plots: `accuracy.png` (accuracy against geodesic threshold), `occlusion.png`. Models trained on "
        "every frame: `model.npz` (SPM) and `reference-model.npz` (HOG templates).", ""])


def _intro(summary: dict, context: dict) -> list:
    runs = summary["runs"]
    return [f"# Pose benchmark ({summary['protocol']} protocol, {runs} run{'s' if runs != 1 else ''})", "",
            *plain_summary(summary), "",
            f"Command: `{context.get('command', '')}`", "",
            f"Data: {context.get('frames', '?')} frames under `{context.get('shards', '')}`; SPM features: "
            f"{context.get('train_features', '?')} frames with training features, {context.get('query_features', '?')}"
            f" with query features ({context.get('without_path_neighbour', 0)} frames had no path neighbour for the "
            "training rule). Criteria (the paper's): **±5° tolerance** (Table 2), every rotation angle within 5°, "
            "inclusive; **sum < 5° (3°)** (Fig. 5), the summed absolute angle errors below 5° (3°). A frame without "
            "an estimate fails. σ: over runs. Schema of results.json: docs/results-schema.md.", ""]


def _paper_tables(evaluation: dict, summary: dict) -> list:
    """The analogues of the paper's Tables 1 and 2, per class, with the paper's numbers beside ours."""
    ecc, classes = evaluation["eccentricity"], summary["classes"]
    lines = ["## Table 1 analogue: SPM", "",
             "The paper's Table 1 counts successful grasps; its pose criterion is Table 2's ±5°, used here.", "",
             "| Class | ±5° % | σ | sum<5° % | sum<3° % | Mean eccentricity | σ | Paper success % | Paper ecc. |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c, row in classes.items():
        s, e, paper = row["spm"], ecc.get(c, {}), PAPER_TABLE1.get(c)
        lines.append(f"| {c} | {_fmt(s['success_tol5'])} | {_fmt(s['std']['success_tol5'])} | {_fmt(s['success_sum5'])} "
                     f"| {_fmt(s['success_sum3'])} | {_fmt(e.get('mean'), 2)} | {_fmt(e.get('std'), 2)} | "
                     f"{paper[0] if paper else '–'} | {paper[2] if paper else '–'} |")
    lines += ["", "## Table 2 analogue: KNN on SPM's vectors, ±5° tolerance", "",
              "| Class | K=1 % | σ | K=3 % | σ | Paper K=1 % | Paper K=3 % |", "|---|---|---|---|---|---|---|"]
    for c, row in classes.items():
        k1, k3, paper = row["knn1"], row["knn3"], PAPER_TABLE2.get(c)
        lines.append(f"| {c} | {_fmt(k1['success_tol5'])} | {_fmt(k1['std']['success_tol5'])} | {_fmt(k3['success_tol5'])} "
                     f"| {_fmt(k3['std']['success_tol5'])} | {paper[0] if paper else '–'} | {paper[2] if paper else '–'} |")
    return lines


def _method_tables(summary: dict, names: list) -> list:
    """Every method over all test frames: the paper's criteria, per-DoF errors, BOP surface errors."""
    lines = []
    lines += ["", "## Every method, all test frames", "",
              "| Method | Estimated | ±5° % | σ | sum<5° % | sum<3° % | AUC 45° | Geodesic median ° | p90 ° "
              "| Azimuth ° | Az. mod 180 ° | Elevation ° | Roll ° | Distance mm |", "|---|" + "---|" * 14]
    for m in names:
        s = summary["methods"].get(m) or summary["chance"]
        d = s["median_error"]
        lines.append(f"| {_name(m)} | {s['estimated']}/{s['frames']} | {_fmt(s['success_tol5'])} | "
                     f"{_fmt(s['std']['success_tol5'])} | {_fmt(s['success_sum5'])} | {_fmt(s['success_sum3'])} | "
                     f"{_fmt(s['auc_45'])} | {_fmt(s['geodesic_median_deg'])} | {_fmt(s['geodesic_p90_deg'])} | "
                     f"{_fmt(d['azimuth_deg'])} | {_fmt(d['azimuth_mod180_deg'])} | {_fmt(d['elevation_deg'])} | "
                     f"{_fmt(d['roll_deg'])} | {_fmt(d['distance_mm'])} |")
    lines += ["", "Per DoF: median absolute errors (spm_data/core/poses.py's viewing angles and distance).", "",
              "## Surface errors (BOP), where the mesh is known", "",
              "| Method | Frames | ADD(-S) <10% d % | ADD <10% d % | ADD-S <10% d % | AR MSSD % | AR MSPD % "
              "| MSSD median mm | MSPD median px |", "|---|---|---|---|---|---|---|---|---|"]
    for m in names:
        s = summary["methods"].get(m) or summary["chance"]
        lines.append(f"| {_name(m)} | {_surface_cell(s, 'frames', 0)} | {_surface_cell(s, 'add_s_recall')} | "
                     f"{_surface_cell(s, 'add_recall')} | {_surface_cell(s, 'adds_recall')} | {_surface_cell(s, 'ar_mssd')} "
                     f"| {_surface_cell(s, 'ar_mspd')} | {_surface_cell(s, 'mssd_median_mm')} | "
                     f"{_surface_cell(s, 'mspd_median_px')} |")
    return lines


def _class_and_occlusion_tables(summary: dict, names: list) -> list:
    classes = summary["classes"]
    lines = []
    lines += ["", "## Per class, ±5° % (geodesic median °)", "",
              "| Class | " + " | ".join(_name(m) for m in names) + " |", "|---|" + "---|" * len(names)]
    for c, row in classes.items():
        lines.append(f"| {c} | " + " | ".join(f"{_fmt(row[m]['success_tol5'])} ({_fmt(row[m]['geodesic_median_deg'], 0)})"
                                               for m in names) + " |")
    lines += ["", "## Fig. 5 analogue: success (sum < 5°) against occlusion", "",
              "| Occlusion | Frames | " + " | ".join(_name(m) for m in names) + " |", "|---|---|" + "---|" * len(names)]
    for b, row in enumerate(summary["occlusion"][names[0]]):
        if row["frames"]:
            cells = " | ".join(_fmt(summary["occlusion"][m][b]["success_sum5"]) for m in names)
            lines.append(f"| {row['low']:.0%}–{row['high']:.0%} | {row['frames']} | {cells} |")
    return lines


def _axes():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=(6, 4), dpi=100)


def _finish(fig, ax, path, xlabel: str, ylabel: str) -> Path:
    """Label, grid, legend, then write ``path`` atomically and free the figure."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    try:
        with atomic_file(path, path.with_name(f".{path.name}.partial.png")) as tmp:  # savefig wants the suffix
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return path


def plot_accuracy(summary: dict, path) -> Path:
    curve = summary["accuracy_curve"]
    fig, ax = _axes()
    for m in [*summary["methods"], *(["chance"] if summary["chance"] else [])]:
        s = summary["methods"].get(m) or summary["chance"]
        if curve[m] is None:  # no frame with all three angles measured (e.g. COIL-100)
            continue
        ax.plot(curve["thresholds_deg"], curve[m], label=f"{_name(m)} (AUC {_fmt(s['auc_45'])})",
                linestyle="--" if m == "chance" else "-")
    ax.set_xlim(0, curve["thresholds_deg"][-1])
    return _finish(fig, ax, path, "geodesic rotation error threshold (°)", "frames within threshold (%)")


def plot_occlusion(summary: dict, path) -> Path:
    fig, ax = _axes()
    for m, rows in summary["occlusion"].items():
        rows = [r for r in rows if r["frames"] and r["success_sum5"] is not None]
        ax.plot([50 * (r["low"] + r["high"]) for r in rows], [r["success_sum5"] for r in rows], marker="o",
                label=_name(m))
    return _finish(fig, ax, path, "occlusion of the object (%)", "success rate (%), rotation error sum < 5°")


def check_report_folder(out_dir) -> Path:
    """``out_dir`` as a Path when it is a folder this process can write in, or can be made as
    one; else a one-line SpmError. Creates nothing: for checking before any work is done."""
    out = Path(out_dir)
    problem = unwritable(out)
    if problem and problem[1] == "file":
        got = "is a file" if problem[0] == out else f"cannot be made: {problem[0]} is a file"
        raise SpmError(f"report folder {out} {got}; give a folder with --report")
    if problem:
        raise SpmError(f"report folder {out} cannot be written: {problem[0]} is read-only; give a writable folder "
                       "with --report")
    return out


def write_error(out_dir, exc: OSError) -> SpmError:
    """The one-line error for an OSError met while writing the report in ``out_dir``."""
    return SpmError(f"could not write the report in {out_dir}: {exc.strerror or exc}; free space there or give "
                    "another folder with --report")


def write_report(evaluation: dict, context: dict, out_dir) -> dict:
    """results.json, results.md, accuracy.png and occlusion.png in ``out_dir``; returns the summary.
    Each file is written whole or not at all; SpmError when one cannot be written."""
    out = Path(out_dir)
    summary = aggregate(evaluation)
    try:
        out.mkdir(parents=True, exist_ok=True)
        plot_accuracy(summary, out / "accuracy.png")
        plot_occlusion(summary, out / "occlusion.png")
        with atomic_file(out / "results.md") as tmp:
            tmp.write_text(markdown(evaluation, summary, context))
        write_json_atomic(out / "results.json", {"schema": SCHEMA, "schema_version": SCHEMA_VERSION,
                                                 "context": context, "summary": summary, "evaluation": evaluation})
    except OSError as exc:
        raise write_error(out, exc) from None
    return summary


def summary_text(summary: dict) -> str:
    """The plain summary and every method's headline figures, for the terminal."""
    lines = [line.replace("**", "") for line in plain_summary(summary)]
    lines.append(f"{'method':<32}{'±5° %':>8}{'sum<5 %':>9}{'geo med':>9}{'AUC45':>7}{'elev °':>8}{'dist mm':>9}")
    for m in [*summary["methods"], *(["chance"] if summary["chance"] else [])]:
        s = summary["methods"].get(m) or summary["chance"]
        lines.append(f"{_name(m):<32}{_fmt(s['success_tol5']):>8}{_fmt(s['success_sum5']):>9}"
                     f"{_fmt(s['geodesic_median_deg']):>9}{_fmt(s['auc_45']):>7}"
                     f"{_fmt(s['median_error']['elevation_deg']):>8}{_fmt(s['median_error']['distance_mm']):>9}")
    return "\n".join(lines)
