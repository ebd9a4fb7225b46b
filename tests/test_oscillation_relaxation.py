"""The relaxation of an oscillating closed-loop iteration (IDIM-IV, DIDIM:
:func:`dynid.estimation.instrumental.oscillation_relaxation`, used by
:func:`dynid.pipeline.control_loop.control_loop_estimate`).

* On a fixed-point map whose plain iteration 2-cycles (Jacobian eigenvalue -1) or oscillates with a
  growing amplitude (-1.5), the relaxed iteration, driven exactly as the control loop drives it,
  converges to the map's own fixed point, within the loop's stopping rule (0.5 standard
  deviations) and, run on, to rounding; the plain iteration does not.
* On a map the plain iteration contracts monotonically (a symmetric Jacobian with eigenvalues in
  [0, 1): every secant eigenvalue, a Rayleigh quotient, lies there too) the rule never triggers:
  the iterates are the plain iteration's, bit for bit.
* On a real DIDIM run through the control loop (shang2dof twin, contracting), no step is relaxed
  and the result carries no relaxation note: tests/test_control_loop.py,
  ``test_didim_from_the_nominal_model_beats_it`` (the twin's run is not repeated here).
"""

from __future__ import annotations

import numpy as np
import pytest

from dynid.estimation.instrumental import oscillation_relaxation


def _linear_map(eigenvalues, seed: int = 0, normal: bool = False):
    """T(x) = x* + M (x - x*) with M = V diag(eigenvalues) V^-1, V a random basis: orthogonal
    (``normal``: M symmetric) or of condition number below 3."""
    rng = np.random.default_rng(seed)
    p = len(eigenvalues)
    Q, _ = np.linalg.qr(rng.standard_normal((p, p)))
    V = Q if normal else Q @ np.diag(rng.uniform(1.0, 3.0, p))
    M = V @ np.diag(eigenvalues) @ np.linalg.inv(V)
    x_star = rng.standard_normal(p) * 10.0
    return (lambda x: x_star + M @ (x - x_star)), x_star


def _iterate(T, x0, scale, relax: bool, max_iterations: int, tolerance: float):
    """The control loop's iteration (control_loop_estimate): the step T(x_k) - x_k measured in units
    of ``scale``; stop below ``tolerance``; else the next iterate T(x_k), or the relaxed one."""
    xs, fxs, alphas = [], [], []
    x = np.array(x0, dtype=float)
    for _ in range(max_iterations):
        fx = T(x)
        xs.append(x)
        fxs.append(fx)
        if np.max(np.abs(fx - x) / scale) < tolerance:
            return fx, xs, alphas, True
        alpha, nxt = 1.0, fx
        if relax and len(xs) >= 2:
            nxt, alpha, _ = oscillation_relaxation(xs[-2], fxs[-2], x, fx, scale)
        alphas.append(alpha)
        x = nxt
    return fxs[-1], xs, alphas, False


@pytest.mark.parametrize("oscillating", [-1.0, -1.5])
def test_a_non_contracting_oscillation_is_relaxed_to_the_fixed_point(oscillating):
    T, x_star = _linear_map([oscillating, 0.3, -0.2, 0.0, 0.5])
    scale = np.full(5, 0.1)  # the standard deviations the moves are measured in
    x0 = x_star + 40.0 * scale  # 40 standard deviations away, as the hexapod's first IV step
    plain = _iterate(T, x0, scale, relax=False, max_iterations=10, tolerance=0.5)
    assert not plain[3]  # the plain iteration does not contract along the oscillating direction
    est, xs, alphas, converged = _iterate(T, x0, scale, relax=True, max_iterations=10, tolerance=0.5)
    assert converged
    assert any(a < 1.0 for a in alphas) and all(0.0 < a <= 1.0 for a in alphas), alphas  # relaxation acted
    # the reported estimate is T(x_k) with a step below 0.5 sd in every coordinate (norm < 0.5 sqrt(5)):
    # for this linear map T(x) - x* = M (I - M)^-1 (T(x) - x), so its distance to the fixed point is at
    # most ||M (I - M)^-1|| times the step, ||.|| bounded through the basis (condition number < 3)
    # by 3 max|nu / (1 - nu)| = 3 * 1.5 / 2.5: a bound derived from the map, not a measured figure
    bound = 3.0 * max(abs(nu / (1.0 - nu)) for nu in (oscillating, 0.3, -0.2, 0.0, 0.5)) * 0.5 * np.sqrt(5)
    assert np.linalg.norm((est - x_star) / scale) < bound
    # run on (tolerance at rounding), the relaxed iteration reaches T's own fixed point: its fixed
    # point is T's, so the relaxation does not move the estimate. Margin: the stop leaves a step below
    # 1e-9 sd = 1e-10 per coordinate, hence (the bound above, 1.8 sqrt(5) per unit step) at most ~4e-10
    # from x*; rounding of T on |x| <= ~40 is ~1e-14. The 4e-8 allowed is 100x the first, 1e6x the second.
    est, *_, converged = _iterate(T, x0, scale, relax=True, max_iterations=200, tolerance=1e-9)
    assert converged
    np.testing.assert_allclose(est, x_star, rtol=0, atol=1e-8 * scale.max() * 40)


@pytest.mark.parametrize("eigenvalues", [[0.6, 0.3, 0.2, 0.0, 0.5], [0.9, 0.05, 0.4, 0.1, 0.7]])
def test_a_monotonically_contracting_iteration_is_never_relaxed(eigenvalues):
    T, x_star = _linear_map(eigenvalues, seed=1, normal=True)
    scale = np.full(5, 0.1)  # uniform: the secant eigenvalues are Rayleigh quotients of M, in [0, 0.9]
    x0 = x_star + 40.0 * scale
    plain = _iterate(T, x0, scale, relax=False, max_iterations=300, tolerance=1e-6)
    relaxed = _iterate(T, x0, scale, relax=True, max_iterations=300, tolerance=1e-6)
    assert plain[3] and relaxed[3]
    assert all(a == 1.0 for a in relaxed[2])  # never triggered: the same iterates, bit for bit
    assert len(plain[1]) == len(relaxed[1])
    for a, b in zip(plain[1], relaxed[1], strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_secant_step_along_the_move():
    """For a linear T, lambda is T's Jacobian along the last move whatever the move's length (a
    relaxed or halved step included), its eigenvalue when the move lies along an eigenvector; the
    relaxed iterate then has no error left along that move (the secant root) and the plain step in
    the other directions."""
    M = np.diag([-1.4, 0.5, 0.2])
    T = lambda x: M @ x  # noqa: E731 (fixed point 0)
    scale = np.array([1.0, 2.0, 0.5])
    x_prev = np.array([1.0, 0.0, 0.0])
    for move in (1.0, 0.37):  # a full step and a relaxed one, along the eigenvector
        x = x_prev + move * (T(x_prev) - x_prev) + np.array([0.0, 0.3, -0.2])  # plus other directions
        x_prev_off = x_prev + np.array([0.0, 0.3, -0.2])
        nxt, alpha, lam = oscillation_relaxation(x_prev_off, T(x_prev_off), x, T(x), scale)
        assert lam == pytest.approx(-1.4, abs=1e-12)
        assert alpha == pytest.approx(1.0 / 2.4, abs=1e-12)
        # the move is exactly along e1 (the offsets cancel to 0 exactly), so components 2-3 are T(x)'s
        # bits; component 1 is a few operations on values of magnitude <= 2.4: a few ulp (5e-16 each),
        # and 1e-14 allows ~20 ulp, whatever the FMA or SIMD path
        np.testing.assert_allclose(nxt, [0.0, *T(x)[1:]], rtol=0, atol=1e-14)
    # no move: no secant, the plain step
    nxt, alpha, lam = oscillation_relaxation(x_prev, T(x_prev), x_prev, T(x_prev), scale)
    assert alpha == 1.0 and np.isnan(lam) and np.array_equal(nxt, T(x_prev))
