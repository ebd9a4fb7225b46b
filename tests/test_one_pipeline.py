"""One pipeline for serial and parallel robots (:mod:`dynid.model.system`).

A parallel robot driven through ball screws logs what a serial arm logs: motor angles and motor
currents. A virtual 3-RPS (builtin:rps3, true parameters 10 % off the nominal ones, rotor and screw
inertia of each leg in its ``Ia`` term) is simulated under computed torque; its exact actuator
states (no filtering, no differentiation: the simulator's own positions, velocities and
accelerations) are logged on the motor side through a ball-screw gear ratio N = 2π / lead,
with an encoder offset, and the leg forces as motor currents i = τ / (N K) with current noise.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import seed
from scipy import stats

from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.estimation import OLS
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import as_system, with_actuator_extras
from dynid.pipeline import identify
from dynid.pipeline.data import build_system
from dynid.pipeline.identification import build_problem
from dynid.pipeline.simulate import run_simulation

LEAD = 0.005  # m per motor turn
N = 2 * np.pi / LEAD  # motor angle per leg length [rad/m]
K = 0.45  # drive gain [N*m/A]
Q0 = np.array([0.61, 0.62, 0.63])  # leg length when the encoder reads zero [m]
SIGMA_I = 0.004  # current noise [A]: N * K * SIGMA_I = 2.3 N of leg force
LEGS = ("P1", "P2", "P3")


@pytest.fixture(scope="module")
def rps3_motor_logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("rps3_motor")
    sims = {}
    for name, k in (("train", 3), ("valid", 4)):  # the true robot keeps its perturbation_seed
        sims[name] = run_simulation(parse_simulate_config({
            "robot": {"model": "builtin:rps3", "perturbation": 0.1, "perturbation_seed": 3},
            "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.4,
                           "max_velocity": 0.1, "max_acceleration": 1.0, "periods": 2, "seed": seed(k)},
            "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
        }, d))
    rng = np.random.default_rng(seed(7))
    for name, sim in sims.items():
        m = sim.motion
        q, dq, ddq = (x[:, [1, 3, 5]] for x in (m.q, m.dq, m.ddq))
        noise = SIGMA_I * rng.standard_normal(m.tau_a.shape)
        cols = {"t": m.t}
        for k, leg in enumerate(LEGS):
            cols[f"theta_{leg}"] = N * (q[:, k] - Q0[k])
            cols[f"dtheta_{leg}"] = N * dq[:, k]
            cols[f"ddtheta_{leg}"] = N * ddq[:, k]
            cols[f"i_{leg}"] = m.tau_a[:, k] / (N * K) + noise[:, k]
            # the same experiment seen at the legs: positions [m], forces [N] with the same noise
            cols[f"q_{leg}"], cols[f"dq_{leg}"], cols[f"ddq_{leg}"] = q[:, k], dq[:, k], ddq[:, k]
            cols[f"tau_{leg}"] = N * K * cols[f"i_{leg}"]
        save_npz(d / f"{name}.npz", cols)
    return d, sims["train"].truth


def _motor_doc(d, **identification) -> dict:
    sig = lambda p, unit, **kw: {"columns": [f"{p}_{leg}" for leg in LEGS], "unit": unit, **kw}  # noqa: E731
    data = {"time": {"column": "t"}, "position": sig("theta", "rad", side="motor"),
            "velocity": sig("dtheta", "rad", side="motor"), "acceleration": sig("ddtheta", "rad", side="motor"),
            "effort": sig("i", "A", kind="current")}
    return {
        "robot": {"model": "builtin:rps3", "gear_ratios": [N] * 3, "drive_gains": [K] * 3, "position_offset": Q0.tolist()},
        "data": {"file": str(d / "train.npz"), **data},
        "validation": {"file": str(d / "valid.npz")},
        "processing": {"derivatives": "measured", "trim_samples": 0},
        # "full": the simulated robot's legs differ (its perturbation); these tests are about the drive train
        "identification": {"method": "ols", "structure": "full", **identification},
        "output": {"plots": False},
    }


def _leg_doc(d, **identification) -> dict:
    sig = lambda p, unit, **kw: {"columns": [f"{p}_{leg}" for leg in LEGS], "unit": unit, **kw}  # noqa: E731
    data = {"time": {"column": "t"}, "position": sig("q", "m"), "velocity": sig("dq", "m"),
            "acceleration": sig("ddq", "m"), "effort": sig("tau", "N", kind="torque")}
    doc = _motor_doc(d, **identification)
    doc["robot"] = {"model": "builtin:rps3"}
    doc["data"] = {"file": str(d / "train.npz"), **data}
    return doc


@pytest.mark.numerics
def test_rps3_from_motor_currents_through_ball_screws_covers_the_truth(rps3_motor_logs):
    d, truth = rps3_motor_logs
    out = identify(parse_config(_motor_doc(d), d))
    res = out.result
    names = truth["base_parameters"]["names"]
    assert tuple(names) == tuple(res.names)
    beta = np.asarray(truth["base_parameters"]["true_values"])
    z = (res.params - beta) / res.bse
    # exact states and white current noise: OLS z-scores are standard normal; the family of
    # intervals at 99.9 % (Bonferroni: a false alarm of 1e-3 for all of them) holds every true base parameter
    bound = stats.norm.ppf(1 - 0.0005 / len(beta))
    assert np.max(np.abs(z)) < bound, dict(zip(names, np.round(z, 2)))
    # rotor (reflected screw) inertias are identified: Ia_P* are base parameters of their own (0.4-2 %
    # relative std over 3 draws of the motions and noise)
    ia = [names.index(f"Ia_{leg}") for leg in LEGS]
    assert np.all(res.rel_std[ia] < 5.0), res.rel_std[ia]
    # the residual is the current noise seen at the legs (~2000 rows a leg: a relative std of
    # 1 / sqrt(2 n) = 1.6 %, 0.1 is 6 of them)
    np.testing.assert_allclose(np.sqrt(res.rss_per_channel / res.n_obs), N * K * SIGMA_I, rtol=0.1)


def test_the_drive_train_route_equals_the_leg_route(rps3_motor_logs):
    d, _ = rps3_motor_logs
    motor = identify(parse_config(_motor_doc(d), d)).result
    legs = identify(parse_config(_leg_doc(d), d)).result
    np.testing.assert_allclose(motor.params, legs.params, rtol=1e-7, atol=1e-9 * np.abs(legs.params).max())
    np.testing.assert_allclose(motor.bse, legs.bse, rtol=1e-6)


@pytest.mark.numerics
def test_mechanism_parallel_decimation_and_min_velocity(rps3_motor_logs):
    d, truth = rps3_motor_logs
    cfg = parse_config(_leg_doc(d), d)
    system = build_system(cfg.robot)
    out = identify(cfg)
    ds, base = out.train, out.base
    whole = build_problem(system, base, ds, parallel_decimate=5, chunk_size=10**9)
    chunked = build_problem(system, base, ds, parallel_decimate=5, chunk_size=300)
    n_dec = -(-ds.n_samples // 5)
    assert list(whole.n_obs) == list(chunked.n_obs) == [n_dec] * 3
    # chunking changes where the batched position solve puts its anchors (dynid.model.loop_batch), so
    # the joint positions of the two routes agree to the solve's tolerance (POSITION_TOL, 1e-10 m), not
    # to rounding; what that moves is far below the noise the estimate's std reflects (current noise
    # 2.3 N of leg force): seen 1.5e-7 to 7e-7 std over three draws; 1e-4 std leaves a factor 140 (14
    # with the tolerances loosened 10x), and a wrong chunk join (rows lost or repeated, a filter
    # restarted) moves it by whole std
    a, b = OLS().fit(chunked), OLS().fit(whole)
    assert np.max(np.abs(a.params - b.params) / b.bse) < 1e-4, np.max(np.abs(a.params - b.params) / b.bse)
    # the config route: parallel decimation of regressor and forces (Gautier) recovers the truth as
    # well as the full-rate fit (the filter removes only noise above the motion's band)
    doc = _leg_doc(d)
    doc["processing"].update(decimate=5, decimate_method="parallel")
    dec = identify(parse_config(doc, d)).result
    beta = np.asarray(truth["base_parameters"]["true_values"])
    assert dec.n_obs.tolist() == [n_dec] * 3
    assert np.max(np.abs((dec.params - beta) / dec.bse)) < stats.norm.ppf(1 - 0.0005 / beta.size)  # family at 99.9 %
    # min_velocity: per actuator equation, the rows of a slower leg are left out
    thr = 0.02
    doc = _leg_doc(d)
    doc["processing"]["min_velocity"] = thr
    slow = identify(parse_config(doc, d)).result
    expect = (np.abs(ds.dq) >= thr).sum(axis=0)
    assert slow.n_obs.tolist() == expect.tolist() and np.all(expect < ds.n_samples)
    assert slow.provenance["row_selection"]["rule"] == "per actuator equation"


def test_robot_extras_become_actuator_terms_of_a_mechanism(rps3_motor_logs):
    d, _ = rps3_motor_logs
    system = build_system(parse_config(_leg_doc(d), d).robot)
    assert [t.name for t in system.model.terms] == [f"{e}_{leg}" for leg in LEGS for e in ("Ia", "fv", "fc")]
    doc = _leg_doc(d)
    doc["robot"]["extras"] = ["Ia", "fv", "fc", "offset"]
    more = build_system(parse_config(doc, d).robot)
    assert [t.name for t in more.model.terms][-3:] == [f"offset_{leg}" for leg in LEGS]
    assert [t.kind for t in more.model.terms][-3:] == ["offset"] * 3
    # the fivebar's MJCF gives its actuators rotor inertia and friction but no offset: robot.extras
    # adds the missing kinds only, after the description's own terms
    from dynid.model.loading import load_model

    five = load_model("builtin:fivebar")
    plus = with_actuator_extras(five, ["Ia", "fv", "fc", "offset"])
    assert plus.terms[: len(five.terms)] == five.terms
    assert [(t.name, t.kind, t.joints) for t in plus.terms[len(five.terms):]] == [
        ("offset_qa1", "offset", (0,)), ("offset_qa2", "offset", (2,))]


def test_a_serial_robot_is_the_mechanism_without_closures():
    from dynid.model.loading import load_model

    arm = as_system(load_model("builtin:generic6r"))
    assert arm.kind == "serial" and arm.channel_names(None) == arm.actuator_names == arm.model.joint_names
    rows = arm.rows(None)
    rng = np.random.default_rng(0)
    q, dq, ddq = (rng.standard_normal((5, 6)) for _ in range(3))
    r = rows(q, dq, ddq, np.zeros((5, 6)))
    from dynid.model.serial_dynamics import inverse_dynamics

    pi = arm.nominal_parameters()
    np.testing.assert_allclose(r.W @ pi, inverse_dynamics(arm.model, pi, q, dq, ddq), atol=1e-9)
    assert isinstance(arm.base_parameters(), BaseParameters)


@pytest.mark.numerics
def test_maximum_likelihood_for_a_serial_arm(tmp_path):
    """Paper 004's maximum likelihood with the filter cut-off (Eq. 24) on a serial arm: the same
    code path as for a mechanism (G = I). Independent route: Gauss–Markov with the period
    covariance at the cut-off ML chose gives the same estimate and ML's force cost."""
    f0, h, periods, fs = 0.5, 3, 6, 250
    n_per = int(fs / f0)
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": "builtin:cobot6r", "perturbation": 0.1, "perturbation_seed": 2},
        "trajectory": {"kind": "fourier", "base_frequency_hz": f0, "harmonics": h, "fill": 0.5, "max_velocity": 1.0,
                       "max_acceleration": 5.0, "periods": periods + 1, "seed": seed(2)},
        "control": {"rate_hz": 500, "kp": 400, "kd": 40, "model": "true", "substeps": 2},
        "sensors": {"position_noise_std": 1e-4, "force_noise_std": 0.05, "seed": seed(2), "log_rate_hz": fs},
    }, tmp_path))
    cols = sim.columns
    keep = slice(n_per, n_per + periods * n_per)  # whole periods after the start-up transient
    save_npz(tmp_path / "log.npz", {k: v[keep] - (cols["t"][n_per] if k == "t" else 0.0) for k, v in cols.items()})
    joints = list(sim.dataset.names)

    def doc(identification: dict, cutoff: float = (h + 0.5) * f0) -> dict:
        return {
            "robot": {"model": "builtin:cobot6r"},
            "data": {"file": str(tmp_path / "log.npz"), "time": {"column": "t"},
                     "position": {"columns": [f"q_{j}" for j in joints], "unit": "rad"},
                     "effort": {"columns": [f"tau_{j}" for j in joints], "kind": "torque", "unit": "N*m"},
                     "rows": [0, 4 * n_per]},
            "validation": {"rows": [4 * n_per, periods * n_per]},
            "processing": {"periodic": {"period_s": 1 / f0, "cutoff_hz": cutoff}},
            "identification": identification,
            "output": {"plots": False},
        }

    ml = identify(parse_config(doc({"method": "ml", "cutoff_range_hz": [1.0, 10.0]}), tmp_path)).result
    fc = ml.solver["cutoff_hz"]
    assert ml.method == "ML" and 1.0 < fc < 10.0
    gm = identify(parse_config(doc({"method": "gm", "noise_covariance": "periodic"}, fc), tmp_path)).result
    # ML evaluates a grid of cut-offs with a closed-form GLS at each (no stopping tolerance): at its
    # chosen one it is that GLS, so the two routes agree to rounding
    np.testing.assert_allclose(ml.params, gm.params, rtol=1e-9, atol=1e-12)
    best = next(r for r in ml.solver["profile"] if r["cutoff_hz"] == fc)
    assert best["force_cost"] == pytest.approx(0.5 * gm.scale * gm.dof, rel=1e-9)


def test_asymmetric_friction_extras_on_serial_joints_and_mechanism_actuators():
    """Shang 2009 Eq. 2 friction (a viscous and a Coulomb coefficient per direction) is a joint
    extra of a serial arm and an actuator term of a mechanism alike; the regressor equals the
    term-by-term torques, and the plant simulates it."""
    from dynid import config
    from dynid.model.loading import load_model, load_robot
    from dynid.model.robot import ALL_EXTRAS
    from dynid.model.serial_dynamics import extras_torque, inverse_dynamics, regressor
    from dynid.simulation.control import SerialPlant

    assert config._ALL_EXTRAS == ALL_EXTRAS
    arm = load_robot("builtin:cobot6r", extras=("Ia", "fv+", "fv-", "fc+", "fc-"))
    assert arm.parameter_names[60:65] == ("Ia1", "fv+1", "fv-1", "fc+1", "fc-1")
    rng = np.random.default_rng(1)
    q, dq, ddq = (rng.standard_normal((40, 6)) for _ in range(3))
    pi = arm.nominal_parameters()
    pi[arm.layout.extra_index["fv+"]], pi[arm.layout.extra_index["fv-"]] = 2.0, 3.0
    pi[arm.layout.extra_index["fc+"]], pi[arm.layout.extra_index["fc-"]] = 0.5, -0.7
    # independent route: RNEA + the friction written out by hand
    by_hand = (np.where(dq > 0, 2.0 * dq + 0.5, 0.0) + np.where(dq < 0, 3.0 * dq - 0.7, 0.0))
    np.testing.assert_allclose(extras_torque(arm, pi, dq, ddq) - ddq * pi[arm.layout.extra_index["Ia"]], by_hand,
                               atol=1e-12)
    np.testing.assert_allclose(regressor(arm, q, dq, ddq) @ pi, inverse_dynamics(arm, pi, q, dq, ddq), atol=1e-9)
    plant = SerialPlant(arm, pi)
    np.testing.assert_allclose(plant.friction.force(dq), by_hand, atol=1e-12)
    smap = as_system(arm).standard_map(as_system(arm).base_parameters())
    assert [arm.parameter_names[i] for i in smap.nonpositive] == [f"fc-{j}" for j in range(1, 7)]
    # a mechanism's actuators take the same extras as joint terms
    five = with_actuator_extras(load_model("builtin:fivebar"), ["fv+", "fc-"])
    assert [(t.name, t.kind) for t in five.terms[-4:]] == [("fv+_qa1", "viscous+"), ("fv+_qa2", "viscous+"),
                                                          ("fc-_qa1", "coulomb-"), ("fc-_qa2", "coulomb-")]


def test_coupled_motors_of_a_mechanism_act_through_their_own_velocity(tmp_path):
    """A drive train coupling a mechanism's two actuators (motor 2 turns with N2 (q_a1 + q_a2), as
    the TX40 wrist) adds the coupled motor's rotor inertia and friction, Iam2, fvm2, fcm2, on its
    own velocity w = c^T qd_a, with c = C[1, :] / C[1, 1] (virtual power: force c_j * f(w) on
    actuator j). The five-bar's actuators are its independent coordinates (G_a = I), so its
    actuator-space columns are those forces, computed here by hand."""
    from dynid.model.closed_loop import actuator_regressor, random_consistent_states

    doc = {"robot": {"model": "builtin:fivebar", "gear_ratios": [10.0, 20.0],
                     "couplings": [{"motor": 2, "joints": [1, 2], "weights": [0.5, 1.0]}]},
           "data": {"file": "log.csv", "position": {"columns": ["a", "b"]}, "effort": {"columns": ["c", "d"]},
                    "sample_rate_hz": 100.0},
           "validation": {"rows": [0, 2]}}
    doc["data"]["rows"] = [2, 4]
    system = build_system(parse_config(doc, tmp_path).robot)
    mech = system.model
    c = np.array([0.5, 1.0])  # C[1, :] / C[1, 1] = (20 * 0.5, 20) / 20
    np.testing.assert_allclose(system.transmission.coupling_weights(1), c)
    terms = {t.name: t for t in mech.terms}
    assert {"Iam2", "fvm2", "fcm2"} <= set(terms) and "Iam1" not in terms
    assert terms["Iam2"].joints == mech.actuated and terms["Iam2"].weights == (0.5, 1.0)
    state = random_consistent_states(mech, 30, np.random.default_rng(3))
    W = actuator_regressor(mech, state).W
    act = list(mech.actuated)
    dqa, ddqa = state.dq[:, act], state.ddq[:, act]
    w, dw = dqa @ c, ddqa @ c
    for name, basis in (("Iam2", dw), ("fvm2", w), ("fcm2", np.sign(w))):
        np.testing.assert_allclose(W[:, :, mech.term_index(name)], basis[:, None] * c[None, :], atol=1e-9)
    # identifiable: the coupled motor's inertia is a base parameter of its own
    assert "Iam2" in system.base_parameters().names
