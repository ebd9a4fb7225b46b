"""The signal-processing study of bench/processing_study.py (issues 6 and 17, paper 004 Fig. 4), in
its quick version: the same fixed excitation, rates and twin as the full study, 2 periods instead
of 4; it reaches the full study's conclusion (bench/README.md section 7) for the physical reason
given there, with a margin from the noise replicates of the experiment."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from scipy import stats

from conftest import REPO


def _study():
    spec = importlib.util.spec_from_file_location("processing_study", REPO / "bench" / "processing_study.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    return study


@pytest.mark.numerics
def test_processing_study_quick(capsys):
    """The study's own seeds (bench/processing_study.py), not conftest.seed: this is the recorded study
    of bench/README.md section 7, in its quick version; its replicates are what the margins count."""
    study = _study()
    b, c, c2 = study.B, study.C, study.C2
    replicates = 4  # the study's 3 (bench/README section 7) and one more noise draw of the same motion
    res = study.study(quick=True, labels=(b, c, c2), coulomb_free=False, seeds=replicates)
    print(study.table(res))
    out = capsys.readouterr().out
    assert "Prediction error variance" in out and c2 in out
    print(out)  # shown on failure, or with pytest -rP
    rows = res["rows"]
    pred = {k: r["mean_variance_N2"] for k, r in rows.items()}
    truth = {k: r["truth_residual_variance_N2"] for k, r in rows.items()}
    # The study's conclusion: the time-domain chain (b) predicts the circle better than the
    # frequency-domain chain at paper 004's kind of window (c). Margin: the same motion measured
    # again with other sensor seeds (independent replicates of the experiment); the one-sided
    # 99.9 % lower confidence bound (Student t) of the mean difference must be above zero (a false
    # alarm of 1e-3). With the study's 3 replicates that bound is mean - 22.3 se: it failed on other
    # OpenBLAS kernels (9.3 +- 0.45 N^2 there: the Coulomb switching amplifies the kernels' rounding
    # into another motion, bench/README section 7), and 99.5 % (9.9 se) was a 5e-3 false alarm; with 4,
    # mean - 10.2 se: 6.3 N^2 here, 5.9 with OpenBLAS's Haswell kernel
    dd = np.asarray(res["difference_c_minus_b"]["values"])
    assert dd.size == replicates
    se = dd.std(ddof=1) / np.sqrt(dd.size)
    assert dd.mean() - stats.t.ppf(0.999, dd.size - 1) * se > 0, (dd, se)
    # ... for the physical reason of bench/README section 7: the window at 10.5 f0 (2.1 Hz) removes
    # the closed loop's response to the Coulomb reversals from the states but not from the forces,
    # so the processed data are less consistent with the true model than after (b) (cut-off 4 Hz).
    # truth = systematic part + the force noise left: 4 N^2 after (b) (forces unfiltered), 4/P N^2
    # after averaging P periods; the systematic parts differ by more than 5 standard errors of a
    # sample variance of the noise (4 N^2 sqrt(2/n), n samples of one period and drive)
    n = round(study.RATE / study.F0)
    noise_se = 4.0 * np.sqrt(2.0 / n)
    assert (truth[c] - 4.0 / res["periods"]) - (truth[b] - 4.0) > 5 * noise_se, truth
    # ... and not because of the domain: the frequency-domain chain with the band of (b) (c')
    # predicts like (b); the difference is small against the band's effect (0.2 against 0.25 x 8.5 N^2)
    assert abs(pred[c2] - pred[b]) < 0.25 * dd.mean(), pred
    # every model is above the force noise of the validation run (4 N^2): a floor no fit can beat
    for k, r in rows.items():
        assert np.all(np.isfinite(r["error_variance_N2"])) and r["mean_variance_N2"] > 4.0 * 0.9, k
    # the leakage of the implicit fit with a 0.5 % period mismatch, which the exact DFT avoids
    # (analytic signals: no excitation involved)
    assert res["leakage"]["dft_rms_error_acc"] < 1e-9 < res["leakage"]["implicit_fit_rms_error_acc"]
