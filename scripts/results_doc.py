"""docs/results.md, rendered from a template and the results.json snapshots it quotes.

Every figure, version, date and frame count in docs/results.md comes from a placeholder of
docs/results/results.md.in filled from a snapshot in docs/results/ (a trimmed copy of one
report's results.json with a ``made`` block: date, machine, command, wall time, feature
version). tests/system/test_results_doc.py renders the template from the committed snapshots
and compares it with docs/results.md byte for byte, and fails on a figure typed by hand.

    python scripts/results_doc.py                  # rewrite docs/results.md
    python scripts/results_doc.py --check          # exit 1, naming the first difference
    python scripts/results_doc.py blocks [--check] # the measure tables of other docs (BLOCK_DOCS)
    python scripts/results_doc.py snapshot views OUT/report-views/results.json \\
        --command "spm train ... --out OUT/report-views" --wall-s 254   # write docs/results/views.json

Placeholders, ``{{...}}`` (SNAP: a snapshot's name, its file docs/results/SNAP.json; PATH: keys
joined by dots, a list index by its number; a PATH whose first key is not a top-level key of
the snapshot is read under ``summary``):

    {{SNAP:PATH[:FMT]}}            the value, formatted by FMT (a Python format spec; ``min``:
                                   seconds as minutes, one decimal); None -> "–"
    {{rate:SNAP:ENTRY[:KEY]}}      "97.5% (95% CI 97.1–97.9, 4,492 frames)": a success rate (KEY,
                                   default success_tol5) of an entry: ENTRY is a method key,
                                   ``chance``, or a PATH under summary (classes.car.template)
    {{best:SNAP}}                  the headline: the method summary.best names, or that none beats
                                   chance beyond both 95% intervals
    {{runs:SNAP}}                  "3 runs" (summary.runs)
    {{name:METHOD}}                a method's display name
    {{range:SNAP:PATH[:FMT]}}      "lo–hi" over a PATH with ``*`` (every key or index there);
    {{min:...}} / {{max:...}}      the smallest / largest of them
    {{count:SNAP:PATH}}            how many keys (or items) the value at PATH has
    {{paper:TABLE:COLUMN[:CLASS]}} the paper's Table 1 or 2 (spm_model/bench/report_tables.py):
                                   one class's figure, or the range over the classes
    {{table:KIND:ARGS}}            a generated table (TABLES below)
    {{measure:NAME:PATH[:FMT]}}    a figure of a measurement that is not a report: the JSON a
                                   benchmark script wrote to docs/results/measures/NAME.json (its
                                   ``summary`` and a ``made`` block; e.g. benchmarks/spm_vector_distance.py)
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import os
import platform
import re
import shutil
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from spm_data.io.files import atomic_file  # noqa: E402
from spm_model.bench.report_tables import PAPER_TABLE1, PAPER_TABLE2  # noqa: E402
from spm_model.methods.registry import METHOD_NAMES  # noqa: E402

SNAPSHOTS = ROOT / "docs" / "results"
TEMPLATE = SNAPSHOTS / "results.md.in"
DOC = ROOT / "docs" / "results.md"
MEASURES = SNAPSHOTS / "measures"
TOP = ("schema", "schema_version", "context", "summary", "evaluation", "made", "bop")
PLACEHOLDER = re.compile(r"\{\{(.+?)\}\}")
DASH = "–"

# ---------------------------------------------------------------------------------------------
# Snapshots: a trimmed results.json (what results.md quotes) and how it was made.

ENTRY_KEYS = ("frames", "estimated", "coverage", "featured", "success_tol5", "success_sum5", "success_sum3",
              "auc_45", "geodesic_median_deg", "pose_class_accuracy", "success_tol5_sym", "geodesic_median_sym_deg",
              "translation_median_mm", "translation_axis_median_mm", "median_error", "surface", "ci95", "std")
CLASS_KEYS = ("frames", "estimated", "success_tol5", "success_sum5", "success_sum3", "geodesic_median_deg", "ci95",
              "std")
INSTANCE_KEYS = ("frames", "estimated", "coverage", "success_tol5", "success_sum5", "success_sum3",
                 "geodesic_median_deg", "translation_median_mm", "pose_class_accuracy", "ci95")
SURFACE_KEYS = ("frames", "add_s_recall", "ar_mssd", "ar_mspd")
STD_KEYS = ("coverage", "success_tol5", "success_sum5", "success_sum3", "auc_45", "geodesic_median_deg")
BIN_KEYS = ("frames", "estimated", "low", "high", "success_tol5", "success_sum5", "success_sum3",
            "geodesic_median_deg", "translation_median_mm", "ci95")
FIG5_CURVES = (("seen", "rectangles"),)


def _round(value):
    """Floats to 4 decimals (the report shows at most 2), recursively."""
    if isinstance(value, float):
        return round(value, 4)
    if isinstance(value, dict):
        return {k: _round(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_round(v) for v in value]
    return value


def _entry(entry: dict | None, keys=ENTRY_KEYS, rates=None) -> dict | None:
    """An entry with ``keys`` only (``rates``: the only rates whose ci95 and std are kept)."""
    if entry is None:
        return None
    out = {k: entry[k] for k in keys if k in entry}
    if rates is not None:
        for k in ("ci95", "std"):
            if isinstance(out.get(k), dict):
                out[k] = {r: out[k][r] for r in rates if r in out[k]}
    if isinstance(out.get("surface"), dict):
        out["surface"] = {k: out["surface"][k] for k in SURFACE_KEYS if k in out["surface"]}
    if isinstance(out.get("std"), dict):
        out["std"] = {k: out["std"][k] for k in STD_KEYS if k in out["std"]}
    return out


def trim(results: dict, made: dict) -> dict:
    """The snapshot of a results.json: schema, context, the summary's figures results.md quotes
    (no accuracy curves or occlusion bins but Fig. 5's seen instances behind rectangles; per class
    and per bin only the rates quoted), the evaluation's eccentricity and per-run ±5° rates, and ``made``."""
    s = results["summary"]
    summary = {"protocol": s["protocol"], "runs": s["runs"],
               "methods": {m: _entry(e) for m, e in s["methods"].items()},
               "chance": _entry(s.get("chance")), "best": s.get("best"), "declined": s.get("declined") or {},
               "classes": {c: {m: _entry(e, CLASS_KEYS, ("success_tol5",)) for m, e in row.items()} for c,
                           row in s["classes"].items()}}
    if s.get("fig5"):
        summary["fig5"] = {}
        for group, kind in FIG5_CURVES:
            curves = (s["fig5"].get(group) or {}).get(kind)
            if curves:
                summary["fig5"].setdefault(group, {})[kind] = {
                    m: [_entry(b, BIN_KEYS, ("success_tol5",
                                             "success_sum5")) for b in rows] for m, rows in curves.items()}
    if s.get("instances"):
        summary["instances"] = {g: {m: _entry(e, INSTANCE_KEYS, ("success_tol5", "pose_class_accuracy"))
                                     for m, e in row.items()} for g, row in s["instances"].items()}
    ev = results.get("evaluation") or {}
    evaluation = {"protocol": ev.get("protocol"), "eccentricity": ev.get("eccentricity") or {},
                  "runs": [{"seed": r.get("seed"),
                            "overall": {m: {"success_tol5": e.get("success_tol5")} for m, e in r["overall"].items()}}
                           for r in ev.get("runs") or []]}
    return _round({"schema": results["schema"], "schema_version": results["schema_version"],
                   "context": results["context"], "summary": summary, "evaluation": evaluation, "made": made})


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _number(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def cpu_seconds() -> float:
    """CPU seconds (user + system, every thread) of this process and its finished children: the
    work a measurement did, which a shared machine's other users slow down less than the wall time."""
    import resource

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def made_block(command: str, wall_s: float, date: str | None = None, note: str | None = None,
               parameters: dict | None = None, before: list | None = None, cpu_s: float | None = None) -> dict:
    """How a snapshot was made: ``parameters`` (the settings of the command it quotes, e.g. the
    image size a benchmark's default gives), ``before`` ([{command, wall_s, date}]: the steps
    that made its input or filled its caches, e.g. the render) and ``cpu_s`` (cpu_seconds) where given."""
    from spm_model.spm.features import FEATURE_VERSION

    made = {"date": date or datetime.date.today().isoformat(), "command": command, "wall_s": round(float(wall_s), 1),
            "machine": {"nproc": os.cpu_count(), "cpu": _cpu_model(),
                        "gpu": "none" if shutil.which("nvidia-smi") is None else "present (not used)"},
            "feature_version": FEATURE_VERSION}
    if parameters:
        made["parameters"] = parameters
    if before:
        made["before"] = before
    if note:
        made["note"] = note
    if cpu_s is not None:
        made["cpu_s"] = round(float(cpu_s), 1)
    return made


def dumps(obj, depth: int = 0, open_levels: int = 4) -> str:
    """JSON with one key per line down to ``open_levels`` deep, each deeper value on one line."""
    if depth >= open_levels or not isinstance(obj, (dict, list)) or not obj:
        return json.dumps(obj, separators=(",", ":"), ensure_ascii=False)
    pad = " " * (depth + 1)
    if isinstance(obj, dict):
        items = [f"{pad}{json.dumps(k, ensure_ascii=False)}:{dumps(v, depth + 1, open_levels)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * depth + "}"
    items = [f"{pad}{dumps(v, depth + 1, open_levels)}" for v in obj]
    return "[\n" + ",\n".join(items) + "\n" + " " * depth + "]"


class InputError(Exception):
    """An input file that is not what the script reads (main prints it as one ``error:`` line)."""


@contextlib.contextmanager
def _input(path, what: str):
    """Any failure reading ``path`` (missing, truncated, not JSON, keys missing) as one InputError."""
    try:
        yield
    except OSError as exc:
        raise InputError(f"{path}: cannot read it ({exc.strerror or exc}); give {what}") from None
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
        detail = f"no {exc}" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
        raise InputError(f"{path}: not {what} ({detail}); give {what}") from None


def write_snapshot(name: str, results_json: Path, command: str, wall_s: float, date: str | None = None,
                   note: str | None = None, folder: Path = SNAPSHOTS, parameters: dict | None = None,
                   before: list | None = None, bop_eval: Path | None = None) -> Path:
    """``bop_eval``: benchmarks/bop_eval.py's JSON for the same run: its per-method AR figures
    become the snapshot's ``bop`` block (bop_toolkit's eval_bop19_pose on the run's export)."""
    path = folder / f"{name}.json"
    with _input(results_json, "a results.json spm train wrote (with its summary)"):
        snap = trim(json.loads(Path(results_json).read_text()),
                    made_block(command, wall_s, date, note, parameters, before))
    if bop_eval is not None:
        with _input(bop_eval, "benchmarks/bop_eval.py's JSON"):
            bop = json.loads(Path(bop_eval).read_text())
            snap["bop"] = {"date": bop["date"][:10], "targets": bop["targets"], "protocol": bop["protocol"],
                           "commands": [c["command"] for c in bop["commands"]], "figures": bop["figures"]}
    folder.mkdir(parents=True, exist_ok=True)   # a new --snapshots folder (train_size.py) is made, not a traceback
    with atomic_file(path) as partial:   # whole or not at all: a killed write leaves the old snapshot
        partial.write_text(dumps(snap) + "\n")
    return path


def load_snapshots(folder: Path = SNAPSHOTS) -> dict:
    return {p.stem: json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))}


def load_measures(folder: Path = MEASURES) -> dict:
    """{NAME: JSON} of docs/results/measures/NAME.json: benchmark scripts' figures ({{measure:...}})."""
    return load_snapshots(folder) if folder.is_dir() else {}


def used_measures(template: str) -> set[str]:
    """The measures a template reads."""
    return {expr.split(":")[1] for expr in PLACEHOLDER.findall(template) if expr.split(":")[0] == "measure"}


# ---------------------------------------------------------------------------------------------
# Values and their formats.

class PlaceholderError(ValueError):
    pass


def _snap(snaps: dict, name: str) -> dict:
    if name not in snaps:
        raise PlaceholderError(f"no snapshot {name!r} (have: {', '.join(sorted(snaps))})")
    return snaps[name]


def _keys(path: str) -> list[str]:
    keys = path.split(".")
    return keys if keys[0] in TOP else ["summary", *keys]


def _step(node, key: str, where: str):
    if isinstance(node, list):
        try:
            return node[int(key)]
        except (ValueError, IndexError):
            raise PlaceholderError(f"{where}: no index {key!r}") from None
    if isinstance(node, dict) and key in node:
        return node[key]
    raise PlaceholderError(f"{where}: no key {key!r}")


def value(snaps: dict, name: str, path: str):
    node = _snap(snaps, name)
    for key in _keys(path):
        node = _step(node, key, f"{name}:{path}")
    return node


def values(snaps: dict, name: str, path: str) -> list:
    """Every value a PATH with ``*`` reaches (None left out)."""
    nodes = [_snap(snaps, name)]
    for key in _keys(path):
        if key == "*":
            nodes = [v for n in nodes for v in (n.values() if isinstance(n, dict) else n)]
        else:
            nodes = [_step(n, key, f"{name}:{path}") for n in nodes]
    return [v for v in nodes if v is not None]


def fmt(v, spec: str = "") -> str:
    if v is None:
        return DASH
    if spec == "min":
        return f"{v / 60:.1f}"
    if isinstance(v, float) and not spec:
        raise PlaceholderError(f"a float ({v}) needs a format")
    return format(v, spec) if spec else str(v)


def name(method: str) -> str:
    return METHOD_NAMES.get(method, method)


def _ci(entry: dict, key: str):
    return (entry.get("ci95") or {}).get(key)


def rate(entry: dict | None, key: str = "success_tol5") -> str:
    """"97.5% (95% CI 97.1–97.9, 4,492 frames)"."""
    v = (entry or {}).get(key)
    if v is None:
        return DASH
    ci = _ci(entry, key)
    if ci is None:
        return f"{v:.1f}%"
    return f"{v:.1f}% (95% CI {ci['low']:.1f}–{ci['high']:.1f}, {_frames_text(ci['n'])})"


def _frames_text(n) -> str:
    return f"{n:,.0f} frame" + ("" if round(n) == 1 else "s")


def _entry_of(snaps: dict, snap: str, ref: str) -> dict:
    if "." in ref:
        return value(snaps, snap, ref)
    if ref == "chance":
        return value(snaps, snap, "summary.chance")
    return value(snaps, snap, f"summary.methods.{ref}")


def _span(vals: list, spec: str) -> str:
    if not vals:
        return DASH
    lo, hi = fmt(min(vals), spec), fmt(max(vals), spec)
    return lo if lo == hi else f"{lo}–{hi}"


PAPER_COLUMNS = {"table1": (PAPER_TABLE1, {"success": (0, ".1f"), "success_std": (1, ".1f"), "ecc": (2, ".2f"),
                                           "ecc_std": (3, ".2f")}),
                 "table2": (PAPER_TABLE2, {"k1": (0, ".1f"), "k1_std": (1, ".1f"), "k3": (2, ".1f"),
                                           "k3_std": (3, ".1f")})}


def paper(table: str, column: str, cls: str | None = None) -> str:
    rows, columns = PAPER_COLUMNS[table]
    i, spec = columns[column]
    if cls:
        return fmt(rows[cls][i], spec)
    return _span([r[i] for r in rows.values()], spec)


def best(snaps: dict, snap: str) -> str:
    s = value(snaps, snap, "summary")
    chance = rate(s.get("chance"))
    if s.get("best"):
        return (f"**{name(s['best'])}** is best, {rate(s['methods'][s['best']])} within ±5°, above chance's "
                f"{chance} beyond both 95% intervals")
    if not s.get("chance"):
        return "no method is called best (chance did not run)"
    return f"**no method beats chance** beyond both 95% intervals (chance {chance} within ±5°)"


# ---------------------------------------------------------------------------------------------
# Tables.

def _table(header: list, rows: list) -> str:
    return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                     + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows])


def _entries(s: dict) -> dict:
    """Methods in report order, then chance."""
    return {**s["methods"], **({"chance": s["chance"]} if s.get("chance") else {})}


def _f(v, digits=1) -> str:
    return DASH if v is None else f"{v:.{digits}f}"


def _ci_cell(entry: dict, key: str = "success_tol5") -> str:
    """"97.5 (97.1–97.9)"."""
    v, ci = entry.get(key), _ci(entry, key)
    if v is None:
        return DASH
    return f"{v:.1f}" if ci is None else f"{v:.1f} ({ci['low']:.1f}–{ci['high']:.1f})"


def _cov(entry: dict) -> str:
    frames, est = entry.get("frames") or 0, entry.get("estimated")
    return "" if est is None or not frames or est >= frames else f" · {100 * est / frames:.0f}% est."


def _bin(row: dict) -> str:
    return f"{row['low'] * 100:.0f}–{row['high'] * 100:.0f}%"


def table_fig5_bins(snaps, snap, curve):
    """Success per occlusion bin: sum<5 / sum<3 / ±5 %; frames per bin in the header."""
    group, kind = curve.split(".")
    curves = value(snaps, snap, f"summary.fig5.{group}.{kind}")
    first = next(iter(curves.values()))
    bins = [i for i, r in enumerate(first) if r["frames"]]
    header = ["method"] + [f"{_bin(first[i])} ({first[i]['frames']:,})" for i in bins]
    rows = [[name(m)] + ["/".join(_f(r[i][k], 0) for k in ("success_sum5", "success_sum3", "success_tol5"))
                         for i in bins] for m, r in curves.items()]
    return _table(header, rows)


def table_fig5_overall(snaps, snap):
    """Every occlusion level together, seen and unseen instances."""
    inst = value(snaps, snap, "summary.instances")
    seen, unseen = inst["seen"], inst.get("unseen") or {}
    n_seen = next(iter(seen.values()))["frames"]
    n_unseen = next(iter(unseen.values()))["frames"] if unseen else 0
    header = [f"method ({n_seen:,} seen / {n_unseen:,} unseen frames)", "seen: ±5° % (95% CI)",
              "seen: sum<5° / sum<3° %", "seen: coverage %", "seen: geodesic median °",
              "seen: translation median mm", "seen: pose class % (SMM's 8 bins)", "unseen: ±5° % (95% CI)",
              "unseen: coverage %", "unseen: pose class %"]
    rows = []
    for m, e in seen.items():
        u = unseen.get(m) or {}
        rows.append([name(m), _ci_cell(e), f"{_f(e.get('success_sum5'))} / {_f(e.get('success_sum3'))}",
                     _f(e.get("coverage"), 0), _f(e.get("geodesic_median_deg")), _f(e.get("translation_median_mm")),
                     _f(e.get("pose_class_accuracy")), _ci_cell(u) if u else DASH, _f(u.get("coverage"), 0),
                     _f(u.get("pose_class_accuracy"))])
    return _table(header, rows)


def table_methods(snaps, snap):
    """One protocol: coverage, features found, ±5° with its interval, σ and the range over runs."""
    s = value(snaps, snap, "summary")
    runs = value(snaps, snap, "evaluation.runs")
    header = ["Method", "Coverage %", "Features (test frames)", "±5° % (95% CI)", "σ over runs",
              "runs min–max"]
    rows = []
    for m, e in _entries(s).items():
        per_run = [r["overall"][m]["success_tol5"] for r in runs if m in r["overall"]
                   and r["overall"][m]["success_tol5"] is not None]
        featured = e.get("featured")
        rows.append([name(m), _f(e.get("coverage")), DASH if featured is None else f"{featured:,}/{e['frames']:,}",
                     _ci_cell(e), _f((e.get("std") or {}).get("success_tol5")),
                     _span(per_run, ".1f") if per_run else DASH])
    return _table(header, rows)


def table_declined(snaps, snap):
    """One bullet per method that declined, with its reason."""
    declined = value(snaps, snap, "summary.declined")
    if not declined:
        return "- No method declined."
    return "\n".join(f"- {name(m)} declined ({d['splits']} of {d['of']} splits): {d['reason']}"
                     for m, d in declined.items())


def _protocols(snaps, arg):
    return [(p, value(snaps, p, "summary")) for p in arg.split(",")]


def _methods(protocols) -> list:
    out = []
    for _, s in protocols:
        out += [m for m in _entries(s) if m not in out]
    if "chance" in out:  # chance last
        out.remove("chance")
        out.append("chance")
    return out


def _frames(s: dict) -> int:
    return (s.get("chance") or next(iter(s["methods"].values())))["frames"]


def _frames_label(s: dict) -> str:
    """"4,462 test frames", or with runs of different test sets (views: a seeded split per run),
    "4,462 test frames in run 1, 4,496 on average": the intervals' n is the average."""
    entry = s.get("chance") or next(iter(s["methods"].values()))
    mean = entry.get("ci95", {}).get("success_tol5", {}).get("n", entry["frames"])
    if round(mean) == entry["frames"]:
        return f"{entry['frames']:,} test frames"
    return f"{entry['frames']:,} test frames in run 1, {mean:,.0f} on average"


def table_protocols(snaps, arg):
    """Every method under every protocol: ±5° (95% CI) / sum<5° / geodesic median / AUC."""
    ps = _protocols(snaps, arg)
    header = ["Method"] + [f"{p} ({_frames_label(s)}): ±5° % (95% CI) / sum<5° % / geodesic median ° / AUC"
                           for p, s in ps]
    rows = []
    for m in _methods(ps):
        cells = []
        for _, s in ps:
            e = _entries(s).get(m)
            cells.append(DASH if e is None else
                         f"{_ci_cell(e)}{_cov(e)} / {_f(e.get('success_sum5'))} / {_f(e.get('geodesic_median_deg'))}"
                         f" / {_f(e.get('auc_45'))}")
        rows.append([name(m)] + cells)
    return _table(header, rows)


def table_dof(snaps, arg):
    ps = _protocols(snaps, arg)
    header = ["Method"] + [f"{p}: azimuth / az. mod 180 / elevation ° / distance mm" for p, _ in ps]
    keys = ("azimuth_deg", "azimuth_mod180_deg", "elevation_deg", "distance_mm")
    rows = []
    for m in _methods(ps):
        cells = []
        for _, s in ps:
            e = _entries(s).get(m)
            med = (e or {}).get("median_error") or {}
            cells.append(DASH if e is None else " / ".join(_f(med.get(k)) for k in keys))
        rows.append([name(m)] + cells)
    return _table(header, rows)


def table_surface(snaps, arg):
    ps = _protocols(snaps, arg)
    header = ["Method"] + [f"{p}: ADD(-S) % / AR MSSD % / AR MSPD %" for p, _ in ps]
    rows = []
    for m in _methods(ps):
        cells = []
        for _, s in ps:
            e = _entries(s).get(m)
            surf = (e or {}).get("surface") or {}
            cells.append(DASH if not surf else " / ".join(_f(surf.get(k)) for k in ("add_s_recall", "ar_mssd",
                                                                                     "ar_mspd")))
        rows.append([name(m)] + cells)
    return _table(header, rows)


def table_classes(snaps, snap):
    """Per class: ±5° % (geodesic median °); frames per class in the first column."""
    classes = value(snaps, snap, "summary.classes")
    methods = []
    for row in classes.values():
        methods += [m for m in row if m not in methods]
    header = ["Class (test frames)"] + [name(m) for m in methods]
    rows = []
    for c, row in classes.items():
        frames = next(iter(row.values()))["frames"]
        rows.append([f"{c} ({frames:,})"] + [DASH if m not in row else
                                             f"{_f(row[m].get('success_tol5'))} "
                                             f"({_f(row[m].get('geodesic_median_deg'), 0)})"
                                             for m in methods])
    return _table(header, rows)


def table_paper1(snaps, snap):
    """SPM per class (±5°, its interval, sum criteria, eccentricity) beside the paper's Table 1."""
    classes = value(snaps, snap, "summary.classes")
    ecc = value(snaps, snap, "evaluation.eccentricity")
    rows = []
    for c, row in classes.items():
        if "spm" not in row:
            continue
        e, ec, p = row["spm"], ecc.get(c) or {}, PAPER_TABLE1.get(c)
        rows.append([c, f"{e['frames']:,}", _ci_cell(e) + _cov(e), _f((e.get("std") or {}).get("success_tol5")),
                     _f(e.get("success_sum5")), _f(e.get("success_sum3")), _f(ec.get("mean"), 2), _f(ec.get("std"), 2),
                     _f(p[0]) if p else DASH, _f(p[2], 2) if p else DASH])
    return _table(["Class", "Frames", "±5° % (95% CI)", "σ", "sum<5° %", "sum<3° %", "Mean eccentricity", "σ",
                   "Paper success %", "Paper ecc."], rows)


def table_paper2(snaps, snap):
    """KNN on SPM's vectors per class beside the paper's Table 2."""
    classes = value(snaps, snap, "summary.classes")
    rows = []
    for c, row in classes.items():
        if "knn1" not in row or "knn3" not in row:
            continue
        k1, k3, p = row["knn1"], row["knn3"], PAPER_TABLE2.get(c)
        rows.append([c, f"{k1['frames']:,}", _ci_cell(k1) + _cov(k1), _ci_cell(k3) + _cov(k3),
                     _f(p[0]) if p else DASH, _f(p[2]) if p else DASH])
    return _table(["Class", "Frames", "K=1 ±5° % (95% CI)", "K=3 ±5° % (95% CI)", "Paper K=1 %", "Paper K=3 %"],
                  rows)


TABLES = {"fig5-bins": table_fig5_bins, "fig5-overall": table_fig5_overall, "methods": table_methods,
          "declined": table_declined, "protocols": table_protocols, "dof": table_dof, "surface": table_surface,
          "classes": table_classes, "paper1": table_paper1, "paper2": table_paper2}


# ---------------------------------------------------------------------------------------------
# A separate run's methods beside a snapshot's (issue 48: the cnn, run alone with chance on the
# same shards, protocol, runs and seeds, so the committed run's splits; snapshot "BASE-cnn").
#   {{table:beside:BASE,EXTRA:KIND[:ARGS]}}   table KIND of BASE with EXTRA's methods that BASE
#                                             lacks grafted in, their rows marked †
#   {{table:beside-note:BASE,EXTRA}}          † said: EXTRA's date, command, wall time, load and
#                                             whether chance, seeded by the run, agrees run by run

BESIDE_MARK = " †"


def _added(snaps, base: str, extra: str) -> list:
    """The methods of ``extra`` that ``base`` lacks (chance aside), in ``extra``'s order."""
    have = value(snaps, base, "summary.methods")
    return [m for m in value(snaps, extra, "summary.methods") if m not in have]


def _graft(base, extra, added: list) -> None:
    """``extra``'s entries of the ``added`` methods copied into ``base`` wherever ``base`` has the
    dict (or list, item by item) that holds them in ``extra``: methods, classes, Fig. 5's curves,
    instances, the runs' overall rates."""
    if isinstance(base, dict) and isinstance(extra, dict):
        for key, item in extra.items():
            if key in added and key not in base:
                base[key] = item
                if "chance" in base:            # chance stays last, as the report orders methods
                    base["chance"] = base.pop("chance")
            elif key in base:
                _graft(base[key], item, added)
    elif isinstance(base, list) and isinstance(extra, list) and len(base) == len(extra):
        for b, e in zip(base, extra):
            _graft(b, e, added)


def _grafted(snaps, base: str, extra: str) -> tuple[dict, list]:
    """A copy of snapshot ``base`` with ``extra``'s added methods grafted in, and those methods."""
    added = _added(snaps, base, extra)
    merged = json.loads(json.dumps(_snap(snaps, base)))
    for part in ("summary", "evaluation"):
        _graft(merged[part], _snap(snaps, extra)[part], added)
    return merged, added


def _marked(text: str, added) -> str:
    for m in dict.fromkeys(added):
        text = text.replace(f"| {name(m)} |", f"| {name(m)}{BESIDE_MARK} |")
    return text


def table_beside(snaps, pair, kind, *args):
    """Table ``kind`` of the first snapshot of ``pair`` with the second's added methods, marked."""
    base, extra = pair.split(",")
    merged, added = _grafted(snaps, base, extra)
    return _marked(TABLES[kind]({**snaps, base: merged}, base, *args), added)


def table_beside_each(snaps, bases, suffix, kind):
    """Table ``kind`` of several snapshots (``bases``, comma-separated: protocols, dof, surface), each
    with the added methods of its snapshot BASE``suffix`` (e.g. loco-cnn) grafted in, marked."""
    merged, added = dict(snaps), []
    for base in bases.split(","):
        merged[base], more = _grafted(snaps, base, base + suffix)
        added += more
    return _marked(TABLES[kind](merged, bases), added)


def _same_chance(snaps, base: str, extra: str) -> bool:
    """Whether chance (a random training pose, seeded by the run) scored the same in every run of
    both snapshots: the same splits and test frames, as far as the snapshots can tell."""
    def per_run(snap):
        return [(r["overall"].get("chance") or {}).get("success_tol5") for r in value(snaps, snap, "evaluation.runs")]
    return per_run(base) == per_run(extra) and None not in per_run(base)


def table_beside_note(snaps, pair):
    """The † line under a beside table."""
    base, extra = pair.split(",")
    made = value(snaps, extra, "made")
    names = ", ".join(name(m) for m in _added(snaps, base, extra))
    same = ("chance scores the same in every run of both, so the splits are the same"
            if _same_chance(snaps, base, extra) else "chance scores differently, so the splits may differ")
    load = f", {made['note']}" if made.get("note") else ""
    return (f"†{names}: a separate run (snapshot [{extra}](results/{extra}.json)), {made['date']}, "
            f"`{made['command']}`, {made['wall_s']:.0f} s{load}; the same data, protocol, runs and seeds as the "
            f"rows beside it: {same}.")


TABLES.update({"beside": table_beside, "beside-each": table_beside_each, "beside-note": table_beside_note})


def table_size_curve(snaps, names):
    """One row per snapshot of benchmarks/train_size.py (the same protocol at growing render sizes):
    frames, the methods' ±5° with intervals, the cnn's training cost, render and train wall times."""
    rows, methods = [], []
    for snap in names.split(","):
        s = value(snaps, snap, "summary")
        methods += [m for m in _entries(s) if m not in methods]
    methods = [m for m in methods if m != "chance"] + ["chance"]
    header = ["Frames rendered (test frames)"] + [f"{name(m)}: ±5° % (95% CI)" for m in methods] + [
        "CNN final fit: s (steps, epochs)", "render s", "train and test s"]
    for snap in names.split(","):
        s, made = value(snaps, snap, "summary"), value(snaps, snap, "made")
        cost = (value(snaps, snap, "context").get("training") or {}).get("cnn") or {}
        entries = _entries(s)
        rows.append([f"{value(snaps, snap, 'context.frames'):,} ({_frames(s):,})"]
                    + [_ci_cell(entries[m]) if m in entries else DASH for m in methods]
                    + [f"{cost['seconds']:.0f} ({cost['steps']}, {cost['epochs']:.1f})" if cost else DASH,
                       f"{made['before'][0]['wall_s']:.0f}" if made.get("before") else DASH, f"{made['wall_s']:.0f}"])
    return _table(header, rows)


TABLES.update({"size-curve": table_size_curve})


# ---------------------------------------------------------------------------------------------
# Rendering.

def resolve(expr: str, snaps: dict) -> str:
    head, *args = expr.split(":")
    if head == "rate":
        return rate(_entry_of(snaps, args[0], args[1]), *args[2:3])
    if head == "best":
        return best(snaps, args[0])
    if head == "runs":
        n = value(snaps, args[0], "summary.runs")
        return f"{n} run" + ("" if n == 1 else "s")
    if head == "name":
        return name(args[0])
    if head in ("range", "min", "max"):
        vals = values(snaps, args[0], args[1])
        spec = args[2] if len(args) > 2 else ""
        if not vals:
            return DASH
        return _span(vals, spec) if head == "range" else fmt((min if head == "min" else max)(vals), spec)
    if head == "count":
        return str(len(value(snaps, args[0], args[1])))
    if head == "paper":
        return paper(*args)
    if head == "measure":
        return fmt(value(load_measures(), args[0], args[1]), args[2] if len(args) > 2 else "")
    if head == "table":
        if args[0] not in TABLES:
            raise PlaceholderError(f"no table {args[0]!r} (have: {', '.join(TABLES)})")
        return TABLES[args[0]](snaps, *args[1:])
    if not args:
        raise PlaceholderError("expected SNAP:PATH[:FMT]")
    return fmt(value(snaps, head, args[0]), args[1] if len(args) > 1 else "")


SNAP_FIRST = ("rate", "best", "runs", "range", "min", "max", "count")  # placeholders whose first argument is SNAP


def used_snapshots(template: str) -> set[str]:
    """The snapshots a template reads."""
    used = set()
    for expr in PLACEHOLDER.findall(template):
        head, *args = expr.split(":")
        if head in SNAP_FIRST:
            used.add(args[0])
        elif head == "table":
            used.update(args[1].split(","))
        elif head not in ("name", "paper", "measure"):
            used.add(head)
    return used


LIST_ITEM = re.compile(r"^(\s*)([-*]|\d+\.)\s+")
KEEP = ("|", "#", "![", "<!--", "```")  # table rows, headings, images, comments, fences: as they are


def reflow(text: str, width: int = 100) -> str:
    """Paragraphs and list items re-wrapped to ``width`` columns (placeholders make lines of any
    length); tables, headings, images, comments and fenced code kept line for line."""
    out, block, fenced = [], [], False

    def flush():
        if block:
            first = block[0]
            item = LIST_ITEM.match(first)
            indent = " " * len(item.group(0)) if item else ""
            words = " ".join(line.strip() for line in block)
            out.extend(textwrap.wrap(words, width, initial_indent=first[:len(first) - len(first.lstrip())],
                                     subsequent_indent=indent, break_long_words=False, break_on_hyphens=False))
            block.clear()

    for line in text.split("\n"):
        if line.startswith("```"):
            flush()
            fenced = not fenced
            out.append(line)
        elif fenced or not line.strip() or line.lstrip().startswith(KEEP):
            flush()
            out.append(line)
        else:
            if LIST_ITEM.match(line):
                flush()
            block.append(line)
    flush()
    return "\n".join(out)


def render(template: str, snaps: dict) -> str:
    def one(match):
        try:
            return resolve(match.group(1), snaps)
        except PlaceholderError as exc:
            line = template.count("\n", 0, match.start()) + 1
            raise PlaceholderError(f"line {line}: {{{{{match.group(1)}}}}}: {exc}") from None
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            line = template.count("\n", 0, match.start()) + 1
            raise PlaceholderError(f"line {line}: {{{{{match.group(1)}}}}}: {type(exc).__name__}: {exc}") from None
    return reflow(PLACEHOLDER.sub(one, template))


# Figures typed by hand: what the template may not hold outside placeholders.
FIGURE = re.compile(r"\d+(?:[.,]\d+)+"                              # 1.5, 1,200, 0.6/0.7 (each part)
                    r"|\d+\s*(?:%|°|mm\b|px\b|pixels?\b|percent\b|ms\b|s\b|min\b|minutes?\b|seconds?\b|h\b|hours?\b"
                    r"|MB\b|GB\b)"
                    r"|\b(?:version|schema|v)\s*\d+"                 # version 7, schema 5, v2
                    r"|\b\d+\s+(?:frames|runs|views|images|splits|objects)\b"
                    r"|\b(?:19|20)\d\d\b", re.IGNORECASE)            # years, dates
# Criteria and fixed design, not results: the success criteria's names, SMM's 45° classes and the
# AUC's 0–45° range, a half turn, the ten 10%-wide occlusion bins, the intervals' confidence.
ALLOWED = re.compile(r"±5°|sum ?< ?[35]°|0–45°|45°|180°|\b\d0–\d{2,3}%|\b95% (?:Wilson )?interval|\b95% CI")


def hand_written(template: str) -> list[tuple[int, str]]:
    """(line, text) of every figure outside placeholders that the allowlist does not name."""
    found = []
    for number, line in enumerate(template.splitlines(), 1):
        prose = ALLOWED.sub(" ", PLACEHOLDER.sub(" ", line))
        found += [(number, m.group(0)) for m in FIGURE.finditer(prose)]
    return found


def first_difference(expected: str, actual: str) -> str | None:
    if expected == actual:
        return None
    a, b = expected.splitlines(keepends=True), actual.splitlines(keepends=True)
    for i, (x, y) in enumerate(zip(a, b), 1):
        if x != y:
            return f"line {i}: rendered {x.rstrip()!r}, file has {y.rstrip()!r}"
    i = min(len(a), len(b)) + 1
    return (f"line {i}: rendered {'(end)' if i > len(a) else repr(a[i - 1].rstrip())}, "
            f"file has {'(end)' if i > len(b) else repr(b[i - 1].rstrip())}")


# ---------------------------------------------------------------------------------------------
# Tables in other docs, between <!-- measure-table:NAME --> (or NAME/PART, another table of the
# same measure) and <!-- /measure-table --> lines, rendered from docs/results/measures/NAME.json
# (`python scripts/results_doc.py blocks`).

BLOCK_DOCS = (ROOT / "docs" / "method.md", ROOT / "README.md", ROOT / "docs" / "spm-ablation.md",
              ROOT / "docs" / "scaling.md")
BLOCK = re.compile(r"(<!-- measure-table:([\w-]+)(/[\w-]+)? -->\n)(.*?)(<!-- /measure-table -->)", re.S)


def _share(part: int, whole: int) -> str:
    return f"{100.0 * part / whole:.1f}%" if whole else DASH


def table_n3m_small_set(measure: dict) -> str:
    """benchmarks/n3m_small_set.py's figures: per method, within ±5° of the clean and hidden test
    frames (estimated frames in brackets) and the poses' sources."""
    rows = []
    for key, label in (("n3m", "`n3m` (marker levels only)"),
                       ("n3m-fallback", "N3M with the fallback (the `n3m` row before issue 34)"),
                       ("sift-pnp", "`sift-pnp`")):
        sets = measure["summary"][key]
        cells = [f"{_share(s['within_5'], s['frames'])} ({_share(s['estimated'], s['frames'])})"
                 for s in (sets["clean"], sets["hidden"])]
        sources = "; ".join(f"{s['from_markers']} / {s['from_ransac']}" for s in (sets["clean"], sets["hidden"]))
        rows.append([label, *cells, sources])
    return _table(["method", "clean", "40% hidden", "poses from markers / RANSAC (clean; hidden)"], rows)


def table_isolation_cost(measure: dict) -> str:
    """benchmarks/isolation_cost.py's figures: per protocol and in total, each way's wall seconds
    per run, their medians and the ratio; then how they were measured (the loads of every run)."""
    s, made = measure["summary"], measure["made"]
    rows = [[part, " / ".join(f"{w:.1f}" for w in f["isolated_s"]), " / ".join(f"{w:.1f}" for w in f["in_process_s"]),
             f"{f['isolated_median_s']:.1f} / {f['in_process_median_s']:.1f}", f"{f['ratio']:.3f}"]
            for part, f in [*s["protocols"].items(), ("total", s["total"])]]
    loads = [x[k] for x in made["loads"] for k in ("start", "end")]
    p = made["parameters"]
    return (_table(["protocol", "isolated, each run (s)", "in-process, each run (s)", "medians (s)",
                    "isolated / in-process"], rows)
            + f"\n\n{made['date']}, `{made['command']}`: {s['frames']:,} frames, methods {p['methods']}, "
            f"--runs {p['runs']}, --workers {p['workers']}, --rounds {p['rounds']} (each way; {p['order']}), "
            f"{made['machine']['nproc']} CPUs, 1-minute load average {min(loads):.1f}–{max(loads):.1f} at the "
            f"runs' starts and ends; results.json summaries identical both ways; target: ratio "
            f"≤ {s['target_ratio']:.2f}.")


SOLVER_ROWS = (("exact_all", "exact Eq. 5 over every training frame"),
               ("exact_subset", "exact Eq. 5 over a seeded 1,000-frame subset (the default)"),
               ("knn_subset", "`projection=\"knn\"` (64 neighbours) over that subset"))


def table_spm_solvers(measure: dict) -> str:
    """benchmarks/train_scaling.py --accuracy-only: SPM's Eq. 5 solvers against the exact solve."""
    s, made = measure["summary"], measure["made"]

    def cell(f, key):
        return f"{f[key]:.1f} (σ {f[key + '_std']:.1f})"
    rows = [[label, cell(s["solvers"][key], "own_sum5"), cell(s["solvers"][key], "own_sum3"),
             cell(s["solvers"][key], "new_sum5"), f"{s['solvers'][key]['fit_cpu_s']:.1f}"]
            for key, label in SOLVER_ROWS]
    return (_table(["solve", f"sum<5° % re-predicting its {s['training_frames']:,} training frames",
                    "sum<3° % (the same)", f"sum<5° % on {s['test_frames']:,} new views", "fit, CPU s"], rows)
            + f"\n\n{made['date']}, `{made['command']}`: the `views` split (seed 0) of {s['frames']:,} frames, "
            f"its first {s['training_frames']:,} training frames with an SPM vector and its test frames with one; "
            f"mean (σ) over {s['seeds']} seeds (the noise copies and Nyström centres vary with the seed); a fit's "
            f"CPU seconds (all its threads); the whole command {made['cpu_s']:,.0f} CPU seconds. Target: the "
            "default within one point of the exact solve.")


def _abl(x) -> str:
    return DASH if x is None else f"{x:.1f}"


def table_spm_ablation(measure: dict) -> str:
    """benchmarks/spm_ablation.py's Table 1: one open choice at a time (1-NN and SPM, two protocols)."""
    rows = []
    for name, r in measure["summary"]["variants"]:
        cells = [name, f"{r['train_coverage_pct']:.0f} / {r['query_coverage_pct']:.0f}"]
        cells += [_abl(r[p][m][k]) for p in ("views", "instances") for m in ("nn", "spm")
                  for k in ("median_deg", "tol5_pct")]
        rows.append(cells)
    return _table(["variant", "train / query vectors (%)", "views 1-NN med°", "views 1-NN ±5° %", "views SPM med°",
                   "views SPM ±5° %", "inst. 1-NN med°", "inst. 1-NN ±5° %", "inst. SPM med°", "inst. SPM ±5° %"],
                  rows)


ABLATION_STAGES = {"a": "(a) keypoint layout (8x8 histogram in the box)", "b": "(b) bunch centres (EM means, ordered)",
                   "c": "(c) ellipse (centre, axes, orientation)", "d": "(d) foci-distance vector (16-d)",
                   "e": "(e) re-projected vector (SPP)", "z": "chance: a random training frame's label"}


def table_spm_ablation_probe(measure: dict) -> str:
    """benchmarks/spm_ablation.py's Table 2: the stage-by-stage 1-NN probe."""
    probe = measure["summary"]["probe"]
    rows = [[label, *(_abl(probe[p][k][m]) for p in ("views", "instances") for m in ("median_deg", "tol5_pct"))]
            for k, label in ABLATION_STAGES.items()]
    return _table(["descriptor", "views 1-NN med°", "views ±5° %", "instances 1-NN med°", "instances ±5° %"], rows)


def table_spm_ablation_made(measure: dict) -> str:
    """How the ablation's measure was made: its subset and command."""
    s, made = measure["summary"], measure["made"]
    sub = s["subset"]
    return (f"{made['date']}, `{made['command']}`: {sub['frames']:,} subset frames ({sub['with_neighbours']:,} "
            f"with their path neighbours) of {sub['shards_frames']:,}: instances 0–{sub['instances'] - 1} of each of "
            f"{sub['classes']} classes, every {sub['azimuth_step']}. azimuth and every {sub['elevation_step']}. "
            f"elevation of the grid; split seed {sub['seed']}; {made['cpu_s']:,.0f} CPU seconds.")


MEASURE_TABLES = {"n3m-small-set": table_n3m_small_set, "isolation-cost": table_isolation_cost,
                  "spm-solvers": table_spm_solvers, "spm-ablation": table_spm_ablation,
                  "spm-ablation/probe": table_spm_ablation_probe, "spm-ablation/made": table_spm_ablation_made}


def fill_blocks(text: str, measures: dict) -> str:
    """``text`` with every measure-table block rendered from its measure."""
    def one(m):
        measure, table = m.group(2), m.group(2) + (m.group(3) or "")
        if table not in MEASURE_TABLES or measure not in measures:
            raise PlaceholderError(f"no measure table {table!r} (tables: {', '.join(MEASURE_TABLES)}; "
                                   f"measures: {', '.join(sorted(measures))})")
        return m.group(1) + MEASURE_TABLES[table](measures[measure]) + "\n" + m.group(5)
    return BLOCK.sub(one, text)


def _blocks_main(argv) -> int:
    check = argv == ["--check"]
    measures = load_measures()
    for doc in BLOCK_DOCS:
        text = doc.read_text()
        filled = fill_blocks(text, measures)
        if check and filled != text:
            print(f"{doc}: its measure tables are not what docs/results/measures/ renders "
                  f"({first_difference(filled, text)}); run python scripts/results_doc.py blocks", file=sys.stderr)
            return 1
        if not check:
            doc.write_text(filled)
        print(f"{doc}: {'up to date' if check else 'written'}")
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["blocks"]:
        return _blocks_main(argv[1:])
    if argv[:1] == ["snapshot"]:
        p = argparse.ArgumentParser(prog="results_doc.py snapshot", description="Write docs/results/NAME.json.")
        p.add_argument("name")
        p.add_argument("results_json", type=Path)
        p.add_argument("--command", required=True, help="the command that made it, as a reader would run it")
        p.add_argument("--wall-s", type=float, required=True, help="its wall time, seconds")
        p.add_argument("--date", default=None)
        p.add_argument("--note", default=None)
        p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                       help="a setting of the command (made.parameters); repeatable")
        p.add_argument("--before", action="append", default=[],
                       help="a command that made the input or filled its caches (made.before); repeatable")
        p.add_argument("--before-wall-s", action="append", type=float, default=[], help="its wall time, each --before")
        p.add_argument("--before-date", default=None, help="their date (default --date)")
        p.add_argument("--folder", type=Path, default=SNAPSHOTS)
        p.add_argument("--bop-eval", type=Path, default=None,
                       help="benchmarks/bop_eval.py's JSON for this run: its AR figures (the snapshot's bop block)")
        a = p.parse_args(argv[1:])
        parameters = {k: _number(v) for k, _, v in (x.partition("=") for x in a.param)}
        if len(a.before) != len(a.before_wall_s):
            p.error("give one --before-wall-s for each --before")
        day = a.before_date or a.date or datetime.date.today().isoformat()
        before = [{"command": c, "wall_s": w, "date": day} for c, w in zip(a.before, a.before_wall_s)] or None
        try:
            path = write_snapshot(a.name, a.results_json, a.command, a.wall_s, a.date, a.note, a.folder, parameters,
                                  before, a.bop_eval)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        print(f"{path} ({path.stat().st_size:,} bytes)")
        return 0
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="compare instead of writing; exit 1 on a difference")
    p.add_argument("--template", type=Path, default=TEMPLATE)
    p.add_argument("--snapshots", type=Path, default=SNAPSHOTS)
    p.add_argument("--doc", type=Path, default=DOC)
    a = p.parse_args(argv)
    try:
        text = render(a.template.read_text(), load_snapshots(a.snapshots))
    except PlaceholderError as exc:
        print(f"{a.template}: {exc}", file=sys.stderr)
        return 2
    if a.check:
        diff = first_difference(text, a.doc.read_text() if a.doc.exists() else "")
        if diff:
            print(f"{a.doc} is not what {a.template} renders ({diff}); run python scripts/results_doc.py",
                  file=sys.stderr)
            return 1
        print(f"{a.doc}: up to date")
        return 0
    a.doc.write_text(text)
    print(f"wrote {a.doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
