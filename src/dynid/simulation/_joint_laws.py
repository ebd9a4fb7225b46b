"""The joint-term laws of the constrained simulator (:class:`~dynid.simulation.closed_loop.ConstrainedSimulator`)
as functions ``law(dq, tau_joint) -> tau_joint - terms(dq)`` built once per simulator.

The terms are the piecewise-linear law :math:`a v^+ + b v^- + c[v>0] + d[v<0] + e` of
:func:`~dynid.model.closed_loop.piecewise_linear_terms` per joint, or its regularized form
:math:`a v^+ + b v^- + \\tfrac12(c-d)\\tanh(v/v_b) + \\tfrac12(c+d)|\\tanh(v/v_b)| + e`
(Olsson et al. 1998, Section 2; ``coulomb_band`` of the simulator). They are evaluated at every
stage of every RK4 step (16 times per control period with 4 substeps), on arrays of a few
joints, where the cost is the per-call overhead of NumPy (about half a microsecond a call), not
the arithmetic. Each law therefore computes the same values, term for term, in fewer
operations:

* :math:`a v^+ + b v^-` is :math:`s v` with the slope :math:`s = a` for :math:`v > 0` and
  :math:`b` otherwise (the other product is an exact zero, and adding an exact zero changes no
  value); the levels likewise: :math:`c`, :math:`d` or 0 by the sign of :math:`v`;
* a term whose coefficients are all zero is left out (it would add an exact zero);
* on mechanisms of at most :data:`SCALAR_JOINTS` joints the law runs on Python floats, one
  joint at a time (IEEE double arithmetic as NumPy's element-wise operations, the same
  operations in the same order), which costs a third of the NumPy calls on six joints; the
  regularized law takes its ``tanh`` from NumPy all the same.

Only signed zeros can differ from the formula (an exact zero added to a zero); NaN velocities
give NaN forces as there. ``tests/test_closed_loop_fast_paths.py`` checks every law against
the formula, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dynid._typing import FloatArray

__all__ = ["SCALAR_JOINTS", "piecewise_law"]

SCALAR_JOINTS = 12
"""Up to this many joints the laws run on Python floats (measured: 1.5 us against 3-4 us of
NumPy calls for six joints; even at about twelve)."""

Law = Callable[[FloatArray, FloatArray], FloatArray]


def piecewise_law(coefficients: FloatArray, band: float | None = None, *, scalar: bool | None = None) -> Law:
    """``law(dq, tau_joint)``: ``tau_joint`` minus the joint terms of ``coefficients``
    ``(a, b, c, d, e)`` (each (n_v,)) at the joint velocities ``dq``.

    Parameters
    ----------
    coefficients : array, shape (5, n_v)
        :func:`~dynid.model.closed_loop.piecewise_linear_terms`.
    band : float, optional
        Velocity band :math:`v_b` of the regularized Coulomb law; None: the sign law.
    scalar : bool, optional
        Python floats (True) or NumPy (False); default: Python floats up to
        :data:`SCALAR_JOINTS` joints.
    """
    a, b, c, d, e = (np.asarray(x, dtype=float) for x in coefficients)
    symmetric = bool(np.array_equal(a, b) and np.array_equal(d, -c) and not np.any(e))
    has_e = bool(np.any(e))
    if scalar is None:
        scalar = a.size <= SCALAR_JOINTS
    if band is None:
        return _sign_scalar(a, b, c, d, e, has_e) if scalar else _sign_numpy(a, b, c, d, e, symmetric)
    odd, even = 0.5 * (c - d), 0.5 * (c + d)  # the formula's constant factors, computed once
    return (_band_scalar if scalar else _band_numpy)(a, b, odd, even, e, float(band), symmetric)


def _sign_numpy(a, b, c, d, e, symmetric: bool) -> Law:
    if symmetric:  # a = b, d = -c, e = 0: a v + c sign(v)
        return lambda dq, tau: tau - (a * dq + c * np.sign(dq))

    def law(dq: FloatArray, tau: FloatArray) -> FloatArray:
        pos = dq > 0
        return tau - (np.where(pos, a, b) * dq + np.where(pos, c, np.where(dq < 0, d, 0.0)) + e)

    return law


def _sign_scalar(a, b, c, d, e, has_e: bool) -> Law:
    rows = list(zip(a.tolist(), b.tolist(), c.tolist(), d.tolist(), e.tolist()))
    array = np.array
    # at v = 0 (and NaN) the levels are v * 0.0: zero (NaN) as the formula's sum of zero terms
    if has_e:
        def law(dq: FloatArray, tau: FloatArray) -> FloatArray:
            return array([t - ((ai * x + ci if x > 0 else bi * x + di if x < 0 else x * 0.0) + ei)
                          for t, x, (ai, bi, ci, di, ei) in zip(tau.tolist(), dq.tolist(), rows)])
    else:
        def law(dq: FloatArray, tau: FloatArray) -> FloatArray:
            return array([t - (ai * x + ci if x > 0 else bi * x + di if x < 0 else x * 0.0)
                          for t, x, (ai, bi, ci, di, _) in zip(tau.tolist(), dq.tolist(), rows)])
    return law


def _band_numpy(a, b, odd, even, e, band: float, symmetric: bool) -> Law:
    def law(dq: FloatArray, tau: FloatArray) -> FloatArray:
        th = np.tanh(dq / band)
        if symmetric:
            return tau - (a * dq + odd * th)
        return tau - (np.where(dq > 0, a, b) * dq + odd * th + even * np.abs(th) + e)

    return law


def _band_scalar(a, b, odd, even, e, band: float, symmetric: bool) -> Law:
    rows = list(zip(a.tolist(), b.tolist(), odd.tolist(), even.tolist(), e.tolist()))
    array, tanh = np.array, np.tanh
    if symmetric:
        def law(dq: FloatArray, tau: FloatArray) -> FloatArray:
            return array([t - (ai * x + oi * h)
                          for t, x, h, (ai, _, oi, _, _) in zip(tau.tolist(), dq.tolist(), tanh(dq / band).tolist(), rows)])
    else:
        def law(dq: FloatArray, tau: FloatArray) -> FloatArray:
            return array([t - ((((ai if x > 0 else bi) * x + oi * h) + vi * abs(h)) + ei)
                          for t, x, h, (ai, bi, oi, vi, ei) in zip(tau.tolist(), dq.tolist(), tanh(dq / band).tolist(), rows)])
    return law
