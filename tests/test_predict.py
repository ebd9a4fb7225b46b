"""``dynid predict`` (issue 20 item 3): a saved identification scored on a new log gives exactly
what ``identify`` reports when that log is its validation log (the same processing, drive train,
Coulomb smoothing and base parameters), the nominal row included; bad input is one line, exit 2.

And the export of every result with a standard vector (issue 20 item 6): for OLS/WLS the standard
vector closest to the nominal one that reproduces the base estimate, written as URDF and checked by
an independent route (pinocchio's URDF parser and its RNEA against the base regressor)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from conftest import seed
from dynid.cli import main
from dynid.config import load_config
from dynid.model import Transmission, load_robot
from dynid.pipeline import identify, write_outputs
from dynid.simulation import FourierTrajectory, simulate_serial

GAINS = [0.5, 0.5, 0.4, 0.3, 0.3, 0.2]
RATIOS = [32.0, 32.0, 45.0, -48.0, 45.0, 32.0]
TR = Transmission.from_ratios(RATIOS, [], drive_gains=GAINS)
ROBOT = load_robot("builtin:generic6r", transmission=TR)
SIGMA = np.array([0.8, 0.8, 0.4, 0.06, 0.06, 0.04])


def _log(path: Path, seed: int, duration: float, fs: float = 100.0, coulomb: bool = True, robot=ROBOT, tr=TR):
    """A simulated motor-side log: encoder angles and motor currents (drive gains per joint)."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.position_limits()
    traj = FourierTrajectory.random(6, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    truth = robot.nominal_parameters()  # the robot's friction is not the description's
    lay = robot.layout
    truth[lay.extra_index["fv"]] *= 1.5
    truth[lay.extra_index["fc"]] *= 0.6 if coulomb else 0.0
    ds = simulate_serial(robot, truth, traj, fs=fs, duration=duration, torque_noise_std=SIGMA, rng=rng)
    theta = (ds.q - tr.position_offset) @ tr.matrix.T
    current = np.linalg.solve(tr.matrix.T, ds.tau.T).T / tr.drive_gains
    header = ",".join(["time"] + [f"enc{j}" for j in range(1, 7)] + [f"cur{j}" for j in range(1, 7)])
    np.savetxt(path, np.column_stack([ds.t, theta, current]), delimiter=",", header=header, comments="", fmt="%.12g")
    return truth


DATA = ('time = { column = "time" }\n'
        'position = { columns = ["enc1", "enc2", "enc3", "enc4", "enc5", "enc6"], side = "motor" }\n'
        'effort = { columns = ["cur1", "cur2", "cur3", "cur4", "cur5", "cur6"], kind = "current", unit = "A" }\n')
ROBOT_TOML = (f'model = "builtin:generic6r"\ngear_ratios = {RATIOS}\ndrive_gains = {GAINS}\n')


def _identify_config(folder: Path, method: str, extra: str = "") -> Path:
    text = (f"[robot]\n{ROBOT_TOML}\n[data]\nfile = \"train.csv\"\n{DATA}\n[validation]\nfile = \"valid.csv\"\n\n"
            "[processing]\nlowpass = { cutoff_hz = 5.0, order = 4, filter_effort = false }\ndecimate = 2\n"
            f"min_velocity = 0.05\n{extra}\n[identification]\nmethod = \"{method}\"\n"
            "coulomb_smoothing = \"auto\"\n\n[output]\nplots = false\n")
    p = folder / "identify.toml"
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """WLS on one simulated log, validated on a second; a third log to predict."""
    d = tmp_path_factory.mktemp("predict")
    truth = _log(d / "train.csv", seed(1), 30.0)
    _log(d / "valid.csv", seed(2), 12.0)
    _log(d / "other.csv", seed(3), 12.0)
    cfg = load_config(_identify_config(d, "wls"))
    outcome = identify(cfg)
    write_outputs(outcome, d / "out")
    return d, outcome, truth


def _log_config(folder: Path, file: str, robot: str | None = None, name: str = "log.toml") -> Path:
    p = folder / name
    p.write_text(("" if robot is None else f"[robot]\n{robot}\n") + f"[data]\nfile = \"{file}\"\n{DATA}")
    return p


@pytest.mark.numerics
def test_predict_on_the_validation_log_reproduces_identify(identified, capsys):
    """Predicting the validation log gives identify's own validation scores, identified and nominal."""
    d, outcome, _ = identified
    rc = main(["predict", str(d / "out"), str(_log_config(d, "valid.csv")), "--out", str(d / "pred"), "-q"])
    assert rc == 0, capsys.readouterr().err
    pred = json.loads((d / "pred" / "predict.json").read_text())
    saved = json.loads((d / "out" / "result.json").read_text())
    # the same computation on the same rows: equal to rounding (the sums run in the same order)
    np.testing.assert_allclose(pred["identified"]["rmse_per_joint"], saved["validation"]["rmse_per_joint"],
                               rtol=1e-12)
    np.testing.assert_allclose(pred["identified"]["r2_per_joint"], saved["validation"]["r2_per_joint"], rtol=1e-12)
    np.testing.assert_allclose(pred["nominal"]["rmse_per_joint"], saved["nominal_validation"]["rmse_per_joint"],
                               rtol=1e-12)
    assert pred["identified"]["n_samples"] == saved["validation"]["n_samples"]
    # the identified model is right up to the sensor noise (WLS on 30 s): RMSE within 15 % of sigma,
    # in N*m at the joints (the motor currents were turned into torques by the drive gains). The RMSE
    # of 536 rows has a relative std of 1 / sqrt(2 x 536) = 3.1 %: 15 % is 4.9 of them (1e-6 per joint;
    # 0.96-1.08 seen over 4 draws, the estimation error included)
    np.testing.assert_allclose(pred["identified"]["rmse_per_joint"], SIGMA, rtol=0.15)
    # and the comparison says per joint which model is better
    for row in pred["per_joint"]:
        assert row["better"] == ("identified" if row["rmse"] < row["nominal_rmse"] else "nominal")
    assert (d / "pred" / "summary.txt").read_text().count("better") >= 1
    assert (d / "pred" / "predict.png").is_file()


@pytest.mark.numerics
def test_predict_on_a_new_log(identified, capsys):
    """A third log: the identified model beats the nominal one (whose friction is off by 50 % viscous
    and 40 % Coulomb, 0.6-3.2 N*m against 0.04-0.8 N*m of noise) on every joint, and its error is
    the sensor noise; the plot is written."""
    d, _, _ = identified
    rc = main(["predict", str(d / "out" / "result.json"), str(_log_config(d, "other.csv", ROBOT_TOML, "o.toml")),
               "--out", str(d / "pred2")])
    out = capsys.readouterr()
    assert rc == 0, out.err
    pred = json.loads((d / "pred2" / "predict.json").read_text())
    np.testing.assert_allclose(pred["identified"]["rmse_per_joint"], SIGMA, rtol=0.15)  # 536 rows: 4.9 std
    # the nominal model's error is 2.2-7.3 times the identified one's over 4 draws (its friction's error
    # is systematic, against the noise)
    assert all(r["better"] == "identified" for r in pred["per_joint"])
    assert (d / "pred2" / "predict.png").is_file()
    assert "identified" in out.out and "nominal" in out.out


def test_processing_from_scores_two_models_on_the_same_rows(identified, tmp_path, capsys):
    """``--processing-from B``: A's model scored on the rows B's processing gives. Identity route:
    A with its own processing named explicitly is A's own prediction; A with B's processing is
    scored on B's rows (B: the same data, another cut-off and decimation) and B's model with
    A's processing on A's rows."""
    d, _, _ = identified
    text = _identify_config(d, "wls").read_text()
    other = tmp_path / "b.toml"
    other.write_text(text.replace("cutoff_hz = 5.0", "cutoff_hz = 8.0").replace("decimate = 2", "decimate = 3")
                     .replace("\"train.csv\"", f"\"{d / 'train.csv'}\"").replace("\"valid.csv\"", f"\"{d / 'valid.csv'}\""))
    assert main(["identify", str(other), "--out", str(tmp_path / "b"), "-q"]) == 0
    log = _log_config(d, "valid.csv")

    def pred(result, name, *extra):
        assert main(["predict", str(result), str(log), "--out", str(tmp_path / name), "--no-plots", "-q", *extra]) == 0, \
            capsys.readouterr().err
        return json.loads((tmp_path / name / "predict.json").read_text())

    a_own, a_self = pred(d / "out", "a"), pred(d / "out", "a_self", "--processing-from", str(d / "out"))
    # the same processing and model: the same computation, equal to rounding
    np.testing.assert_allclose(a_self["identified"]["rmse_per_joint"], a_own["identified"]["rmse_per_joint"], rtol=1e-12)
    b_own, a_on_b = pred(tmp_path / "b", "b_own"), pred(d / "out", "a_on_b", "--processing-from", str(tmp_path / "b"))
    b_on_a = pred(tmp_path / "b", "b_on_a", "--processing-from", str(d / "out"))
    assert a_on_b["identified"]["n_samples"] == b_own["identified"]["n_samples"] != a_own["identified"]["n_samples"]
    assert b_on_a["identified"]["n_samples"] == a_own["identified"]["n_samples"]
    # the measured efforts of those rows are B's: the nominal model's score is the same to rounding
    np.testing.assert_allclose(a_on_b["nominal"]["rmse_per_joint"], b_own["nominal"]["rmse_per_joint"], rtol=1e-12)
    assert any("scored with the processing of" in n for n in a_on_b["notes"])
    # another robot's result is refused in one line
    capsys.readouterr()
    assert main(["predict", str(d / "out"), str(log), "--out", str(tmp_path / "x"), "--processing-from",
                 str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.startswith("dynid: error:")


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dynid: error: "), err
    return lines[0]


def test_bad_inputs_are_one_line(identified, tmp_path, capsys):
    d, _, _ = identified
    log = _log_config(d, "valid.csv")
    # missing result
    assert main(["predict", str(tmp_path / "nothing"), str(log), "--out", str(tmp_path / "p")]) == 2
    assert "no result.json" in _error_line(capsys)
    # wrong robot
    wrong = _log_config(tmp_path, str(d / "valid.csv"), 'model = "builtin:puma560"')
    assert main(["predict", str(d / "out"), str(wrong), "--out", str(tmp_path / "p")]) == 2
    assert "not the robot" in _error_line(capsys)
    # the same robot with other drive gains
    other = _log_config(tmp_path, str(d / "valid.csv"), ROBOT_TOML.replace("0.2]", "0.25]"), "g.toml")
    assert main(["predict", str(d / "out"), str(other), "--out", str(tmp_path / "p")]) == 2
    assert "drive_gains differs" in _error_line(capsys)
    # mismatched joints: five columns for six joints
    five = tmp_path / "five.toml"
    five.write_text(f"[data]\nfile = \"{d / 'valid.csv'}\"\n" + DATA.replace(', "enc6"', "").replace(', "cur6"', ""))
    assert main(["predict", str(d / "out"), str(five), "--out", str(tmp_path / "p")]) == 2
    _error_line(capsys)
    # a processing table (the result's processing is used, not another)
    proc = tmp_path / "proc.toml"
    proc.write_text(log.read_text().replace(f"file = \"valid.csv\"", f"file = \"{d / 'valid.csv'}\"")
                    + "\n[processing]\ndecimate = 1\n")
    assert main(["predict", str(d / "out"), str(proc), "--out", str(tmp_path / "p")]) == 2
    assert "[processing] is not read" in _error_line(capsys)
    # an older result.json: no prediction inputs
    old = tmp_path / "old"
    old.mkdir()
    doc = json.loads((d / "out" / "result.json").read_text())
    del doc["prediction_inputs"]
    (old / "result.json").write_text(json.dumps(doc))
    assert main(["predict", str(old), str(log), "--out", str(tmp_path / "p")]) == 2
    assert "another dynid version" in _error_line(capsys)
    # a foreign JSON file
    (old / "result.json").write_text('{"hello": 1}')
    assert main(["predict", str(old), str(log), "--out", str(tmp_path / "p")]) == 2
    assert "not a dynid result" in _error_line(capsys)
    assert not (tmp_path / "p").exists()


def _states(rng, n, dof=6):
    """States away from velocity reversals (|v| >= 0.5 rad/s: the smooth Coulomb sign of the fit,
    whose width is the velocity-noise std of about 1e-3 rad/s, is the sign there to rounding)."""
    q = rng.uniform(-2.0, 2.0, (n, dof))
    v = rng.choice([-1.0, 1.0], (n, dof)) * rng.uniform(0.5, 2.0, (n, dof))
    return q, v, rng.normal(size=(n, dof)) * 3.0


def test_ols_export_is_the_closest_consistent_standard_vector_and_pinocchio_agrees(identified):
    """WLS gives base parameters only; the exported URDF holds the physically consistent standard
    vector closest to the nominal one with those base parameters, or, when no consistent vector
    gives them (an estimate within its noise of the consistent set's boundary), the one that misses
    them least, and the summary says by how much (issue 34, item 5). Independent route: pinocchio's
    URDF parser and RNEA, plus the joint terms the file records (damping, friction, and the
    Ia/offset comments), give the joint torques Phi_b(q, v, a) B pi of the exported vector to
    rounding."""
    import re

    from dynid.estimation.consistent_standard import MARGIN, consistent_standard
    from dynid.model.base_parameters import body_violation, parameter_scales
    from dynid.model.serial_dynamics import regressor
    from dynid.pipeline.identification import standard_vector

    d, outcome, _ = identified
    path = d / "out" / "model.urdf"
    assert path.is_file()
    text = path.read_text()
    summary = (d / "out" / "summary.txt").read_text()
    assert "one of many" in text and "one of many" in summary and "physically consistent" in summary
    base, beta = outcome.base, outcome.result.params
    pi, notes = standard_vector(outcome)
    system = outcome.system
    assert all(body_violation(pi[blk]) == "" for blk in system.body_blocks())
    nominal = system.nominal_parameters()
    s = parameter_scales(system.parameter_names, system.body_blocks(), nominal)
    found = consistent_standard(beta, system.standard_map(base), nominal, s, outcome.result.cov_params)
    np.testing.assert_array_equal(pi, found.params)  # the same rule, deterministic
    if found.exact:
        np.testing.assert_allclose(base.from_standard(pi), beta, rtol=1e-10, atol=1e-10 * np.abs(beta).max())
    else:  # the mismatch, in standard deviations of the estimate, as the summary reports it
        L = np.linalg.cholesky(outcome.result.cov_params)
        miss = float(np.linalg.norm(np.linalg.solve(L, base.from_standard(pi) - beta)))
        assert miss == pytest.approx(found.mismatch, rel=1e-9)
        assert f"misses them by {found.mismatch:.3g}" in summary
        # the least any consistent vector misses them by, to the solver's accuracy: the slab's slack
        # (10 x Clarabel's tolerances on the first SDP, mismatch_slack) plus the second SDP's primal
        # residual on the slab (slack_prior, the same at its own status)
        # (below: r_star is the minimum over bodies kept MARGIN inside the consistent set; a consistent
        # vector may miss by that much less, 10 MARGIN relative allowed)
        r_star, slack = found.stages["mismatch_min"], found.stages["slack"]
        assert r_star * (1 - 10 * MARGIN) - slack <= miss <= r_star + slack + found.stages["slack_prior"]
    rng = np.random.default_rng(5)
    # the file read back by pinocchio
    loaded = pin.buildModelFromUrdf(str(path))
    terms = re.findall(r"dynid: joint (\S+) Ia=(\S+) off=(\S+)", text)
    Ia = np.array([float(t[1]) for t in terms])
    off = np.array([float(t[2]) for t in terms])
    q, v, a = _states(rng, 25)
    Y = regressor(outcome.robot, q, v, a)
    expected = base.regressor(Y) @ base.from_standard(pi)
    data = loaded.createData()
    for k in range(q.shape[0]):
        tau = (pin.rnea(loaded, data, q[k], v[k], a[k]) + Ia * a[k] + loaded.damping * v[k]
               + loaded.friction * np.sign(v[k]) + off)
        np.testing.assert_allclose(tau, expected[k], rtol=1e-8, atol=1e-8 * np.abs(expected).max())


LEARN = ('[learning]\nmodel = "lstm"\nwindow = 4\nhidden = 8\nepochs = 3\nlambda = 0.2\nseed = 0\n'
         'max_seconds = 60\n')


def test_hierarchical_and_learned_results_predict_as_identify_validated(tmp_path, capsys):
    """A hierarchical fit (paper 003 Sec. 3.3: rigid-body base parameters + friction curves; the
    linear family, Eq. 2, keeps the test fast) with a residual network (Sec. 3.4): predict on the
    validation log gives identify's validation scores, its nominal row (the description's model
    *with* its friction) and the network's row, from what result.json and result_learning.pt hold."""
    _log(tmp_path / "train.csv", 4, 12.0)
    _log(tmp_path / "valid.csv", 5, 5.0)
    cfg = _identify_config(tmp_path, "wls").read_text().replace(
        'coulomb_smoothing = "auto"\n', 'hierarchical = true\nfriction_model = "linear"\n').replace(
        "[output]", LEARN + "\n[output]")
    (tmp_path / "identify.toml").write_text(cfg)
    assert main(["identify", str(tmp_path / "identify.toml"), "--out", str(tmp_path / "out"), "-q"]) == 0, \
        capsys.readouterr().err
    rc = main(["predict", str(tmp_path / "out"), str(_log_config(tmp_path, "valid.csv")), "--out",
               str(tmp_path / "pred"), "-q", "--no-plots"])
    assert rc == 0, capsys.readouterr().err
    pred = json.loads((tmp_path / "pred" / "predict.json").read_text())
    saved = json.loads((tmp_path / "out" / "result.json").read_text())
    assert "hierarchical" in saved["method"]
    for mine, theirs in ((pred["identified"], saved["validation"]), (pred["nominal"], saved["nominal_validation"]),
                         (pred["with_network"], saved["learning"]["validation_with_network"])):
        np.testing.assert_allclose(mine["rmse_per_joint"], theirs["rmse_per_joint"], rtol=1e-10)
    assert not (tmp_path / "pred" / "predict.png").exists()


LEGS = ("P1", "P2", "P3")


@pytest.fixture(scope="module")
def rps3(tmp_path_factory):
    """A virtual 3-RPS (builtin:rps3 as described) under computed torque: two logs of the
    simulator's leg lengths, velocities and accelerations and the leg forces with 1e-4 N of noise,
    OLS on the first. The robot is its description and the noise tiny: at 0.05 N this 4 s motion
    leaves the rigid-body base parameters with standard deviations of about 10x their values (the
    reflected screw inertia and the friction dominate the leg forces), and their closest standard
    vector is not physically consistent (origin-frame inertias at their nominal values around
    moved centres of mass give negative inertias about the centre of mass): the export writes the
    closest consistent one instead (issue 34, item 5; dynid.estimation.consistent_standard)."""
    from dynid._files import save_npz
    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation

    d = tmp_path_factory.mktemp("rps3")
    rng = np.random.default_rng(11)
    for name, seed in (("train", 3), ("valid", 4)):
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": "builtin:rps3", "perturbation": 0.0},
            "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.4,
                           "max_velocity": 0.1, "max_acceleration": 1.0, "periods": 2, "seed": seed},
            "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
        }, d))
        m = sim.motion
        cols = {"t": m.t}
        for k, leg in enumerate(LEGS):
            cols[f"q_{leg}"], cols[f"dq_{leg}"], cols[f"ddq_{leg}"] = (x[:, 2 * k + 1] for x in (m.q, m.dq, m.ddq))
            cols[f"tau_{leg}"] = m.tau_a[:, k] + 1e-4 * rng.standard_normal(m.t.shape)
        save_npz(d / f"{name}.npz", cols)
    data = ('time = { column = "t" }\nposition = { columns = ["q_P1", "q_P2", "q_P3"], unit = "m" }\n'
            'velocity = { columns = ["dq_P1", "dq_P2", "dq_P3"], unit = "m" }\n'
            'acceleration = { columns = ["ddq_P1", "ddq_P2", "ddq_P3"], unit = "m" }\n'
            'effort = { columns = ["tau_P1", "tau_P2", "tau_P3"], unit = "N" }\n')
    (d / "identify.toml").write_text(
        f'[robot]\nmodel = "builtin:rps3"\n\n[data]\nfile = "train.npz"\n{data}\n[validation]\nfile = "valid.npz"\n\n'
        '[processing]\nderivatives = "measured"\ntrim_samples = 0\n\n'
        '[identification]\nmethod = "ols"\n\n[output]\nplots = false\n')
    (d / "log.toml").write_text(f'[data]\nfile = "valid.npz"\n{data}')
    assert main(["identify", str(d / "identify.toml"), "--out", str(d / "out"), "-q"]) == 0
    return d


def test_mechanism_predict_and_mjcf_export(rps3, capsys):
    """A closed-loop mechanism: predict reproduces identify's validation; model.mjcf holds the
    standard vector closest to the nominal one. Independent route: pinocchio's MJCF parser reads
    the bodies' inertias and the joints' armature, damping and friction; through the base map they
    give the estimated base parameters."""
    from dynid.model.mechanism_io import load_mechanism

    d = rps3
    assert main(["predict", str(d / "out"), str(d / "log.toml"), "--out", str(d / "pred"), "-q", "--no-plots"]) == 0, \
        capsys.readouterr().err
    pred = json.loads((d / "pred" / "predict.json").read_text())
    saved = json.loads((d / "out" / "result.json").read_text())
    np.testing.assert_allclose(pred["identified"]["rmse_per_joint"], saved["validation"]["rmse_per_joint"], rtol=1e-12)
    np.testing.assert_allclose(pred["nominal"]["rmse_per_joint"], saved["nominal_validation"]["rmse_per_joint"],
                               rtol=1e-12)
    path = d / "out" / "model.mjcf"
    assert path.is_file() and "one of many" in path.read_text()
    loaded, _ = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    mech = load_mechanism("builtin:rps3")
    names = list(mech.parameter_names)
    pi = np.full(len(names), np.nan)
    for k, j in enumerate(mech.bodies):
        jl = loaded.getJointId(mech.pin_model.names[j])
        pi[10 * k: 10 * k + 10] = loaded.inertias[jl].toDynamicParameters()
    field = {"Ia": "armature", "fv": "damping", "fc": "friction"}
    for i, n in enumerate(names[10 * len(mech.bodies):]):
        kind, joint = n.split("_", 1)
        pi[10 * len(mech.bodies) + i] = getattr(loaded, field[kind])[loaded.joints[loaded.getJointId(joint)].idx_v]
    assert np.all(np.isfinite(pi))
    # the structure identify chose (structure "auto": rps3's three legs tied unless the log rejects it); the
    # export gives every tied body its group's values, which T^+ maps back exactly
    system = as_structured(mech, saved["structure"]["chosen"])
    base = system.base_parameters()
    want = np.array([p["value"] for p in saved["params"]])
    assert list(base.names) == [p["name"] for p in saved["params"]]
    np.testing.assert_allclose(base.from_standard(system.reduce_parameters(pi)), want, rtol=1e-9,
                               atol=1e-9 * np.abs(want).max())


def as_structured(mech, structure: str):
    from dynid.model.system import as_system

    return as_system(mech).with_structure(structure)


def test_mjcf_refuses_an_inertia_pinocchio_would_misread(tmp_path):
    """A body whose inertia about its centre of mass has a negative diagonal entry is refused in
    one line: pinocchio's MJCF parser would read that entry as 0 (and the file would not give the
    base parameters back), MuJoCo refuses it."""
    from dynid.errors import ModelError
    from dynid.io.export import inertia_about_com, write_mjcf
    from dynid.model.mechanism_io import load_mechanism

    mech = load_mechanism("builtin:rps3")
    pi = mech.nominal_parameters().copy()
    k = next(k for k, j in enumerate(mech.bodies) if pi[10 * k] > 0)
    m, c, I_c = inertia_about_com(pi[10 * k: 10 * k + 10])
    pi[10 * k + 4] -= 1.5 * I_c[0, 0]  # Ixx about the joint origin: the same shift about the centre of mass
    with pytest.raises(ModelError, match="negative Ixx about its centre of mass"):
        write_mjcf(mech, pi, tmp_path / "m.mjcf")
    assert not (tmp_path / "m.mjcf").exists()
