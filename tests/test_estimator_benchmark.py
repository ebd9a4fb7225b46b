"""bench/estimator_benchmark.py (issue 36, item 5): the quick run (every method on at least one
twin), its statistics against the truth, the best-method rule, and the user-facing method tables
against the recorded full run (bench/data/estimator_benchmark.json), so that they cannot drift."""

from __future__ import annotations

import json
import re
import statistics
import sys

import pytest
from scipy import stats

from conftest import REPO

sys.path.insert(0, str(REPO / "bench"))
import estimator_benchmark as bench  # noqa: E402


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    assert bench.main(["--quick", "--out", str(out)]) == 0
    doc = json.loads((out / bench.OUT_JSON.name).read_text())
    return doc, (out / bench.OUT_MD.name).read_text()


def _rows(doc):
    for robot, r in doc["robots"].items():
        for sit, s in r["situations"].items():
            yield robot, sit, s


@pytest.mark.numerics
def test_clean_wls_truth_inside_its_own_ellipsoid(quick):
    doc, _ = quick
    w = doc["robots"]["cobot6r"]["situations"]["clean"]["methods"]["wls"]
    assert w["status"] == "ok" and w["p"] > 20
    # with white force noise and unbiased regressors chi2 = e' Sigma^-1 e of the truth is chi-square
    # with p degrees of freedom under WLS's own covariance: above its 1 - 1e-3 quantile once in a
    # thousand logs. The clean twin's only bias (the half-sample lag of the held torque against the
    # central-difference acceleration) is below the 1 N*m noise by construction (module docstring:
    # 1 N*m chosen so that it is), so a failure means a wrong covariance or a biased regressor.
    assert w["chi2_over_p"] * w["p"] <= stats.chi2.ppf(1 - 1e-3, w["p"])
    # the other least-squares methods share the data; OLS and IRLS (no outliers: Huber weights 1 on
    # almost every row) report the same kind of covariance
    for m in ("ols", "irls"):
        r = doc["robots"]["cobot6r"]["situations"]["clean"]["methods"][m]
        assert r["chi2_over_p"] * r["p"] <= stats.chi2.ppf(1 - 1e-3, r["p"])


def test_every_method_ran_or_gave_a_stated_refusal(quick):
    doc, md = quick
    seen = {}
    for robot, sit, s in _rows(doc):
        for m, r in s["methods"].items():
            seen.setdefault(m, []).append(r)
            if r["status"] == "ok":
                assert r["seconds"] > 0 and r["heldout_pct"] > 0 and r["param_error_pct"] >= 0
                assert r["nominal_heldout_pct"] > 0
            else:
                assert r["status"] in ("refused", "n/a") and r["reason"] and "\n" not in r["reason"]
                assert f"{r['status']}: {r['reason'][:40]}" in md
    assert set(seen) == set(bench.METHODS)
    # the rule needs at least one method that ran per robot and situation
    assert all(any(r["status"] == "ok" for r in s["methods"].values()) for _, _, s in _rows(doc))


def _rule(rows: dict) -> str:
    """The stated rule (bench.RULE), written again independently of bench.best_method."""
    ran = {m: r for m, r in rows.items() if r["status"] == "ok" and r["runs"] == r["draws"]}
    covered = {m: r for m, r in ran.items() if r["covered"]}
    def ratio(r):  # held-out error over the CAD model's on the same rows, mean over the draws that ran
        ok = [d for d in r["per_draw"] if d["status"] == "ok"]
        return sum(d["heldout_pct"] / d["nominal_heldout_pct"] for d in ok) / len(ok)

    pool = covered if any(ratio(r) < 1 for r in covered.values()) else ran
    low = min(pool, key=lambda m: ratio(pool[m]))
    h0 = ratio(pool[low])

    def se(m):  # the paired difference's standard error over the draws
        d = [x["heldout_pct"] / x["nominal_heldout_pct"] - y["heldout_pct"] / y["nominal_heldout_pct"]
             for x, y in zip(pool[m]["per_draw"], pool[low]["per_draw"])]
        return statistics.stdev(d) / len(d) ** 0.5 if len(d) > 1 else 0.0

    tied = {m: r for m, r in pool.items() if ratio(r) - h0 <= max(se(m), 0.005 * h0)}
    best = min(tied, key=lambda m: tied[m]["seconds"])
    # a fit that predicts worse than the CAD model is not recommended: keep the nominal model
    return best if ratio(tied[best]) < 1 else "nominal"


def _best_row(md: str) -> dict[str, list[str]]:
    """Robot -> the methods of its table's **best** row, situation by situation."""
    out, robot = {}, None
    for line in md.splitlines():
        if line.startswith("### ") and not line.startswith("### Best"):
            robot = line[4:].strip()
        elif line.startswith("| **best** |") and robot:
            out[robot] = re.findall(r"\*\*([a-z+]+)\*\*", line[len("| **best** |"):])
    return out


def _check_rule(doc: dict, md: str) -> None:
    rows_md = _best_row(md)
    table = bench.parse_recommendation(md)
    for robot, r in doc["robots"].items():
        sits = list(r["situations"])
        for k, sit in enumerate(sits):
            s = r["situations"][sit]
            best = s["best"]["method"]
            assert best == _rule(s["methods"]), (robot, sit)
            assert rows_md[robot][k] == best and table[robot][sit] == best, (robot, sit)


def test_best_method_follows_the_stated_rule(quick):
    _check_rule(*quick)


def _recorded():
    doc = json.loads(bench.OUT_JSON.read_text())
    return doc, {robot: {sit: s["best"]["method"] for sit, s in r["situations"].items()}
                 for robot, r in doc["robots"].items()}


def test_recorded_full_run_follows_the_rule():
    doc, _ = _recorded()
    assert not doc["meta"]["quick"]
    assert set(doc["robots"]) == set(bench.ROBOTS)
    _check_rule(doc, bench.OUT_MD.read_text())


@pytest.mark.parametrize("page", ["README.md", "docs/guide/parallel-robots.md", "docs/howto/which-method.md",
                                  "bench/README.md"])
def test_recommendations_match_the_benchmark(page):
    _, best = _recorded()
    assert bench.parse_recommendation((REPO / page).read_text()) == best
