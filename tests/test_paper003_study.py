"""Paper 003's Tables 1, 4, 6, 7, 8 on its cobot6r twin (dynid.studies.paper003; issue 19, items 5-6).

The quick study runs once per module (logs and results in a temporary folder): the friction
experiment, training, VT1 and VT2 simulated with ``dynid simulate`` (Eq. 15 friction with a 10 ms
memory), ``dynid friction``, one ``dynid identify`` per row. The tests check item 6's targets
with margins from the method (the noise floor a held-out Sum cannot separate), the figures by a
second route where one exists (``dynid identify``'s own validation; Table 1's network against the
product's), and that the quick version concludes what the last full run concluded
(bench/data/paper003_full.json, written by ``bench/paper003_study.py --record``).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import torch  # the [learning] extra (make test installs it): the +PI-LSTM row needs it
from dynid.signals import lowpass
from dynid.studies.paper003 import (
    FAMILIES,
    JOINTS,
    LOWPASS,
    ONE_SHOT,
    conclusions,
    paper003_study,
    twin_documents,
)

from conftest import draw, seed  # noqa: E402

torch.set_num_threads(1)
FULL = Path(__file__).resolve().parents[1] / "bench" / "data" / "paper003_full.json"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper003")
    # another draw of the experiments under DYNID_TEST_SEED (conftest.draw); the comparison with the
    # recorded full study (test_quick_concludes_...) is for the recorded draw and is not a numerics test
    return SimpleNamespace(folder=folder, result=paper003_study(quick=True, folder=folder, draw=draw()))


def _sums(study, vt):
    return {k: float(np.sum(v)) for k, v in study.result.vt[vt].items()}


def test_the_twin_records_its_friction_with_memory(study):
    truth = json.loads((study.folder / "train" / "truth.json").read_text())
    doc = twin_documents()["train"]["robot"]["friction"]
    assert truth["ground_truth_friction"] == doc and doc["memory"] == 0.01 and doc["model"] == "smooth_stribeck"
    # the linear friction the Eq. 15 truth replaces is recorded as 0 in the plant's parameters
    std = dict(zip(truth["parameter_names"], truth["true_parameters"]))
    replaced = truth["replaced_by_ground_truth_friction"]
    assert len(replaced) == 18 and all(std[n] == 0.0 for n in replaced)
    # every experiment runs the same plant
    for k in ("VT1", "VT2", "friction"):
        other = json.loads((study.folder / k / "truth.json").read_text())
        assert other["ground_truth_friction"] == doc and other["true_parameters"] == truth["true_parameters"]


def test_the_example_friction_config_is_the_studys(study):
    """examples/friction/paper003_twin.toml (the command-line route) fits what the study fits."""
    from dynid.config.friction import load_friction_config

    ex = load_friction_config(Path(__file__).resolve().parents[1] / "examples" / "friction" / "paper003_twin.toml")
    f = study.result.settings["friction"]["friction"]
    assert (list(ex.models), ex.skip, ex.settle, ex.held_out) == (f["models"], f["skip"], f["settle"], f["held_out"])


def test_the_friction_experiment_is_the_designed_one(study):
    """The study runs dynid design (kind constant_velocity, min_span) -> simulate -> friction: the
    slow speeds get the long windows where K_v is decided, the fast ones the shortest, and the
    friction log's windows have the designed lengths."""
    design = json.loads((study.folder / "friction_design" / "design.json").read_text())
    doc = study.result.settings["design"]["design"]
    log = np.genfromtxt(study.folder / "friction" / "log.csv", delimiter=",", names=True)
    rate = 1.0 / float(np.median(np.diff(log["t"])))
    for j in design["joints"]:
        for lv in j["speeds"]:
            expect = min(max(doc["window"], doc["min_span"] / lv["speed"]), doc["max_window"])
            assert lv["window"] == pytest.approx(expect, rel=1e-9)
        k = int(j["name"].split("_")[1])
        for lv in (j["speeds"][0], j["speeds"][-1]):
            on = (log["cv_joint"] == k) & np.isclose(log["cv_speed"], lv["speed"]) & (log["cv_direction"] > 0)
            assert abs(on.sum() / rate - lv["window"]) <= 2.0 / rate
    assert study.result.settings["friction"]["friction"]["skip"] == doc["skip"]
    # the stored design that examples/twins/cobot6r_paper003_friction.toml replays is this design
    stored = Path(__file__).resolve().parents[1] / "examples" / "twins" / "cobot6r_paper003_friction_design.json"
    assert stored.read_bytes() == (study.folder / "friction_design" / "design.json").read_bytes()


@pytest.mark.numerics
def test_friction_fit_is_the_best_the_points_allow(study):
    """Eq. 15 fitted to each joint's points fits them at least as well as the truth's own
    coefficients (weighted, the fit's objective): a fit worse than the truth is a local minimum
    (joint 1's was, chi2 172 against 16, before the fits started from every Stribeck-velocity
    level). And the points decide K_v to better than 5 % (1 std at the truth), so a 10 % target
    on it is meaningful on every joint."""
    for j, c in study.result.friction_identifiability.items():
        assert c["chi2_red_fit"] <= c["chi2_red_truth"] * (1 + 1e-6), (j, c)
        assert c["rel_std_at_truth"]["kv"] < 0.05, (j, c)


@pytest.mark.numerics
def test_noise_floor_is_the_filtered_noise(study):
    """The floor row is the noise std times the low-pass's noise gain; by another route: the std of
    a long filtered white sequence (200 000 samples: its relative sampling error is ~0.5 %)."""
    fs = 200.0
    x = np.random.default_rng(seed(0)).standard_normal(200_000)
    gain = float(np.std(lowpass(x, LOWPASS["cutoff_hz"], fs, LOWPASS["order"])[1000:-1000]))
    noise = np.asarray(twin_documents()["train"]["sensors"]["force_noise_std"])
    for vt in ("VT1", "VT2"):
        np.testing.assert_allclose(study.result.vt[vt]["noise floor"], noise * gain, rtol=0.02)


def test_study_figures_are_the_products_own_validation(study):
    """VT1 per-joint RMSE of every row as the study computes it (its own pass over the processed
    log) equals what dynid identify reported for its held-out log, +PI-LSTM included."""
    r = study.result
    for name, per in r.product_vt1.items():
        np.testing.assert_allclose(r.vt["VT1"][name] if name in r.vt["VT1"] else r.table7["VT1"][name[3:]], per,
                                   rtol=1e-9)


def test_table1_lstm_is_the_products_network(study):
    """Table 1's PI-LSTM (residual route) and the +PI-LSTM row (model + network route) on VT2."""
    r = study.result
    lstm = next(row for row in r.table1 if row["model"] == "PI-LSTM")
    np.testing.assert_allclose(lstm["rmse_per_joint"], r.vt["VT2"]["+PI-LSTM"], rtol=1e-7)
    alone = next(row for row in r.table1 if row["model"] == "Proposed-FBPE alone")
    np.testing.assert_allclose(alone["rmse_per_joint"], r.vt["VT2"]["Proposed-FBPE"], rtol=1e-7)


@pytest.mark.numerics
def test_no_row_beats_the_noise(study):
    """Held-out measurement noise is irreducible: no row's RMSE goes below 0.8 x the floor on any
    joint (the RMSE of ~1000 low-passed noise samples, ~100 effective at 10 Hz of 200 Hz, scatters
    by ~7 %; 0.8 is 3 of those)."""
    for vt in ("VT1", "VT2"):
        floor = np.asarray(study.result.vt[vt]["noise floor"])
        for name, per in study.result.vt[vt].items():
            assert np.all(np.asarray(per) >= 0.8 * floor), (vt, name)


@pytest.mark.numerics
def test_target_1_proposed_fbpe_against_wls_fbpe(study):
    """Item 6 asks Proposed-FBPE's VT2 Sum to be at most 0.8 x WLS+LMI's (paper: 22.3 vs 28.6). On
    the twin's in-range trajectories the full run gives 0.815 (bench/README; 0.712 on the earlier
    trajectories that left the joint limits): the target is not met, and the record's verdict
    (``target_1_holds``) is compared with the quick run's by the conclusions test. What holds on both
    and is checked here: Proposed-FBPE is better than every one-shot row on both logs by more than the
    noise floor's Sum (what noise alone could move a Sum)."""
    for vt in ("VT1", "VT2"):
        s = _sums(study, vt)
        assert min(s[r] for r in ONE_SHOT) - s["Proposed-FBPE"] > s["noise floor"], (vt, s)


@pytest.mark.numerics
def test_target_2_pi_lstm(study):
    """Item 6 asks the PI-LSTM to lower the VT2 Sum by at least 20 %. The full run on the in-range
    trajectories gains 56.8 % (bench/README), the quick one what the record's conclusions say. Here
    what holds on both: the network lowers the Sum by more than the noise floor's Sum. (An earlier
    version also asserted that it cannot go below the truth-with-memory row: wrong — that row is the
    plant's friction evaluated on the processed states, and a sequence model that sees the processed
    signals also learns the low-pass's errors in the variables; on the in-range twin it reaches 2.38
    against that row's 4.39. The floor itself is checked by test_no_row_beats_the_noise.)"""
    s = _sums(study, "VT2")
    assert s["Proposed-FBPE"] - s["+PI-LSTM"] > s["noise floor"]


@pytest.mark.numerics
def test_target_3_friction_coefficients_of_the_true_family(study):
    """dynid friction's Eq. 15 fit to the steady-state points (``settle = true``) of the designed
    experiment (the steady state of the plant's friction is exactly Eq. 15): every coefficient
    within 10 % of the truth on every joint (bench/README: 36 of 36, the worst 4.6 %; with the
    fixed 1 s skip and 4 s windows joint 4's K_v was -11.4 %, a PID transient in its 0.005 rad/s
    point)."""
    fit = study.result.friction_fit
    for j in JOINTS:
        for n in ("fc", "fs", "fv", "vs", "kv", "alpha"):
            assert abs(fit[j][n]["rel_error"]) <= 0.10, (j, n, fit[j][n])


@pytest.mark.numerics
def test_target_4_nonlinear_friction_beats_coulomb_viscous(study):
    """Table 7: under Proposed-FBPE each nonlinear family predicts VT1 and VT2 better than Coulomb-
    viscous by more than the noise floor's Sum, and the improved Stribeck model (the truth's
    steady-state family) best, as in the paper."""
    lin = FAMILIES[0][0]
    for vt in ("VT1", "VT2"):
        t7 = {k: float(np.sum(v)) for k, v in study.result.table7[vt].items()}
        floor = _sums(study, vt)["noise floor"]
        for label, *_ in FAMILIES[1:]:
            assert t7[lin] - t7[label] > floor, (vt, label, t7)
        assert min(t7, key=t7.get) == FAMILIES[3][0]


def test_quick_concludes_what_the_full_study_concluded(study):
    if not FULL.is_file():
        pytest.fail(f"{FULL} is missing: run bench/paper003_study.py --record {FULL}")
    full = json.loads(FULL.read_text())
    assert not full["quick"]
    assert conclusions(study.result) == full["conclusions"]
