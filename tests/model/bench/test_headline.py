"""spm_model.bench.headline: the best method is named only when it beats chance beyond both 95%
intervals; every rate carries its frames and interval."""

import numpy as np
import pytest

from spm_model.bench.headline import beats, best_method, plain_summary, rate_text
from spm_model.bench.metrics import intervals, wilson_interval
from spm_model.methods.registry import METHOD_NAMES


@pytest.mark.parametrize("rate, n, low, high", [(0.0, 10, 0.0, 27.75), (50.0, 10, 23.66, 76.34),
                                                (100.0, 4, 51.01, 100.0), (20.0, 100, 13.34, 28.88)])
def test_wilson_interval_matches_the_published_values(rate, n, low, high):
    # Brown, Cai & DasGupta (2001) / any statistics table: 0/10 -> [0, 0.2775], 5/10 -> [0.2366, 0.7634].
    assert wilson_interval(rate, n) == pytest.approx((low, high), abs=0.01)
    assert wilson_interval(None, 10) is None and wilson_interval(50.0, 0) is None


def _entry(rate, n):
    e = {"frames": n, "estimated": n, "success_tol5": rate, "auc_45": rate, "geodesic_median_deg": 10.0}
    e["ci95"] = intervals(e, {"success_tol5": n})
    return e


def test_a_method_below_chance_is_never_named_best():
    summary = {"protocol": "views", "methods": {"smm": _entry(2.3, 400)}, "chance": _entry(4.2, 400)}
    first = plain_summary(summary)[0]
    assert best_method(summary) is None
    assert first.startswith("- **No method beats chance here (views protocol)**") and "SMM" not in first
    assert "4.2% (95% CI 2.6–6.6, 400 frames)" in first


def test_a_method_above_chance_but_inside_its_interval_is_not_named():
    summary = {"protocol": "views", "methods": {"spm": _entry(12.0, 25)}, "chance": _entry(4.0, 25)}
    assert not beats(summary["methods"]["spm"], summary["chance"])           # [4.2, 30.0] vs [0.7, 19.5]
    assert best_method(summary) is None and "SPM" not in plain_summary(summary)[0]


def test_without_chance_no_method_is_called_best():
    summary = {"protocol": "views", "methods": {"spm": _entry(90.0, 500)}, "chance": None}
    assert best_method(summary) is None
    assert plain_summary(summary)[0].startswith("- **No method is called best here (views protocol)**")


def test_spy_the_headline_names_a_method_only_beyond_both_intervals():
    """Thousands of random summaries: whenever the first line names a method, its interval's
    lower bound is above chance's upper bound; whenever one does so, the best is named."""
    rng = np.random.default_rng(0)
    named = unnamed = 0
    for _ in range(3000):
        n = int(rng.integers(1, 300))
        methods = {m: _entry(100.0 * rng.binomial(n, p) / n, n)
                   for m, p in zip(("spm", "knn1", "smm", "n3m"), rng.uniform(0, 1, 4))}
        chance = _entry(100.0 * rng.binomial(n, rng.uniform(0, 0.5)) / n, n)
        summary = {"protocol": "views", "methods": methods, "chance": chance}
        first = plain_summary(summary)[0]
        shown = [m for m in methods if f"**Best method, views protocol: {METHOD_NAMES[m]}**" in first]
        top = max(methods, key=lambda m: (methods[m]["success_tol5"], methods[m]["auc_45"]))
        if shown:
            named += 1
            assert shown == [top]
            assert methods[top]["ci95"]["success_tol5"]["low"] > chance["ci95"]["success_tol5"]["high"]
        else:
            unnamed += 1
            assert first.startswith("- **No method beats chance here")
            assert methods[top]["ci95"]["success_tol5"]["low"] <= chance["ci95"]["success_tol5"]["high"]
    assert named > 100 and unnamed > 100          # both cases were exercised


def test_rate_text_carries_frames_and_interval():
    assert rate_text(_entry(50.0, 10)) == "50.0% (95% CI 23.7–76.3, 10 frames)"
    assert rate_text({"success_tol5": None}) == "–" and rate_text({"success_tol5": 5.0}) == "5.0%"


def test_spm_at_chance_is_said_to_be_the_known_result_and_only_then():
    from spm_model.bench.headline import SPM_AT_CHANCE

    at_chance = {"protocol": "loco", "methods": {"spm": _entry(0.4, 1000), "pca": _entry(60.0, 1000)},
                 "chance": _entry(0.7, 1000)}
    lines = plain_summary(at_chance)
    assert lines.count(SPM_AT_CHANCE) == 1 and "docs/results.md" in SPM_AT_CHANCE
    assert lines.index(SPM_AT_CHANCE) == 2   # after the headline and every other method's rate
    above = {**at_chance, "methods": {"spm": _entry(60.0, 1000)}}
    assert SPM_AT_CHANCE not in plain_summary(above)
    assert SPM_AT_CHANCE not in plain_summary({**at_chance, "chance": None})   # nothing to compare with
    assert SPM_AT_CHANCE not in plain_summary({**at_chance, "methods": {"pca": _entry(60.0, 1000)}})
