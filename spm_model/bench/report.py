"""Reports of an evaluation: results.json (schema: docs/results-schema.md, keys in its
order), results.md (bench/report_tables.py), accuracy.png (accuracy against geodesic
threshold) and occlusion.png (success against occlusion: the paper's Fig. 5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_data.errors import SpmError
from spm_data.io.outputs import unwritable
from spm_data.io.files import atomic_file, write_json_atomic
from spm_model.bench.headline import best_method
from spm_model.bench.metrics import CURVE_THRESHOLDS, refresh_intervals
from spm_model.bench.report_tables import FEW_FRAMES, fmt, markdown, name, summary_text

__all__ = ["SCHEMA", "SCHEMA_VERSION", "aggregate", "check_report_folder", "markdown", "summary_text",
           "write_error", "write_report"]

SCHEMA = "spm-results"
SCHEMA_VERSION = 5
COUNTS = ("frames", "estimated", "low", "high")


def _mean_tree(items: list):
    """Mean over runs of every number in a list of same-shaped dicts (None where all are None)."""
    first = next((i for i in items if i is not None), None)
    if isinstance(first, dict):
        return {k: _mean_tree([i.get(k) if i else None for i in items]) for k in first}
    values = [v for v in items if v is not None]
    return float(np.mean(values)) if values else None


def _std_tree(items: list):
    """σ over runs of every number (None with fewer than two runs that have it)."""
    first = next((i for i in items if i is not None), None)
    if isinstance(first, dict):
        return {k: _std_tree([i.get(k) if i else None for i in items]) for k in first
                if k not in COUNTS and k != "ci95"}
    values = [v for v in items if v is not None]
    return float(np.std(values)) if len(values) > 1 else None


def _mean_rows(per_run: list) -> list:
    """Occlusion bins of several runs -> one list: counts of the first run, means of the rest, the
    intervals at the mean rates and ``std`` (σ over runs of each rate; None with one run)."""
    return [refresh_intervals({**{k: row[k] for k in COUNTS if k in row},
                               **_mean_tree([{k: v for k, v in r[b].items() if k not in COUNTS} for r in per_run]),
                               "std": _std_tree([{k: v for k, v in r[b].items() if k not in COUNTS}
                                                 for r in per_run])})
            for b, row in enumerate(per_run[0])]


def _summary(per_run: list) -> dict:
    out = _mean_tree(per_run)
    for k in ("frames", "estimated", "featured"):
        if k in per_run[0]:
            out[k] = per_run[0][k]
    out["std"] = _std_tree([{k: v for k, v in r.items() if k != "featured"} for r in per_run])
    return refresh_intervals(out)


def declined(evaluation: dict) -> dict:
    """{method: {"reason": its first reason, "splits": splits it declined, "of": every split of
    every run}} for each method that declined anywhere (spm_model/bench/protocols.py)."""
    total = sum(len(r.get("splits", ())) for r in evaluation["runs"])
    out = {}
    for r in evaluation["runs"]:
        for m, where in r.get("declined", {}).items():
            entry = out.setdefault(m, {"reason": next(iter(where.values())), "splits": 0, "of": total})
            entry["splits"] += len(where)
    return {m: out[m] for m in evaluation["methods"] if m in out}


def declined_everywhere(evaluation: dict) -> dict:
    """{method: reason} of the methods that declined in every split of every run: no figures."""
    return {m: d["reason"] for m, d in declined(evaluation).items() if d["splits"] == d["of"]}


def aggregate(evaluation: dict) -> dict:
    """The ``summary`` of results.json: means over runs with σ (docs/results-schema.md); the
    methods that declined everywhere have no figures, only their entry in ``declined``."""
    runs = evaluation["runs"]
    gone = declined_everywhere(evaluation)
    names = [m for m in evaluation["methods"] if m not in gone]
    overall = {m: _summary([r["overall"][m] for r in runs]) for m in names}
    classes = {}
    for c in evaluation["classes"]:
        per_run = [r["classes"][c] for r in runs if c in r["classes"]]
        if per_run:
            classes[c] = {m: _summary([p[m] for p in per_run]) for m in names}
    occlusion = {m: _mean_rows([r["occlusion"][m] for r in runs]) for m in names}
    curve = {"thresholds_deg": CURVE_THRESHOLDS.tolist(),
             **{m: (np.mean([r["accuracy_curve"][m] for r in runs], axis=0).tolist()
                    if all(r["accuracy_curve"][m] is not None for r in runs) else None) for m in names}}
    out = {"protocol": evaluation["protocol"], "runs": len(runs),
           "methods": {m: overall[m] for m in names if m != "chance"}, "chance": overall.get("chance"), "best": None,
           "declined": declined(evaluation), "classes": classes, "occlusion": occlusion, "accuracy_curve": curve}
    out["best"] = best_method(out)
    if "fig5" in runs[0]:
        out["fig5"] = {g: {k: {m: _mean_rows([r["fig5"][g][k][m] for r in runs]) for m in names}
                           for k in kinds} for g, kinds in runs[0]["fig5"].items()}
        out["instances"] = {g: {m: _summary([r["instances"][g][m] for r in runs]) for m in names}
                            for g in runs[0]["instances"]}
    return out


def _axes(width: float = 6.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=(width, 4), dpi=100)


def _finish(fig, ax, path, xlabel: str, ylabel: str, legend_outside: bool = False) -> Path:
    """Label, grid, legend, then write ``path`` atomically and free the figure."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    if not ax.get_legend_handles_labels()[1]:  # nothing drawn: say why instead of an empty legend
        ax.text(0.5, 0.5, "no frame measures this (e.g. one angle only, as COIL)", ha="center", va="center",
                transform=ax.transAxes, fontsize=9, color="0.4")
    elif legend_outside:  # beside the curves, which fill the whole plot
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    else:
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
        ax.plot(curve["thresholds_deg"], curve[m], label=f"{name(m)} (AUC {fmt(s['auc_45'])})",
                linestyle="--" if m == "chance" else "-")
    ax.set_xlim(0, curve["thresholds_deg"][-1])
    return _finish(fig, ax, path, "geodesic rotation error threshold (°)", "frames within threshold (%)")


def plot_occlusion(summary: dict, path) -> Path:
    """Success (sum < 5°, solid, with its 95% Wilson interval as a bar; sum < 3°, dotted) against occlusion:
    with offgrid, the seen instances' rectangle curves (the paper's Fig. 5), else every test
    frame's. Each bin's frame count is printed over it; bins under FEW_FRAMES frames are hollow
    markers; methods are offset a little along x so that equal curves (several at 0) stay visible."""
    fig5 = (summary.get("fig5") or {}).get("seen") or (summary.get("fig5") or {}).get("all") or {}
    curves = fig5.get("rectangles") or fig5.get("all") or summary["occlusion"]
    fig, ax = _axes(8.5 if fig5 else 6.0)
    spread = 4.0 / max(len(curves), 1)  # % of occlusion between neighbouring methods' markers (a bin is 10)
    for i, (m, rows) in enumerate(curves.items()):
        rows = [r for r in rows if r["frames"] and r["success_sum5"] is not None]
        x = np.array([50 * (r["low"] + r["high"]) for r in rows]) + spread * (i - (len(curves) - 1) / 2)
        y = [r["success_sum5"] for r in rows]
        line, = ax.plot(x, y, label=name(m), linestyle="--" if m == "chance" else "-", zorder=3)
        colour = line.get_color()
        band = [(r.get("ci95") or {}).get("success_sum5") for r in rows]
        if rows and all(band):  # a bar per bin, not a filled band: nine methods' bands would hide each other
            low, high = np.array([b["low"] for b in band]), np.array([b["high"] for b in band])
            ax.errorbar(x, y, yerr=np.maximum(0.0, [np.array(y) - low, high - np.array(y)]),  # float noise at 0 and 100
                        fmt="none", ecolor=colour, elinewidth=0.8, alpha=0.45, zorder=2)
        few = np.array([r["frames"] < FEW_FRAMES for r in rows], bool)
        ax.scatter(x[~few], np.array(y)[~few], color=colour, s=18, zorder=4)
        ax.scatter(x[few], np.array(y)[few], facecolors="white", edgecolors=colour, s=18, zorder=4)
        if fig5:
            ax.plot(x, [r["success_sum3"] for r in rows], linestyle=":", color=colour)
    first = next(iter(curves.values()), [])
    for r in first:
        if r["frames"]:
            ax.annotate(f"n={r['frames']}", (50 * (r["low"] + r["high"]), 101), ha="center", va="bottom",
                        fontsize=6, color="0.3", annotation_clip=False)
    title = ("Fig. 5: seen instances, rectangles; solid sum < 5° (bars: 95% interval), dotted sum < 3°" if fig5
             else "bars: 95% interval")
    ax.set_title(title + f"; hollow: under {FEW_FRAMES} frames", fontsize=8, pad=14)
    return _finish(fig, ax, path, "occlusion of the object (%)", "success rate (%)" if fig5 else
                   "success rate (%), rotation error sum < 5°", legend_outside=bool(fig5))


def check_report_folder(out_dir) -> Path:
    """``out_dir`` as a Path when it is a folder this process can write in, or can be made as
    one; else a one-line SpmError. Creates nothing: for checking before any work is done."""
    out = Path(out_dir)
    problem = unwritable(out)
    if problem and problem[1] == "file":
        got = "is a file" if problem[0] == out else f"cannot be made: {problem[0]} is a file"
        raise SpmError(f"report folder {out} {got}; give a folder with --out")
    if problem:
        raise SpmError(f"report folder {out} cannot be written: {problem[0]} is read-only; give a writable folder "
                       "with --out")
    return out


def write_error(out_dir, exc: OSError) -> SpmError:
    """The one-line error for an OSError met while writing the report in ``out_dir``."""
    return SpmError(f"could not write the report in {out_dir}: {exc.strerror or exc}; free space there or give "
                    "another folder with --out")


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
                                                 "context": context, "summary": summary, "evaluation": evaluation},
                          sort_keys=False)  # in docs/results-schema.md's order
    except OSError as exc:
        raise write_error(out, exc) from None
    return summary
