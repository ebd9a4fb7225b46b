"""``[identification] hierarchical = true`` on mechanisms (paper 003 §3.3, Algorithm 1; issue 19
item 2, the mechanism half; :mod:`dynid.pipeline.hierarchical`, "Mechanisms").

Two simulated twins whose actuated joints have paper 003's improved Stribeck friction (Eq. 15)
while the passive joints keep viscous friction (what ``dynid simulate``'s ``[robot.friction]``
plants: :func:`dynid.pipeline.simulate._mechanism_friction`):

* ``builtin:fivebar`` (2 actuators, 2 DOF: the curves reach the channels through the identity,
  per-actuator refits);
* the guide's redundant ``planar3`` (docs/guide/friction.md; 3 actuators, 2 DOF, projected equations
  :math:`G_a^T\\tau_a`: each equation mixes the actuators' friction, one joint nonlinear refit
  over all curves).

The logs: a Fourier motion of the independent coordinates, every joint's state solved through the
loop (:meth:`~dynid.model.mechanism.Mechanism.solve_positions`, :meth:`~dynid.model.mechanism.Mechanism.states`),
the actuator forces of the *plant* (:class:`~dynid.simulation.closed_loop.ConstrainedSimulator`
with that friction, the forward dynamics dynid simulate integrates) found by inverting its
forward dynamics at each sample (the accelerations are affine in the forces), plus white noise.
No regressor code is involved in making the data.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import run_dynid, seed
from dynid.config import parse_config
from dynid.errors import ConfigError
from dynid.estimation.friction_curves import MODELS, CurveFit, curve_force
from dynid.model import load_model
from dynid.model.base_parameters import perturb_bodies
from dynid.model.friction import SmoothStribeck
from dynid.model.system import as_system
from dynid.pipeline import identify
from dynid.pipeline.hierarchical import (EPS_PARAM, EPS_RMSE, EPS_TOTAL, MAX_ITER, HierarchicalFriction,
                                         projection_kind, rigid_system)
from dynid.pipeline.identification import write_outputs
from dynid.pipeline.simulate import _coordinate_box, _mechanism_friction
from dynid.simulation.closed_loop import ConstrainedSimulator
from dynid.trajectories import FourierTrajectory

REPO = Path(__file__).resolve().parents[1]
PLANAR3 = str(REPO / "examples" / "own_robot" / "planar3" / "planar3.xml")
FS = 100.0
SIGMA = 0.01  # force noise per actuator [N*m]

# Eq. 15 per actuated joint (the fivebar's two, planar3's three: qa1, qa2, qb1 in actuator order)
FRICTION = {
    "fivebar": dict(fc=[0.15, 0.12], fs=[0.30, 0.25], fv=[0.08, 0.10], vs=[0.08, 0.10], kv=[200.0, 150.0],
                    alpha=[0.7, 0.8]),
    "planar3": dict(fc=[0.15, 0.12, 0.10], fs=[0.30, 0.25, 0.20], fv=[0.08, 0.10, 0.05], vs=[0.08, 0.10, 0.10],
                    kv=[200.0, 150.0, 150.0], alpha=[0.7, 0.8, 0.9]),
}
PASSIVE_FV = 0.02  # the passive elbows' viscous friction [N*m*s/rad] (the description says 0.005)


def _mech(name: str):
    return load_model("builtin:fivebar") if name == "fivebar" else load_model(PLANAR3, independent=["qa1", "qa2"])


def _truth(mech) -> np.ndarray:
    """The plant's standard parameters: bodies 10 % off the description, passive viscous friction 0.02
    (the actuated joints' linear friction terms are replaced by the Eq. 15 curves in the plant)."""
    true = perturb_bodies(mech.nominal_parameters(), mech.body_blocks(), 0.1, np.random.default_rng(4))
    names = list(mech.parameter_names)
    act = set(mech.actuated)
    for t in mech.terms:
        if t.kind == "viscous" and not set(t.joints) <= act:
            true[names.index(t.name)] = PASSIVE_FV
    return true


def _motion(mech, seed: int, n: int):
    lo, hi, _ = _coordinate_box(mech)
    traj = FourierTrajectory.random(2, 5, 0.2, np.random.default_rng(seed), lo, hi, max_velocity=1.5,
                                    max_acceleration=6.0, fill=0.5)
    t = np.arange(n) / FS
    u, du, ddu = traj.sample(t)
    return t, mech.states(mech.solve_positions(u), du, ddu)


def _plant_forces(mech, true, friction, state) -> np.ndarray:
    """Actuator forces that make the plant (constrained forward dynamics with ``friction``) follow
    ``state``: its accelerations are affine in the forces, solved per sample (least squares: a
    redundant mechanism's minimum-norm forces; any other split gives the same projected equations)."""
    sim = ConstrainedSimulator(mech, true, friction=_mechanism_friction(mech, true, friction))
    na = mech.n_actuators
    out = np.empty((state.q.shape[0], na))
    for i, (q, dq, ddq) in enumerate(zip(state.q, state.dq, state.ddq)):
        a0 = sim.acceleration(q, dq, np.zeros(na))
        A = np.column_stack([sim.acceleration(q, dq, e) - a0 for e in np.eye(na)])
        out[i] = np.linalg.lstsq(A, ddq - a0, rcond=None)[0]
    return out


def _log(name: str, path: Path, seed: int, n: int) -> None:
    mech = _mech(name)
    t, st = _motion(mech, seed, n)
    tau = _plant_forces(mech, _truth(mech), SmoothStribeck(**FRICTION[name]), st)
    tau = tau + np.random.default_rng(seed + 100).standard_normal(tau.shape) * SIGMA
    qa = st.q[:, list(mech.actuated)]
    np.savez(path, t=t, **{f"q_{j}": qa[:, k] for k, j in enumerate(mech.actuated_names)},
             **{f"tau_{j}": tau[:, k] for k, j in enumerate(mech.actuated_names)})


def _doc(folder: Path, name: str, ident: dict, plots: bool = False, processing: dict | None = None) -> dict:
    act = _mech(name).actuated_names
    robot = {"model": "builtin:fivebar"} if name == "fivebar" else {"model": PLANAR3, "independent": ["qa1", "qa2"]}
    return {
        "robot": robot,
        "data": {"file": str(folder / f"{name}_train.npz"), "time": {"column": "t", "unit": "s"},
                 "position": {"columns": [f"q_{j}" for j in act]}, "effort": {"columns": [f"tau_{j}" for j in act]}},
        "validation": {"file": str(folder / f"{name}_valid.npz")},
        **({"processing": processing} if processing else {}),
        "identification": ident,
        "output": {"plots": plots},
    }


def _config(folder: Path, name: str, ident: dict, **kw):
    return parse_config(_doc(folder, name, ident, **kw), folder)


HIER = {"method": "wls", "hierarchical": True, "friction_model": "arctan"}
PHYS = {"physical_consistency": True, "margin": 1e-4}


def _runs(d: Path, name: str) -> dict:
    _log(name, d / f"{name}_train.npz", seed(1), 2000)
    _log(name, d / f"{name}_valid.npz", seed(2), 1000)
    return {"dir": d, (name, "linear"): identify(_config(d, name, {"method": "wls"})),
            (name, "arctan"): identify(_config(d, name, HIER))}


@pytest.fixture(scope="module")
def fivebar(tmp_path_factory):
    return _runs(tmp_path_factory.mktemp("hier_fivebar"), "fivebar")


@pytest.fixture(scope="module")
def planar3(tmp_path_factory):
    return _runs(tmp_path_factory.mktemp("hier_planar3"), "planar3")


def _held_out(o) -> np.ndarray:
    return np.array(o.validation.to_dict()["rmse_per_joint"])


def _nominal(o) -> np.ndarray:
    return np.array(o.nominal_validation.to_dict()["rmse_per_joint"])


def test_regressor_and_prediction_reproduce_the_plants_actuator_forces():
    """At the truth, the friction-free base regressor of the rigid system times the true base
    parameters plus the true curves through P (:meth:`HierarchicalFriction.channel_force`) equal the
    plant's actuator forces (projected for planar3) on noise-free states: to round-off, ~1e-8 of
    forces of order 1 (the plant's constrained forward dynamics are solved by pinocchio's proximal
    KKT solver with mu = 1e-12)."""
    for name in ("fivebar", "planar3"):
        mech = _mech(name)
        true = _truth(mech)
        t, st = _motion(mech, 3, 300)
        tau = _plant_forces(mech, true, SmoothStribeck(**FRICTION[name]), st)
        system = rigid_system(as_system(mech))
        fm = system.force_model(None)
        base = system.base_parameters(fm)
        std = np.array([true[list(mech.parameter_names).index(n)] for n in system.parameter_names])
        act = list(mech.actuated)
        rows = system.rows(fm)(st.q[:, act], st.dq[:, act], st.ddq[:, act], tau)
        model = MODELS["smooth_stribeck"]
        fits = tuple(CurveFit("smooth_stribeck", model, np.array([FRICTION[name][k][j] for k in model]),
                              np.full(6, np.nan), np.zeros(6, bool), np.full((6, 6), np.nan), np.nan, np.nan, 0,
                              True, "truth") for j in range(len(act)))
        fr = HierarchicalFriction("arctan", "smooth_stribeck", tuple(mech.actuated_names), fits,
                                  projection_kind(system, fm))
        pred = base.regressor(rows.W) @ base.from_standard(std) + fr.channel_force(st.dq[:, act], rows.Ga)
        assert fr.projection == ("identity" if name == "fivebar" else "projected")
        err = np.abs(pred - rows.y).max()
        assert err < 1e-8 * max(1.0, np.abs(rows.y).max()), (name, err)
        # and without the curves the forces are not explained: the check can fail
        assert np.abs(pred - fr.channel_force(st.dq[:, act], rows.Ga) - rows.y).max() > 0.1


@pytest.mark.numerics
def test_fivebar_loop_converges_by_the_papers_rules_before_50_iterations(fivebar):
    """The loop stops by the paper's rules. Finding: how soon depends on the draw (4, 32 and 11
    iterations over 3 draws; near the end the curves' change falls by only ~0.96 an iteration),
    because the passive elbows' viscous columns trade with the curves (below): 50 iterations are not
    guaranteed, and a loop that runs out says so (as planar3's)."""
    o = fivebar["fivebar", "arctan"]
    h = o.result.solver["hierarchical"]
    hist = h["history"]
    last, before = hist[-1], hist[-2]
    assert h["converged"] == (h["stop"] == "converged"), h["stop"]
    if h["converged"]:
        assert h["iterations"] < MAX_ITER
        change = np.abs(np.array(last["rmse_per_joint"]) - before["rmse_per_joint"])
        assert np.all(change <= EPS_RMSE) and change.sum() <= EPS_TOTAL and last["param_change"] <= EPS_PARAM
        assert before["param_change"] > EPS_PARAM  # it stopped at the first iteration that met the rules
    else:
        assert h["stop"] == "max_iterations" and h["iterations"] == MAX_ITER
        assert any("NOT converged" in n for n in o.result.notes)
    totals = [x["rmse_total"] for x in hist]
    assert all(b <= a * (1 + 1e-4) for a, b in zip(totals, totals[1:]))  # block-coordinate descent (RISE_TOL)
    # the model is complete: the training residual is the noise (2000 samples: the sample std within 1.6 %
    # (1 std) of SIGMA; 7 % is 4.4 std, 1e-5 per joint)
    np.testing.assert_allclose(last["rmse_per_joint"], SIGMA, rtol=0.07)
    m = h["mechanism"]
    assert m["projection"] == "identity" and m["curves_on"] == ["qa1", "qa2"]
    assert sorted(m["replaced_linear_terms"]) == ["fc_qa1", "fc_qa2", "fv_qa1", "fv_qa2"]
    assert m["passive_linear_terms"] == ["fv_qb1", "fv_qb2"]
    # the passive joints' viscous friction stays a base parameter of the rigid-body step. Finding: it is not
    # determined here: 15-56 % off the truth over 3 draws, 9-23 of its reported std (that std is the rigid-body
    # WLS's, conditional on the curves, and a passive elbow's velocity is a combination of the actuators'
    # (qd_b = G_b(q) u), so its column trades with the curves' viscous/power-law part); what the pair does is
    # held to the held-out forces (test_fivebar_held_out_...), not to the truth
    for n in ("fv_qb1", "fv_qb2"):
        assert np.isfinite(o.result.params[o.result.names.index(n)])


@pytest.mark.numerics
def test_fivebar_friction_recovered_within_its_reported_uncertainty(fivebar):
    """Every Eq. 15 coefficient within 4.5 reported standard deviations (7e-6 each; white noise, a
    rigid-body part determined to ~1 % (mx, mz, Iyy of the proximal links): the std conditional on it
    is honest here, at most 3.0 over 3 draws), and the curve within 6 % of the truth over the speeds
    the motion covers: a sanity bound, not derived (the coefficients' covariance is not reported, and
    the passive viscous columns trade with the curves: 1.2-4.3 % over 3 draws, where a fit of 6
    coefficients to 2000 rows alone would predict to ~0.4 % of the curve)."""
    fr = fivebar["fivebar", "arctan"].result.solver["hierarchical"]["friction"]
    v = np.linspace(0.1, 1.2, 50)
    for k, j in enumerate(("qa1", "qa2")):
        c = fr[j]
        for n in MODELS["smooth_stribeck"]:
            assert c[n]["std"] is not None and not c[n]["at_bound"], (j, n)
            assert abs(c[n]["value"] - FRICTION["fivebar"][n][k]) < 4.5 * c[n]["std"], (j, n, c[n])
        fit = curve_force("smooth_stribeck", {n: c[n]["value"] for n in c}, v)
        true = curve_force("smooth_stribeck", {n: FRICTION["fivebar"][n][k] for n in FRICTION["fivebar"]}, v)
        np.testing.assert_allclose(fit, true, rtol=0.06, err_msg=j)


@pytest.mark.numerics
def test_fivebar_held_out_at_the_noise_level_better_than_one_shot_and_nominal(fivebar):
    hier, lin = _held_out(fivebar["fivebar", "arctan"]), _held_out(fivebar["fivebar", "linear"])
    np.testing.assert_allclose(hier, SIGMA, rtol=0.1)  # 1000 held-out samples: 2.2 % (1 std) plus the fit's ~1 %
    # the same rows and noise, the linear model's systematic misfit: hier / lin 0.37-0.49 over 3 draws
    assert np.all(hier < 0.7 * lin)
    # the nominal model with the description's linear friction (the one-shot run's prior): hier / nominal <= 0.11
    assert np.all(hier < 0.2 * _nominal(fivebar["fivebar", "linear"]))
    # the hierarchical run's own prior is that model too (not the friction-free rigid regressor)
    np.testing.assert_allclose(_nominal(fivebar["fivebar", "arctan"]), _nominal(fivebar["fivebar", "linear"]), rtol=1e-9)


def _tail(h) -> float:
    """How far a loop's last curves can be from its fixed point, in its own measure of a change (the
    relative change of each curve on the training rows, its norm over the curves): it converges
    linearly, so the rest of the way is at most c_last rho / (1 - rho), rho the largest of its last
    three ratios (tests/test_hierarchical.py)."""
    c = [x["param_change"] for x in h["history"] if x["param_change"] is not None]
    rho = max(b / a for a, b in zip(c[-4:-1], c[-3:]))
    assert rho < 1, c
    return c[-1] * rho / (1 - rho)


@pytest.mark.numerics
def test_fivebar_with_lmi_constraints(fivebar):
    """physical_consistency = true: each rigid-body step is WLS + LMI (dynid.estimation.physical) on
    the mechanism's rigid system; no constraint binds (the truth is 10 % off the description, inside
    the set), so the loop has the fixed point of the run without them and ends within both loops'
    convergence tails of the same curves (identical here: the LMI fit returns the unconstrained
    estimate unchanged)."""
    d = fivebar["dir"]
    o = identify(_config(d, "fivebar", {**HIER, **PHYS}))
    lin = identify(_config(d, "fivebar", {"method": "wls", **PHYS}))
    h = o.result.solver["hierarchical"]
    ref = fivebar["fivebar", "arctan"]
    assert o.result.method.startswith("WLS+LMI") and h["stop"] == ref.result.solver["hierarchical"]["stop"]
    assert o.result.solver["active_constraints"] == []
    assert np.all(_held_out(o) < 0.7 * _held_out(lin))  # as without the constraints
    bound = _tail(h) + _tail(ref.result.solver["hierarchical"])
    for k, j in enumerate(("qa1", "qa2")):  # the loop's measure, on the training rows' speeds (odd curves)
        v = np.abs(ref.train.dq[:, k])
        fa, fb = (curve_force("smooth_stribeck", {n: c[j][n]["value"] for n in MODELS["smooth_stribeck"]}, v)
                  for c in (h["friction"], ref.result.solver["hierarchical"]["friction"]))
        d = float(np.linalg.norm(fa - fb) / max(np.linalg.norm(fa), np.linalg.norm(fb)))
        assert d <= bound, (j, d, bound)


@pytest.mark.numerics
def test_redundant_planar3_projected_equations(planar3):
    """The projected equations mix the three actuators' friction (P = G_a^T): one joint nonlinear
    refit of all three curves. The curves are recovered within 10 % over the speeds the motion covers
    (not within the std: the loop ends at 50 iterations here, see below, and the std is conditional
    on a rigid-body part still drifting), and the held-out projected forces are predicted at the noise
    level (each projected channel carries the noise of its actuators: sqrt(1 + g^2) * SIGMA, larger
    than SIGMA), well below the one-shot linear WLS and the nominal model.

    Finding: block-coordinate descent converges slowly here (linear rate), because the mixed channels
    couple the curves with the rigid-body columns; whether the paper's parameter rule (1e-3) is met by
    iteration 50 depends on the draw (5, 6 and 49 iterations over 3 draws; once 50 without), and the
    result says which (stop = "max_iterations", converged = false)."""
    o = planar3["planar3", "arctan"]
    h = o.result.solver["hierarchical"]
    assert h["mechanism"]["projection"] == "projected" and h["mechanism"]["curves_on"] == ["qa1", "qa2", "qb1"]
    assert h["mechanism"]["friction_fit"].startswith("one bounded nonlinear least squares over all actuators")
    hist = h["history"]
    totals = [x["rmse_total"] for x in hist]
    assert all(b <= a * (1 + 1e-4) for a, b in zip(totals, totals[1:]))
    assert h["converged"] == (h["stop"] == "converged")
    if not h["converged"]:
        assert h["stop"] == "max_iterations" and h["iterations"] == MAX_ITER
        assert any("NOT converged" in n for n in o.result.notes)
    v = np.linspace(0.1, 1.2, 50)
    fr = h["friction"]
    for k, j in enumerate(("qa1", "qa2", "qb1")):
        fit = curve_force("smooth_stribeck", {n: fr[j][n]["value"] for n in fr[j]}, v)
        true = curve_force("smooth_stribeck", {n: FRICTION["planar3"][n][k] for n in FRICTION["planar3"]}, v)
        np.testing.assert_allclose(fit, true, rtol=0.10, err_msg=j)
    hier, lin = _held_out(o), _held_out(planar3["planar3", "linear"])
    # the projected channels' noise, sqrt(1 + g^2) SIGMA along the motion: 1.38-1.44 and 1.09-1.12 SIGMA over 3 draws
    assert np.all(hier < 1.6 * SIGMA) and np.all(hier > SIGMA * 0.9)
    # systematic misfits of the others: hier / lin <= 0.49 and hier / nominal <= 0.09 over 3 draws
    assert np.all(hier < 0.7 * lin) and np.all(hier < 0.2 * _nominal(planar3["planar3", "linear"]))


@pytest.mark.numerics
def test_redundant_planar3_min_norm_force_model(planar3):
    """The logs' forces are the minimum-norm ones that drive the plant (:func:`_plant_forces`), so the
    ``"min_norm"`` force model is exact for them: outputs per actuator, the curves reach them through
    P = (G_a^T)^+ G_a^T (each actuator's output mixes all three actuators' friction). Held-out at
    the noise per actuator (measured 0.0102 0.0102 0.0100 N*m, one-shot linear 0.0175 0.0256 0.0163)."""
    d = planar3["dir"]
    o = identify(_config(d, "planar3", {**HIER, "force_model": "min_norm"}))
    lin = identify(_config(d, "planar3", {"method": "wls", "force_model": "min_norm"}))
    h = o.result.solver["hierarchical"]
    assert h["mechanism"]["projection"] == "min_norm" and o.validation.channel_names == ("qa1", "qa2", "qb1")
    np.testing.assert_allclose(_held_out(o), SIGMA, rtol=0.1)  # 1000 held-out samples: 2.2 % (1 std) plus the fit's
    assert np.all(_held_out(o) < 0.8 * _held_out(lin))  # the linear model's misfit: ratio 0.40-0.62 over 3 draws


def test_outputs_record_the_choice_history_and_plot(fivebar, tmp_path):
    o = identify(_config(fivebar["dir"], "fivebar", HIER, plots=True))
    files = write_outputs(o, tmp_path / "out")
    assert "hierarchical.png" in files and (tmp_path / "out" / "hierarchical.png").stat().st_size > 10_000
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    h = doc["solver"]["hierarchical"]
    assert set(h["friction"]) == {"qa1", "qa2"} and len(h["history"]) == h["iterations"]
    assert h["mechanism"]["passive_linear_terms"] == ["fv_qb1", "fv_qb2"]
    names = [p["name"] for p in doc["params"]]
    # the actuated joints' friction left the regressor; their rotor inertia (grouped) and the passive
    # joints' viscous friction stayed
    assert not any(n.startswith(("fc_qa", "fv_qa")) for n in names) and {"fv_qb1", "fv_qb2"} <= set(names)
    text = (tmp_path / "out" / "summary.txt").read_text()
    assert "mechanism: nonlinear curves on the actuated joints" in text
    assert "passive joints' friction (fv_qb1, fv_qb2) kept as linear columns" in text


def test_refusals_that_remain(tmp_path):
    """Before any data is read (the logs named here do not exist): parallel decimation (a low-pass of
    the regressor columns does not commute with the curve) and the pose domain of a platform's
    periodic processing (not validated with the loop)."""
    with pytest.raises(ConfigError, match="does not commute"):
        identify(_config(tmp_path, "fivebar", HIER, processing={"decimate": 2, "decimate_method": "parallel"}))
    doc = _doc(tmp_path, "fivebar", HIER, processing={"periodic": {"period_s": 10.0, "cutoff_hz": 0.55, "domain": "pose"}})
    doc["robot"] = {"model": "builtin:rps3"}
    doc["data"]["position"]["columns"] = doc["data"]["effort"]["columns"] = ["a", "b", "c"]
    with pytest.raises(ConfigError, match="loop has not been validated"):
        identify(parse_config(doc, tmp_path))


SIMULATE = """[robot]
model = "builtin:fivebar"
perturbation = 0.1
[robot.friction]
model = "smooth_stribeck"
fc = [0.15, 0.12]
fs = [0.30, 0.25]
fv = [0.08, 0.10]
vs = [0.08, 0.10]
kv = [200.0, 150.0]
alpha = [0.7, 0.8]
[trajectory]
kind = "fourier"
base_frequency_hz = 0.5
harmonics = 4
fill = 0.5
max_velocity = 1.5
max_acceleration = 8.0
periods = {periods}
seed = {seed}
[control]
rate_hz = 500
kp = 400
kd = 40
substeps = 2
[sensors]
encoder_resolution = 1e-5
force_noise_std = 0.01
log_rate_hz = 250
seed = {seed}
"""

IDENTIFY = """[robot]
model = "builtin:fivebar"
[data]
file = "train/log.csv"
time = {{ column = "t", unit = "s" }}
position = {{ columns = ["q_qa1", "q_qa2"], unit = "rad" }}
effort = {{ columns = ["tau_qa1", "tau_qa2"], kind = "torque", unit = "N*m" }}
[validation]
file = "valid/log.csv"
[processing]
lowpass = {{ cutoff_hz = 20.0, order = 4, filter_effort = false }}
{processing}
[identification]
method = "wls"
{ident}
"""


@pytest.mark.numerics
def test_cli_from_dynid_simulate_with_robot_friction(tmp_path):
    """End to end: ``dynid simulate``'s pipeline (in process) with ``[robot.friction]`` (Eq. 15 on
    the five-bar's actuated joints, the description's viscous friction on the passive elbows: the
    plant of :func:`dynid.pipeline.simulate._mechanism_friction`) under closed-loop control, then
    ``dynid identify`` with ``hierarchical = true`` on the command line. The 20 Hz low-pass smears the friction's
    transition at the reversals (a jump of 2 F_s within ~0.01 rad/s), so neither model reaches the
    0.01 N*m noise here (measured 0.048/0.024 hierarchical, 0.058/0.038 one-shot linear on all
    held-out rows; the loop stops after 4 iterations because the training RMSE rose, said in the
    notes); the hierarchical model must still be the better one on every channel (the same rows and
    noise for both: the linear model's misfit, hier / lin 0.50-0.82 over 3 draws). A setting the
    loop refuses is one line on stderr, exit 2."""
    import tomllib

    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation, write_simulation

    for name, k, periods in (("train", 2, 3), ("valid", 5, 2)):  # in process: a subprocess's imports cost 5-10 s
        doc = tomllib.loads(SIMULATE.format(seed=seed(k), periods=periods))
        write_simulation(run_simulation(parse_simulate_config(doc, tmp_path)), tmp_path / name)
    (tmp_path / "id.toml").write_text(IDENTIFY.format(processing="", ident='hierarchical = true\nfriction_model = "arctan"'))
    r = run_dynid(["identify", "id.toml", "--out", "id", "-q"], tmp_path)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "id" / "result.json").read_text())
    h = res["solver"]["hierarchical"]
    assert h["mechanism"]["replaced_linear_terms"] == ["fv_qa1", "fc_qa1", "fv_qa2", "fc_qa2"]
    assert (tmp_path / "id" / "hierarchical.png").stat().st_size > 10_000
    assert "kept as linear columns of the rigid-body step" in (tmp_path / "id" / "summary.txt").read_text()
    lin = identify(_toml_config(tmp_path, IDENTIFY.format(processing="", ident="")))
    hier = np.array(res["validation"]["rmse_per_joint"])
    assert np.all(hier < _held_out(lin)), (hier, _held_out(lin))
    (tmp_path / "bad.toml").write_text(IDENTIFY.format(
        processing='decimate = 2\ndecimate_method = "parallel"', ident='hierarchical = true\nfriction_model = "arctan"'))
    r = run_dynid(["identify", "bad.toml", "--out", "bad", "-q"], tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("dynid: error: ") and "commute" in lines[0]


def _toml_config(folder: Path, text: str):
    import tomllib

    return parse_config(tomllib.loads(text), folder)
