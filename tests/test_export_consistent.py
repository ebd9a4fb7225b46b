"""Standard parameters a simulator can trust (issue 34, item 5): the standard vector behind
model.urdf / model.mjcf is the physically consistent one closest to the prior that gives the
estimated base parameters (:func:`dynid.estimation.consistent_standard.consistent_standard`), and
no body with a negative mass or an impossible inertia reaches those files."""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest

from conftest import seed
from dynid.errors import InputError
from dynid.estimation.consistent_standard import MARGIN, consistent_standard
from dynid.io.export import write_model
from dynid.model import load_robot
from dynid.model.base_parameters import body_violation, parameter_scales, perturb_bodies
from dynid.model.mechanism_io import load_mechanism
from dynid.model.system import as_system
from dynid.tolerances import clarabel_tolerances

MODELS = ("builtin:cobot6r", "builtin:generic6r", "builtin:rps3")


def _setup(model: str, structure: str | None = None):
    robot = load_mechanism(model) if model in ("builtin:rps3", "builtin:hexapod") else load_robot(model)
    system = as_system(robot) if structure is None else as_system(robot).with_structure(structure)
    base = system.base_parameters()
    nominal = system.nominal_parameters()
    scale = parameter_scales(system.parameter_names, system.body_blocks(), nominal)
    return robot, system, base, system.standard_map(base), nominal, scale


def _inconsistent(pi, system) -> bool:
    return any(body_violation(pi[blk]) for blk in system.body_blocks())


def _distance(pi, nominal, scale) -> float:
    return float(np.linalg.norm((pi - nominal) / scale))


@pytest.mark.parametrize("model", MODELS)
def test_the_prior_is_exported_unchanged_when_it_gives_the_estimate(model):
    """Identity case: base parameters of the nominal vector give the nominal vector back (to
    rounding: the closed form pi0 + S (BS)^+ (beta - B pi0) with beta - B pi0 = 0), with no SDP."""
    _, system, base, smap, nominal, scale = _setup(model)
    found = consistent_standard(base.from_standard(nominal), smap, nominal, scale)
    assert found.exact and not found.projected and found.mismatch == 0.0
    np.testing.assert_allclose(found.params, nominal, rtol=0, atol=1e-12 * np.abs(nominal).max())


@pytest.mark.numerics
def test_an_inconsistent_prior_is_not_exported_as_it_is():
    """The PUMA 560's classical parameters (Armstrong et al. 1986, builtin:puma560) give link 1
    only Izz (Ixx + Iyy < Izz: no rigid body has that inertia). Its own base parameters are
    exported as a consistent vector that gives them exactly, not as the prior."""
    _, system, base, smap, nominal, scale = _setup("builtin:puma560")
    assert _inconsistent(nominal, system)
    beta = base.from_standard(nominal)
    found = consistent_standard(beta, smap, nominal, scale)
    assert found.exact and found.projected and not _inconsistent(found.params, system)
    cond = np.linalg.cond(base.B * scale)  # the final move's rounding (next test)
    np.testing.assert_allclose(base.from_standard(found.params), beta, rtol=0,
                               atol=10 * np.finfo(float).eps * cond * np.abs(beta).max())


@pytest.mark.numerics
@pytest.mark.parametrize("model", MODELS)
def test_base_parameters_of_a_consistent_vector_give_the_closest_consistent_vector(model):
    """Base parameters of a consistent vector far from the prior (bodies perturbed by 50 %): the
    closest vector to the prior with those base parameters has a body that is not consistent, and
    the rule's answer is consistent, gives the base parameters to rounding, and is no farther from
    the prior than any consistent vector with the same base parameters we can find (the truth, and
    the truth moved along the null space of B while it stays consistent).

    Margins: B pi = beta after the final move by S (BS)^+: rounding times cond(BS) (10 eps cond |beta|);
    optimality: the SDP's optimum is over bodies whose pseudo-inertia is >= MARGIN of the prior's
    largest eigenvalue, so a candidate inside the full consistent set may be closer by about
    MARGIN per parameter in units of S (10 MARGIN sqrt(p)), plus Clarabel's relative gap."""
    _, system, base, smap, nominal, scale = _setup(model)
    rng = np.random.default_rng(seed(51))
    for _ in range(20):  # a draw whose closest vector is not consistent (the first, in every draw seen)
        truth = perturb_bodies(nominal, system.body_blocks(), 0.5, rng)
        beta = base.from_standard(truth)
        if _inconsistent(base.to_standard(beta, nominal, scale), system):
            break
    else:
        pytest.fail("20 draws of the perturbed bodies all gave a consistent closest vector")
    found = consistent_standard(beta, smap, nominal, scale)
    pi = found.params
    assert found.exact and found.projected
    assert not _inconsistent(pi, system)
    assert all(pi[blk[0]] > 0 for blk in system.body_blocks())
    cond = np.linalg.cond(base.B * scale)
    np.testing.assert_allclose(base.from_standard(pi), beta, rtol=0,
                               atol=10 * np.finfo(float).eps * cond * np.abs(beta).max())
    d_star = _distance(pi, nominal, scale)
    allow = 10 * MARGIN * np.sqrt(pi.size) + 10 * clarabel_tolerances()["tol_gap_rel"] * d_star
    null = np.linalg.svd(base.B)[2][base.n_base:].T
    candidates = [truth] + [truth + null @ rng.normal(size=null.shape[1]) * t for t in (1e-3, 1e-2) for _ in range(10)]
    tried = 0
    for c in candidates:
        if _inconsistent(c, system):
            continue
        tried += 1
        assert d_star <= _distance(c, nominal, scale) + allow
    assert tried >= 1


@pytest.mark.numerics
def test_structural_zeros_stay_zero():
    """The hexapod with the papers' structure (symmetric bodies: 21 parameters fixed at zero,
    dynid.model.reduction): base parameters of a consistent vector with those zeros (bodies
    perturbed by 50 %) give a consistent vector with the zeros exactly zero and the base parameters
    to rounding (the final move leaves the zeros where they are)."""
    _, system, base, smap, nominal, scale = _setup("builtin:hexapod", "paper")
    assert smap.zero.size > 0
    rng = np.random.default_rng(seed(56))
    truth = perturb_bodies(nominal, system.body_blocks(), 0.5, rng)
    truth[smap.zero] = 0.0
    assert not _inconsistent(truth, system)
    beta = base.from_standard(truth)
    found = consistent_standard(beta, smap, nominal, scale)
    assert found.exact and not _inconsistent(found.params, system)
    assert np.all(found.params[smap.zero] == 0.0)
    cond = np.linalg.cond(base.B * scale)
    np.testing.assert_allclose(base.from_standard(found.params), beta, rtol=0,
                               atol=10 * np.finfo(float).eps * cond * np.abs(beta).max())


@pytest.mark.numerics
def test_base_parameters_no_consistent_vector_gives_are_missed_by_the_least():
    """Base parameters no consistent vector gives (the nominal ones with body 3's inertias negated):
    the answer is consistent and says it misses them (exact False) by the smallest mismatch any
    consistent vector has, to the solver's accuracy; every consistent vector tried (the prior,
    perturbed priors) misses them by at least that.

    Margins: the first SDP's optimum is within its slack (10 x Clarabel's gap and feasibility
    tolerances at the data's scale, ``mismatch_slack``) of the true minimum over bodies kept MARGIN
    inside the consistent set (the full set may allow about MARGIN relative less: 10 MARGIN
    allowed); the second holds the mismatch within that slack, to its own feasibility tolerance
    (``slack_prior``)."""
    _, system, base, smap, nominal, scale = _setup("builtin:cobot6r")
    bad = nominal.copy()
    blk = system.body_blocks()[2]
    bad[blk[4:]] = -bad[blk[4:]]
    beta = base.from_standard(bad)
    found = consistent_standard(beta, smap, nominal, scale)
    assert not found.exact and found.projected and found.mismatch > 0
    assert not _inconsistent(found.params, system)
    L = np.diag(np.linalg.norm(base.B * scale, axis=1))  # the metric without a covariance (its docstring)
    miss = lambda pi: float(np.linalg.norm(np.linalg.solve(L, base.from_standard(pi) - beta)))  # noqa: E731
    assert miss(found.params) == pytest.approx(found.mismatch, rel=1e-12)
    r_star, slack = found.stages["mismatch_min"], found.stages["slack"]
    low = r_star * (1 - 10 * MARGIN) - slack  # r_star: over bodies kept MARGIN inside the consistent set
    assert low <= found.mismatch <= r_star + slack + found.stages["slack_prior"]
    rng = np.random.default_rng(seed(52))
    for c in [nominal] + [perturb_bodies(nominal, system.body_blocks(), 0.3, rng) for _ in range(20)]:
        assert miss(c) >= low


def test_write_model_refuses_an_inconsistent_body(tmp_path):
    """model.urdf / model.mjcf are never written with a body that is not physically consistent:
    a one-line InputError, no file (write_urdf itself still writes and flags it)."""
    for robot in (load_robot("builtin:cobot6r"), load_mechanism("builtin:rps3")):
        params = robot.nominal_parameters()
        blk = robot.body_blocks()[2]
        params[blk[0]] = -params[blk[0]]
        with pytest.raises(InputError, match="refusing to write model.(urdf|mjcf): 1 body is not physically consistent"):
            write_model(robot, params, tmp_path)
        assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- through dynid identify
def _poor_logs(d, model: str, legs, noise: float = 0.02, perturbation: float = 0.1):
    """A short excitation (one period of three harmonics): the data leave many standard parameters
    free and the closest vector to the prior is not consistent. Exact states, white effort noise of
    ``noise`` times each channel's largest effort; the true robot's bodies ``perturbation`` off the
    nominal ones (consistent: dynid.model.base_parameters.perturb_bodies)."""
    from dynid._files import save_npz
    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation

    rng = np.random.default_rng(seed(53))
    fast = model == "builtin:cobot6r"
    for name, k in (("train", 54), ("valid", 55)):
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": model, "perturbation": perturbation, "perturbation_seed": 3},
            "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.4,
                           "max_velocity": 1.0 if fast else 0.1, "max_acceleration": 3.0 if fast else 1.0,
                           "periods": 1, "seed": seed(k)},
            "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true"},
        }, d))
        m = sim.motion
        q, dq, ddq = (x if legs is None else x[:, legs] for x in (m.q, m.dq, m.ddq))
        tau = m.tau if legs is None else m.tau_a
        cols = {"t": m.t}
        for j in range(q.shape[1]):
            cols[f"q{j}"], cols[f"dq{j}"], cols[f"ddq{j}"] = q[:, j], dq[:, j], ddq[:, j]
            cols[f"tau{j}"] = tau[:, j] + noise * np.abs(tau[:, j]).max() * rng.standard_normal(q.shape[0])
        save_npz(d / f"{name}.npz", cols)
    n = q.shape[1]
    unit = "rad" if legs is None else "m"
    col = lambda p: str([f"{p}{j}" for j in range(n)])  # noqa: E731
    (d / "id.toml").write_text(
        f'[robot]\nmodel = "{model}"\n\n[data]\nfile = "train.npz"\ntime = {{ column = "t" }}\n'
        f'position = {{ columns = {col("q")}, unit = "{unit}" }}\nvelocity = {{ columns = {col("dq")}, unit = "{unit}" }}\n'
        f'acceleration = {{ columns = {col("ddq")}, unit = "{unit}" }}\n'
        f'effort = {{ columns = {col("tau")}, unit = "{"N*m" if legs is None else "N"}", kind = "torque" }}\n\n'
        '[validation]\nfile = "valid.npz"\n\n[processing]\nderivatives = "measured"\ntrim_samples = 0\n\n'
        '[identification]\nmethod = "ols"\nstructure = "full"\n\n[output]\nplots = false\n')


def _standard_from_urdf(path, robot) -> np.ndarray:
    """The standard vector pinocchio reads from the URDF: bodies' inertias, damping (fv), friction
    (fc), and the rotor inertias and offsets the file records as comments."""
    loaded = pin.buildModelFromUrdf(str(path))
    text = path.read_text()
    lay = robot.layout
    pi = np.full(lay.n_params, np.nan)
    for k, blk in enumerate(robot.body_blocks()):
        pi[blk] = loaded.inertias[k + 1].toDynamicParameters()
    terms = {t[0]: (float(t[1]), float(t[2])) for t in re.findall(r"dynid: joint (\S+) Ia=(\S+) off=(\S+)", text)}
    for k in range(robot.dof):
        name = loaded.names[k + 1]
        pi[lay.extra_index["fv"][k]] = loaded.damping[k]
        pi[lay.extra_index["fc"][k]] = loaded.friction[k]
        pi[lay.extra_index["Ia"][k]], pi[lay.extra_index["offset"][k]] = terms[name]
    return pi, [loaded.inertias[k + 1] for k in range(len(robot.body_blocks()))]


def _standard_from_mjcf(path, mech) -> np.ndarray:
    """The standard vector pinocchio reads from the MJCF: bodies' inertias, armature (Ia), damping
    (fv) and frictionloss (fc) of the joints (as test_predict's MJCF round trip)."""
    loaded, _ = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    names = list(mech.parameter_names)
    pi = np.full(len(names), np.nan)
    inertias = []
    for k, j in enumerate(mech.bodies):
        jl = loaded.getJointId(mech.pin_model.names[j])
        pi[10 * k: 10 * k + 10] = loaded.inertias[jl].toDynamicParameters()
        inertias.append(loaded.inertias[jl])
    field = {"Ia": "armature", "fv": "damping", "fc": "friction"}
    for i, n in enumerate(names[10 * len(mech.bodies):]):
        kind, joint = n.split("_", 1)
        pi[10 * len(mech.bodies) + i] = getattr(loaded, field[kind])[loaded.joints[loaded.getJointId(joint)].idx_v]
    return pi, inertias


@pytest.mark.numerics
@pytest.mark.parametrize("model", ["builtin:cobot6r", "builtin:rps3"])
@pytest.mark.parametrize(("noise", "perturbation"), [(0.02, 0.1), (1e-7, 0.5)], ids=["noisy", "noise-free"])
def test_identify_exports_consistent_bodies_that_give_the_estimate(tmp_path, model, noise, perturbation):
    """``dynid identify`` (OLS, base parameters only) on a poor excitation of a serial arm (URDF)
    and of a closed chain (the 3-RPS, MJCF): the closest vector to the prior is not consistent;
    the file read back by pinocchio has every body with mass > 0 and an inertia about its centre of
    mass that is positive semidefinite and within the triangle inequalities, and through the base
    map it gives the identified base parameters: to the 17 significant digits the files hold
    (1e-9, the parallel-axis round trip) when a consistent vector gives them, else within the
    mismatch the summary reports (in standard deviations of the estimate, to the solver's slack).
    Nearly noise-free efforts of a robot whose bodies are 50 % off the nominal ones (consistent):
    the estimate is the truth's base parameters to 1e-7, which a consistent vector gives, so the
    export must reproduce it (``exact``; with 2 % noise the estimate is often a few standard
    deviations outside the consistent set: then the mismatch branch)."""
    from dynid.cli import main
    from dynid.estimation.results import IdentificationResult

    closed = model == "builtin:rps3"
    _poor_logs(tmp_path, model, [1, 3, 5] if closed else None, noise, perturbation)
    assert main(["identify", str(tmp_path / "id.toml"), "--out", str(tmp_path / "out"), "-q"]) == 0
    robot, system, base, smap, nominal, scale = _setup(model)
    res = IdentificationResult.load(tmp_path / "out" / "result.json")
    assert list(res.names[: base.n_base]) == list(base.names)
    beta = np.asarray(res.params[: base.n_base])
    assert _inconsistent(base.to_standard(beta, nominal, scale), system)  # the data leave the bodies free
    path = tmp_path / "out" / ("model.mjcf" if closed else "model.urdf")
    pi, inertias = (_standard_from_mjcf if closed else _standard_from_urdf)(path, robot)
    assert np.all(np.isfinite(pi))
    for I in inertias:
        assert I.mass > 0
        lam = np.linalg.eigvalsh(I.inertia)
        tol = 1e-12 * max(1.0, np.abs(lam).max())  # the rounding of the parallel-axis shift
        assert lam[0] >= -tol and lam[0] + lam[1] >= lam[2] - tol
    summary = (tmp_path / "out" / "summary.txt").read_text()
    assert "physically consistent" in summary
    found = consistent_standard(beta, smap, nominal, scale, res.cov_params)  # what the summary reports
    assert found.exact or noise > 1e-6
    if found.exact:
        # the exact branch ends with the linear projection onto B pi = beta: its residual is
        # eps x cond(B S) x ||beta||, inside 1e-9 relative for any cond(B S) below 1e6; no solver tolerance enters
        np.testing.assert_allclose(base.from_standard(pi), beta, rtol=1e-9, atol=1e-9 * np.abs(beta).max())
        assert "misses them" not in summary
    else:
        L = np.linalg.cholesky(res.cov_params)
        miss = float(np.linalg.norm(np.linalg.solve(L, base.from_standard(pi) - beta)))
        assert f"misses them by {found.mismatch:.3g}" in summary
        # (below: r_star is the minimum over bodies kept MARGIN inside the consistent set; a consistent
        # vector may miss by that much less, 10 MARGIN relative allowed)
        r_star, slack = found.stages["mismatch_min"], found.stages["slack"]
        assert r_star * (1 - 10 * MARGIN) - slack <= miss <= r_star + slack + found.stages["slack_prior"]
