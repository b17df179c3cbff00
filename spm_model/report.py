"""Reports of an evaluation: results.json, results.md (the paper's Table 1 and
Table 2 analogues, errors of every method) and the success-against-occlusion plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spm_data.shards import atomic_file, write_json_atomic

METHOD_NAMES = {"spm": "SPM", "knn1": "KNN K=1", "knn3": "KNN K=3", "pca": "PCA-based", "ls": "LS-based"}
PAPER_TABLE1 = {"box": (97.2, 0.9, 0.31, 0.09), "car": (95.6, 1.1, 0.44, 0.12), "motorcycle": (92.8, 1.6, 0.61, 0.11),
                "ball": (88.4, 2.5, 0.76, 0.08), "animal4": (87.9, 2.9, 0.84, 0.09), "cup": (86.6, 3.3, 0.87, 0.07)}
PAPER_TABLE2 = {"box": (94.7, 2.6, 94.2, 2.3), "car": (91.5, 3.2, 94.5, 3.0), "motorcycle": (92.0, 1.8, 95.5, 1.1),
                "ball": (86.2, 3.4, 86.1, 2.5), "animal4": (83.3, 3.7, 83.8, 2.9), "cup": (82.6, 3.4, 82.8, 3.2)}


def _mean_std(values):
    values = [v for v in values if v is not None]
    return (float(np.mean(values)), float(np.std(values))) if values else (None, None)


def aggregate(evaluation: dict) -> dict:
    """Per class (and "all") and method: mean and sigma over runs of each summary figure."""
    runs = evaluation["runs"]
    rows = {}
    for c in [*evaluation["classes"], "all"]:
        per_run = [r["overall"] if c == "all" else r["classes"].get(c) for r in runs]
        per_run = [p for p in per_run if p]
        if not per_run:
            continue
        rows[c] = {m: {key: dict(zip(("mean", "std"), _mean_std([p[m][key] for p in per_run])))
                       for key in per_run[0][m] if key not in ("frames", "estimated")}
                   | {"frames": per_run[0][m]["frames"], "estimated": per_run[0][m]["estimated"]}
                   for m in per_run[0]}
    curve = {}
    for m in METHOD_NAMES:
        curve[m] = []
        for b, row in enumerate(runs[0]["occlusion"][m]):
            mean, std = _mean_std([r["occlusion"][m][b]["success_5"] for r in runs])
            curve[m].append({**{k: row[k] for k in ("low", "high", "frames")}, "success_5": mean, "std": std})
    return {"table": rows, "occlusion": curve}


def _fmt(value, digits=1, scale=1.0):
    return "–" if value is None else f"{value * scale:.{digits}f}"


def markdown(evaluation: dict, summary: dict, context: dict) -> str:
    table, ecc = summary["table"], evaluation["eccentricity"]
    runs = len(evaluation["runs"])
    lines = [f"# SPM results ({evaluation['protocol']} protocol, {runs} run{'s' if runs != 1 else ''})", "",
             f"Command: `{context.get('command', '')}`", "",
             f"Data: {context.get('frames', '?')} frames under `{context.get('shards', '')}`; "
             f"features: {context.get('train_features', '?')} frames with training features, "
             f"{context.get('query_features', '?')} with query features "
             f"({context.get('without_path_neighbour', 0)} frames had no path neighbour for the training rule). Success: the sum of the absolute "
             "rotation-angle errors below 5° (3°); a frame without an estimate fails. σ: over runs.", "",
             "## Table 1 analogue: SPM", "",
             "| Class | Success % (<5°) | σ | Success % (<3°) | σ | Mean eccentricity | σ | Paper success % | Paper ecc. |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c, row in table.items():
        s5, s3 = row["spm"]["success_5"], row["spm"]["success_3"]
        e = ecc.get(c, {})
        paper = PAPER_TABLE1.get(c)
        lines.append(f"| {c} | {_fmt(s5['mean'])} | {_fmt(s5['std'])} | {_fmt(s3['mean'])} | {_fmt(s3['std'])} | "
                     f"{_fmt(e.get('mean'), 2)} | {_fmt(e.get('std'), 2)} | "
                     f"{paper[0] if paper else '–'} | {paper[2] if paper else '–'} |")
    lines += ["", "## Table 2 analogue: KNN on the same features", "",
              "| Class | K=1 % | σ | K=3 % | σ | Paper K=1 % | Paper K=3 % |", "|---|---|---|---|---|---|---|"]
    for c, row in table.items():
        k1, k3 = row["knn1"]["success_5"], row["knn3"]["success_5"]
        paper = PAPER_TABLE2.get(c)
        lines.append(f"| {c} | {_fmt(k1['mean'])} | {_fmt(k1['std'])} | {_fmt(k3['mean'])} | {_fmt(k3['std'])} | "
                     f"{paper[0] if paper else '–'} | {paper[2] if paper else '–'} |")
    lines += ["", "## Every method: success and errors (mean over runs)", "",
              "| Class | Method | Estimated | Success % (<5°) | Success % (<3°) | Geodesic median ° | p90 ° "
              "| Translation median mm | p90 mm |", "|---|---|---|---|---|---|---|---|---|"]
    for c, row in table.items():
        for m, name in METHOD_NAMES.items():
            r = row[m]
            lines.append(f"| {c} | {name} | {r['estimated']}/{r['frames']} | {_fmt(r['success_5']['mean'])} | "
                         f"{_fmt(r['success_3']['mean'])} | {_fmt(r['geodesic_median']['mean'])} | "
                         f"{_fmt(r['geodesic_p90']['mean'])} | {_fmt(r['translation_median']['mean'], 0, 1000)} | "
                         f"{_fmt(r['translation_p90']['mean'], 0, 1000)} |")
    lines += ["", "## Success (<5°) against occlusion (Fig. 5 analogue)", "",
              "| Occlusion | Frames | " + " | ".join(METHOD_NAMES.values()) + " |",
              "|---|---|" + "---|" * len(METHOD_NAMES)]
    for b, row in enumerate(summary["occlusion"]["spm"]):
        if row["frames"]:
            cells = " | ".join(_fmt(summary["occlusion"][m][b]["success_5"]) for m in METHOD_NAMES)
            lines.append(f"| {row['low']:.0%}–{row['high']:.0%} | {row['frames']} | {cells} |")
    lines += ["", "Plot: `occlusion.png`. Model trained on every frame: `model.npz`.", ""]
    return "\n".join(lines)


def plot_occlusion(summary: dict, path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    for m, name in METHOD_NAMES.items():
        rows = [r for r in summary["occlusion"][m] if r["frames"] and r["success_5"] is not None]
        x = [50 * (r["low"] + r["high"]) for r in rows]
        ax.plot(x, [r["success_5"] for r in rows], marker="o", label=name)
    ax.set_xlabel("occlusion of the object (%)")
    ax.set_ylabel("success rate (%), rotation error sum < 5°")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    with atomic_file(path, path.with_name(f".{path.name}.partial.png")) as tmp:  # savefig wants the suffix
        fig.savefig(tmp)
    plt.close(fig)
    return path


def write_report(evaluation: dict, context: dict, out_dir) -> dict:
    """results.json, results.md and occlusion.png in ``out_dir``; returns the aggregate."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = aggregate(evaluation)
    plot_occlusion(summary, out / "occlusion.png")
    text = markdown(evaluation, summary, context)
    with atomic_file(out / "results.md") as tmp:
        tmp.write_text(text)
    write_json_atomic(out / "results.json", {"context": context, "summary": summary, "evaluation": evaluation})
    return summary


def table1_text(evaluation: dict, summary: dict) -> str:
    """The Table 1 analogue as plain text for the terminal."""
    lines = [f"{'class':<12}{'success% <5':>12}{'sigma':>8}{'<3':>8}{'sigma':>8}{'ecc':>7}{'sigma':>7}"]
    for c, row in summary["table"].items():
        s5, s3, e = row["spm"]["success_5"], row["spm"]["success_3"], evaluation["eccentricity"].get(c, {})
        lines.append(f"{c:<12}{_fmt(s5['mean']):>12}{_fmt(s5['std']):>8}{_fmt(s3['mean']):>8}{_fmt(s3['std']):>8}"
                     f"{_fmt(e.get('mean'), 2):>7}{_fmt(e.get('std'), 2):>7}")
    return "\n".join(lines)
