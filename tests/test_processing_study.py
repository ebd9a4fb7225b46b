"""The signal-processing study of bench/processing_study.py (issue 6, paper 004 Fig. 4), in its
quick version: it runs end to end and prints its table."""

from __future__ import annotations

import importlib.util

from conftest import REPO


def test_processing_study_quick(capsys):
    spec = importlib.util.spec_from_file_location("processing_study", REPO / "bench" / "processing_study.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    res = study.study(quick=True)
    print(study.table(res))
    out = capsys.readouterr().out
    assert "Prediction error variance" in out and "(c) frequency domain" in out
    rows = res["rows"]
    # the frequency-domain processing predicts the circle better than the time-domain chain
    assert rows["(c) frequency domain"]["mean_variance_N2"] < rows["(b) time domain"]["mean_variance_N2"]
    # and the leakage of the implicit fit with a 0.5 % period mismatch, which the DFT avoids
    assert res["leakage"]["dft_rms_error_acc"] < 1e-9 < res["leakage"]["implicit_fit_rms_error_acc"]
