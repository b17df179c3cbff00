"""results.md and the terminal summary of an aggregated evaluation (bench/report.py):
a plain summary first, then the paper's Table 1, Table 2 and Fig. 5 analogues and
every method's errors. Every table is GitHub-flavoured markdown whose header and
delimiter rows come from the same list of cells; the method columns come from
bench/metrics.py's METRICS."""

from __future__ import annotations

from spm_model.bench.headline import coverage_note as _cov, fmt, name, plain_summary
from spm_model.bench.metrics import METRICS, RATES, metric_value
from spm_model.methods.registry import SAVED_MODELS

PAPER_TABLE1 = {"box": (97.2, 0.9, 0.31, 0.09), "car": (95.6, 1.1, 0.44, 0.12), "motorcycle": (92.8, 1.6, 0.61, 0.11),
                "ball": (88.4, 2.5, 0.76, 0.08), "animal4": (87.9, 2.9, 0.84, 0.09), "cup": (86.6, 3.3, 0.87, 0.07)}
PAPER_TABLE2 = {"box": (94.7, 2.6, 94.2, 2.3), "car": (91.5, 3.2, 94.5, 3.0), "motorcycle": (92.0, 1.8, 95.5, 1.1),
                "ball": (86.2, 3.4, 86.1, 2.5), "animal4": (83.3, 3.7, 83.8, 2.9), "cup": (82.6, 3.4, 82.8, 3.2)}
FEW_FRAMES = 20  # a bin with fewer frames is marked: its rate's 95% interval is wider than ±20 points
SURFACE = (("frames", "Frames", 0), ("add_s_recall", "ADD(-S) <10% d %", 1), ("add_recall", "ADD <10% d %", 1),
           ("adds_recall", "ADD-S <10% d %", 1), ("ar_mssd", "AR MSSD %", 1), ("ar_mspd", "AR MSPD %", 1),
           ("mssd_median_mm", "MSSD median mm", 1), ("mspd_median_px", "MSPD median px", 1))
FIG5_CELL = "sum<5° / sum<3° / ±5° %, each [95% interval] (geodesic median °)"
# What a method returns decides which criterion can judge it: said under every table it is in.
OWN_CRITERION = {"smm": ("pose_class_accuracy",
                         "SMM returns the rotation of one training view (the nearest of its voted pose class) and a "
                         "translation scaled from it: ±5° and sum < 5° are met only where a training view lies that "
                         "close to the truth, so its own criterion is the pose class ({} azimuth classes of 45°)")}



def table(header: list, rows: list) -> list:
    """A GFM table: the delimiter row has exactly as many cells as the header."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + \
           ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def rate_cell(entry_: dict, key: str, digits: int = 1) -> str:
    """A success rate with its 95% Wilson interval and, over several runs, σ: "90.4 [88.1–92.3] σ1.2"."""
    value, ci = metric_value(entry_, key), (entry_.get("ci95") or {}).get(key)
    std = (entry_.get("std") or {}).get(key)
    text = fmt(value, digits) + (f" [{ci['low']:.{digits}f}–{ci['high']:.{digits}f}]" if ci and value is not None
                                 else "")
    return text + (f" σ{std:.{digits}f}" if std is not None and value is not None else "")


def own_criterion_lines(summary: dict, names: list) -> list[str]:
    """Under a table: for a method judged by its own criterion too (OWN_CRITERION), why, and that figure."""
    from spm_model.methods.smm import PAPER_BINS

    return [f"{why.format(PAPER_BINS)}: {rate_cell(entry(summary, m), key)} % over all test frames."
            for m, (key, why) in OWN_CRITERION.items() if m in names and m in summary["methods"]]


def entry(summary: dict, m: str) -> dict:
    return summary["methods"].get(m) or summary["chance"]


def markdown(evaluation: dict, summary: dict, context: dict) -> str:
    names = list(summary["methods"]) + (["chance"] if summary["chance"] else [])
    if not names:
        return "\n".join(_intro(summary, context) + [models_sentence(context), ""])
    return "\n".join(_intro(summary, context) + _fig5_tables(summary, names) + _paper_tables(evaluation, summary)
                     + _method_tables(summary, names) + _class_and_occlusion_tables(summary, names) + [
        "", "Plots: `accuracy.png` (accuracy against geodesic threshold), `occlusion.png` (success against "
        f"occlusion). {models_sentence(context)}", ""])


def models_sentence(context: dict) -> str:
    """What the run fitted on every training frame and wrote, and what it could not fit."""
    models = context.get("models")
    if models is None:
        return ""
    rows = SAVED_MODELS   # read when the report is written: every row with a model file
    written = [f"`{rows[k].model_file}` ({rows[k].model_title})" for k, v in models.items() if v == "written"]
    missing = [f"{rows[k].model_title} declined ({v['declined']})" for k, v in models.items() if v != "written"]
    text = ("Models trained on every training frame: " + " and ".join(written) + "." if written
            else "No model was written.")
    cost = context.get("training", {}).get("cnn")
    if cost:   # what the learned model cost (each split's fit has the same budget)
        text += (f" The CNN trained in {cost['seconds']:.1f} s ({cost['steps']} steps, {cost['epochs']:g} epochs "
                 f"of {cost['frames']} frames, on {cost['device']}).")
    return text + (" " + "; ".join(missing) + "." if missing else "")


def _intro(summary: dict, context: dict) -> list:
    runs = summary["runs"]
    test = f", tested on the frames under `{context['test']}`" if context.get("test") else ""
    return [f"# Pose benchmark ({summary['protocol']} protocol, {runs} run{'s' if runs != 1 else ''})", "",
            *plain_summary(summary), "",
            f"Command: `{context.get('command', '')}`", "",
            f"Data: {context.get('frames', '?')} frames under `{context.get('shards', '')}`{test}; of those, "
            f"{context.get('train_features', '?')} have SPM's training feature (the frames the final SPM model "
            f"trained on) and {context.get('query_features', '?')} its query feature "
            f"({context.get('without_path_neighbour', 0)} frames had no path neighbour for the training rule). "
            "Methods see test frames as a camera gives them: image, visible mask and K, in a seeded random order. "
            "Criteria (the paper's): **±5° tolerance** (Table 2), every rotation angle within 5°, inclusive; "
            "**sum < 5° (3°)** (Fig. 5), the summed absolute angle errors below 5° (3°); *sym.*: the same up to "
            "the object's declared symmetries. A frame without an estimate fails. Every success rate is shown as "
            "% [its 95% Wilson interval over the frames it counts] and, over several runs, σ over runs. "
            "Schema of results.json: docs/results-schema.md.", "", *_unit_line(context)]


def _unit_line(context: dict) -> list:
    """A line when the data's lengths are not metres (a capture imported without --scale)."""
    if context.get("length_unit", "m") == "m":
        return []
    return ["**Lengths**: the shards hold the capture's world units (imported without `--scale`), so every "
            "\"mm\" below is a thousandth of that unit, not a millimetre.", ""]


def _fig5_tables(summary: dict, names: list) -> list:
    """Offgrid only: the paper's Fig. 5 per instance group and occluder, every method."""
    fig5 = summary.get("fig5")
    if not fig5:
        return []
    lines = ["## Fig. 5, our reading of it: success against occlusion, views off the training grid", "",
             f"Each cell: {FIG5_CELL}. *seen*: test views of training instances at random poses; *unseen*: "
             "instances of seen classes that never trained. Bins: the fraction of the object hidden.", ""]
    titles = {"seen": "seen instances", "unseen": "unseen instances", "all": "every test frame"}
    for group, kinds in fig5.items():
        for kind, curves in kinds.items():
            if kind == "all" and len(kinds) > 1:
                continue  # the per-occluder tables say it all
            occluder = {"all": "any occluder", "rectangles": "rectangles (spm-data occlude)",
                        "distractors": "3-D distractors"}.get(kind, kind)
            rows = []
            for b, row in enumerate(curves[names[0]]):
                if row["frames"]:
                    rows.append([f"{row['low']:.0%}–{row['high']:.0%}", row["frames"]] + [
                        _fig5_cell(curves[m][b]) for m in names])
            lines += [f"### {titles.get(group, group)}, {occluder}", ""]
            lines += table(["Occlusion", "Frames"] + [name(m) for m in names], rows) + [""]
    groups = summary.get("instances") or {}
    if groups:
        rows = [[titles.get(g, g), name(m), entry_["frames"]] + [rate_cell(entry_, k) for k in (
                    "coverage", "success_sum5", "success_sum3", "success_tol5", "success_tol5_sym",
                    "geodesic_median_deg", "translation_axis_median_mm.x", "translation_axis_median_mm.y",
                    "translation_axis_median_mm.z")]
                for g, methods in groups.items() for m, entry_ in methods.items() if m in names]
        lines += ["### Every occlusion level together", ""]
        lines += table(["Instances", "Method", "Frames", "Coverage %", "sum<5° %", "sum<3° %", "±5° %", "±5° sym. %",
                        "Geodesic median °", "tx mm", "ty mm", "tz mm"], rows) + ["", *own_criterion_lines(summary,
                                                                                                           names)]
    return lines


def _fig5_cell(row: dict) -> str:
    return (f"{rate_cell(row, 'success_sum5', 0)} / {rate_cell(row, 'success_sum3', 0)} / "
            f"{rate_cell(row, 'success_tol5', 0)} ({fmt(row.get('geodesic_median_deg'))}){_cov(row)}")


def _paper_tables(evaluation: dict, summary: dict) -> list:
    """The analogues of the paper's Tables 1 and 2, per class, with the paper's numbers beside ours."""
    ecc, classes = evaluation["eccentricity"], summary["classes"]
    rows = []
    for c, row in classes.items():
        if "spm" not in row:
            continue
        s, e, paper = row["spm"], ecc.get(c, {}), PAPER_TABLE1.get(c)
        rows.append([c, s["frames"], rate_cell(s, "success_tol5") + _cov(s), rate_cell(s, "success_sum5"),
                     rate_cell(s, "success_sum3"), fmt(e.get("mean"), 2), fmt(e.get("std"), 2),
                     paper[0] if paper else "–", paper[2] if paper else "–"])
    lines = []
    if rows:
        lines += ["## Table 1 analogue: SPM", "",
                  "The paper's Table 1 counts successful grasps; its pose criterion is Table 2's ±5°, used here.", ""]
        lines += table(*_paper_columns_kept(["Class", "Frames", "±5° %", "sum<5° %", "sum<3° %",
                                             "Mean eccentricity", "σ", "Paper success %", "Paper ecc."], rows))
    rows = []
    for c, row in classes.items():
        if "knn1" in row and "knn3" in row:
            k1, k3, paper = row["knn1"], row["knn3"], PAPER_TABLE2.get(c)
            rows.append([c, k1["frames"], rate_cell(k1, "success_tol5") + _cov(k1),
                         rate_cell(k3, "success_tol5") + _cov(k3), paper[0] if paper else "–",
                         paper[2] if paper else "–"])
    if rows:
        lines += ["", "## Table 2 analogue: KNN on SPM's vectors, ±5° tolerance", ""]
        lines += table(*_paper_columns_kept(["Class", "Frames", "K=1 %", "K=3 %", "Paper K=1 %", "Paper K=3 %"], rows))
    return lines


def _paper_columns_kept(header: list, rows: list) -> tuple[list, list]:
    """(header, rows) without the "Paper ..." columns when no row's class is one of the paper's
    (a capture, COIL objects): columns of "–" alone say nothing."""
    empty = [i for i, h in enumerate(header) if h.startswith("Paper") and all(r[i] == "–" for r in rows)]
    return ([h for i, h in enumerate(header) if i not in empty],
            [[c for i, c in enumerate(r) if i not in empty] for r in rows])


def _method_tables(summary: dict, names: list) -> list:
    """Every method over all test frames: every METRICS column (σ after ±5°), then BOP surface errors."""
    header = ["Method", "Estimated", "Features"] + [k.header for k in METRICS]
    rows = []
    for m in names:
        s = entry(summary, m)
        featured = s.get("featured")
        row = [name(m), f"{s['estimated']}/{s['frames']}", "–" if featured is None else f"{featured}/{s['frames']}"]
        rows.append(row + [rate_cell(s, k.key, k.digits) if k.key in RATES else fmt(metric_value(s, k.key), k.digits)
                           for k in METRICS])
    lines = ["", "## Every method, all test frames", ""] + table(header, rows)
    lines += ["", "Estimated: test frames the method gave an estimate for; Features: test frames it found its "
              "features on (SIFT keypoints, SPM's ellipse; – where the method does not say). Every success rate "
              "counts a frame without an estimate as a failure; medians are over the frames with one (Coverage "
              "says how many that is).", *own_criterion_lines(summary, names), "",
              "Per DoF: median absolute errors (spm_data/core/poses.py's viewing angles and distance); "
              "tx, ty, tz: along the camera's axes (the paper's Figs. 6–7)."]
    if not any(entry(summary, m).get("surface") for m in names):
        return lines   # no test frame's mesh is known (imported photos): no table of dashes
    rows = [[name(m)] + [fmt((entry(summary, m).get("surface") or {}).get(k), d) for k, _, d in SURFACE]
            for m in names]
    header = ["Method"] + [h for _, h, _ in SURFACE]
    return lines + ["", "## Surface errors (BOP), where the mesh is known", ""] + table(header, rows)


def _class_and_occlusion_tables(summary: dict, names: list) -> list:
    rows = [[c, row[names[0]]["frames"]]
            + [f"{rate_cell(row[m], 'success_tol5')} ({fmt(row[m]['geodesic_median_deg'], 0)}){_cov(row[m])}"
               for m in names]
            for c, row in summary["classes"].items()]
    lines = ["", "## Per class, ±5° % [95% interval] (geodesic median °; where not every frame got an estimate, "
             "the share that did)", ""] + table(["Class", "Frames"] + [name(m) for m in names], rows)
    rows = [[f"{row['low']:.0%}–{row['high']:.0%}", row["frames"]]
            + [rate_cell(summary["occlusion"][m][b], "success_sum5") + _cov(summary["occlusion"][m][b])
               for m in names]
            for b, row in enumerate(summary["occlusion"][names[0]]) if row["frames"]]
    lines += ["", "## Success (sum < 5°, % [95% interval]) against occlusion, every test frame", ""]
    return lines + table(["Occlusion", "Frames"] + [name(m) for m in names], rows)


def summary_text(summary: dict) -> str:
    """The plain summary and every method's headline figures (METRICS with a terminal
    column), for the terminal; with offgrid, one Fig. 5 line per method."""
    shown = [m for m in METRICS if m.terminal]
    lines = [line.replace("**", "") for line in plain_summary(summary)]
    if not summary["methods"] and not summary["chance"]:
        return "\n".join(lines)
    names = [*summary["methods"], *(["chance"] if summary["chance"] else [])]
    width = max(32, *(len(name(m)) + 1 for m in names))   # every row in line, however long a name
    lines.append(f"{'method':<{width}}" + "".join(f"{m.terminal:>9}" for m in shown))
    for m in names:
        s = entry(summary, m)
        lines.append(f"{name(m):<{width}}" + "".join(f"{fmt(metric_value(s, k.key), k.digits):>9}" for k in shown))
    fig5 = (summary.get("fig5") or {}).get("seen") or (summary.get("fig5") or {}).get("all")
    if fig5:
        curves = fig5.get("rectangles") or fig5.get("all")
        shown_rows = [r for r in next(iter(curves.values())) if r["frames"]]
        lines.append("Fig. 5 (sum < 5° %, bins " + ", ".join(f"{r['low']:.0%} (n={r['frames']}"
                                                            f"{'*' if r['frames'] < FEW_FRAMES else ''})"
                                                            for r in shown_rows) + " occluded; "
                     f"* under {FEW_FRAMES} frames: read as a hint; intervals in results.md):")
        width = max(len(name(m)) for m in curves) + 1
        for m, rows in curves.items():
            est, frames = sum(r.get("estimated", r["frames"]) for r in rows), sum(r["frames"] for r in rows)
            lines.append(f"  {name(m):<{width}}"
                         + " ".join(f"{fmt(r['success_sum5'], 0):>4}" for r in rows if r["frames"])
                         + (f"  ({100 * est / frames:.0f}% estimated)" if frames and est < frames else ""))
    return "\n".join(lines)


SCHEMA_BEGIN = ("<!-- metrics: made from spm_model/bench/metrics.py METRICS by "
                "`python -m spm_model.bench.report_tables` -->")
SCHEMA_END = "<!-- end of metrics -->"


ENTRY_FIRST = (
    "| `frames` | frames scored (with at least one measured angle), in the first run (the `views` split draws a "
    "new test set each run) |",
    "| `estimated` | of those, frames the method gave an estimate for (a missing estimate fails every criterion), "
    "first run; an estimate may leave unmeasured components NaN |",
)
ENTRY_LAST = (
    "| `surface` | `null` when no test frame's mesh is known; else {`frames`, `add_recall`, `adds_recall`, "
    "`add_s_recall` (ADD for asymmetric objects, ADD-S for objects with a symmetry), each the % below 10% of the "
    "object's diameter; `ar_mssd`, `ar_mspd` (the BOP challenge's average recalls: MSSD thresholds 5–50% of the "
    "diameter, MSPD thresholds 5–50 px × width/640); `add_median_mm`, `adds_median_mm`, `mssd_median_mm`, "
    "`mspd_median_px`} (spm_model/bench/surface_metrics.py) |",
    "| `ci95` | {rate key: {`low`, `high`, `n`}} for `success_tol5`, `success_sum5`, `success_sum3`, "
    "`success_tol5_sym` and `pose_class_accuracy` where they have a value: the 95% Wilson score interval (%) over "
    "the `n` frames the rate counts; over several runs, the interval at the mean rate over one run's frames (runs "
    "share most frames, so pooling them would claim too much) |",
    "| `std` | σ over runs of the keys above (`null` with fewer than two runs) |",
)


def schema_rows() -> list:
    """docs/results-schema.md's table of a summary entry: counts, one row per METRICS entry
    (its key and meaning), ``surface`` and ``std``."""
    rows = [*ENTRY_FIRST, *(f"| `{m.key}` | {m.meaning} |" for m in METRICS), *ENTRY_LAST]
    return ["| key | meaning |", "|---|---|", *rows]


def update_schema_doc(path) -> bool:
    """Rewrite the METRICS rows between the markers of ``path``; whether anything changed."""
    from pathlib import Path

    path = Path(path)
    text = path.read_text()
    head, rest = text.split(SCHEMA_BEGIN + "\n", 1)
    _, tail = rest.split(SCHEMA_END, 1)
    new = head + SCHEMA_BEGIN + "\n" + "\n".join(schema_rows()) + "\n" + SCHEMA_END + tail
    if new != text:
        path.write_text(new)
    return new != text


if __name__ == "__main__":
    import sys

    changed = update_schema_doc(sys.argv[1] if len(sys.argv) > 1 else "docs/results-schema.md")
    print("docs/results-schema.md updated" if changed else "docs/results-schema.md is up to date")
