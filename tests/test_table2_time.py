"""Paper 004 Table II's twin in the time domain, at reduced size (issue 17, item 5): the nominal
hexapod on the stored D-optimal design (``bench/hexapod_coverage.py --table2``: 8 periods; here 3,
two to train, one held out), 10 Hz low-pass with ``min_velocity`` and ``reversal_guard``.

The acceptance: for at least 90 % of the 24 rows (22) the truth lies within 3 std of Gauss-Markov
and of the time-domain maximum likelihood, and ML's cut-off is interior to its searched range. The
full version (bench/README §9 B, "Table II twin on the stored design") has GM 24 and ML 24 of 24
with f_c 25.2 Hz in 5-80 Hz; this one, measured, GM 24 and ML 23 of 24 with f_c 20 Hz (neighbours
15.9 and 25.2): the same conclusion. The count is statistical (each row's |z| is a draw); the
margin is two rows of the 24: three or more of 24 independent rows beyond 3 std has probability
C(24, 3) 0.0027^3 ~ 4e-5 (a false alarm on another draw, DYNID_TEST_SEED: conftest.draw)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import REPO, draw

sys.path.insert(0, str(REPO / "bench"))
import hexapod_coverage as hc  # noqa: E402

from dynid.config import parse_config  # noqa: E402
from dynid.pipeline.identification import identify  # noqa: E402

NEED = 22  # 90 % of the 24 rows


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("table2")
    doc, truth = hc.table2_log(d, periods=3, draw=draw())
    return d, doc, truth


def _run(log, ident: dict):
    d, doc, truth = log
    out = identify(parse_config({**doc, "processing": hc.TABLE2_GUARD,
                                 "identification": {"structure": "paper", **ident}}, d))
    names, z = hc.table2_z(out, truth)
    assert len(names) == 24
    return out, z


@pytest.mark.numerics
def test_gauss_markov_covers_the_truth_on_90_percent_of_the_rows(log):
    out, z = _run(log, {"method": "gm"})
    assert int((z < 3).sum()) >= NEED, dict(zip(hc.table2_z(out, log[2])[0], np.round(z, 2)))


@pytest.mark.numerics
def test_maximum_likelihood_covers_the_truth_with_an_interior_cut_off(log):
    out, z = _run(log, {"method": "ml", "cutoff_range_hz": [5.0, 80.0], **hc.TABLE2_NOISE})
    assert int((z < 3).sum()) >= NEED, np.round(z, 2)
    sv = out.result.solver
    grid = [r["cutoff_hz"] for r in sv["profile"]]
    assert grid[0] < sv["cutoff_hz"] < grid[-1]  # interior: the likelihood has its minimum inside the range
    costs = [r["cost"] for r in sv["profile"] if r["cost"] is not None]
    assert min(costs) == pytest.approx(next(r["cost"] for r in sv["profile"] if r["cutoff_hz"] == sv["cutoff_hz"]))
