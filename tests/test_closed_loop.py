"""Closed-loop dynamics checked by independent routes, for every built-in mechanism.

(i)   pinocchio's constrained forward dynamics (KKT, no regressor) integrated under given
      actuator forces: the regressor-based model reproduces those forces along the motion;
(ii)  power of the actuator forces = d/dt(kinetic + potential energy) + friction dissipation,
      the energies from pinocchio's energy functions and differentiated numerically;
(iii) base regressor · base parameters == full regressor · full parameters.
"""

from __future__ import annotations

import _loop_reference as reference
import numpy as np
import pinocchio as pin
import pytest

from dynid.model.closed_loop import (
    actuator_forces,
    actuator_regressor,
    mechanism_base_parameters,
    random_consistent_states,
    term_columns,
)
from dynid.model.mechanism import JointCoordinates
from dynid.model.robots import MECHANISMS, build_mechanism
from dynid.simulation.closed_loop import ConstrainedSimulator

NAMES = sorted(MECHANISMS)
_CACHE: dict[str, object] = {}


def mechanism(name):
    if name not in _CACHE:
        _CACHE[name] = build_mechanism(name)
    return _CACHE[name]


def _distributions(mech):
    return ["projected", "min_norm", "min_norm_local_friction"] if mech.redundant else [None]


def _amplitudes(mech):
    """Motion amplitude per independent coordinate: 2 cm for lengths, 0.1 rad for angles."""
    ind = mech.independent
    if isinstance(ind, JointCoordinates):
        return np.array([0.02 if "P" in mech.pin_model.joints[j + 1].shortname() else 0.1 for j in ind.joints])
    return np.full(ind.size, 0.02)


def smooth_motion(mech, t):
    """u(t) = u_ref + A sin(w t + phase): analytic positions, velocities, accelerations."""
    u_ref = mech.coordinates(mech.q_ref)[0]
    k = np.arange(u_ref.size)
    amp, w, ph = _amplitudes(mech), 2.0 + 1.3 * k, 0.7 * k
    arg = np.outer(t, w) + ph
    return u_ref + amp * np.sin(arg), amp * w * np.cos(arg), -amp * w**2 * np.sin(arg)


def _test_params(mech, rng):
    """Nominal parameters with the joint terms perturbed (so that no term is zero)."""
    pi = mech.nominal_parameters()
    nb = mech.n_body_params
    theta = pi[nb:]
    scale = np.where(theta != 0, np.abs(theta), 0.05)
    signs = np.array([-1.0 if t.kind == "coulomb-" else 1.0 for t in mech.terms])
    pi[nb:] = signs * scale * rng.uniform(0.5, 1.5, size=theta.size)
    offsets = [nb + k for k, t in enumerate(mech.terms) if t.kind == "offset"]
    pi[offsets] = 0.0  # an offset is not a physical force; it has no place in a power balance
    return pi


@pytest.mark.parametrize("name", NAMES)
def test_constrained_forward_dynamics_reproduced_by_regressor(name):
    """(i) forces -> pinocchio constraintDynamics -> motion -> regressor -> same forces."""
    mech = mechanism(name)
    rng = np.random.default_rng(1)
    pi = _test_params(mech, rng)
    dist = "projected" if mech.redundant else None
    # force scale: the actuator forces of a unit acceleration of the independent coordinates
    rest = mech.states(mech.q_ref[None], np.zeros((1, mech.dof)), np.ones((1, mech.dof)))
    scale = np.abs(actuator_forces(mech, pi, rest, distribution="min_norm" if mech.redundant else None)).max()
    hold = actuator_forces(mech, pi, mech.states(mech.q_ref[None], np.zeros((1, mech.dof)), np.zeros((1, mech.dof))),
                           distribution="min_norm" if mech.redundant else None)[0]
    phases = rng.uniform(0, 2 * np.pi, mech.n_actuators)
    freqs = rng.uniform(2.0, 6.0, mech.n_actuators)

    def tau_fn(t):
        return hold + 3.0 * scale * np.sin(freqs * t + phases)

    sim = ConstrainedSimulator(mech, pi, baumgarte=(100.0, 20.0))
    motion = sim.simulate(mech.q_ref, np.zeros(mech.nv), tau_fn, duration=0.3, dt=1e-3)
    assert np.abs(mech.constraint_residual(motion.q)).max() < 1e-6
    u = mech.coordinates(motion.q)
    assert np.ptp(u, axis=0).min() > 1e-3, "the test motion is too small to mean anything"
    state = mech.kinematic_state(motion.q, motion.dq, motion.ddq)
    reg = actuator_regressor(mech, state, distribution=dist)
    predicted = reg.W @ pi
    measured = reg.outputs(motion.tau_a)
    rel = np.abs(predicted - measured).max() / np.abs(measured).max()
    assert rel < 1e-6, rel


@pytest.mark.parametrize("name", [n for n in NAMES if n == "shang2dof"])
@pytest.mark.parametrize("dist", ["min_norm", "min_norm_local_friction"])
def test_distributed_forces_drive_the_same_motion(name, dist):
    """Redundant actuation: forces of a distribution model, applied to pinocchio's
    constrained forward dynamics, produce the accelerations they were computed for."""
    mech = mechanism(name)
    rng = np.random.default_rng(2)
    pi = _test_params(mech, rng)
    t = np.linspace(0.0, 1.0, 25)
    u, du, ddu = smooth_motion(mech, t)
    q = mech.solve_positions(u)
    state = mech.states(q, du, ddu)
    tau = actuator_regressor(mech, state, distribution=dist).W @ pi
    sim = ConstrainedSimulator(mech, pi)
    ddq = np.array([sim.acceleration(q[i], state.dq[i], tau[i]) for i in range(t.size)])
    rel = np.abs(ddq - state.ddq).max() / np.abs(state.ddq).max()
    assert rel < 1e-6, rel
    # and the two distributions differ (the internal force is a real modelling choice)
    other = "min_norm" if dist != "min_norm" else "min_norm_local_friction"
    assert np.abs(actuator_regressor(mech, state, distribution=other).W @ pi - tau).max() > 1e-3 * np.abs(tau).max()


@pytest.mark.parametrize("name", NAMES)
def test_power_balance(name):
    """(ii) actuator power = dE/dt + friction dissipation along a smooth closed-loop motion."""
    mech = mechanism(name)
    rng = np.random.default_rng(3)
    pi = _test_params(mech, rng)
    model = mech.with_parameters(pi)
    data = model.createData()
    nb = mech.n_body_params
    theta = pi[nb:]
    inertia = np.array([t.kind == "inertia" for t in mech.terms])
    h = 1e-5
    t0 = np.linspace(0.05, 0.9, 12)
    tt = np.concatenate([t0 - h, t0, t0 + h])
    u, du, ddu = smooth_motion(mech, tt)
    q = mech.solve_positions(u)
    state = mech.states(q, du, ddu)

    def energy(i):
        e = pin.computeKineticEnergy(model, data, state.q[i], state.dq[i]) + pin.computePotentialEnergy(model, data, state.q[i])
        rotor = term_columns(mech, state.dq[i][None], state.dq[i][None])[0]  # inertia columns hold dq here
        return e + 0.5 * float(np.einsum("ik,k,i->", rotor[:, inertia], theta[inertia], state.dq[i]))

    E = np.array([energy(i) for i in range(tt.size)])
    n = t0.size
    dE = (E[2 * n :] - E[:n]) / (2 * h)
    mid = slice(n, 2 * n)
    F = term_columns(mech, state.dq[mid], state.ddq[mid])
    dissipation = np.einsum("nik,k,ni->n", F[:, :, ~inertia], theta[~inertia], state.dq[mid])
    for dist in _distributions(mech):
        sub = type(state)(q=state.q[mid], dq=state.dq[mid], ddq=state.ddq[mid], G=state.G[mid], cond=state.cond[mid])
        reg = actuator_regressor(mech, sub, distribution=dist)
        y = reg.W @ pi
        if dist == "projected":
            power = np.einsum("nu,nu->n", y, du[mid])  # y = G_a^T tau_a, so u-dot . y = q_a-dot . tau_a
        else:
            power = np.einsum("na,na->n", y, state.dq[mid][:, list(mech.actuated)])
        err = np.abs(power - dE - dissipation).max() / np.abs(power).max()
        assert err < 1e-6, (dist, err)


@pytest.mark.parametrize("name", NAMES)
def test_base_regressor_reproduces_full(name):
    """(iii) on fresh constraint-consistent states and random parameters."""
    mech = mechanism(name)
    base = mechanism_base_parameters(mech)
    rng = np.random.default_rng(4)
    state = random_consistent_states(mech, 30, rng)
    for dist in _distributions(mech):
        W = actuator_regressor(mech, state, distribution=dist).W
        for _ in range(3):
            pi = rng.normal(size=mech.n_standard_params)
            full = W @ pi
            np.testing.assert_allclose(base.regressor(W) @ base.from_standard(pi), full, atol=1e-9 * np.abs(full).max())
    # the base columns are independent on these fresh states
    Wb = base.regressor(actuator_regressor(mech, state, distribution="projected" if mech.redundant else None).W)
    assert np.linalg.matrix_rank(Wb.reshape(-1, base.n_base)) == base.n_base


@pytest.mark.parametrize("name", NAMES)
def test_velocity_and_acceleration_maps(name):
    """J_c G = 0, J_u G = I, and accelerations equal finite differences of the velocities."""
    mech = mechanism(name)
    h = 1e-6
    t0 = np.linspace(0.1, 0.8, 5)
    tt = np.concatenate([t0 - h, t0, t0 + h])
    u, du, ddu = smooth_motion(mech, tt)
    state = mech.states(mech.solve_positions(u), du, ddu)
    n = t0.size
    for i in range(n, 2 * n):
        Jc = mech.constraint_jacobian(state.q[i])
        assert np.abs(Jc @ state.G[i]).max() < 1e-10
        assert np.abs(Jc @ state.dq[i]).max() < 1e-10
    fd = (state.dq[2 * n :] - state.dq[:n]) / (2 * h)
    np.testing.assert_allclose(state.ddq[n : 2 * n], fd, atol=1e-5 * np.abs(fd).max())
    np.testing.assert_allclose(mech.coordinates(state.q), u, atol=1e-10)


@pytest.mark.parametrize("name", NAMES)
def test_rnea_route_equals_the_regressor_for_every_force_model(name):
    """The controllers' route to the model forces (pinocchio RNEA with the parameters' inertias +
    joint terms, projected; model and data reused across calls) equals the closed-loop regressor
    times the parameters, for every force model of the mechanism."""
    mech = mechanism(name)
    rng = np.random.default_rng(7)
    pi = _test_params(mech, rng)
    state = random_consistent_states(mech, 12, rng)
    model = mech.with_parameters(pi)
    data = model.createData()
    for dist in _distributions(mech):
        by_regressor = np.einsum("nop,p->no", actuator_regressor(mech, state, distribution=dist).W, pi)
        by_rnea = actuator_forces(mech, pi, state, distribution=dist, model=model, data=data)
        scale = np.abs(by_regressor).max()
        np.testing.assert_allclose(by_rnea, by_regressor, rtol=0, atol=1e-9 * scale, err_msg=str(dist))


def test_actuator_states_start_from_known_joint_positions():
    """Starting points that already satisfy the loop closures and the actuator positions (a
    simulation's joint positions, as DIDIM passes them) are taken as they are, and give the
    velocities and accelerations of the Gauss-Newton route; starting points 1e-4 away converge
    to the same positions (Gauss-Newton stops once a step is below tol = 1e-10, and converges
    quadratically, so the two agree far below 10 tol); a wrong shape is refused."""
    from dynid.errors import InputError
    from dynid.model import load_model
    from dynid.model.closed_loop import random_consistent_states
    from dynid.model.loop_kinematics import actuator_states

    mech = load_model("builtin:hexapod")
    rng = np.random.default_rng(0)
    st = random_consistent_states(mech, 12, rng)
    act = list(mech.actuated)
    qa, dqa, ddqa = st.q[:, act], st.dq[:, act], st.ddq[:, act]
    ref, _ = actuator_states(mech, qa, dqa, ddqa, tol=1e-10)
    same, resid = actuator_states(mech, qa, dqa, ddqa, tol=1e-10, q_start=ref.q)
    np.testing.assert_array_equal(same.q, ref.q)
    np.testing.assert_array_equal(same.dq, ref.dq)
    np.testing.assert_array_equal(same.ddq, ref.ddq)
    assert np.all(resid < 1e-10)
    near, _ = actuator_states(mech, qa, dqa, ddqa, tol=1e-10, q_start=ref.q + 1e-4 * rng.standard_normal(ref.q.shape))
    assert np.max(np.abs(near.q - ref.q)) < 1e-9
    with pytest.raises(InputError, match="starting joint positions"):
        actuator_states(mech, qa, dqa, ddqa, q_start=ref.q[:, :3])


# ---------------------------------------------------------------- the vectorized closure rows
def _weld_fivebar():
    """The five-bar with its connect replaced by a weld ('6d'): a four-bar, 1 DOF (as in
    tests/test_mechanism_io.py)."""
    import tempfile
    from importlib import resources
    from pathlib import Path

    from dynid.model.mechanism_io import load_mechanism_mjcf

    text = (resources.files("dynid.model.robots") / "fivebar.xml").read_text()
    connect = '<connect name="P" body1="dist1" body2="dist2" anchor="0.27 0 0.36"/>'
    assert connect in text
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "weld.xml"
        path.write_text(text.replace(connect, '<weld name="W" body1="dist1" body2="dist2"/>'))
        return load_mechanism_mjcf(path, actuated=["qa1"])


def _grounded_fourbar():
    """A planar four-bar closed on the ground: three revolute links in a chain, the tip of the
    third pinned to a world point (a closure side on the fixed base, joint 0)."""
    from dynid.model.mechanism import LoopClosure, Mechanism

    model = pin.Model()
    parent, place = 0, pin.SE3.Identity()
    for k, length in enumerate((0.5, 1.0, 0.8)):
        parent = model.addJoint(parent, pin.JointModelRZ(), place, f"j{k + 1}")
        inertia = pin.Inertia(1.0 + k, np.array([length / 2, 0.0, 0.0]), np.diag([0.01, 0.02 + 0.01 * k, 0.03]))
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
        place = pin.SE3(np.eye(3), np.array([length, 0.0, 0.0]))
    tip = LoopClosure("tip", 3, pin.SE3(np.eye(3), np.array([0.8, 0.0, 0.0])), 0,
                      pin.SE3(np.eye(3), np.array([1.1, 0.1, 0.0])))
    return Mechanism(model, (tip,), actuated=(0,), q_guess=np.array([1.5, -1.2, -1.6]), name="grounded four-bar")


CLOSURE_CASES = NAMES + ["weld fivebar", "grounded fourbar"]


def _closure_case(name):
    if name in NAMES:
        return mechanism(name)
    if name not in _CACHE:
        _CACHE[name] = {"weld fivebar": _weld_fivebar, "grounded fourbar": _grounded_fourbar}[name]()
    return _CACHE[name]


@pytest.mark.parametrize("name", CLOSURE_CASES)
def test_closure_rows_equal_the_per_closure_route_and_the_derivative(name):
    """The loop-closure residual and Jacobian, computed for all sides at once (one pass, masks and
    a constant +-1 stacking matrix), equal the closure-by-closure route to rounding, off the
    assembly too (the projection and the position solves start there); and the exact Jacobian is
    the derivative of the residual (central differences at an assembled configuration, h = 1e-6:
    truncation h^2 |c'''| and rounding eps |c| / h, both far below 1e-7 of the scale)."""
    mech = _closure_case(name)
    rng = np.random.default_rng(3)
    data = mech.pin_model.createData()
    for q in mech.q_ref + 1e-2 * rng.standard_normal((4, mech.nv)):
        for exact in (False, True):
            res, rows = reference.closure_rows(mech, q, exact)
            np.testing.assert_allclose(mech._constraint_residual(q, data), res, rtol=0, atol=1e-14 * max(1.0, np.abs(res).max()))
            scale = np.abs(rows).max()
            np.testing.assert_allclose(mech._constraint_jacobian(q, data, exact=exact), rows, rtol=0, atol=1e-13 * scale)
    q = mech.project(mech.q_ref + 1e-2 * rng.standard_normal(mech.nv))
    v, h = rng.standard_normal(mech.nv), 1e-6
    fd = (mech._constraint_residual(q + h * v, data) - mech._constraint_residual(q - h * v, data)) / (2 * h)
    Jv = mech._constraint_jacobian(q, data, exact=True) @ v
    np.testing.assert_allclose(Jv, fd, rtol=0, atol=1e-7 * np.abs(Jv).max())


@pytest.mark.parametrize("name", CLOSURE_CASES + ["hexapod in task space"])
def test_one_sample_states_equal_the_batched_route(name):
    """Mechanism.states of one sample (a controller's call: its own route on 2-D arrays, skew
    matrices for the cross products) equals the batched route's sample to rounding: relative
    differences of a linear solve at most about n cond(A) eps (cond of [J_c; J_u] as states
    reports it), here asserted with 100 n cond eps."""
    mech = build_mechanism("hexapod").in_task_space() if name == "hexapod in task space" else _closure_case(name)
    rng = np.random.default_rng(5)
    state = random_consistent_states(mech, 6, rng)
    du = np.einsum("nij,nj->ni", np.linalg.pinv(state.G), state.dq)  # u-rates of the drawn states
    ddu = rng.standard_normal(du.shape)
    batch = mech.states(state.q, du, ddu)
    for i in range(state.n):
        one = mech.states(state.q[i : i + 1], du[i : i + 1], ddu[i : i + 1])
        tol = 100 * mech.nv * batch.cond[i] * np.finfo(float).eps
        for what in ("dq", "ddq", "G"):
            a, b = getattr(one, what)[0], getattr(batch, what)[i]
            np.testing.assert_allclose(a, b, rtol=0, atol=tol * np.abs(b).max(), err_msg=f"{what} sample {i}")
        assert one.cond[0] == pytest.approx(batch.cond[i], rel=tol)


def test_qr_least_squares_equal_the_svd():
    """The loop solvers' QR route (projection, Gauss-Newton steps) gives numpy's SVD least squares
    for full rank, minimum-norm for wide matrices, and falls back to the SVD for rank deficient
    ones (the minimum-norm solution, which QR without pivoting would not give)."""
    from dynid.model.loop_kinematics import lstsq_full_rank, row_space

    rng = np.random.default_rng(11)
    for m, n in ((18, 24), (24, 24), (30, 24), (1, 3)):
        A, b = rng.standard_normal((m, n)), rng.standard_normal(m)
        ref = np.linalg.lstsq(A, b, rcond=None)[0]
        np.testing.assert_allclose(lstsq_full_rank(A, b), ref, rtol=0, atol=1e3 * np.linalg.cond(A) * np.finfo(float).eps * np.abs(ref).max())
    A = rng.standard_normal((18, 24))
    Q, _ = row_space(A)
    np.testing.assert_allclose(Q @ Q.T, np.linalg.pinv(A) @ A, atol=1e-12)  # the projector onto the rows
    A[5] = A[3]  # rank 17
    assert row_space(A) is None
    b = rng.standard_normal(18)
    b[5] = b[3]
    np.testing.assert_allclose(lstsq_full_rank(A, b), np.linalg.lstsq(A, b, rcond=None)[0], atol=1e-12)


def test_actuator_states_from_starts_reports_the_sample_that_cannot_be_assembled():
    """From starting points the position solve runs on blocks of samples at once; a sample whose
    actuator positions no assembly reaches (one strut 3 m longer than the others allow) is still
    a one-line ModelError naming that sample (with the chunk's offset), as sample by sample."""
    from dynid.errors import ModelError
    from dynid.model.loop_kinematics import actuator_states

    mech = build_mechanism("hexapod")
    st = random_consistent_states(mech, 8, np.random.default_rng(2))
    act = list(mech.actuated)
    qa = st.q[:, act].copy()
    qa[5, 2] += 3.0
    with pytest.raises(ModelError, match=r"^sample 105: actuator positions .* cannot be assembled"):
        actuator_states(mech, qa, st.dq[:, act], st.ddq[:, act], q_start=st.q, sample_offset=100)
    with pytest.raises(ModelError, match=r"^sample 105: "):  # sample by sample (no starting points): the same
        actuator_states(mech, qa, st.dq[:, act], st.ddq[:, act], sample_offset=100)
