"""The physically consistent identification study of issue 8 (bench/physical_study.py), quick
version: it runs through the product's entry points, prints its tables, and its findings hold at
small size."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest

from conftest import REPO, draw

sys.path.insert(0, str(REPO / "bench"))
import physical_study as study  # noqa: E402


def _consistent(row: dict) -> bool:
    """The estimator's own standard parameters: every pseudo-inertia >= 0 up to solver accuracy."""
    scale = max(1.0, float(np.max(np.abs(row["params"]))))
    return row["min_eig_estimate"] is not None and row["min_eig_estimate"] >= -1e-9 * scale


def _check_common(run: dict) -> None:
    rows = run["rows"]
    # the unconstrained fits are not physically consistent (a body's pseudo-inertia, or a rotor inertia)
    for label in ("LS", "WLS"):
        assert not rows[label]["feasible"] and rows[label]["violated"], (label, rows[label]["violated"])
        assert rows[label]["min_eig_feasibility"] < 0
    for label in study.LMI_ROWS:
        r = rows[label]
        if "error" in r:
            continue
        assert _consistent(r), (label, r["min_eig_estimate"])
        assert r["active"] is not None and r["chi2_increase"] > 0
        # the constraints do not make the prediction of unseen motion worse than plain LS
        assert r["total"] <= 1.1 * rows["LS"]["total"], (label, r["total"], rows["LS"]["total"])
    for label in ("WLS+LMI+Euclidean", "WLS+LMI+log-det"):
        sw = run["sweeps"][label]
        if sw["chosen"] is None:
            continue
        chosen = [x for x in sw["rows"] if x.get("lambda") == sw["chosen"]]
        assert chosen and (chosen[0]["delta_chi2"] <= sw["limit"] or sw["none_accepted"])
        assert rows[label]["lambda"] == sw["chosen"]
    # eps_RA is defined on both the noisy and the noise-free held-out efforts
    for r in rows.values():
        if "error" not in r:
            assert 0 < r["eps_ra_original"] < 100 and 0 < r["eps_ra_perturbed"] < 100
    # the noise floor is the configured noise
    assert run["reference"]["noise"]["total"] > 0


@pytest.fixture(scope="module")
def serial():
    return study.serial_study(quick=True, draw=draw())


@pytest.mark.numerics
def test_serial_twin(serial, capsys):
    study.print_part(serial, "A")
    run = serial["runs"][0]
    rows = run["rows"]
    _check_common(run)
    # a 6R arm: is_feasible agrees with the estimator on every constrained row, and the
    # truth of this twin (perturbation_seed chosen for it) is physically consistent
    for label in study.LMI_ROWS:
        assert rows[label]["feasible"], (label, rows[label]["violated"])
    assert run["truth_feasible"] and min(run["truth_min_eig_standard"]) > 0
    # every row, regularized ones included, ran
    assert all("error" not in r for r in rows.values())
    # the recovered standard parameters: Euclidean regularization pulls the masses towards the
    # (close) nominal values, far closer than the constrained fit alone
    err = run["errors"]
    assert err["WLS+LMI+Euclidean"]["mass_median_pct"] < err["WLS+LMI"]["mass_median_pct"]
    assert err["LS"]["z_median"] is not None and err["LS+LMI"]["z_median"] is None
    nl = run["nonlinear"]
    # paper 000's "Nonlinear (Opt.)": the Stribeck fit ran through dynid identify, is physically
    # consistent and has a friction curve per joint
    assert nl["status"] == "ok", nl["status"]
    assert nl["row"]["method"] == "WLS+LMI+Stribeck" and nl["row"]["feasible"] and _consistent(nl["row"])
    assert sorted(nl["row"]["stribeck"]) == run["channels"]
    assert "Nonlinear (Opt.)" in run["errors"]
    out = capsys.readouterr().out
    for head in ("A1.", "A2.", "A3.", "A4.", "A4b.", "A5.", "Linear (LSM)", "Linear (Opt.)", "Nonlinear (Opt.)", "noise floor"):
        assert head in out, head


@pytest.mark.numerics
def test_parallel_twin(capsys):
    res = study.parallel_study(quick=True, draw=draw())
    study.print_part(res, "B")
    run = res["runs"][0]
    _check_common(run)
    assert run["channels"] == ["P1", "P2", "P3"]
    # the log-det row either ran and is consistent, or names why it did not
    r = run["rows"]["WLS+LMI+log-det"]
    assert ("error" in r and r["error"]) or _consistent(r)
    # section B8 (issue 17, item 5), the full study's conclusions at small size:
    lim = run["limits"]
    rows, cad = lim["rows"], lim["cad"]
    # with exact states the Stribeck fit recovers the truth's hump (72 N) and predicts at the
    # noise floor, far below half of the CAD model's error on the same states. (Not asserted: the
    # linear constrained fit against the CAD model there, 0.8 x on the recorded draw, 0.98 x on
    # another: a property of the draw, printed in the table.)
    x = rows["Nonlinear (Opt.), exact states"]
    assert x["total"] < 1.3 * lim["noise"] and x["ratio"] < 0.5, x
    assert all(abs(f["Fs"] - f["Fc"] - 72.0) < 10.0 for f in x["stribeck"].values()), x["stribeck"]
    # on the processed held-out states that same true model predicts worse than the CAD model:
    # the held-out Sum is decided by the slow samples (reversals), not by the friction model
    assert rows["exact-state Nonlinear, processed held-out"]["ratio"] > 1.0
    assert lim["split"]["exact_nonlinear_fast"] < 0.75 * lim["split"]["cad_fast"], lim["split"]
    # the in-sample bound: fitted on the held-out log itself, neither model class gets below
    # 0.85 x CAD, so the nonlinear target (0.5 x CAD) is out of reach of any training log, and
    # the best linear row sits at the CAD row's level (within 5 %, thin either way)
    for label in ("in-sample bound, linear (OLS)", "in-sample bound, Nonlinear"):
        assert 0.85 < rows[label]["ratio"] < 1.0, (label, rows[label])
    acc = study.acceptance(run)
    assert not acc["nonlinear_ok"] and acc["best_nonlinear_total"] > 1.5 * 0.5 * cad
    assert abs(acc["best_linear_total"] / cad - 1.0) < 0.05, acc
    # (b) on the held-out rows each fit's own row selection keeps, the CAD model on the same rows.
    # The RMSEs are over 2000-4500 rows a channel: a few per cent of statistical spread, so the
    # margins below are several of those.
    sel = {label: r["selected"] for label, r in rows.items() if "selected" in r}
    for label, b in sel.items():
        # nothing beats the noise: every row's noise floor is the configured 5 N a leg (+-10 %)
        assert 0.9 * lim["noise"] < b["noise"] < 1.1 * lim["noise"], (label, b)
        assert b["truth"] > 0.95 * b["noise"] and b["total"] > 0.95 * b["noise"], (label, b)
    # the guide's default selection (docs/guide/parallel-robots.md: min_velocity, guard "auto") keeps
    # rows where the truth is at the noise, and there the CAD model is within 2x of the noise: the noise alone is above half
    # the CAD row, so no model can reach 0.5 x CAD on those rows
    d = sel["WLS+LMI, min_velocity 2 v_S, guard auto"]
    assert d["truth"] < 1.1 * d["noise"], d
    assert acc["b_default_noise_ratio"] > 0.55 and acc["b_default_truth_ratio"] > 0.55, acc
    # with that selection and the Stribeck fit (min_velocity v_S/10, guard auto) the fit runs since the
    # warm-start fix (until then refused for dFs_P3); the quick version does not fit it (test time).
    # With it, (b) is decided by the draw, so it is not asserted: its rows are the best nonlinear row,
    # 0.58 x CAD in the full run (not met), 0.61 / 0.70 / 0.50 (met, at the noise: truth 0.48 x) / 0.80
    # (another row) when the quick version fitted it on DYNID_TEST_SEED 0-3; on its rows the truth is
    # 0.57 x in the full run but 0.41 x on seed 1, so "the truth above 0.55 x CAD on the rows of every
    # selection fixed in advance" no longer holds either. What holds on every draw: every row at or
    # above the noise (above) and the best linear row well below CAD
    assert acc["b_best_linear_ratio"] < 0.85, acc
    # guard auto alone: the fit finds the hump (at least half the truth's on a leg: the recorded draw)
    # or, where the guard left too few slow rows (another draw), is refused for its dFs - never a
    # flat curve reported as a fit
    label = "Nonlinear (Opt.), guard auto"
    if label in lim["refused"]:
        assert "dFs_" in lim["refused"][label], lim["refused"][label]
    else:
        auto = rows[label]["stribeck"]
        assert max(f["Fs"] - f["Fc"] for f in auto.values()) > 36.0, auto
    # short, hand-tuned guards keep the hump's rows: the fit finds a hump (ΔF above half the
    # truth's on every leg) and on those rows the truth is below 0.5 x CAD, so the target is not
    # out of reach there; the fit stays between the truth and the CAD model
    for label in ("Nonlinear (Opt.), min_velocity v_S/10, guard 0.01 s", "Nonlinear (Opt.), min_velocity v_S/10, guard 0.02 s"):
        b = rows[label]["selected"]
        assert all(f["Fs"] - f["Fc"] > 36.0 for f in rows[label]["stribeck"].values()), rows[label]["stribeck"]
        assert b["truth"] < 0.5 * b["cad"] and b["truth"] < b["total"] < 0.8 * b["cad"], (label, b)
    # issue 36, item 3 (bench/README "3-RPS scored on the moving rows"): every fit with a
    # min_velocity scored on the held-out rows above it, beside its whole-log error, CAD on the same
    # rows and the held-out-fit floors. Margins: the RMSE Sums are over 1500-2200 rows a leg, a few
    # per cent of statistical spread (1/sqrt(2n) for the noise-dominated ones); 0.05 on a ratio is
    # several of those
    mov = lim["moving"]
    for label, r in mov["rows"].items():
        # the linear floor is least squares on exactly those rows: no linear model (the fit, CAD)
        # beats it in pooled RMS. Exact; 1e-9 covers the floor's QR solve (eps * cond ~ 1e-11)
        assert r["floor_linear_pooled"] <= r["cad_pooled"] * (1 + 1e-9), (label, r)
        if r["kind"] == "linear":
            assert r["floor_linear_pooled"] <= r["pooled"] * (1 + 1e-9), (label, r)
        # on the moving rows the error is far below the whole-log one (the reversals decide that)
        assert r["total"] < 0.6 * r["whole"] or min(r["kept_pct"]) > 99, (label, r)
        assert 0.9 * lim["noise"] < r["noise"] < 1.1 * lim["noise"], (label, r)
    ma = study.moving_acceptance(mov)
    # the target is not met by a min_velocity fixed in advance or derived from the training log; the
    # best linear row is below CAD and below the best Stribeck row
    assert not ma["nonlinear_ok"] and ma["best_nonlinear_ratio"] > 0.55, ma
    assert ma["linear_ok"] and ma["best_linear_ratio"] < 0.9 and ma["best_linear_ratio"] < ma["best_nonlinear_ratio"], ma
    # why, from the floors: at 2 v_S (the linear rows) the noise alone is above half CAD, and at
    # v_S/10 the Stribeck structure fitted to the held-out log itself is far above it (the chatter)
    sweep = {e["min_velocity"]: e for e in mov["sweep"]}
    assert sweep[0.01]["noise"] > 0.55 * sweep[0.01]["cad"], sweep[0.01]
    # (the quick version fits the Stribeck floor only at 2 mm/s: the full one has it at v_S/10 too,
    # 0.86 x CAD; the linear floor and the truth say the same here)
    nl = mov["rows"]["Nonlinear (Opt.), min_velocity v_S/10"]
    assert nl["floor_linear"] > 0.7 * nl["cad"] and nl["truth"] > 0.7 * nl["cad"], nl
    assert nl.get("floor_stribeck", np.inf) > 0.7 * nl["cad"], nl
    # only in a narrow band of min_velocity (2 mm/s = 0.4 v_S here) do the Stribeck floor and the
    # truth drop below half CAD
    e = sweep[0.002]
    assert e["floor_stribeck"] < 0.45 * e["cad"] and e["truth"] < 0.45 * e["cad"], e
    # there the training log's Stribeck fit runs (until the warm-start fix it was refused for dFs_P3)
    # and identifies a hump: its pooled RMS on those rows is below the linear floor's. A Stribeck fit
    # with dFs = 0 is a model of the linear structure, and the linear floor is least squares on exactly
    # those rows, so no such model gets below it in pooled RMS (exact; 1e-9 covers the QR solve, as
    # above): being below it needs the hump. (0.44 x CAD in the full run, 0.47 on its draws 1, 2; quick
    # 0.37-0.57 x on DYNID_TEST_SEED 0-3, trained on one period.) Tuned on held-out results: not part
    # of the verdict above
    label = "Nonlinear (Opt.), min_velocity 2 mm/s"
    assert label not in mov["refused"], mov["refused"]
    r2 = mov["rows"][label]
    assert r2["pooled"] < r2["floor_linear_pooled"] * (1 - 1e-9), r2
    # the product's derived min_velocity (dynid init: 3 sigma of the velocity noise, 1 um encoders)
    # keeps every moving row but the chatter too: there CAD is better than the fits (1.19 x in the full
    # run, 1.09-1.28 x on the quick DYNID_TEST_SEED 0-3; the truth itself 1.18-1.26 x: the chatter
    # rows' processed states, not the fit, decide it). The claim is the threshold, 1.0: the lowest draw
    # is 9 % above it, several times the RMSEs' few per cent of spread (the 1.1 once asserted failed
    # on seed 3)
    d = mov["rows"]["Nonlinear (Opt.), min_velocity derived (3 sigma_v)"]
    assert min(d["kept_pct"]) > 99 and d["ratio"] > 1.0, d
    # section B10 (bench/README "B10. The 3-RPS moving rows with Kalman-smoothed states"): the same
    # description with processing.derivatives = "kalman"
    k = lim["kalman"]
    ks, st = k["settings"], k["states"]
    # the smoother's equivalent cut-off f_K = lambda^(-1/8) / (2 pi T) is above the Butterworth path's
    # 10 Hz (its likelihood follows the 1 um encoder's quantization noise, 1e-6/sqrt(12) m)...
    assert min(ks["cutoff_hz"]) > 10.0, ks
    # ...so it smears a velocity reversal over less time: near the reversals (true speed below v_S)
    # the processed velocity is closer to the exact one on every leg. The error of a smeared kink
    # scales with the filter's time constant 1/(2 pi f_c), 10 / f_K < 0.35 here; the noise (the same
    # quantization through a wider band) adds to it, so only 0.75 is asserted
    for a, b in zip(st["kalman"]["dq_slow"], st["butterworth"]["dq_slow"]):
        assert a < 0.75 * b, st
    # the smoother's own velocity std (steady state, its white-snap model) is far below its actual
    # error at the reversals (the friction's stick-slip is not in its model), so the product's rule,
    # 3 sigma_v (dynid init), keeps the chattering rows: (nearly) every row kept, and there the fit is
    # at CAD's level or worse (1.03-2.3 x on the quick draws 0, 2, 3; 1.14-1.69 x on the full draws 0-2), far from 0.5 x
    assert all(3 * s < e for s, e in zip(ks["sigma_v"], st["kalman"]["dq_slow"])), (ks, st)
    km = k["moving"]
    d = km["rows"]["Nonlinear (Opt.), min_velocity derived (3 sigma_v)"]
    assert min(d["kept_pct"]) > 98 and d["ratio"] > 0.9, d
    # at min_velocity = v_S/10 (0.5 mm/s, fixed in advance from the truth's v_S) the Kalman path's
    # velocity error at the reversals is about a quarter of min_velocity (a wrong Coulomb sign on
    # few rows) where the Butterworth one's is about half: the truth drops from above 0.7 x CAD
    # (asserted above) to below 0.5 x, and the Stribeck fit fixed in advance reaches the target there
    e = km["rows"]["Nonlinear (Opt.), min_velocity v_S/10"]
    assert e["truth"] < 0.45 * e["cad"] and e["ratio"] <= 0.5, e
    # but no setting derived from the training log alone reaches it: the smoother's 3 sigma_v keeps
    # the chatter (above), and B9's reversal rule at the smoother's cut-off, a_rev / (2 pi f_K), lies
    # below v_S/10 (the full run fits it: 0.52-0.76 x CAD over three draws)
    assert max(ks["reversal_min_velocity"]) < 0.0005, ks
    # the training log's 2 mm/s Stribeck fit was refused in B9 for a dFs (recorded draw): not for lack
    # of rows in the hump's band (hundreds a leg), but because the estimator's warm-start grid starts at
    # v_S = 0.02 x the RMS speed, where the dFs column exp(-(|v|/v_S)^2) is numerically zero on every
    # row above 2 mm/s for the legs it names (entries below 1e-9 against order 1 in the Coulomb
    # columns; the rank test drops a column below 1e-14 of the largest norm), while at the grid's
    # second v_S the column is there (above 1e-3) on every leg. Since the warm-start fix the estimator
    # skips such a candidate (recorded with its reason) and fits from the others (asserted above)
    assert min(k["hump_band_rows"]) > 100, k["hump_band_rows"]
    gc = k["grid_column"]
    assert min(gc[0.05]) > 1e-3, gc
    # (a skipped candidate is one at the grid's first v_S, for legs whose column is below 1e-9 there)
    for vs_rel, _, why in r2["warm_start_refused"]:
        legs = [int(x) - 1 for x in re.findall(r"dFs_P(\d)", why)]
        assert vs_rel == 0.02 and legs and all(gc[0.02][j] < 1e-9 for j in legs), (why, gc)
    out = capsys.readouterr().out
    assert "B1." in out and "B4." in out and "B8." in out and "B9." in out and "B10." in out and "Linear (Opt.)" in out
