"""``dynid simulate``: virtual experiments from a config, the twins, determinism, bad input."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO

from dynid.config.simulate import load_simulate_config, parse_simulate_config
from dynid.errors import ConfigError
from dynid.io import TableReader
from dynid.model.closed_loop import actuator_regressor
from dynid.model.robots import build_mechanism
from dynid.pipeline.simulate import run_simulation, write_simulation

TWINS = sorted((REPO / "examples" / "twins").glob("*.toml"))

SHANG = """
[robot]
model = "builtin:shang2dof"
perturbation = 0.1

[trajectory]
kind = "circle"
centre = [0.29, 0.25]
radius = 0.04
speed = 0.2
turns = 0.25
ramp = 0.1

[control]
rate_hz = 500
kp = 35000
kd = 300

[sensors]
encoder_resolution = 1e-5
force_noise_std = 0.02
force_correlation = 0.5
seed = 7

[output]
format = "{fmt}"
"""


def _dynid(*args, cwd):
    return subprocess.run([sys.executable, "-m", "dynid.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("fmt", ["csv", "npz"])
def test_simulate_cli_writes_log_truth_and_is_deterministic(tmp_path, fmt):
    (tmp_path / "sim.toml").write_text(SHANG.format(fmt=fmt))
    for out in ("a", "b"):
        r = _dynid("simulate", "sim.toml", "--out", out, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
    for name in (f"log.{fmt}", "truth.json", "metadata.json", "config.toml"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    log = TableReader(tmp_path / "a" / f"log.{fmt}")
    assert set(log.available) >= {"t", "q_qa1", "q_qa3", "tau_qa2", "ref_x", "ref_y"}
    truth = json.loads((tmp_path / "a" / "truth.json").read_text())
    meta = json.loads((tmp_path / "a" / "metadata.json").read_text())
    mech = build_mechanism("shang2dof")
    true = np.array(truth["true_parameters"])
    assert truth["parameter_names"] == list(mech.parameter_names)
    assert not np.allclose(true, truth["nominal_parameters"])  # perturbed truth
    assert meta["constraint_error_max"] < 1e-8 and meta["tracking"]["p_rsme"] < 1e-4
    # positions on the encoder grid, force noise with the asked correlation is there
    q = log.columns(["q_qa1", "q_qa2", "q_qa3"])
    np.testing.assert_allclose(np.round(q / 1e-5) * 1e-5, q, atol=1e-12)


def test_logged_forces_are_the_true_robot_s(tmp_path):
    """Noise-free sensors: the logged actuator forces, projected, equal the closed-loop model
    of the parameters in truth.json along the simulated motion (whose accelerations came from
    pinocchio's constraint dynamics), and not the controller's nominal model."""
    cfg = parse_simulate_config(
        {"robot": {"model": "builtin:shang2dof", "perturbation": 0.2},
         "trajectory": {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.03, "speed": 0.1, "turns": 0.2},
         "control": {"rate_hz": 500, "kp": 20000, "kd": 250}},
        tmp_path,
    )
    out = run_simulation(cfg)
    assert out.metadata["tracking"]["p_rsme"] < 1e-4
    d = out.dataset
    assert d.meta["effort_kind"] == "torque" and d.names == ("qa1", "qa2", "qa3")
    mech = build_mechanism("shang2dof")
    true = np.array(out.truth["true_parameters"])
    m = out.motion
    state = mech.kinematic_state(m.q, m.dq, m.ddq)
    reg = actuator_regressor(mech, state, distribution="projected")
    logged = np.column_stack([out.columns[f"tau_qa{i}"] for i in (1, 2, 3)])
    np.testing.assert_allclose(reg.outputs(logged), reg.W @ true, atol=1e-8 * np.abs(logged).max())
    # ... and not the nominal model's (the controller's), which differs by 20 %
    nominal = np.array(out.truth["nominal_parameters"])
    assert np.abs(reg.outputs(logged) - reg.W @ nominal).max() > 1e-3 * np.abs(logged).max()
    np.testing.assert_allclose(np.column_stack([out.columns[f"q_qa{i}"] for i in (1, 2, 3)]), m.q[:, [0, 2, 4]])
    written = write_simulation(out, tmp_path / "o")
    assert written == ["log.csv", "truth.json", "metadata.json", "timing.json"]


@pytest.mark.parametrize("path", TWINS, ids=[p.stem for p in TWINS])
def test_twins_run(path):
    """Every twin config is valid and runs (shortened to 0.3 s here)."""
    cfg = dataclasses.replace(load_simulate_config(path), duration=0.3)
    out = run_simulation(cfg)
    m = out.metadata
    assert m["n_samples"] > 50  # 0.3 s: 61 samples at the 200 Hz log rate of the paper 003 twin
    if m["kind"] == "closed-loop":
        assert m["constraint_error_max"] < 1e-8
    if path.stem == "hexapod_fourier":  # task-space excitation (paper 004): pose and angular velocity logged
        assert m["independent_coordinates"] == ["PX", "PY", "PZ", "RZ", "RY", "RX"]
        assert {"ref_wx", "ref_wy", "ref_wz"} <= set(out.columns)


def test_task_space_needs_a_parallel_robot(tmp_path):
    doc = {"robot": {"model": "builtin:generic6r"}, "trajectory": {"kind": "fourier", "coordinates": "task"}}
    with pytest.raises(ConfigError, match="is for parallel robots"):
        run_simulation(parse_simulate_config(doc, tmp_path))


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"robot": {"model": "builtin:shang2dof", "colour": "red"}}, "unknown key robot.colour"),
        ({"trajectory": {"kind": "circle", "radius": 0.04, "speed": 0.2}}, "a circle needs 'centre'"),
        ({"robot": {"model": "builtin:rps3"}}, "is a path of 2 coordinates but the robot has 3"),
        ({"control": {"kind": "pid", "kp": [100.0, 100.0]}}, "has 2 entries; the robot has 3 actuators \\(one PID per actuator\\)"),
        ({"control": {"kind": "pid", "model": "nowhere"}}, "control.model: identification result not found"),
        ({"sensors": {"log_rate_hz": 300}}, "must divide control.rate_hz"),
        ({"sensors": {"force_covariance": [[1, 0], [0, 1]], "force_noise_std": 1}}, "not both"),
    ],
)
def test_bad_simulate_configs(tmp_path, patch, message):
    doc = {"robot": {"model": "builtin:shang2dof"},
           "trajectory": {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.04, "speed": 0.2, "turns": 0.5},
           "control": {"rate_hz": 500}}
    doc.update(patch)
    with pytest.raises(ConfigError, match=message):
        run_simulation(parse_simulate_config(doc, tmp_path))


def test_simulate_cli_errors_are_one_line(tmp_path):
    (tmp_path / "bad.toml").write_text('[robot]\nmodel = "builtin:shang2dof"\n[trajectory]\nkind = "spiral"\n')
    r = _dynid("simulate", "bad.toml", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "trajectory.kind" in r.stderr
    assert not (tmp_path / "o").exists()


def test_ground_truth_friction_and_payload(tmp_path):
    """[robot.friction] replaces the linear friction of the truth (a Stribeck friction on the
    five-bar's motors) and [robot.payload] loads a serial arm: both reach the logged forces."""
    base = {"trajectory": {"kind": "fourier", "base_frequency_hz": 1.0, "harmonics": 2, "fill": 0.1, "seed": 1},
            "control": {"rate_hz": 500}, "simulation": {"duration": 0.2}}
    runs = {}
    for label, robot in (("plain", {"model": "builtin:fivebar"}),
                         ("stribeck", {"model": "builtin:fivebar",
                                       "friction": {"model": "stribeck", "fc": 2.0, "fs": 3.0, "fv": 1.0, "vs": 0.05}})):
        runs[label] = run_simulation(parse_simulate_config({**base, "robot": robot}, tmp_path))
    extra = runs["stribeck"].columns["tau_qa1"] - runs["plain"].columns["tau_qa1"]
    assert np.abs(extra).max() > 1.0  # N*m: about the 2-3 N*m of the Stribeck drive friction
    assert runs["stribeck"].truth["ground_truth_friction"]["model"] == "stribeck"
    arm = {"model": "builtin:generic6r"}
    heavy = {**arm, "payload": {"mass": 5.0, "com": [0.0, 0.0, 0.1], "inertia": [0.01, 0.01, 0.01]}}
    t_arm = run_simulation(parse_simulate_config({**base, "robot": arm}, tmp_path)).columns["tau_joint_2"]
    t_heavy = run_simulation(parse_simulate_config({**base, "robot": heavy}, tmp_path)).columns["tau_joint_2"]
    assert np.abs(t_heavy - t_arm).max() > 5.0  # N*m: 5 kg on the wrist loads the shoulder
    # payload.body: the last body by default, or another one
    last = run_simulation(parse_simulate_config({**base, "robot": {**arm, "payload": {**heavy["payload"], "body": "joint_6"}}},
                                                tmp_path))
    np.testing.assert_array_equal(last.columns["tau_joint_2"], t_heavy)
    assert last.truth["payload"]["body"] == "joint_6"
    elbow = run_simulation(parse_simulate_config({**base, "robot": {**arm, "payload": {**heavy["payload"], "body": "joint_3"}}},
                                                 tmp_path)).columns
    assert np.abs(elbow["tau_joint_2"] - t_arm).max() > 5.0 and np.abs(elbow["tau_joint_2"] - t_heavy).max() > 0.1
    with pytest.raises(ConfigError, match="needs \\['fs', 'vs'\\]"):
        parse_simulate_config({**base, "robot": {"model": "builtin:fivebar", "friction": {"model": "stribeck", "fc": 1, "fv": 1}}}, tmp_path)
    with pytest.raises(ConfigError, match="declares no platform; name the body"):
        run_simulation(parse_simulate_config({**base, "robot": {"model": "builtin:fivebar", "payload": {"mass": 1.0}}}, tmp_path))


def test_circle_of_a_platform_in_task_space(tmp_path):
    """trajectory.axes places a 2-D path in two of the hexapod's six task coordinates (paper
    004's validation circle); the others stay at the reference pose."""
    cfg = parse_simulate_config({
        "robot": {"model": "builtin:hexapod"},
        "trajectory": {"kind": "circle", "coordinates": "task", "axes": ["PX", "PY"], "centre": [0.0, 0.0],
                       "radius": 0.01, "speed": 0.02, "turns": 0.1, "ramp": 0.1},
        "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
    }, tmp_path)
    out = run_simulation(cfg)
    c = out.columns
    assert np.ptp(c["ref_PX"]) > 1e-3 and np.ptp(c["ref_PZ"]) == 0.0 and np.ptp(c["ref_RZ"]) == 0.0
    np.testing.assert_allclose(np.hypot(c["ref_PX"], c["ref_PY"]), 0.01, atol=1e-12)
    with pytest.raises(ConfigError, match="name 2 of the coordinates"):
        run_simulation(parse_simulate_config({**cfg.raw, "trajectory": {**cfg.raw["trajectory"], "axes": ["PX", "QQ"]}}, tmp_path))


def test_simulate_a_variant_built_in_code(tmp_path):
    """run_simulation(robot=...) simulates a variant of the configured model (here without Coulomb
    friction, the controlled experiment of bench/processing_study.py): truth.json holds the
    variant's parameters, the logged forces are the variant's, and a model with other parameters
    is refused."""
    from dynid.errors import ModelError

    mech = build_mechanism("shang2dof")
    zero = {t.name for t in mech.terms if t.kind.startswith("coulomb")}
    variant = dataclasses.replace(mech, nominal_terms={k: 0.0 if k in zero else v for k, v in mech.nominal_terms.items()})
    cfg = parse_simulate_config(
        {"robot": {"model": "builtin:shang2dof"},
         "trajectory": {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.03, "speed": 0.1, "turns": 0.2},
         "control": {"rate_hz": 500, "kp": 20000, "kd": 250, "model": "true"}},
        tmp_path,
    )
    out = run_simulation(cfg, robot=variant)
    assert out.truth["model"] == "variant of builtin:shang2dof"
    names, true = out.truth["parameter_names"], np.array(out.truth["true_parameters"])
    assert {names[k]: true[k] for k in range(len(names)) if names[k] in zero} == dict.fromkeys(zero, 0.0)
    assert np.all(np.array(out.truth["nominal_parameters"]) == true)
    m = out.motion
    reg = actuator_regressor(mech, mech.kinematic_state(m.q, m.dq, m.ddq), distribution="projected")
    logged = np.column_stack([out.columns[f"tau_qa{i}"] for i in (1, 2, 3)])
    np.testing.assert_allclose(reg.outputs(logged), reg.W @ true, atol=1e-8 * np.abs(logged).max())
    # the configured model's own Coulomb friction is not in the logged forces
    assert np.abs(reg.outputs(logged) - reg.W @ mech.nominal_parameters()).max() > 1e-3 * np.abs(logged).max()
    with pytest.raises(ModelError, match="other parameters"):
        run_simulation(cfg, robot=build_mechanism("hexapod"))


def test_truth_json_records_no_friction_the_plant_did_not_use(tmp_path):
    """Issue 19 item 5: with [robot.friction] the plant's friction is that model alone; the linear
    friction terms it replaces are recorded as 0 and listed, so that the recorded parameters plus the
    ground-truth model give the logged torques exactly (serial arm, noise-free, computed torque)."""
    from dynid.model import friction as fr
    from dynid.model import load_robot
    from dynid.model.serial_dynamics import inverse_dynamics

    cfg = {"robot": {"model": "builtin:cobot6r", "perturbation": 0.1,
                     "friction": {"model": "smooth_stribeck", "fc": 1.0, "fs": 1.5, "fv": 2.0, "vs": 0.05, "kv": 200.0,
                                  "alpha": 0.8}},
           "trajectory": {"kind": "fourier", "base_frequency_hz": 1.0, "harmonics": 2, "fill": 0.2, "seed": 1},
           "control": {"rate_hz": 500}, "simulation": {"duration": 0.4}}
    out = run_simulation(parse_simulate_config(cfg, tmp_path))
    truth = out.truth
    robot = load_robot("builtin:cobot6r")
    replaced = truth["replaced_by_ground_truth_friction"]
    assert set(replaced) == {n for n in robot.parameter_names if n.startswith(("fv", "fc", "off"))}
    rec = dict(zip(truth["parameter_names"], truth["true_parameters"]))
    assert all(rec[n] == 0.0 for n in replaced) and any(v != 0.0 for n, v in rec.items() if n.startswith("Ia"))
    m = out.motion
    model = fr.SmoothStribeck(fc=1.0, fs=1.5, fv=2.0, vs=0.05, kv=200.0, alpha=0.8)
    tau = inverse_dynamics(robot, np.asarray(truth["true_parameters"]), m.q, m.dq, m.ddq) + model.force(m.dq)
    np.testing.assert_allclose(m.tau, tau, atol=1e-8 * np.abs(tau).max())


def test_a_commanded_motion_outside_the_joint_limits_is_refused(tmp_path):
    """The whole reference is checked against a serial robot's joint limits before anything runs:
    a circle of radius 2 rad in joints 1-2 of the cobot (joint 2 within +-1.6 rad) is refused in one
    line that names the joint, and nothing is written; a rest-to-rest Fourier at 0.05 Hz (whose
    quintic used to leave the range by several radians) now simulates inside it."""
    (tmp_path / "c.toml").write_text(
        '[robot]\nmodel = "builtin:cobot6r"\n[trajectory]\nkind = "circle"\naxes = ["joint_1", "joint_2"]\n'
        'centre = [0.0, 0.0]\nradius = 2.0\nspeed = 1.0\nturns = 0.5\n[control]\nrate_hz = 500\nkp = 400\nkd = 40\n')
    r = _dynid("simulate", "c.toml", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "leaves the joint limits" in r.stderr and "joint_2" in r.stderr and "joint_1 " not in r.stderr
    assert not (tmp_path / "o").exists()
    doc = {"robot": {"model": "builtin:cobot6r"},
           "trajectory": {"kind": "fourier", "base_frequency_hz": 0.05, "harmonics": 5, "fill": 0.6,
                          "max_velocity": 1.0, "max_acceleration": 3.0, "quintic": True, "seed": 6},
           "control": {"rate_hz": 200, "kp": 400, "kd": 40}}
    cfg = dataclasses.replace(parse_simulate_config(doc, tmp_path), duration=None)
    from dynid.pipeline.simulate import _trajectory
    from dynid.model.loading import load_model
    robot = load_model("builtin:cobot6r")
    traj, _ = _trajectory(cfg, robot)
    lo, hi = robot.position_limits()
    q = traj.sample(np.linspace(0.0, traj.duration, 8001))[0]
    assert np.all(q >= lo) and np.all(q <= hi)
    doc["trajectory"]["harmonics"] = 1
    with pytest.raises(ConfigError, match="at least 2 harmonics"):
        _trajectory(parse_simulate_config(doc, tmp_path), robot)
