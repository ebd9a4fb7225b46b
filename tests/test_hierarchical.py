"""``[identification] hierarchical = true`` (paper 003 §3.3, Algorithm 1; issue 19 item 2): on a
6R cobot whose joints have paper 003's improved Stribeck friction (Eq. 15, the coefficients of
examples/friction/simulate.toml), the alternation of rigid-body WLS (+ LMI) and per-joint friction
refits converges by the paper's rules well before 50 iterations, recovers the friction within its
reported uncertainty, and predicts a held-out motion at the noise level, where the one-shot WLS
with linear Coulomb + viscous friction cannot. With the linear family the alternation lands on the
one-shot joint least squares (block-coordinate descent on the same objective). Bad settings are
one-line errors.

The logs are synthesized as in tests/test_stribeck_identify.py: torques of a Fourier excitation
by the regressor (rigid body, rotor inertia, offset) plus the friction model itself
(:class:`~dynid.model.friction.SmoothStribeck`, the class ``[robot.friction] model =
"smooth_stribeck"`` of dynid simulate uses), white Gaussian noise per joint.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import run_dynid, seed
from dynid.config import parse_config
from dynid.errors import ConfigError, InputError
from dynid.estimation.friction_curves import curve_force
from dynid.model import load_model, regressor
from dynid.model.friction import SmoothStribeck
from dynid.pipeline import identify
from dynid.pipeline.hierarchical import EPS_PARAM, EPS_RMSE, EPS_TOTAL, MAX_ITER
from dynid.pipeline.identification import write_outputs
from dynid.trajectories import FourierTrajectory

FS = 100.0
COBOT = load_model("builtin:cobot6r")
LAY = COBOT.layout
FC, FV = LAY.extra_index["fc"], LAY.extra_index["fv"]
NAMES = COBOT.joint_names
TRUTH = COBOT.nominal_parameters().copy()
for _b in range(LAY.n_bodies):  # well inside the physically consistent set
    TRUTH[10 * _b] += 0.01
    TRUTH[10 * _b + np.array([4, 6, 9])] += 0.02
# paper 003's improved Stribeck model (Eq. 15) per joint: examples/friction/simulate.toml
FRICTION = dict(fc=[3.0, 3.5, 2.5, 1.2, 1.0, 0.8], fs=[5.0, 5.5, 4.0, 1.8, 1.6, 1.2], fv=[4.0, 5.0, 3.0, 1.5, 1.2, 1.0],
                vs=[0.05, 0.04, 0.06, 0.08, 0.05, 0.1], kv=[200.0, 300.0, 150.0, 100.0, 200.0, 150.0],
                alpha=[0.7, 0.6, 0.8, 0.9, 0.7, 0.8])
TRUE_FRICTION = SmoothStribeck(**FRICTION)
SIGMA = np.array([0.3, 0.3, 0.2, 0.1, 0.05, 0.05])  # torque noise [N*m]


def _log(path: Path, seed: int, n: int) -> None:
    lo, hi = COBOT.position_limits()
    traj = FourierTrajectory.random(6, 5, 0.1, np.random.default_rng(seed), lo, hi, max_velocity=1.5,
                                    max_acceleration=5.0, fill=0.7)
    t = np.arange(n) / FS
    q, dq, ddq = traj.sample(t)
    rigid = TRUTH.copy()
    rigid[FC] = rigid[FV] = 0.0
    tau = regressor(COBOT, q, dq, ddq) @ rigid + TRUE_FRICTION.force(dq)
    tau = tau + np.random.default_rng(seed + 100).standard_normal(tau.shape) * SIGMA
    np.savez(path, t=t, **{f"q_{j}": q[:, k] for k, j in enumerate(NAMES)},
             **{f"tau_{j}": tau[:, k] for k, j in enumerate(NAMES)})


def _doc(folder: Path, ident: dict, model: str = "builtin:cobot6r", plots: bool = False) -> dict:
    return {
        "robot": {"model": model},
        "data": {"file": str(folder / "train.npz"), "time": {"column": "t", "unit": "s"},
                 "position": {"columns": [f"q_{j}" for j in NAMES]}, "effort": {"columns": [f"tau_{j}" for j in NAMES]}},
        "validation": {"file": str(folder / "valid.npz")},
        "identification": ident,
        "output": {"plots": plots},
    }


def _config(folder: Path, ident: dict, **kw):
    return parse_config(_doc(folder, ident, **kw), folder)


HIER = {"method": "wls", "hierarchical": True, "friction_model": "arctan"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("hier")
    _log(d / "train.npz", seed(1), 2000)
    _log(d / "valid.npz", seed(2), 1000)
    out = {"dir": d}
    for key, ident in (("linear", {"method": "wls"}), ("arctan", HIER),
                       ("hier_linear", {**HIER, "friction_model": "linear"})):
        out[key] = identify(_config(d, ident))
    return out


def _held_out(o) -> np.ndarray:
    return np.array(o.validation.to_dict()["rmse_per_joint"])


@pytest.mark.numerics
def test_loop_converges_by_the_papers_rules_before_50_iterations(runs):
    h = runs["arctan"].result.solver["hierarchical"]
    assert h["stop"] == "converged" and h["converged"] and h["iterations"] < MAX_ITER, h["stop"]
    assert h["family"] == "arctan" and h["model"] == "smooth_stribeck" and h["equation"] == "paper 003 Eq. 15"
    hist = h["history"]
    assert len(hist) == h["iterations"] and all(x["kept"] for x in hist)
    last, before = hist[-1], hist[-2]
    change = np.abs(np.array(last["rmse_per_joint"]) - before["rmse_per_joint"])
    assert np.all(change <= EPS_RMSE) and change.sum() <= EPS_TOTAL and last["param_change"] <= EPS_PARAM
    assert before["param_change"] > EPS_PARAM  # it stopped at the first iteration that met the rules
    # block-coordinate descent on one objective: the training RMSE never rises by more than the loop's own
    # stopping rule lets it (RISE_TOL = 1e-4: it keeps the previous iterate and stops)
    totals = [x["rmse_total"] for x in hist]
    assert all(b <= a * (1 + 1e-4) for a, b in zip(totals, totals[1:]))
    # the model is complete: what remains of the training torques is the noise (2000 samples a joint: the
    # sample std of white noise within 1.6 % (1 std) of the truth, ~0.4 % low for the fitted parameters;
    # 7 % is 4.2 std: 3e-5 per joint)
    np.testing.assert_allclose(last["rmse_per_joint"], SIGMA, rtol=0.07)


@pytest.mark.numerics
def test_the_true_family_is_recovered_within_its_reported_uncertainty(runs):
    """Every coefficient of Eq. 15 within 4.5 of its reported standard deviations (7e-6 each, 2.5e-4
    over the 36; the residuals are white here and the rigid-body part is well determined, so the
    Jacobian std, conditional on it, is honest: at most 3.1 over 3 draws), and the friction curve
    within 3 % of the truth over the speeds the motion covers: a fit of p = 6 coefficients to n =
    2000 rows predicts to sigma sqrt(p / n) on average over its rows, 0.4-0.5 % of the curve here,
    so 3 % is 6 of that or more (measured at most 1.5 % over 3 draws; the coefficients' errors are
    strongly correlated and cancel in the curve: their std alone, added up, would allow 15 %, and
    their covariance is not reported)."""
    fr = runs["arctan"].result.solver["hierarchical"]["friction"]
    v = np.linspace(0.1, 1.2, 50)
    for k, j in enumerate(NAMES):
        c = fr[j]
        for name in ("fc", "fs", "fv", "vs", "kv", "alpha"):
            est, std = c[name]["value"], c[name]["std"]
            assert std is not None and not c[name]["at_bound"], (j, name)
            assert abs(est - FRICTION[name][k]) < 4.5 * std, (j, name, est, FRICTION[name][k], std)
        fit = curve_force("smooth_stribeck", {n: c[n]["value"] for n in c}, v)
        true = curve_force("smooth_stribeck", {n: FRICTION[n][k] for n in FRICTION}, v)
        np.testing.assert_allclose(fit, true, rtol=0.03, err_msg=j)


@pytest.mark.numerics
def test_held_out_prediction_at_the_noise_level_and_better_than_one_shot_linear_wls(runs):
    hier, lin = _held_out(runs["arctan"]), _held_out(runs["linear"])
    # the rigid-body part plus the fitted friction curves predict the held-out motion to the noise: 1000 rows a
    # joint, the sample rms within 2.2 % (1 std) of sigma, plus the estimate's share (p / n ~ 1 %); 10 % is 4 std
    np.testing.assert_allclose(hier, SIGMA, rtol=0.1)
    # on the same rows and noise, the linear model's systematic misfit: hier / lin 0.50-0.82 per joint over 3 draws
    assert np.all(hier <= lin)
    # the linear Coulomb + viscous model misses the Stribeck hump and the power law: 0.67-0.71 in total over 3 draws
    assert hier.sum() < 0.8 * lin.sum()


@pytest.mark.numerics
def test_the_nominal_baseline_keeps_the_descriptions_friction(runs):
    """The prior every model must beat is the robot description *with* its friction terms, as in a
    one-shot run on the same held-out rows, not the friction-free regressor the hierarchical fit
    uses: the same nominal errors as the linear run's, to rounding."""
    hier, lin = runs["arctan"], runs["linear"]
    np.testing.assert_allclose(hier.nominal_validation.rmse, lin.nominal_validation.rmse, rtol=1e-9)
    assert hier.prior is not None and hier.prior["beats_nominal"]


@pytest.mark.numerics
def test_linear_family_lands_on_the_one_shot_least_squares(runs):
    """Alternating two least-squares fits of one objective converges to its joint minimizer: with the
    linear family (Eq. 2) the hierarchical loop lands on the estimate of one WLS with Coulomb + viscous
    columns. Up to their weights: the one-shot WLS weights each joint by the noise of its OLS
    residual, the loop by its own residual's, which differ by a relative delta (7-10 % over 3 draws);
    a WLS estimate moves under that by about delta of its std (to first order the move's covariance
    is at most delta^2 times the estimate's), so every parameter within 4.5 delta of its std (the
    one-shot model's misfit of the Stribeck hump is not noise, so a first-order guide: at most
    0.07 std measured). Its held-out errors differed from the one-shot's by up to 1.8e-3, against
    the 2e-3 once asserted."""
    o = runs["hier_linear"]
    h = o.result.solver["hierarchical"]
    assert h["stop"] == "converged" and h["iterations"] <= 5
    base = runs["linear"].result
    delta = float(np.max(np.abs(np.array(h["history"][-1]["rmse_per_joint"]) / base.noise_std - 1)))
    loop = dict(zip(o.result.names, o.result.params))
    for k, j in enumerate(NAMES):
        loop[f"fc{k + 1}"], loop[f"fv{k + 1}"] = h["friction"][j]["fc"]["value"], h["friction"][j]["fv"]["value"]
    assert set(loop) == set(base.names)
    z = {n: (loop[n] - v) / s for n, v, s in zip(base.names, base.params, base.bse)}
    assert all(abs(x) < 4.5 * delta for x in z.values()), (delta, max(z.items(), key=lambda t: abs(t[1])))


def _tail(h) -> float:
    """How far the loop's last curves can be from its fixed point, in its own measure of a change
    (the relative change of each joint's curve on the training rows, its norm over the joints): the
    loop converges linearly (each change 0.6-0.7 of the one before), so the rest of the way is at
    most c_last rho / (1 - rho), rho the largest of its last three ratios."""
    c = [x["param_change"] for x in h["history"] if x["param_change"] is not None]
    rho = max(b / a for a, b in zip(c[-4:-1], c[-3:]))
    assert rho < 1, c
    return c[-1] * rho / (1 - rho)


def _curve_change(a: dict, b: dict, v: np.ndarray) -> float:
    """The loop's measure of the change between two curves on the speeds ``v``."""
    fa, fb = (curve_force("smooth_stribeck", {n: c[n]["value"] for n in FRICTION}, v) for c in (a, b))
    return float(np.linalg.norm(fa - fb) / max(np.linalg.norm(fa), np.linalg.norm(fb)))


@pytest.mark.numerics
def test_with_lmi_constraints_and_a_friction_prior(runs, tmp_path):
    """physical_consistency = true: each rigid-body fit is the WLS + LMI of dynid.estimation.physical;
    friction_prior: the loop starts from a dynid friction result (here the truth 30 % off) and ends on
    the same friction as without one: no constraint binds (the truth is well inside), so both loops
    have the same fixed point, and each stops within its convergence tail (_tail) of it."""
    d = runs["dir"]
    models = {j: {"models": {"smooth_stribeck": {"coefficients": {
        n: {"value": 1.3 * FRICTION[n][k], "std": None, "at_bound": False} for n in FRICTION}}}}
        for k, j in enumerate(NAMES)}
    prior = tmp_path / "friction.json"
    prior.write_text(json.dumps({"format": "dynid-friction-1", "joints": models}))
    phys = {"physical_consistency": True, "margin": 1e-4}
    o = identify(_config(d, {**HIER, **phys, "friction_prior": str(prior)}))
    lin = identify(_config(d, {"method": "wls", **phys}))
    h = o.result.solver["hierarchical"]
    assert o.result.method.startswith("WLS+LMI") and h["stop"] == "converged" and h["iterations"] < MAX_ITER
    assert h["start"].startswith("friction_prior")
    assert np.all(_held_out(o) <= _held_out(lin)) and _held_out(o).sum() < 0.8 * _held_out(lin).sum()
    assert o.result.solver["active_constraints"] == []
    ref = runs["arctan"]
    bound = _tail(h) + _tail(ref.result.solver["hierarchical"])
    for k, j in enumerate(NAMES):  # on the training rows' speeds, as the loop measures (the curves are odd)
        d = _curve_change(h["friction"][j], ref.result.solver["hierarchical"]["friction"][j], np.abs(ref.train.dq[:, k]))
        assert d <= bound, (j, d, bound)


def test_outputs_carry_friction_history_and_plot(runs, tmp_path):
    o = identify(_config(runs["dir"], HIER, plots=True))
    files = write_outputs(o, tmp_path / "out")
    assert "hierarchical.png" in files and (tmp_path / "out" / "hierarchical.png").stat().st_size > 10_000
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    h = doc["solver"]["hierarchical"]
    assert set(h["friction"]) == set(NAMES) and len(h["history"]) == h["iterations"]
    assert {"rmse_per_joint", "rmse_total", "param_change"} <= set(h["history"][0])
    # the regressor has no friction columns; the rotor inertia and the offset stay
    names = [p["name"] for p in doc["params"]]
    assert not any(n.startswith(("fc", "fv")) for n in names) and any(n.startswith("off") for n in names)
    text = (tmp_path / "out" / "summary.txt").read_text()
    assert "hierarchical iterative identification" in text and "iteration history" in text


@pytest.mark.parametrize("ident, message", [
    ({"method": "wls", "friction_model": "arctan"}, "hierarchical = true"),
    ({"method": "wls", "hierarchical": True}, "name the friction family"),
    ({"method": "wls", "hierarchical": True, "friction_model": "lugre"}, "friction_model"),
    ({"method": "gm", "hierarchical": True, "friction_model": "arctan"}, "not method 'gm'"),
    ({"method": "wls", "friction_prior": "f.json"}, "friction_prior"),
    ({**HIER, "coulomb_smoothing": "auto"}, "coulomb_smoothing"),
    ({**HIER, "covariance": "hac"}, "covariance"),
])
def test_config_errors(tmp_path, ident, message):
    with pytest.raises(ConfigError, match=message):
        _config(tmp_path, ident)


def test_runtime_errors(runs, tmp_path):
    d = runs["dir"]
    with pytest.raises(InputError, match="not found"):
        identify(_config(d, {**HIER, "friction_prior": str(tmp_path / "none.json")}))
    other = tmp_path / "friction.json"
    other.write_text(json.dumps({"joints": {j: {"models": {"power_law": {"coefficients": {}}}} for j in NAMES}}))
    with pytest.raises(InputError, match="no 'smooth_stribeck' fit"):
        identify(_config(d, {**HIER, "friction_prior": str(other)}))


def test_cli_one_line_error(runs, tmp_path):
    d = runs["dir"]
    cols = lambda k: "[" + ", ".join(f'"{k}_{j}"' for j in NAMES) + "]"  # noqa: E731
    cfg = tmp_path / "identify.toml"
    cfg.write_text(f"""[robot]\nmodel = "builtin:cobot6r"\n[data]\nfile = "{d / 'train.npz'}"\ntime = {{ column = "t" }}
position = {{ columns = {cols('q')} }}\neffort = {{ columns = {cols('tau')} }}\n[validation]\nfile = "{d / 'valid.npz'}"
[identification]\nmethod = "wls"\nfriction_model = "powerlaw"\n""")
    r = run_dynid(["identify", str(cfg), "--out", str(tmp_path / "o")], tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dynid: error: ") and "hierarchical = true" in lines[0]
