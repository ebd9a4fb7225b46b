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


def test_kuka_run3_better_than_flobaroid_on_every_joint(capsys):
    for f in ("measurements_1.npz", "measurements_3.npz", "kuka_lwr4.urdf", "kuka_lwr4_identified.urdf"):
        shared_file("kuka_lwr4", f)
    outcome = identify(example_config("kuka_lwr4", output={"plots": False}))
    assert outcome.result.method == "WLS+LMI"
    assert outcome.result.solver["status"] == "optimal"
    # physical consistency: every body's pseudo-inertia is positive semidefinite
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
    assert np.all(ours < theirs), f"dynid {np.round(ours, 3)} vs FloBaRoID {np.round(theirs, 3)}"
