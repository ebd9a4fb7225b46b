"""The batched position solve of :func:`~dynid.model.loop_kinematics.actuator_states` (issue 37
item 1, :mod:`dynid.model.loop_batch`: anchors one after the other, the samples between them at
once) gives the roots of the sample-by-sample Gauss–Newton loop, to the solver's tolerance.

Margin. Both routes stop when a step is below ``tol`` (infinity norm) and do not take it. The
loop's steps are Newton steps: the error left is that step plus a second-order term, below
``tol``. The batched route's last steps are chord steps with a Jacobian :math:`\\tilde A` other
than :math:`A` (of the first Newton step, or of the nearest anchor), converging at the rate
:math:`\\rho = \\|\\tilde A^{-1}(\\tilde A - A)\\| < 1/2` (else it falls back to Newton), so its
error is at most :math:`\\mathrm{tol}/(1-\\rho) \\le 2\\,\\mathrm{tol}`. Both roots are the same
(same branch, :mod:`dynid.model.loop_batch`), so :math:`|q_b - q_s| \\le 3\\,\\mathrm{tol}`, plus
rounding of the residual: :math:`\\mathrm{cond}(A)\\,\\varepsilon\\,\\max|q|` per route (A well
conditioned here, condition numbers below 1e3: 1e-12 at most, written as that bound).

Velocities and accelerations are smooth maps of the positions: a position error :math:`\\delta`
changes them by about :math:`\\mathrm{cond}(A)\\,(\\delta / \\ell)` relatively (:math:`\\ell` the
shortest link, 0.05 m here): with :math:`\\delta = 3\\cdot 10^{-10}` below 1e-6 relative.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from dynid.errors import ModelError
from dynid.model import loop_kinematics as lk
from dynid.model.robots import build_mechanism

TOL = 1e-10
EPS = np.finfo(float).eps

# mechanism, amplitude of the independent coordinates' motion [rad or m], samples, duration [s]
CASES = {
    "hexapod": (0.03, 1500, 3.0),  # 500 Hz, two windows of anchors
    "rps3": (0.05, 600, 1.2),
    "fivebar": (0.15, 600, 1.2),
    "shang2dof": (0.02, 600, 1.2),  # redundant actuation: least-squares steps
    "hexapod coarse": (0.03, 150, 6.0),  # 25 Hz: the checks fail on some segments, the loop solves them
}


def _log(name):
    """A smooth motion (three sines per independent coordinate) and its actuator positions."""
    amp, n, duration = CASES[name]
    mech = build_mechanism(name.split()[0])
    rng = np.random.default_rng(37)
    t = np.linspace(0.0, duration, n)
    u0 = mech.coordinates(mech.q_ref)[0]
    w = rng.uniform(1.0, 3.0, (3, u0.size))
    ph = rng.uniform(0, 2 * np.pi, (3, u0.size))
    u = u0 + amp * sum(np.sin(np.outer(t, w[k]) + ph[k]) for k in range(3)) / 3
    q = mech.solve_positions(u, q0=mech.q_ref)
    act = list(mech.actuated)
    return mech, q, q[:, act]


def _both(mech, qa, q0, **kw):
    seq = lk._actuator_positions(mech, qa, q0, TOL, 30, kw.get("offset", 0), mech.pin_model.createData(), sequential=True)
    bat = lk._actuator_positions(mech, qa, q0, TOL, 30, kw.get("offset", 0), mech.pin_model.createData())
    return seq, bat


@pytest.mark.numerics
@pytest.mark.parametrize("name", list(CASES))
def test_batched_position_solve_equals_the_sequential_loop(name, monkeypatch):
    mech, q, qa = _log(name)
    seq, bat = _both(mech, qa, q[0])
    bound = 3 * TOL + 1e-12  # module docstring
    assert np.abs(bat - seq).max() <= bound
    assert np.abs(bat - q).max() <= bound + 1e-11  # and the motion itself (solved to 1e-12 on the residual)
    # the velocities and accelerations of the public route, against the loop's
    rng = np.random.default_rng(1)
    dqa, ddqa = rng.standard_normal(qa.shape), rng.standard_normal(qa.shape)
    st, resid = lk.actuator_states(mech, qa, dqa, ddqa, q0=q[0], tol=TOL)
    monkeypatch.setattr(lk, "_actuator_positions", functools.partial(lk._actuator_positions, sequential=True))
    ref, resid_ref = lk.actuator_states(mech, qa, dqa, ddqa, q0=q[0], tol=TOL)
    assert np.abs(st.q - ref.q).max() <= bound
    # velocities and accelerations are maps evaluated at positions that differ by <= 3 tol (1e-10 m):
    # their relative change is ~3 tol x the maps' curvature over a metre-sized mechanism (~1e-9), plus the
    # velocity map against the normal equations at rounding (seen 3e-11 / 1.6e-10); 1e-6 leaves 1e3
    np.testing.assert_allclose(st.dq, ref.dq, rtol=0, atol=1e-6 * np.abs(ref.dq).max())
    np.testing.assert_allclose(st.ddq, ref.ddq, rtol=0, atol=1e-6 * np.abs(ref.ddq).max())
    np.testing.assert_allclose(resid, resid_ref, rtol=0, atol=bound)


@pytest.mark.numerics
def test_a_coarse_log_falls_back_to_the_loop_where_the_checks_fail(monkeypatch):
    """On a log sampled at 25 Hz the anchors' extrapolation or the samples' deviation from the
    line between anchors fails the branch checks on some segments: those are solved by the loop
    (counted here), the others batched, and all agree with the loop (the test above)."""
    mech, q, qa = _log("hexapod coarse")
    solved = []
    loop = lk._positions_loop

    def counting(*args, **kw):
        solved.append(args[1].shape[0])
        return loop(*args, **kw)

    monkeypatch.setattr(lk, "_positions_loop", counting)
    bat = lk._actuator_positions(mech, qa, q[0], TOL, 30, 0, mech.pin_model.createData())
    assert 2 < sum(solved) < qa.shape[0]  # beyond the first two samples, and not all
    monkeypatch.setattr(lk, "_positions_loop", loop)
    seq = lk._actuator_positions(mech, qa, q[0], TOL, 30, 0, mech.pin_model.createData(), sequential=True)
    assert np.abs(bat - seq).max() <= 3 * TOL + 1e-12


@pytest.mark.numerics
@pytest.mark.parametrize("bad", [1, 65, 200, 299])
def test_an_unreachable_sample_still_raises_with_its_number(bad):
    """A sample whose actuator positions no assembly reaches (one strut 3 m longer): the same
    one-line ModelError from both routes, naming the sample (with ``sample_offset``) and the
    condition number, wherever it falls (one of the first samples, an anchor, between anchors, the last)."""
    mech, q, qa = _log("hexapod")
    qa = qa[:300].copy()
    qa[bad, 2] += 3.0
    zeros = np.zeros_like(qa)
    for sequential in (True, False):
        with pytest.raises(ModelError, match=rf"^sample {100 + bad}: actuator positions .* cannot be assembled .*"
                                             r"condition number"):
            if sequential:
                lk._actuator_positions(mech, qa, q[0], TOL, 30, 100, mech.pin_model.createData(), sequential=True)
            else:
                lk.actuator_states(mech, qa, zeros, zeros, q0=q[0], tol=TOL, sample_offset=100)


@pytest.mark.parametrize("name", ["hexapod", "rps3", "fivebar", "shang2dof", "shang2dof grounded"])
def test_batched_rows_equal_the_closure_residual_and_jacobian(name):
    """The batched route's rows (the Jacobian on its non-zero entries, the residual as one product
    by a constant matrix) at unassembled configurations: the same differences of the same
    products as :func:`closure_residual` and :func:`closure_jacobian`, to rounding (1e-15 m for
    the residual's sums in another order). "grounded": one closure side on the fixed base."""
    import dataclasses

    import pinocchio as pin

    from dynid.model import loop_batch as lb

    mech = build_mechanism(name.split()[0])
    if name.endswith("grounded"):
        cl = list(mech.closures)
        cl[1] = dataclasses.replace(cl[1], joint_a=0, placement_a=pin.SE3(np.eye(3), np.array([0.1, 0.2, 0.0])))
        mech = dataclasses.replace(mech, closures=tuple(cl))
    pt = lb._points(mech)
    data = mech.pin_model.createData()
    view = lb.placement_view(mech, data)
    rows = mech.constraint_rows
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = mech.q_ref + 0.2 * rng.standard_normal(mech.nv)
        J = pin.computeJointJacobians(mech.pin_model, data, q).copy()
        H = np.empty((1, len(pt.joints), 12))
        lb._placements(pt, data, view, H[0])
        c, Jc = lb._stacked(pt, J[None], H)
        ref_c, ref_J = lk.closure_residual(mech, q, data)[rows], lk.closure_jacobian(mech, q, data)[rows]
        # the same few products and sums in another order (batched einsum against per-sample numpy):
        # rounding, a few eps of the placements' and Jacobians' size (about 1 here); 64 eps of their
        # largest entry leaves room for another BLAS kernel or SIMD path, and a wrong term shows at 1e-3
        tol_c = 64 * np.finfo(float).eps * max(1.0, float(np.abs(H).max()))
        tol_J = 64 * np.finfo(float).eps * max(1.0, float(np.abs(J).max()), float(np.abs(H).max()) * float(np.abs(J).max()))
        np.testing.assert_allclose(c[0], ref_c, rtol=0, atol=tol_c)
        np.testing.assert_allclose(lb._residual_rows(pt, H)[0], ref_c, rtol=0, atol=tol_c)
        np.testing.assert_allclose(Jc[0], ref_J, rtol=0, atol=tol_J)
