"""KUKA LWR4+, FloBaRoID's recordings (../shared/data/kuka_lwr4): identify on run 1, validate on
run 3 (another, faster trajectory); FloBaRoID's own identified URDF (rigid body only) predicts
run 3 through exactly the same processing; dynid must be better on every joint."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from _realdata import example_config, show, table
from conftest import shared_file

from dynid.model.loading import load_pin_model
from dynid.pipeline import identify

pytestmark = pytest.mark.realdata


def _rigid_body_rmse(urdf, ds):
    model = load_pin_model(urdf)
    data = model.createData()
    pred = np.array([pin.rnea(model, data, q, v, a) for q, v, a in zip(ds.q, ds.dq, ds.ddq)])
    return np.sqrt(np.mean((ds.tau - pred) ** 2, axis=0))


@pytest.mark.numerics
def test_kuka_run3_better_than_flobaroid_on_every_joint(capsys):
    for f in ("measurements_1.npz", "measurements_3.npz", "kuka_lwr4.urdf", "kuka_lwr4_identified.urdf"):
        shared_file("kuka_lwr4", f)
    outcome = identify(example_config("kuka_lwr4", output={"plots": False}))
    assert outcome.result.method == "WLS+LMI"
    # solved (with the tolerances tightened 100x Clarabel fails numerically on run 1 and PhysicalLS retries at
    # looser ones, up to 1e-6: then optimal_inaccurate, with the factor recorded)
    assert outcome.result.solver["status"] in ("optimal", "optimal_inaccurate")
    # physical consistency: every body's pseudo-inertia is positive semidefinite (PhysicalLS checks its
    # solution's constraints after the solve and widens its buffer until they hold, whatever Clarabel's
    # tolerances: -1e-7 is eigvalsh's rounding on these bodies' scale, not the solver's)
    assert min(outcome.result.solver["min_pseudo_inertia_eigenvalue"]) > -1e-7
    ours = outcome.validation.rmse
    theirs = _rigid_body_rmse(shared_file("kuka_lwr4", "kuka_lwr4_identified.urdf"), outcome.held_out)
    cad = _rigid_body_rmse(shared_file("kuka_lwr4", "kuka_lwr4.urdf"), outcome.held_out)
    # for the record: unconstrained WLS on run 1 alone (same data) extrapolates poorly to run 3
    plain = identify(example_config("kuka_lwr4", output={"plots": False},
                                    identification={"method": "wls", "physical_consistency": False})).validation.rmse
    rows = [[outcome.robot.joint_names[j], f"{cad[j]:.3f}", f"{theirs[j]:.3f}", f"{plain[j]:.3f}", f"{ours[j]:.3f}"] for j in range(7)]
    show(capsys, table("KUKA LWR4+ run 3 torque RMSE [N*m] (identified on run 1)",
                       ["joint", "CAD URDF", "FloBaRoID URDF", "dynid WLS", "dynid WLS+LMI"], rows))
    # real data, no draw: the closest joint is lwr_1 (0.533 against 0.545, 2 %); the SDP's optimum moves
    # by its gap (conftest.sdp_chi2_slack: a fraction of a std at 10x loosened tolerances), far less
    assert np.all(ours < theirs), f"dynid {np.round(ours, 3)} vs FloBaRoID {np.round(theirs, 3)}"


def _pd_share(outcome, n=1000, seed=0):
    """Share of random configurations (uniform within the joint limits) at which the mass matrix of
    the identified base parameters is positive definite. M(q) e_i = W_b(q, 0, e_i) beta - W_b(q, 0, 0) beta."""
    from dynid.model.serial_dynamics import regressor

    robot, base, beta = outcome.robot, outcome.base, outcome.result.params
    lo, hi = robot.position_limits()
    rng = np.random.default_rng(seed)
    nv = robot.dof
    eye, z = np.eye(nv), np.zeros((nv, nv))
    ok = 0
    for q in lo + (hi - lo) * rng.random((n, nv)):
        Wq = base.regressor(regressor(robot, np.tile(q, (nv, 1)), z, eye))
        W0 = base.regressor(regressor(robot, q[None], z[:1], z[:1]))
        M = (Wq @ beta - W0 @ beta).T
        ok += np.linalg.eigvalsh(0.5 * (M + M.T))[0] > 0
    return ok / n


@pytest.mark.numerics
def test_kuka_constrained_validates_and_has_positive_definite_mass_matrices(capsys):
    """Issue 8 acceptance: on run 3, the constrained model is within 5 % of the unconstrained RMSE,
    and its mass matrix is positive definite at 1000 random configurations (OLS's share reported)."""
    for f in ("measurements_1.npz", "measurements_3.npz", "kuka_lwr4.urdf"):
        shared_file("kuka_lwr4", f)
    rows = []
    for method in ("ols", "wls"):
        plain = identify(example_config("kuka_lwr4", output={"plots": False},
                                        identification={"method": method, "physical_consistency": False}))
        cons = identify(example_config("kuka_lwr4", output={"plots": False},
                                       identification={"method": method, "physical_consistency": True, "margin": 1e-6}))
        assert min(cons.result.solver["min_pseudo_inertia_eigenvalue"]) >= 1e-6
        r_plain, r_cons = plain.validation.rmse, cons.validation.rmse
        total_plain, total_cons = float(np.sqrt(np.mean(r_plain**2))), float(np.sqrt(np.mean(r_cons**2)))
        share_plain, share_cons = _pd_share(plain), _pd_share(cons)
        rows.append([method.upper(), f"{total_plain:.3f}", f"{total_cons:.3f}", f"{100 * share_plain:.1f} %",
                     f"{100 * share_cons:.1f} %", str(len(cons.result.solver["active_constraints"]))])
        assert total_cons <= 1.05 * total_plain, (method, total_cons, total_plain)
        assert np.all(r_cons <= 1.05 * r_plain), (method, r_cons, r_plain)
        assert share_cons == 1.0
        # independent route: pinocchio's CRBA on the exported standard parameters is positive definite
        std = cons.result.solver["standard_params"]
        model = cons.robot.with_parameters(np.array([std[n] for n in cons.robot.parameter_names]))
        data = model.createData()
        lo, hi = cons.robot.position_limits()
        for q in lo + (hi - lo) * np.random.default_rng(1).random((200, 7)):
            M = pin.crba(model, data, q)
            assert np.linalg.eigvalsh(np.triu(M) + np.triu(M, 1).T)[0] > 0
    show(capsys, table("KUKA LWR4+ run 3 (identified on run 1): RMS of the joint torque RMSEs [N*m] and positive "
                       "definite mass matrices at 1000 random configurations",
                       ["method", "RMSE plain", "RMSE +LMI", "M(q) > 0 plain", "M(q) > 0 +LMI", "active"], rows))
