"""The options a benchmark script's output folder was made with, recorded in the folder.

A script that renders (or occludes, imports) into a folder resumes there when run again;
with other options it would silently reuse data made with the first ones, or mix the two.
``claim`` records the options that determine the data (not those that only change
training or the report) in the folder the first time, and refuses a later run with other
ones in one line naming the option and both values:

    error: out/x was made with --step 20, not --step 5; give another --out or the same options

Option keys are the script's flags (``--step``; a bool ``--x`` reads ``--x`` / ``--no-x``);
other keys (constants of the script, such as a seed) read ``key value``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spm_data.io.files import write_json_atomic  # noqa: E402


def _json(value):
    return json.loads(json.dumps(value))   # tuples as lists: as the record reads back


def show(key: str, value) -> str:
    """``--step 20``, ``--classes box,cup``, ``--no-distractors``; ``seed 0`` for a constant."""
    if key.startswith("--") and isinstance(value, bool):
        return key if value else "--no-" + key[2:]
    if isinstance(value, list):
        value = ",".join(str(v) for v in value)
    return f"{key} {'(none)' if value is None else value}"


def claim(out, options: dict, *, record: str, data=(), script: str = "this script") -> bool:
    """Make ``out`` a folder of data made with ``options`` (JSON values), or check that it is.

    True: the folder is new and ``out/record`` now holds ``options`` (written atomically), so the
    caller writes whatever describes its data (specs). False: the folder was made with these very
    options (reuse, resume). Otherwise exits 1 with one line: another option's value, an unreadable
    record, or data (any of ``data``, paths under ``out``) without a record (an older script's)."""
    out = Path(out)
    path = out / record
    options = _json(options)
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            sys.exit(f"error: {path} is unreadable ({exc}); give another --out or delete {out}")
        for key in list(options) + [k for k in old if k not in options]:
            if old.get(key) != options.get(key):
                sys.exit(f"error: {out} was made with {show(key, old.get(key))}, not {show(key, options.get(key))}; "
                         "give another --out or the same options")
        return False
    made = [p for p in data if (out / p).exists()]
    if made:
        sys.exit(f"error: {out} holds {out / made[0]} from an older {script}, which did not record its options "
                 f"({record}); give another --out or delete {out}")
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, options, sort_keys=False)
    return True
