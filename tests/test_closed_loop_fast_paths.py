"""The closed-loop simulation's per-call routes equal the general routes they stand for.

The control loop of a mechanism (:func:`dynid.simulation.closed_loop.simulate_mechanism_control`,
replayed at every DIDIM/IV iteration) evaluates its controller once per period and the plant's
joint terms 16 times per period; those calls take shorter routes on the small arrays:

* the joint-term laws of the plant (:mod:`dynid.simulation._joint_laws`): the same operations on
  the same values, so equal **bit for bit** to the formula
  :math:`a v^+ + b v^- + c[v>0] + d[v<0] + e` (and its regularized form);
* the projection's closure rows (:func:`~dynid.model.loop_kinematics.point_closure_rows`): the
  same differences of the same points, **bit for bit**;
* the controller's coordinates (one kinematics pass for the coordinates and the velocity map):
  the same placements and products, **bit for bit**;
* the controller's forces (:class:`~dynid.model.closed_loop.OneSampleForces`): the joint terms
  summed per joint (the batched route's sum of term columns in another order) and the
  projection and pseudo-inverse on one sample. Both routes are backward stable, so the two
  results differ by a relative amount of order :math:`\\mathrm{cond}(G_a)\\,\\varepsilon` (the
  velocity map itself, when it comes from the one-sample kinematics, adds
  :math:`\\mathrm{cond}([J_c; J_u])\\,\\varepsilon`, tests/test_closed_loop.py); asserted, as there,
  with a factor :math:`100\\,n_v` for the length of the sums: for these well-conditioned 2-6 DOF
  mechanisms (condition numbers 2-30) a relative tolerance of about 1e-12.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynid.model import loop_kinematics as lk
from dynid.model.closed_loop import OneSampleForces, actuator_forces, piecewise_linear_terms, random_consistent_states
from dynid.model.robots import build_mechanism
from dynid.simulation._joint_laws import piecewise_law
from dynid.simulation.closed_loop import AugmentedPD, ConstrainedSimulator

EPS = np.finfo(float).eps
CASES = ["shang2dof", "rps3", "hexapod", "fivebar", "hexapod in task space", "shang2dof smoothed"]


def _mechanism(name):
    if name == "hexapod in task space":
        return build_mechanism("hexapod").in_task_space()
    if name == "shang2dof smoothed":  # Coulomb terms through erf: the controller's general term route
        mech = build_mechanism("shang2dof")
        return dataclasses.replace(mech, coulomb_width=(0.01,) * mech.nv)
    return build_mechanism(name)


def _params(mech, rng):
    """Nominal parameters with every joint term non-zero (of its physical sign) and offsets."""
    pi = mech.nominal_parameters()
    nb = mech.n_body_params
    signs = np.array([-1.0 if t.kind == "coulomb-" else 1.0 for t in mech.terms])
    pi[nb:] = signs * (np.abs(pi[nb:]) + rng.uniform(0.05, 0.2, pi.size - nb))
    return pi


def _formula(coef, dq, band=None):
    """The joint terms as the simulator's docstring writes them, term by term."""
    a, b, c, d, e = coef
    if band is None:
        return a * np.maximum(dq, 0.0) + b * np.minimum(dq, 0.0) + c * (dq > 0) + d * (dq < 0) + e
    th = np.tanh(dq / band)
    return a * np.maximum(dq, 0.0) + b * np.minimum(dq, 0.0) + 0.5 * (c - d) * th + 0.5 * (c + d) * np.abs(th) + e


def _coefficient_sets(rng, nv):
    a, b = rng.uniform(0.1, 2.0, nv), rng.uniform(0.1, 2.0, nv)
    c, d = rng.uniform(0.1, 1.0, nv), -rng.uniform(0.1, 1.0, nv)
    zero = np.zeros(nv)
    mask = rng.uniform(size=nv) < 0.3  # some joints without any term
    yield "asymmetric", np.array([a, b, c, d, zero]) * ~mask
    yield "with offsets", np.array([a, b, c, d, rng.standard_normal(nv)])
    yield "symmetric", np.array([a, a, c, -c, zero]) * ~mask
    yield "viscous only", np.array([a, a, zero, zero, zero])


@pytest.mark.parametrize("nv", [4, 6, 24])
@pytest.mark.parametrize("band", [None, 0.05])
def test_joint_laws_equal_the_formula_bit_for_bit(nv, band):
    """Every law (sign or regularized; Python floats or NumPy; symmetric or not) gives the formula's
    values exactly, at velocities of both signs, exact zeros, values within the band and NaN."""
    rng = np.random.default_rng(nv)
    dqs = [rng.standard_normal(nv), np.zeros(nv), 1e-3 * rng.standard_normal(nv),
           np.where(rng.uniform(size=nv) < 0.5, 0.0, rng.standard_normal(nv)), np.full(nv, np.nan)]
    tau = rng.standard_normal(nv)
    for label, coef in _coefficient_sets(rng, nv):
        for scalar in (True, False, None):
            law = piecewise_law(coef, band, scalar=scalar)
            for dq in dqs:
                np.testing.assert_array_equal(law(dq, tau), tau - _formula(coef, dq, band), err_msg=f"{label} {scalar}")


@pytest.mark.parametrize("band", [None, 0.05])
def test_simulator_joint_forces_are_the_formula(band):
    """The simulator's joint forces (shang2dof: asymmetric friction on the drives, viscous on the
    passive joints; hexapod: symmetric Coulomb and viscous) are the formula of its coefficients."""
    rng = np.random.default_rng(3)
    for name in ("shang2dof", "hexapod"):
        mech = build_mechanism(name)
        sim = ConstrainedSimulator(mech, _params(mech, rng), coulomb_band=band)
        np.testing.assert_array_equal(sim._friction_coefficients, piecewise_linear_terms(mech, sim._theta))
        for dq in (rng.standard_normal(mech.nv), np.zeros(mech.nv)):
            tau_a = rng.standard_normal(mech.n_actuators)
            expected = sim.Sa.T @ tau_a - _formula(sim._friction_coefficients, dq, band)
            np.testing.assert_array_equal(sim.joint_forces(dq, tau_a), expected)


@pytest.mark.parametrize("name", ["shang2dof", "rps3", "hexapod", "fivebar"])
def test_projection_rows_equal_the_closure_rows_bit_for_bit(name):
    """The projection's residual and Jacobian of point closures (one pass, the moving sides only)
    equal closure_residual and closure_jacobian on the independent rows exactly, off the assembly."""
    mech = build_mechanism(name)
    rng = np.random.default_rng(4)
    data = mech.pin_model.createData()
    rows = mech.constraint_rows
    for q in mech.q_ref + 1e-2 * rng.standard_normal((4, mech.nv)):
        c, J = lk.point_closure_rows(mech, q, data)
        np.testing.assert_array_equal(c, lk.closure_residual(mech, q, data)[rows])
        np.testing.assert_array_equal(J, lk.closure_jacobian(mech, q, data, True)[rows])


@pytest.mark.parametrize("name", CASES)
def test_one_sample_forces_equal_the_batched_route(name):
    """OneSampleForces (per-joint sums of the joint terms) equals the batched actuator_forces (term
    columns) on the same states, for every force model: relative differences below
    100 n_v cond(G_a) eps (module docstring)."""
    mech = _mechanism(name)
    rng = np.random.default_rng(5)
    pi = _params(mech, rng)
    state = random_consistent_states(mech, 6, rng)
    model = mech.with_parameters(pi)
    data = model.createData()
    act = list(mech.actuated)
    for dist in ("projected", "min_norm", "min_norm_local_friction") if mech.redundant else (None,):
        batched = actuator_forces(mech, pi, state, distribution=dist)
        for per_joint in (True, False):
            forces = OneSampleForces(mech, pi, dist, per_joint=per_joint)
            for i in range(state.n):
                one = forces(state.q[i], state.dq[i], state.ddq[i], state.G[i], model, data)
                tol = 100 * mech.nv * np.linalg.cond(state.G[i][act]) * EPS
                np.testing.assert_allclose(one, batched[i], rtol=0, atol=tol * np.abs(batched[i]).max(),
                                           err_msg=f"{dist} per_joint={per_joint} sample {i}")


@pytest.mark.parametrize("name", CASES)
def test_controller_equals_the_general_routes(name):
    """AugmentedPD's fused call (one kinematics pass for the coordinates, their rates and the
    velocity map) equals Mechanism.coordinates / coordinate_velocities / states (the batched
    route) and actuator_forces: the coordinates exactly (the same placements and products); the
    forces, with zero gains (so that no gain multiplies a rounding difference of the coordinates),
    below 100 n_v cond([J_c; J_u]) cond(G_a) eps relative (module docstring)."""
    mech = _mechanism(name)
    rng = np.random.default_rng(6)
    pi = _params(mech, rng)
    state = random_consistent_states(mech, 5, rng)
    dist = "min_norm_local_friction" if mech.redundant else None
    zero = np.zeros(mech.dof)
    ctrl = AugmentedPD(mech, pi, zero, zero, dist)
    data = mech.pin_model.createData()
    act = list(mech.actuated)
    two = lambda x: np.repeat(np.asarray(x)[None], 2, axis=0)  # noqa: E731  (the batched route)
    for q, dq in zip(state.q, state.dq):
        u, du = lk._one_coordinates(mech, lk._one_geometry(mech, q, data, 1e8), dq)
        np.testing.assert_array_equal(u, mech.coordinates(q)[0])
        np.testing.assert_array_equal(du, mech.coordinate_velocities(q, dq)[0])
        ref = (u + 1e-3, rng.standard_normal(mech.dof), rng.standard_normal(mech.dof))
        batch = mech.states(two(q), two(du), two(ref[2]))
        expected = actuator_forces(mech, pi, batch, distribution=dist)[0]
        tol = 100 * mech.nv * batch.cond[0] * np.linalg.cond(batch.G[0][act]) * EPS
        np.testing.assert_allclose(ctrl(1e-3, q, dq, ref), expected, rtol=0, atol=tol * np.abs(expected).max())


def test_controller_is_the_one_sample_route_bit_for_bit_on_shang2dof():
    """On the demo's robot (one-sided viscous and Coulomb friction: at most two non-zero terms per
    joint at a time, so the per-joint sums are the term columns' sums exactly) the fused
    controller gives, bit for bit, what the public one-sample routes give (Mechanism.coordinates,
    coordinate_velocities, states and actuator_forces of one sample): the simulation of the demo
    is unchanged to the last bit, not only to rounding (paper 001's gains)."""
    mech = build_mechanism("shang2dof")
    rng = np.random.default_rng(8)
    pi = _params(mech, rng)
    state = random_consistent_states(mech, 6, rng)
    kp, kv = np.full(2, 35000.0), np.full(2, 300.0)
    for dist in ("min_norm", "min_norm_local_friction", "projected"):
        ctrl = AugmentedPD(mech, pi, kp, kv, dist)
        model = mech.with_parameters(pi)
        data = model.createData()
        for q, dq in zip(state.q, state.dq):
            u, du = mech.coordinates(q)[0], mech.coordinate_velocities(q, dq)[0]
            ref = (u + 1e-4 * rng.standard_normal(2), rng.standard_normal(2), rng.standard_normal(2))
            a = ref[2] + kv * (ref[1] - du) + kp * (ref[0] - u)
            one = mech.states(q[None], du[None], a[None])
            expected = actuator_forces(mech, pi, one, distribution=dist, model=model, data=data)[0]
            np.testing.assert_array_equal(ctrl(2e-3, q, dq, ref), expected, err_msg=str(dist))


def test_controller_refuses_a_state_that_is_not_finite():
    """A NaN state is an InputError, as from Mechanism.states (before LAPACK sees it)."""
    from dynid.errors import InputError

    mech = build_mechanism("shang2dof")
    pi = mech.nominal_parameters()
    ctrl = AugmentedPD(mech, pi, np.full(2, 1e3), np.full(2, 50.0), "min_norm")
    q, u = mech.q_ref, mech.coordinates(mech.q_ref)[0]
    bad = q.copy()
    bad[1] = np.nan
    with pytest.raises(InputError, match="finite"):
        ctrl(1e-3, bad, np.zeros(mech.nv), (u, np.zeros(2), np.zeros(2)))
    with pytest.raises(InputError, match="finite"):
        ctrl(1e-3, q, np.zeros(mech.nv), (u, np.zeros(2), np.full(2, np.nan)))
