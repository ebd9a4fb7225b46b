"""builtin:shang2dof against the closed form of paper 001 (Shang, Cong & Kong 2009)."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.errors import ModelError
from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters
from dynid.model.mechanism import JointCoordinates, Mechanism
from dynid.model.robots import build_mechanism
from dynid.model.robots import shang2dof as s


@pytest.fixture(scope="module")
def mech():
    return build_mechanism("shang2dof")


def _abc_of(mech, pi):
    """a_i, b_i, c_i of paper 001 from standard parameters (module docstring of shang2dof)."""
    idx = {n: k for k, n in enumerate(mech.parameter_names)}
    out = {"a": [], "b": [], "c": []}
    for i in range(1, 4):
        out["a"].append(pi[idx[f"Izz_qa{i}"]] + pi[idx[f"m_qb{i}"]] * s.LINK**2)
        out["b"].append(pi[idx[f"Izz_qb{i}"]])
        out["c"].append(pi[idx[f"mx_qb{i}"]] * s.LINK)
    return {k: np.array(v) for k, v in out.items()}


def _friction_of(mech, pi):
    idx = {n: k for k, n in enumerate(mech.parameter_names)}
    fr = {k: np.array([pi[idx[f"{k}_qa{i}"]] for i in range(1, 4)]) for k in ("fv+", "fv-", "fc+", "fc-")}
    fr["fvb"] = np.array([pi[idx[f"fv_qb{i}"]] for i in range(1, 4)])
    return fr


def test_geometry_and_counts(mech):
    assert (mech.dof, mech.n_actuators, mech.nv, len(mech.bodies)) == (2, 3, 6, 6)
    assert mech.redundant
    # planar loops closed by 3-D point constraints: the two z rows are redundant and dropped
    assert mech.constraint_rows.tolist() == [0, 1, 3, 4]
    q = s.inverse_kinematics(s.CENTRE[None])[0]
    pin_model = mech.pin_model
    bases = [pin_model.jointPlacements[j].translation[:2] for j in (1, 3, 5)]
    np.testing.assert_allclose(bases, s.BASES)
    np.testing.assert_allclose([pin_model.jointPlacements[j].translation[0] for j in (2, 4, 6)], 0.244)
    assert np.abs(mech.constraint_residual(q)).max() < 1e-12


def test_nominal_values_are_table3_and_table2(mech):
    pi = mech.nominal_parameters()
    abc = _abc_of(mech, pi)
    for k in "abc":
        np.testing.assert_allclose(abc[k], s.TABLE3[k], rtol=1e-12)
    fr = _friction_of(mech, pi)
    for k in fr:
        np.testing.assert_allclose(fr[k], s.TABLE2[k], rtol=1e-12)
    # 9 dynamic + 15 friction parameters of Eqs. 7-9
    assert sum(len(v) for v in s.TABLE3.values()) + len(mech.terms) == 24


def test_closed_form_equals_general_closed_loop(mech):
    """Paper 001 Eqs. 1-6 (written out by hand) == general machinery, to 1e-10."""
    rng = np.random.default_rng(0)
    for trial in range(3):
        pi = mech.nominal_parameters()
        nb = mech.n_body_params
        # random but physically shaped values: inertias and friction scaled, my = 0 as in Eq. 1
        pi[:nb] *= np.repeat(rng.uniform(0.7, 1.3, len(mech.bodies)), 10)
        pi[nb:] *= rng.uniform(0.5, 1.5, len(mech.terms))
        n = 40
        xy = s.CENTRE + 0.06 * rng.uniform(-1, 1, (n, 2))
        dxy, ddxy = 0.3 * rng.standard_normal((n, 2)), 2.0 * rng.standard_normal((n, 2))
        proj_cf, tau_cf = s.closed_form_forces(xy, dxy, ddxy, _abc_of(mech, pi), _friction_of(mech, pi))
        state = mech.states(mech.solve_positions(xy), dxy, ddxy)
        proj = actuator_regressor(mech, state, distribution="projected").W @ pi
        tau = actuator_regressor(mech, state, distribution="min_norm_local_friction").W @ pi
        assert np.abs(proj - proj_cf).max() < 1e-10 * np.abs(proj_cf).max()
        assert np.abs(tau - tau_cf).max() < 1e-10 * np.abs(tau_cf).max()


def test_inverse_kinematics_matches_newton(mech):
    rng = np.random.default_rng(5)
    xy = s.CENTRE + 0.08 * rng.uniform(-1, 1, (30, 2))
    q_ik = s.inverse_kinematics(xy)
    q_n = mech.solve_positions(xy)
    d = np.mod(q_n - q_ik + np.pi, 2 * np.pi) - np.pi
    assert np.abs(d).max() < 1e-9


def test_point_mass_at_O_is_not_identifiable(mech):
    """A point mass at O moved from chain 1 to chain 2 leaves every regressor row unchanged:
    two combinations of Table 3's nine a, b, c are not identifiable (10 rigid-body base
    parameters with the my first moments, not 12)."""
    rng = np.random.default_rng(6)
    xy = s.CENTRE + 0.06 * rng.uniform(-1, 1, (20, 2))
    state = mech.states(mech.solve_positions(xy), rng.standard_normal((20, 2)), rng.standard_normal((20, 2)))
    W = actuator_regressor(mech, state, distribution="projected").W
    idx = {n: k for k, n in enumerate(mech.parameter_names)}
    d = np.zeros(mech.n_standard_params)
    mass, L = 0.7, s.LINK
    for i, sign in ((1, -1.0), (2, 1.0)):  # point mass at (L, 0, 0) in the frame of qb_i
        d[idx[f"m_qb{i}"]] += sign * mass
        d[idx[f"mx_qb{i}"]] += sign * mass * L
        for axis in ("Iyy", "Izz"):
            d[idx[f"{axis}_qb{i}"]] += sign * mass * L**2
    assert np.abs(W @ d).max() < 1e-12 * np.abs(W).max()
    base = mechanism_base_parameters(mech)
    n_rb = sum(1 for i in base.independent if i < mech.n_body_params)
    assert (base.n_base, n_rb) == (25, 10)
    np.testing.assert_allclose(base.B @ d, 0.0, atol=1e-9)
    # in Table 3's (a, b, c) coordinates the lost directions are those of point_mass_null_space
    nul = s.point_mass_null_space()
    assert np.linalg.matrix_rank(nul) == 2


def test_minimum_norm_is_minimum_norm(mech):
    rng = np.random.default_rng(7)
    xy = s.CENTRE + 0.05 * rng.uniform(-1, 1, (10, 2))
    state = mech.states(mech.solve_positions(xy), rng.standard_normal((10, 2)), rng.standard_normal((10, 2)))
    pi = mech.nominal_parameters()
    reg_mn = actuator_regressor(mech, state, distribution="min_norm")
    reg_loc = actuator_regressor(mech, state, distribution="min_norm_local_friction")
    tau_mn, tau_loc = reg_mn.W @ pi, reg_loc.W @ pi
    # same projection (both produce the motion) ...
    proj = actuator_regressor(mech, state, distribution="projected").W @ pi
    np.testing.assert_allclose(np.einsum("nau,na->nu", reg_mn.Ga, tau_mn), proj, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nau,na->nu", reg_loc.Ga, tau_loc), proj, atol=1e-12)
    # ... and the min-norm one is the shortest
    assert np.all(np.linalg.norm(tau_mn, axis=1) <= np.linalg.norm(tau_loc, axis=1) + 1e-12)


def test_errors_name_the_cause(mech):
    with pytest.raises(ModelError, match="out of reach of chain"):
        s.inverse_kinematics([[0.9, 0.25]])
    with pytest.raises(ModelError, match="unreachable"):
        mech.solve_positions([[0.9, 0.25]])
    with pytest.raises(ModelError, match="redundantly actuated"):
        state = mech.states(mech.q_ref[None], np.zeros((1, 2)), np.zeros((1, 2)))
        actuator_regressor(mech, state)
    # singular: chain 1 stretched (O at distance 2L from A1)
    q = mech.q_ref.copy()
    q[0], q[1] = 0.0, 0.0
    with pytest.raises(ModelError, match="singular"):
        mech.kinematic_state(q[None], np.zeros((1, 6)), np.zeros((1, 6)))
    import dataclasses

    with pytest.raises(ModelError, match="under-actuated"):
        Mechanism(mech.pin_model, mech.closures, actuated=(0,), independent=mech.independent, q_guess=mech.q_ref)
    # redundant actuation without independent coordinates: the best-conditioned 2 of the 3 actuated
    # joints are chosen (issue 34, item 3), no longer refused
    chosen = Mechanism(mech.pin_model, mech.closures, actuated=(0, 2, 4), q_guess=mech.q_ref)
    assert len(chosen.independent.joints) == 2 and set(chosen.independent.joints) <= {0, 2, 4}
    assert chosen.independent_choice
    with pytest.raises(ModelError, match="no loop closure"):
        Mechanism(mech.pin_model, (), actuated=(0, 2), independent=JointCoordinates((0, 2)))
    bad = dataclasses.replace(mech.closures[0], joint_b=42)
    with pytest.raises(ModelError, match="does not exist"):
        Mechanism(mech.pin_model, (bad,), actuated=(0, 2), q_guess=mech.q_ref)
