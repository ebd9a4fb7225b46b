"""The estimator study of issue 7 (bench/estimator_study.py), quick version: it runs, prints its
tables, and its findings hold at small size."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "bench"))
import estimator_study as study  # noqa: E402


def test_paper001_weighting_the_observation_matrix(capsys):
    res = study.shang_tables(quick=True)
    print(study.shang_table(res))
    runs = res["runs"]
    plain, weighted = runs["circle"], runs["circle, nominal weighting"]
    # Eq. 17 scales columns: the same estimate and relative accuracies, another condition number
    np.testing.assert_allclose(weighted["params"], plain["params"], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(weighted["rel_std_pct"], plain["rel_std_pct"], rtol=1e-8)
    assert weighted["cond_Zww"] is not None and weighted["cond_Zww"] != pytest.approx(weighted["cond_Zw"], rel=0.1)
    # the weighted criterion as the design objective: that design reaches the lower weighted
    # condition number, and its worst-determined (small) parameters get the better relative
    # accuracy (at full size: 33 % against 623 %; bench/README.md section 9)
    crit = res["design_criteria"]
    assert crit["design cond(Z_ww)"]["weighted_cond"] < crit["design cond(Z_w)"]["weighted_cond"]
    assert crit["design cond(Z_w)"]["cond"] < crit["design cond(Z_ww)"]["cond"]
    a = np.asarray(runs["design cond(Z_w)"]["rel_std_pct"])
    b = np.asarray(runs["design cond(Z_ww)"]["rel_std_pct"])
    assert b.max() < a.max()
    assert "A. shang2dof" in capsys.readouterr().out


def test_paper004_table2_gm_vs_ml(capsys):
    res = study.hexapod_table2(quick=True)
    print(study.hexapod_table(res))
    assert [r["name"] for r in res["rows"]] == list(study.PAPER_TABLE2)
    # the truth of the twin's friction is the paper's Gauss-Markov column
    assert all(r["truth"] == pytest.approx(r["paper_gm"]) for r in res["rows"])
    costs = [r for r in res["ml_profile"] if r["cost"] is not None]
    best = min(costs, key=lambda r: r["cost"])
    assert best["cutoff_hz"] == res["ml_cutoff_hz"] > res["gm_cutoff_hz"]
    assert "f_c [Hz]" in capsys.readouterr().out


def test_montecarlo_coverage_table(capsys):
    res = study.coverage(quick=True)
    print(study.coverage_table(res))
    for method in ("ols", "wls", "gm"):
        assert res[method]["trials"] == 10
        assert 85.0 <= res[method]["coverage_pct"] <= 100.0, (method, res[method])
    assert "C. Coverage" in capsys.readouterr().out
