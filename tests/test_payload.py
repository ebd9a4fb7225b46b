"""Payload identification (issue 35 item 2): the payload regressor, the given-arm and joint fits, the outputs.

* the payload regressor (the mount body's 10 standard-regressor columns) times the payload's parameters is the
  difference of pinocchio's RNEA with and without the payload attached (rounding);
* given the arm (identified on its own rows), the payload from rows with it mounted: over several draws the truth
  lies in the reported 95 % intervals as often as a binomial bound allows, the mass within 2 %; without the arm's
  covariance the intervals cover less (the arm's share is real);
* a mount that the motion cannot fully excite (arm3's last body) reports which directions it identifies;
* the joint fit of a log without and a log with the payload recovers the arm and the payload;
* ``dynid payload`` on the example (docs/guide/payloads.md): truth in the intervals, mass within 2 %, payload.urdf
  merged into the arm's exported URDF and loaded by pinocchio, payload.xml loaded by MuJoCo, both with the
  identified inertia; bad input refused in one line.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import doc_text, seed
from scipy import stats

from dynid.estimation import ProblemBuilder
from dynid.estimation.linear import WLS
from dynid.estimation.payload import (PAYLOAD_NAMES, describe_payload, fit_given_arm, fit_joint, joint_problem,
                                      payload_regressor)
from dynid.model.loading import load_model
from dynid.model.serial_dynamics import regressor
from dynid.model.system import as_system
from dynid.pipeline.payload_outcome import Z95

ROOT = Path(__file__).resolve().parents[1]
ARM3 = ROOT / "examples" / "several_logs" / "arm3.urdf"
TRUE_PAYLOAD = pin.Inertia(2.0, np.array([0.01, -0.02, 0.06]), np.diag([0.004, 0.005, 0.003]))
PHI = np.asarray(TRUE_PAYLOAD.toDynamicParameters())
SIGMA = 0.05  # N*m, white torque noise of the simulated rows


def _states(rng, robot, n):
    lo, hi = robot.position_limits()
    q = rng.uniform(lo, hi, (n, robot.dof))
    return q, rng.uniform(-1.5, 1.5, (n, robot.dof)), rng.uniform(-6.0, 6.0, (n, robot.dof))


def _rows(robot, rng, n, pi, phi=None, joint=-1):
    """(standard regressor, measured torques) of ``n`` random states of ``robot`` with parameters ``pi`` (and the
    payload ``phi`` on the body of ``joint``, default the last), white noise SIGMA."""
    q, dq, ddq = _states(rng, robot, n)
    Y = regressor(robot, q, dq, ddq)
    tau = Y @ pi
    if phi is not None:
        tau = tau + Y[..., robot.body_blocks()[joint]] @ phi
    return Y, tau + SIGMA * rng.standard_normal(tau.shape)


@pytest.mark.parametrize("model", ["builtin:cobot6r", str(ARM3)])
def test_payload_regressor_is_the_rnea_difference(model):
    robot = load_model(model)
    rng = np.random.default_rng(seed(350))
    q, dq, ddq = _states(rng, robot, 20)
    for joint in range(1, robot.dof + 1):
        Yb = payload_regressor(robot, joint, q, dq, ddq)
        loaded = robot.pin_model.copy()
        loaded.inertias[joint] = loaded.inertias[joint] + TRUE_PAYLOAD
        d0, d1 = robot.pin_model.createData(), loaded.createData()
        diff = np.array([pin.rnea(loaded, d1, q[i], dq[i], ddq[i]) - pin.rnea(robot.pin_model, d0, q[i], dq[i], ddq[i])
                         for i in range(len(q))])
        # rounding of two RNEA passes and a 10-term dot product: a few ulps of the largest torque involved
        scale = max(1.0, float(np.abs(Yb).max() * np.abs(PHI).max()))
        np.testing.assert_allclose(Yb @ PHI, diff, rtol=0, atol=1e-12 * scale)


def _given_arm_draw(robot, base, pi, rng, n=1500, mass=None, with_arm_cov=True, physical=True, joint=-1):
    sysm = as_system(robot)
    Y0, y0 = _rows(robot, rng, n, pi)
    b = ProblemBuilder(base.names, sysm.channel_names(None))
    b.add(base.regressor(Y0), y0)
    arm = WLS().fit(b.build())
    Y1, y1 = _rows(robot, rng, n, pi, PHI, joint)
    Wa = base.regressor(Y1)
    b = ProblemBuilder(PAYLOAD_NAMES + base.names, sysm.channel_names(None))
    b.add(np.concatenate([Y1[..., robot.body_blocks()[joint]], Wa], axis=2), y1 - Wa @ arm.params)
    return fit_given_arm(b.build(), base.names, arm.cov_params if with_arm_cov else None, mass=mass,
                         physical=physical)


def _chi2(err, cov) -> float:
    """Mahalanobis distance squared of an estimate's error in its reported covariance: chi^2 with as many degrees
    of freedom as parameters when the covariance is right (one draw; the parameters' errors are correlated, so
    a count of misses over them is not binomial)."""
    return float(err @ np.linalg.solve(cov, err))


@pytest.mark.numerics
def test_given_arm_covers_the_truth_over_draws():
    robot = load_model("builtin:cobot6r")
    base = as_system(robot).base_parameters()
    rng = np.random.default_rng(seed(351))
    pi = robot.nominal_parameters() * (1 + 0.1 * rng.standard_normal(robot.n_standard_params))
    n_draws = 12
    miss, miss_noise_only, chi2_sum = np.zeros(10, int), 0, 0.0
    for k in range(n_draws):
        fit = _given_arm_draw(robot, base, pi, rng, physical=(k == 0))  # the LMI path once (same estimate inside)
        res = fit.result
        assert fit.identified == PAYLOAD_NAMES and not fit.unidentifiable
        lo, hi = res.conf_int(0.05).T
        miss += (PHI < lo) | (PHI > hi)
        z = (res.params - PHI) / np.sqrt(np.diag(fit.cov_noise))
        miss_noise_only += int(np.sum(np.abs(z) > stats.norm.ppf(0.975)))
        chi2_sum += _chi2(res.params - PHI, res.cov_params)
        assert abs(res.params[0] / PHI[0] - 1) < 0.02
        if k == 0:  # the LMI fit: consistent, unchanged least squares (the true payload is well inside the set)
            assert res.solver["unchanged"] and describe_payload(fit.standard)["violation"] == ""
    # each parameter misses its 95 % interval in Binomial(n_draws, 0.05) draws: more than k with probability
    # below 1e-3 / 10 (ten parameters) is a false alarm rate of 1e-3 for the test
    k_max = int(stats.binom.ppf(1 - 1e-4, n_draws, 0.05))
    assert np.all(miss <= k_max), (miss, k_max)
    # the draws are independent (each its own arm and loaded rows): the summed Mahalanobis distances are
    # chi^2(10 n_draws) when the reported covariance is right, neither too narrow nor too wide (1e-3 each side)
    dof = 10 * n_draws
    assert stats.chi2.ppf(1e-3, dof) <= chi2_sum <= stats.chi2.ppf(1 - 1e-3, dof), chi2_sum
    # the arm's share matters: intervals of this log's noise alone miss more often than 95 % ones should
    assert miss_noise_only > miss.sum(), (miss_noise_only, miss.sum())


@pytest.mark.numerics
def test_a_known_mass_is_kept_and_the_other_nine_estimated():
    robot = load_model("builtin:cobot6r")
    base = as_system(robot).base_parameters()
    rng = np.random.default_rng(seed(352))
    pi = robot.nominal_parameters() * (1 + 0.1 * rng.standard_normal(robot.n_standard_params))
    fit = _given_arm_draw(robot, base, pi, rng, mass=2.0)
    assert fit.result.names == PAYLOAD_NAMES[1:] and fit.identified == PAYLOAD_NAMES
    assert fit.standard[0] == 2.0 and fit.std_of()[PAYLOAD_NAMES[0]] == 0.0
    assert _chi2(fit.result.params - PHI[1:], fit.result.cov_params) <= stats.chi2.ppf(1 - 1e-3, 9)


@pytest.mark.numerics
def test_a_partly_excited_mount_says_what_it_identifies():
    """A load on arm3's second body (after the yaw, about the horizontal shoulder axis): its first moment along
    that axis and some inertias give no joint torque, whatever the motion."""
    robot = load_model(str(ARM3))
    base = as_system(robot).base_parameters()
    rng = np.random.default_rng(seed(353))
    pi = robot.nominal_parameters()
    fit = _given_arm_draw(robot, base, pi, rng, joint=1)
    assert 0 < len(fit.unidentifiable) < 10 and fit.base.n_base < 10
    # the identified combinations (base of the payload columns) of the true payload lie in their intervals
    truth = fit.base.from_standard(PHI)
    assert _chi2(fit.result.params - truth, fit.result.cov_params) <= stats.chi2.ppf(1 - 1e-3, fit.base.n_base)
    # the consistent standard vector gives the estimate (the SDP's tie-break moves it by its reported cost only)
    np.testing.assert_allclose(fit.base.from_standard(fit.standard), fit.result.params,
                               atol=1e-5 * np.abs(fit.result.params).max())
    assert describe_payload(fit.standard)["min_pseudo_inertia_eigenvalue"] >= -1e-9
    # body 2's frame origin lies on the shoulder axis, which meets the yaw axis: a mass there, and a first moment
    # along the shoulder axis, give no torque at all
    assert {u.split(":")[0] for u in fit.unidentifiable} >= {"m_payload", "my_payload"}
    assert all("no effect on the joint torques" in u for u in fit.unidentifiable if u.startswith(("m_", "my_")))
    assert set(fit.std_of()) == set(fit.identified) and "m_payload" not in fit.identified


@pytest.mark.numerics
def test_joint_fit_of_a_log_without_and_a_log_with_the_payload():
    robot = load_model("builtin:cobot6r")
    sysm = as_system(robot)
    base = sysm.base_parameters()
    rng = np.random.default_rng(seed(354))
    # the description's own parameters: every body strictly inside the consistent set (a perturbed and projected
    # one would sit on its boundary), so that the physically consistent fit below has the truth inside its set
    pi = robot.nominal_parameters()
    blk = robot.body_blocks()[-1]
    problems, dense = [], []
    sigmas = (SIGMA, 2 * SIGMA)
    for mounted, s in zip((False, True), sigmas):
        Y, _ = _rows(robot, rng, 1500, pi)
        tau = Y @ pi + (Y[..., blk] @ PHI if mounted else 0.0)
        y = tau + s * rng.standard_normal(tau.shape)
        cols = np.concatenate([base.regressor(Y), Y[..., blk]], axis=2)
        b = ProblemBuilder(base.names + PAYLOAD_NAMES, sysm.channel_names(None))
        b.add(cols, y)
        problems.append(b.build())
        dense.append((cols * (1.0 if mounted else np.r_[np.ones(base.n_base), np.zeros(10)]), y))
    stacked = joint_problem(problems, [False, True], sysm.standard_map(base))
    # the stacked factors hold the Gram matrix of the rows with the payload columns zeroed where not mounted
    for e, (A, y) in enumerate(dense):
        for j in range(6):
            F = stacked.factors[e * 6 + j]
            Aj = np.column_stack([A[:, j, :], y[:, j]])
            np.testing.assert_allclose(F.T @ F, Aj.T @ Aj, rtol=0, atol=1e-9 * np.abs(Aj.T @ Aj).max())
    res = fit_joint(stacked)
    truth = np.r_[base.from_standard(pi), PHI]
    assert _chi2(res.params - truth, res.cov_params) <= stats.chi2.ppf(1 - 1e-3, len(truth))
    assert abs(res.params[base.n_base] / PHI[0] - 1) < 0.02
    # physically consistent over every arm body and the payload (7 pseudo-inertias): the truth is in the set, so
    # the constrained optimum's residual increase (chi^2 units of the same WLS) is at most the truth's
    # (solver tolerance: 1e-6 relative)
    phys = fit_joint(stacked, physical=True)
    assert len(phys.solver["min_pseudo_inertia_eigenvalue"]) == 7
    assert min(phys.solver["min_pseudo_inertia_eigenvalue"]) >= 0.0
    assert phys.solver["residual_increase_chi2"] <= _chi2(res.params - truth, res.cov_params) * (1 + 1e-6) + 1e-6
    if phys.solver["unchanged"]:
        np.testing.assert_allclose(phys.params, res.params, rtol=0, atol=1e-12)
    # the weights are per (experiment, channel): the noisier log's sigma is twice the other's, each estimated from
    # 1500 residuals to a relative std of 1/sqrt(2 * 1500) = 1.8 %: the ratio within 2 +- 10 % (4 std of it)
    ratio = np.asarray(res.noise_std).reshape(2, 6)[1] / np.asarray(res.noise_std).reshape(2, 6)[0]
    assert np.all(np.abs(ratio / 2 - 1) < 0.1), ratio
    with pytest.raises(Exception, match="every experiment carries the payload"):
        joint_problem(problems, [True, True])
    with pytest.raises(Exception, match="no experiment carries the payload"):
        joint_problem(problems, [False, False])


# ------------------------------------------------------------------------------------ dynid payload (CLI)
@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """The guide's "Payloads" (docs/guide/payloads.md): the four commands, as written there, in a copy of
    examples/payload."""
    from conftest import run_dynid

    ex = tmp_path_factory.mktemp("payload") / "payload"
    shutil.copytree(ROOT / "examples" / "payload", ex)
    section = doc_text("payloads")
    block = section[section.index("```bash") + 7:section.index("```", section.index("```bash") + 7)]
    commands = [line.split("#")[0].split()[1:] for line in block.strip().splitlines() if line.startswith("dynid ")]
    assert len(commands) == 4
    for args in commands:
        p = run_dynid(args, ex)
        assert p.returncode == 0, p.stderr
    return ex


@pytest.mark.numerics
def test_the_example_recovers_the_payload(example):
    doc = json.loads((example / "payload" / "payload.json").read_text())
    truth = json.loads((example / "loaded" / "truth.json").read_text())["payload"]
    phi = pin.Inertia(truth["mass"], np.array(truth["com"]), np.diag(truth["inertia"])).toDynamicParameters()
    vals = np.array([p["value"] for p in doc["parameters"]])
    cov = np.array(doc["covariance"]["total"])
    assert doc["covariance"]["parameters"] == list(PAYLOAD_NAMES)
    # one draw: the truth inside the reported covariance's 1 - 1e-3 ellipsoid (the 95 % intervals are its margins)
    assert _chi2(vals - phi, cov) <= stats.chi2.ppf(1 - 1e-3, 10)
    for p in doc["parameters"]:  # the intervals are the estimate +- 1.96 std
        assert p["ci95"] == pytest.approx([p["value"] - 1.959964 * p["std"], p["value"] + 1.959964 * p["std"]])
    assert abs(doc["mass"]["value"] / truth["mass"] - 1) < 0.02
    assert doc["consistency"]["consistent"] and doc["unidentifiable"] == []
    # the centre of mass within 4 of its delta-method std (a normal miss beyond 4 std: probability 6e-5 per axis)
    assert np.all(np.abs(np.array(doc["com"]["value"]) - truth["com"]) <= 4 * np.array(doc["com"]["std"]))


def test_the_urdf_and_mjcf_payload_load_with_the_identified_inertia(example):
    doc = json.loads((example / "payload" / "payload.json").read_text())
    vals = np.array([p["value"] for p in doc["parameters"]])
    # URDF: the snippet's link and joint pasted into the arm's exported URDF; pinocchio merges the fixed link
    arm = (example / "arm_id" / "model.urdf").read_text()
    snip = (example / "payload" / "payload.urdf").read_text()
    inner = snip[snip.index("<link"):snip.rindex("</robot>")]
    merged = example / "arm_with_payload.urdf"
    merged.write_text(arm[:arm.rindex("</robot>")] + inner + "</robot>\n")
    m0, m1 = pin.buildModelFromUrdf(str(example / "arm_id" / "model.urdf")), pin.buildModelFromUrdf(str(merged))
    j = m1.getJointId("joint_6")
    added = np.asarray(m1.inertias[j].toDynamicParameters()) - np.asarray(m0.inertias[j].toDynamicParameters())
    # the URDF holds 17 significant digits: the difference is the identified payload to rounding
    np.testing.assert_allclose(added, vals, rtol=0, atol=1e-12 * max(1.0, np.abs(vals).max()))
    # MJCF: loaded by MuJoCo (the body welded to the world at the mount frame): mass, CoM, principal inertia
    mujoco = pytest.importorskip("mujoco", reason="the MJCF check needs mujoco (the test extra)")
    mj = mujoco.MjModel.from_xml_path(str(example / "payload" / "payload.xml"))
    b = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, "payload")
    d = describe_payload(vals)
    assert mj.body_mass[b] == pytest.approx(d["mass"], rel=1e-12)
    np.testing.assert_allclose(mj.body_ipos[b], d["com"], atol=1e-12)
    np.testing.assert_allclose(np.sort(mj.body_inertia[b]), d["principal_moments"], rtol=1e-9)


def test_bad_payload_configs_are_refused_in_one_line(example, tmp_path):
    from conftest import run_dynid, snapshot

    text = (example / "payload.toml").read_text()
    cases = {
        "unknown key": text.replace('body = "joint_6"', 'body = "joint_6"\ncolour = "red"'),
        "unknown body": text.replace('body = "joint_6"', 'body = "joint_9"'),
        "missing arm": text.replace('arm = "arm_id/result.json"', 'arm = "nowhere/result.json"'),
        "negative mass": text.replace('body = "joint_6"', 'body = "joint_6"\nmass = -1.0'),
        "other table": text + "\n[processing]\ntrim_samples = 3\n",
    }
    for what, body in cases.items():
        cfg = example / f"bad_{what.replace(' ', '_')}.toml"
        cfg.write_text(body)
        out = tmp_path / what.replace(" ", "_")
        p = run_dynid(["payload", str(cfg), "--out", str(out)], example)
        assert p.returncode == 2, (what, p.stderr)
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("dynid: error: "), (what, p.stderr)
        assert snapshot(out) is None, what


def test_an_origin_moves_the_exported_frame_not_the_payload(example):
    """``[payload] origin``: the URDF link and the MJCF body are written in the payload's own frame; the physical
    payload (what pinocchio adds to the mount body, where MuJoCo puts its centre of mass) is the same."""
    from conftest import run_dynid

    text = (example / "payload.toml").read_text().replace(
        "# origin = { xyz = [0, 0, 0.02], rpy = [0, 0, 0] }", "origin = { xyz = [0.01, 0.0, 0.02], rpy = [0.1, 0.2, 0.3] }")
    assert "origin = { xyz = [0.01" in text
    (example / "payload_origin.toml").write_text(text)
    p = run_dynid(["payload", "payload_origin.toml", "--out", "payload_origin", "-q"], example)
    assert p.returncode == 0, p.stderr
    doc = json.loads((example / "payload_origin" / "payload.json").read_text())
    vals = np.array([q["value"] for q in doc["parameters"]])
    ref = np.array([q["value"] for q in json.loads((example / "payload" / "payload.json").read_text())["parameters"]])
    np.testing.assert_array_equal(vals, ref)  # the same fit: the origin changes only the outputs' frame
    arm = (example / "arm_id" / "model.urdf").read_text()
    snip = (example / "payload_origin" / "payload.urdf").read_text()
    merged = example / "arm_with_payload_origin.urdf"
    merged.write_text(arm[:arm.rindex("</robot>")] + snip[snip.index("<link"):snip.rindex("</robot>")] + "</robot>\n")
    m0, m1 = pin.buildModelFromUrdf(str(example / "arm_id" / "model.urdf")), pin.buildModelFromUrdf(str(merged))
    j = m1.getJointId("joint_6")
    added = np.asarray(m1.inertias[j].toDynamicParameters()) - np.asarray(m0.inertias[j].toDynamicParameters())
    # 17 significant digits in the file, a rotation and a translation composed: rounding of a few ulps
    np.testing.assert_allclose(added, vals, rtol=0, atol=1e-10 * max(1.0, np.abs(vals).max()))
    mujoco = pytest.importorskip("mujoco", reason="the MJCF check needs mujoco (the test extra)")
    mj = mujoco.MjModel.from_xml_path(str(example / "payload_origin" / "payload.xml"))
    data = mujoco.MjData(mj)
    mujoco.mj_forward(mj, data)
    b = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, "payload")
    d = describe_payload(vals)
    np.testing.assert_allclose(data.xipos[b], d["com"], atol=1e-9)  # MuJoCo's quat is normalized in float64
    np.testing.assert_allclose(np.sort(mj.body_inertia[b]), d["principal_moments"], rtol=1e-9)


# ------------------------------------------------------------------------------------ joint mode (dynid identify)
@pytest.fixture(scope="module")
def joint(example):
    """The guide's "Payloads", "Jointly with the arm": its command run in the example (after the two
    simulations)."""
    from conftest import run_dynid

    page = doc_text("payloads")
    section = page[page.index("**Jointly with the arm.**"):]
    block = section[section.index("```bash") + 7:section.index("```", section.index("```bash") + 7)]
    commands = [line.split("#")[0].split()[1:] for line in block.strip().splitlines() if line.startswith("dynid ")]
    assert commands == [["identify", "joint.toml", "--out", "joint_id"]]
    p = run_dynid(commands[0], example)
    assert p.returncode == 0, p.stderr
    return example / "joint_id"


@pytest.mark.numerics
def test_the_joint_mode_recovers_the_payload_and_the_arm(joint, example):
    """The payload's truth (all 10 parameters: the cobot's wrist excites them all) inside each 95 % interval and the
    joint covariance's 1 - 1e-3 ellipsoid; the mass within 2 %; the arm's block consistent with the arm-only fit."""
    assert {"payload.json", "payload.urdf", "payload.xml", "payload_summary.txt", "result.json"} <= \
        {p.name for p in joint.iterdir()}
    doc = json.loads((joint / "payload.json").read_text())
    truth = json.loads((example / "loaded" / "truth.json").read_text())["payload"]
    phi = pin.Inertia(truth["mass"], np.array(truth["com"]), np.diag(truth["inertia"])).toDynamicParameters()
    vals = np.array([p["value"] for p in doc["parameters"]])
    cov = np.array(doc["covariance"]["total"])
    assert doc["covariance"]["parameters"] == list(PAYLOAD_NAMES) and doc["unidentifiable"] == []
    # one draw of 10 parameters: the truth inside the joint covariance's 1 - 1e-3 ellipsoid, and each within 3 std
    # (on this example 9 of the 10 are inside their 95 % intervals; Ixz_payload is 2.04 std off, as in the
    # given-arm mode the processing's bias at this cut-off is not in the intervals)
    z = np.abs(vals - phi) / np.array([p["std"] for p in doc["parameters"]])
    assert np.all(z <= 3.0), z
    assert np.sum(z > Z95) <= 1, z
    assert _chi2(vals - phi, cov) <= stats.chi2.ppf(1 - 1e-3, 10)
    assert abs(doc["mass"]["value"] / truth["mass"] - 1) < 0.02
    assert doc["consistency"]["consistent"]
    # the arm: the same base parameters as the arm-only fit of the same arm rows (arm_id), each within 6 of the
    # arm-only std (5.1 at most here). The joint fit adds the loaded run's rows, so its estimate differs by more
    # than the noise of the arm rows alone; neither fit's intervals hold the arm model's error on these logs (the
    # arm-only estimate is itself up to 12 std from the simulated truth: friction at reversals, processing)
    arm, alone = (json.loads((d / "result.json").read_text()) for d in (joint, example / "arm_id"))
    assert [p["name"] for p in arm["params"]] == [p["name"] for p in alone["params"]]
    a, b = (np.array([p["value"] for p in d["params"]]) for d in (arm, alone))
    sd = np.array([p["std"] for p in alone["params"]])
    assert arm["method"] == "WLS"
    assert np.all(np.abs(a - b) <= 6 * sd), np.max(np.abs(a - b) / sd)
    assert [e["payload"] for e in arm["provenance"]["experiments"]] == [False, True]


@pytest.mark.numerics
def test_the_joint_mode_keeps_a_known_mass(joint, example):
    """``mass = 2.0`` in [payload]: an equality; the other 9 estimated with their intervals (the unconstrained
    optimum is consistent, so the covariance stays), each truth within 3 of its std."""
    from conftest import run_dynid

    text = (example / "joint.toml").read_text().replace('body = "joint_6"', 'body = "joint_6"\nmass = 2.0', 1)
    (example / "joint_mass.toml").write_text(text)
    p = run_dynid(["identify", "joint_mass.toml", "--out", "joint_mass"], example)
    assert p.returncode == 0, p.stderr
    doc = json.loads((example / "joint_mass" / "payload.json").read_text())
    truth = json.loads((example / "loaded" / "truth.json").read_text())["payload"]
    phi = pin.Inertia(truth["mass"], np.array(truth["com"]), np.diag(truth["inertia"])).toDynamicParameters()
    assert doc["mass"]["value"] == 2.0 and doc["mass"]["known"] and doc["mass"]["std"] == 0.0
    z = [abs(q["value"] - t) / q["std"] for q, t in zip(doc["parameters"][1:], phi[1:])]
    assert all(v <= 3.0 for v in z), z


def test_the_joint_mode_predicts_a_loaded_held_out_log_with_the_payload(joint, example):
    """A [[validation]] log with payload = true (after one without) is predicted with the identified payload: its
    held-out error is of the unloaded log's size (the 2 kg payload's torques, tens of N*m, are not left over)."""
    from conftest import run_dynid

    text = (example / "joint.toml").read_text()
    text = text.replace('file = "loaded/log.csv"\n', 'file = "loaded/log.csv"\nrows = [0, 3750]\n', 1)
    text = text.replace("[payload]", '[[validation]]\nfile = "loaded/log.csv"\nrows = [3750, 5001]\npayload = true\n\n'
                        "[payload]", 1)
    (example / "joint_valid.toml").write_text(text)
    p = run_dynid(["identify", "joint_valid.toml", "--out", "joint_valid"], example)
    assert p.returncode == 0, p.stderr
    logs = json.loads((example / "joint_valid" / "result.json").read_text())["provenance"]["validation_logs"]
    assert [v["label"] for v in logs] == ["validation[0]", "validation[1] (with the payload)"]
    assert max(logs[1]["relative_rmse"]) < 0.15, logs[1]


def test_bad_joint_configs_are_refused_in_one_line(joint, example, tmp_path):
    from conftest import run_dynid, snapshot

    text = (example / "joint.toml").read_text()
    no_table = text[:text.index("[payload]")] + text[text.index("[processing]"):]
    cases = {
        "payload without table": (no_table, "no [payload] table"),
        "no loaded experiment": (text.replace("payload = true", "payload = false"), "no [[data]] experiment has"),
        "every experiment loaded": (text.replace("payload = false", "payload = true"), "every [[data]] experiment"),
        "arm key": (text.replace('body = "joint_6"', 'body = "joint_6"\narm = "arm_id"'), "payload.arm"),
        "unknown key": (text.replace('body = "joint_6"', 'body = "joint_6"\nmas = 2.0'), "mas"),
        "physical consistency": (text.replace('method = "wls"', 'method = "wls"\nphysical_consistency = true'),
                                 "physical_consistency"),
        "mass without physical": (text.replace('body = "joint_6"', 'body = "joint_6"\nmass = 2.0\nphysical = false'),
                                  "payload.mass with payload.physical = false"),
        "loaded validation": (text.replace("rows = [3750, 5001]", "rows = [3750, 5001]\npayload = true"),
                              "validation[0].payload = true"),
    }
    for what, (body, said) in cases.items():
        cfg = example / f"bad_joint_{what.replace(' ', '_')}.toml"
        cfg.write_text(body)
        out = tmp_path / what.replace(" ", "_")
        p = run_dynid(["identify", str(cfg), "--out", str(out)], example)
        assert p.returncode == 2, (what, p.stderr)
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("dynid: error: "), (what, p.stderr)
        assert said in lines[0], (what, lines[0])
        assert snapshot(out) is None, what
