"""Square-root extended and unscented Kalman filters for joint state-parameter estimation
(``[identification] method = "ekf"`` / ``"ukf"``; the robot-side model is built by
:mod:`dynid.pipeline.kalman_estimate`). Pure NumPy: no pipeline, no robot model.

The problem
-----------
A state :math:`x = (s, \\beta)` with a linear process and a nonlinear measurement,

.. math::

    x_{k+1} = F x_k + w_k,\\quad w_k \\sim N(0, Q),\\qquad z_k = h_k(x_k) + v_k,\\quad v_k \\sim N(0, R),

where :math:`s` is a kinematic state (:mod:`dynid.signals.kalman`'s white-snap model per
actuator coordinate) and :math:`\\beta` the base parameters (constant: their rows of :math:`Q`
are zero). The identification of robot dynamics by an extended Kalman filter on such a joint
state is Gautier & Poignet 2001 ("Extended Kalman filtering and weighted least squares dynamic
identification of robot", *Control Engineering Practice* 9(12)); Leboutet et al. 2021 (the
survey behind BIRDy, "Inertial parameter identification in robotics: a survey", *Applied
Sciences* 11(9)) compare it with the unscented filter.

Square roots, never a covariance
--------------------------------
Every covariance is carried as a square root :math:`S` with :math:`P = S^T S` (any square
root: the array algorithms need no triangular one) and every update is one QR factorization of
a pre-array (Kailath, Sayed & Hassibi 2000, *Linear Estimation*, Ch. 12, array algorithms):

* prediction: :math:`[S F^T;\\ Q^{1/2}] = \\Theta [S';\\ 0]`, so :math:`S'^T S' = F P F^T + Q`
  (:func:`predict`);
* measurement (Morf-Kailath form): with :math:`\\bar S = S H^T` (m columns),

  .. math::

      \\begin{bmatrix} R^{1/2} & 0 \\\\ \\bar S & S \\end{bmatrix} = \\Theta
      \\begin{bmatrix} X & Y \\\\ 0 & Z \\end{bmatrix},\\quad
      X^T X = R + H P H^T = P_{zz},\\ X^T Y = H P = P_{xz}^T,\\ Z^T Z = P - P_{xz} P_{zz}^{-1} P_{xz}^T,

  and the mean moves by :math:`K e = Y^T X^{-T} e` (:func:`update`). :math:`P` is never formed,
  no Cholesky factor of a difference (a possibly indefinite matrix) is ever taken.

EKF (:func:`run`, ``kind = "ekf"``): :math:`\\bar S = S H^T` with :math:`H` the Jacobian the
caller's ``linearize(k, x, S)`` returns at the predicted state, :math:`e = z - h(x)`; the caller may
add rows under :math:`R^{1/2}` (a square root of more innovation covariance) and shift
:math:`h(x)`: the Gaussian second-order terms of a measurement bilinear in two parts of the state
(:func:`bilinear_second_order`).

UKF (``kind = "ukf"``): the square-root unscented filter (van der Merwe & Wan 2001, "The
square-root unscented Kalman filter for state and parameter estimation", ICASSP; the unscented
transform of Julier & Uhlmann 1997, "A new extension of the Kalman filter to nonlinear
systems", and 2004, "Unscented filtering and nonlinear estimation", *Proc. IEEE* 92(3)) with
:math:`\\alpha = 1, \\kappa = 0, \\beta_{UT} = 0`: :math:`\\lambda = 0`, the centre point's weights
both 0 and the :math:`2L` others :math:`1/(2L)`, all non-negative, spread :math:`\\gamma = \\sqrt L`.
The sigma points are :math:`x \\pm \\gamma s_i` (:math:`s_i` the rows of :math:`S`), passed
through :math:`h_k` in one batched call (``measure(k, X)``). With
:math:`a_i = (Z_i^+ - Z_i^-)/2`, :math:`b_i = (Z_i^+ + Z_i^-)/2 - \\hat z` and
:math:`\\hat z = \\sum_i (Z_i^+ + Z_i^-)/(2L)`, the unscented moments are
:math:`P_{zz} = R + (A^T A + B^T B)/L` and :math:`P_{xz} = S^T A/\\gamma`, so the pre-array

.. math::

    \\begin{bmatrix} R^{1/2} & 0 \\\\ B/\\gamma & 0 \\\\ A/\\gamma & S \\end{bmatrix}

gives, by the same QR, :math:`X^T X = P_{zz}`, :math:`X^T Y = P_{xz}^T` and
:math:`Z^T Z = P - P_{xz} P_{zz}^{-1} P_{xz}^T`: the square-root UKF's mean and covariance without
its Cholesky downdate (van der Merwe & Wan's update :math:`\\mathrm{cholupdate}(S, K S_z^T, -1)`
may fail in rounding; the array form cannot). :math:`A/\\gamma` is the central-difference
Jacobian times the square root (the statistical linearization), :math:`B/\\gamma` the square root
of the second-order spread added to :math:`R`. The process is linear, and the unscented
transform of a linear map is exact: the time update is :func:`predict`.

Partially linear measurements (``run(..., linear=p)``: the UKF of the identification)
-------------------------------------------------------------------------------------
With :math:`x = (u, b)`, :math:`b` the last ``p`` entries and :math:`h(x) = f(u) + H(u) b` (the
forces :math:`W(q, \\dot q, \\ddot q)\\beta`: linear in the parameters), the plain 2L-point transform
above is short of the product of the uncertainties of :math:`u` and :math:`b`. For
:math:`h = x^T M x` it integrates :math:`\\sum_i (s_i^T M s_i)^2`-type terms only, the diagonal of
:math:`M` in the basis of the rows :math:`s_i`, whereas the Gaussian variance is
:math:`2 \\sum_{ij} (s_i^T M s_j)^2`: the terms :math:`i \\ne j` are missing, so a row that
moves only :math:`b` (an upper-triangular square root has :math:`p` of them) never meets the
:math:`u` part of the others, and most of :math:`\\mathrm{Var}(\\delta u^T G b)` is left out of
:math:`P_{zz}` (the symmetric set matches the moments up to the second only: Julier & Uhlmann
2004). On the serial arm's 2 s periodic motion the covariance was then optimistic: the truth's chi-square 67.6 to
5.1e5 for 22 parameters in four draws (tests/test_every_method_contract.py, bench/README.md).
The update used instead integrates over :math:`u` by sigma points and over :math:`b` exactly, given
:math:`u` (the linear substructure of Morelande & Ristic 2006, "Reduced sigma point filtering for
partially linear models", ICASSP; the same moments in the linear-regression Kalman filters of
arXiv:2009.07571). With the square root upper triangular (a QR of :math:`S`),
:math:`S = [S_u;\\ 0\\ R_b]`, :math:`x - \\hat x = S^T \\zeta` splits into :math:`\\xi` (the first
:math:`n_u` rows, which move :math:`u` and :math:`b`'s conditional mean with it) and :math:`\\eta`
(:math:`R_b`: :math:`b`'s covariance given :math:`u`, independent of :math:`u`). The sigma points
:math:`\\hat x \\pm \\sqrt{n_u}\\, s_i` over the :math:`n_u` rows of :math:`S_u` give :math:`\\hat z`,
:math:`A`, :math:`B` as above, and :math:`V_c = R_b H(u_c)^T` at each of them the rest:
:math:`E_u[H R_b^T R_b H^T] = \\bar V^T \\bar V + \\sum_c (V_c - \\bar V)^T (V_c - \\bar V)/(2 n_u)` and
:math:`\\mathrm{Cov}(x, H(u) R_b^T \\eta) = S_\\eta^T \\bar V`, so the pre-array

.. math::

    \\begin{bmatrix} R^{1/2} & 0 \\\\ B/\\gamma & 0 \\\\ D & 0 \\\\ A/\\gamma & S_u \\\\
    \\bar V & S_\\eta \\end{bmatrix},
    \\quad D^T D = \\sum_c (V_c - \\bar V)^T (V_c - \\bar V)/(2 n_u),\\ \\gamma = \\sqrt{n_u},

gives :math:`P_{zz}`, :math:`P_{xz}` and the updated square root by the same QR. Exact when
:math:`H` is affine and :math:`f` quadratic in :math:`u` (tests/test_kalman_estimators.py), with
:math:`2 n_u` sigma points instead of :math:`2 L`.

Consistency: per channel the normalized innovation :math:`e_c^2 / (P_{zz})_{cc}` has mean 1
when the model's noise levels and linearization hold (:attr:`FilterRun.nis`); :func:`nis_bound` is
the largest mean a consistent filter exceeds with a given false-alarm rate (a diverged filter's is
hundreds).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import solve_triangular

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["FilterRun", "predict", "update", "unscented_arrays", "bilinear_second_order", "run", "root", "nis_bound",
           "KINDS"]

KINDS = ("ekf", "ukf")


def root(P: FloatArray) -> FloatArray:
    """A square root ``S`` with ``S^T S = P`` of a symmetric positive semi-definite matrix, by its
    eigendecomposition (negative rounding eigenvalues clipped to 0; no Cholesky factorization)."""
    P = np.asarray(P, dtype=float)
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    return np.sqrt(np.clip(w, 0.0, None))[:, None] * V.T


def _r(a: FloatArray) -> FloatArray:
    return np.linalg.qr(a, mode="r")


def predict(S: FloatArray, F: FloatArray, Qh: FloatArray) -> FloatArray:
    """The predicted square root: the R factor of ``[S F^T; Qh]`` (``Qh^T Qh = Q``)."""
    n = S.shape[1]
    return _r(np.vstack([S @ F.T, Qh]))[:n]


def update(x: FloatArray, S: FloatArray, SHt: FloatArray, Rh: FloatArray, e: FloatArray,
           extra: FloatArray | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One measurement update in array form (module docstring): state ``x`` (n,), square root
    ``S`` (n, n), ``SHt = S H^T`` (n, m), ``Rh`` (m, m) with ``Rh^T Rh = R``, innovation ``e`` (m,),
    ``extra`` (r, m): more rows of the innovation's square root (the UKF's second-order spread).
    Returns the updated state, square root and ``X`` (m, m) with ``X^T X = P_zz``."""
    n, m = S.shape[1], Rh.shape[0]
    top = Rh if extra is None else np.vstack([Rh, extra])
    pre = np.block([[top, np.zeros((top.shape[0], n))], [SHt, S]])
    post = _r(pre)
    X, Y, Z = post[:m, :m], post[:m, m:], post[m:m + n, m:]
    w = solve_triangular(X, e, trans="T")  # X^{-T} e: the whitened innovation
    return x + Y.T @ w, Z, X


def unscented_arrays(S: FloatArray, Zp: FloatArray, Zm: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The unscented transform's mean ``z_hat``, ``A / gamma`` (the pre-array's ``S H^T``) and
    ``B / gamma`` (its extra noise rows) from the images ``Zp``, ``Zm`` (L, m) of the sigma points
    ``x + gamma s_i`` and ``x - gamma s_i`` (alpha = 1, kappa = 0, beta = 0: module docstring)."""
    L = S.shape[0]
    gamma = np.sqrt(L)
    zhat = (Zp.sum(axis=0) + Zm.sum(axis=0)) / (2 * L)
    A = 0.5 * (Zp - Zm)
    B = 0.5 * (Zp + Zm) - zhat
    return zhat, A / gamma, B / gamma


def bilinear_second_order(U: FloatArray, B: FloatArray, G: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The Gaussian second-order terms of a measurement bilinear in two parts of the state,
    ``h_c = f_c(u) + W_c(u) beta``, from its mixed Hessian only: ``U`` (L, a) and ``B`` (L, p) the
    columns of the square root ``S`` that map to ``u`` and ``beta`` (``P = S^T S``), ``G`` (a, m, p)
    the derivatives ``dW/du_i``. Returns the mean shift ``1/2 tr(H_c P)`` (m,) and a square root
    (m, m) of ``1/2 tr(H_c P H_d P)`` (the added innovation covariance), with
    ``H_c = [[0, G_c], [G_c^T, 0]]``: ``s_i^T H_c s_j = T_c,ij = M_c,ij + M_c,ji``,
    ``M_c = U G_c B^T`` (Athans, Wishner & Bertolini 1968; Bar-Shalom, Li & Kirubarajan 2001,
    Sec. 10.3.2). The pure ``u`` and pure ``beta`` Hessians are left out: the second is 0, the first
    is the curvature of the rows over the kinematic state's spread (positions known to the encoder
    noise)."""
    M = np.einsum("la,amp,kp->mlk", U, G, B)  # (m, L, L)
    T = M + M.transpose(0, 2, 1)
    shift = np.einsum("mll->m", M)  # 1/2 tr(H_c P) = 1/2 sum_i T_c,ii = sum_i M_c,ii
    Tm = T.reshape(T.shape[0], -1)
    return shift, root(0.5 * (Tm @ Tm.T))


def _partially_linear_update(k: int, x: FloatArray, S: FloatArray, Rh: FloatArray, z: FloatArray,
                             measure: Callable[[int, FloatArray], Any], linear: int
                             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The UKF's measurement update for ``h(x) = f(u) + H(u) b`` with ``x = (u, b)``, ``b`` the last
    ``linear`` entries (module docstring, "partially linear"). ``measure(k, X)`` returns ``(h, H)``:
    ``h`` (c, m) at each row of ``X`` and ``H`` (c, m, linear) its coefficients of ``b`` there."""
    n = S.shape[1]
    nu = n - linear
    S = _r(S)  # upper triangular: rows nu: are b's conditional square root given u (zero in u's columns)
    Su, Sb = S[:nu], S[nu:]
    gamma = np.sqrt(nu)
    sig = gamma * Su
    Zb, Hb = measure(k, np.vstack([x + sig, x - sig]))
    hx, A, B = unscented_arrays(Su, Zb[:nu], Zb[nu:])
    Rbb = Sb[:, nu:]
    V = np.einsum("ij,cmj->cim", Rbb, Hb)  # (2 nu, linear, m): R_bb H(u_c)^T
    Vbar = V.mean(axis=0)
    D = (V - Vbar).reshape(-1, V.shape[2])
    m = Rh.shape[0]
    top = np.vstack([Rh, B, root(D.T @ D / V.shape[0])])  # m rows for the 2 nu linear blocks
    pre = np.block([[top, np.zeros((top.shape[0], n))], [np.vstack([A, Vbar]), S]])
    post = _r(pre)
    X, Y, Z = post[:m, :m], post[:m, m:], post[m:m + n, m:]
    w = solve_triangular(X, z - hx, trans="T")
    return x + Y.T @ w, Z, X, hx


def nis_bound(steps: int, channels: int, false_alarm: float = 1e-3) -> float:
    """The largest per-channel normalized innovation mean square (:attr:`FilterRun.nis` over
    ``steps`` steps) a consistent filter exceeds on any of ``channels`` channels with probability at
    most ``false_alarm``: the innovations of a filter whose model holds are white and Gaussian with
    the covariance it predicts, so ``steps * nis_c`` is chi-square with ``steps`` degrees of freedom
    (the NIS test of Bar-Shalom, Li & Kirubarajan 2001, *Estimation with Applications to Tracking
    and Navigation*, Sec. 5.4.2, per channel), at level ``false_alarm / channels`` per channel
    (Bonferroni). One-sided: a mean square below 1 is a cautious filter, not a diverged one."""
    from scipy.stats import chi2

    steps = max(int(steps), 1)
    return float(chi2.ppf(1.0 - false_alarm / max(int(channels), 1), steps) / steps)


@dataclasses.dataclass(frozen=True)
class FilterRun:
    """The filter's last state and square root, and its innovations: ``nis`` (m,) the mean over
    steps ``skip:`` of ``e_c^2 / (P_zz)_cc`` per measurement channel, ``innovations`` (N, m)."""

    kind: str
    x: FloatArray
    S: FloatArray
    innovations: FloatArray
    innovation_var: FloatArray  # (N, m): the diagonal of P_zz at each step
    nis: FloatArray
    steps: int

    @property
    def P(self) -> FloatArray:
        """The final covariance ``S^T S`` (formed on request only)."""
        return self.S.T @ self.S


Linearize = Callable[[int, FloatArray, FloatArray], tuple[FloatArray, FloatArray, "FloatArray | None"]]
"""``linearize(k, x, S) -> (h, H, extra)`` of the EKF (:func:`run`)."""


def run(kind: str, z: FloatArray, x0: FloatArray, S0: FloatArray, F: FloatArray, Qh: FloatArray, Rh: FloatArray, *,
        linearize: Linearize | None = None,
        measure: Callable[[int, FloatArray], Any] | None = None, skip: int = 0, linear: int = 0,
        progress: Callable[[int, int], None] | None = None) -> FilterRun:
    """Run the square-root EKF or UKF (module docstring) over measurements ``z`` (N, m) from the
    a-priori state ``x0`` (n,) with square root ``S0`` (``S0^T S0 = P0``): at each step a
    measurement update, then a prediction with ``F`` (n, n), ``Qh`` (r, n). ``linearize(k, x, S)``
    (EKF) returns ``(h, H, extra)``: the predicted measurement, the Jacobian ``H`` (m, n) and ``extra``
    (r, m) or None, more rows of the innovation's square root (:func:`bilinear_second_order`);
    ``measure(k, X)`` (UKF) returns ``h_k`` of each
    row of ``X`` (b, n) as (b, m); with ``linear = p`` > 0 (UKF) it returns ``(h, H)``, ``H`` (b, m, p) the
    coefficients of the last ``p`` state entries, in which ``h`` is linear (module docstring: partially
    linear measurements). ``skip``: steps left out of the NIS mean (the start)."""
    if kind not in KINDS:
        raise InputError(f"filter kind must be one of {KINDS}, got {kind!r}")
    if kind == "ekf" and linearize is None or kind == "ukf" and measure is None:
        raise InputError(f"the {kind.upper()} needs {'linearize' if kind == 'ekf' else 'measure'}")
    z = np.asarray(z, dtype=float)
    N, m = z.shape
    x, S = np.array(x0, dtype=float), np.array(S0, dtype=float)
    if kind == "ukf" and not 0 <= linear < x.size:
        raise InputError(f"linear must count 0 to {x.size - 1} trailing state entries (sigma points need a "
                         f"nonlinear part), got {linear}")
    E, V = np.empty((N, m)), np.empty((N, m))
    for k in range(N):
        if kind == "ekf":
            hx, H, extra = linearize(k, x, S)
            x, S, X = update(x, S, S @ H.T, Rh, z[k] - hx, extra)
            E[k], V[k] = z[k] - hx, np.sum(X * X, axis=0)
        elif linear:
            x, S, X, hx = _partially_linear_update(k, x, S, Rh, z[k], measure, linear)
            E[k], V[k] = z[k] - hx, np.sum(X * X, axis=0)
        else:
            L = S.shape[0]
            sig = np.sqrt(L) * S
            Zb = measure(k, np.vstack([x + sig, x - sig]))
            hx, SHt, extra = unscented_arrays(S, Zb[:L], Zb[L:])
            x, S, X = update(x, S, SHt, Rh, z[k] - hx, extra)
            E[k], V[k] = z[k] - hx, np.sum(X * X, axis=0)
        if k < N - 1:
            x, S = F @ x, predict(S, F, Qh)
        if progress is not None and (k % 200 == 0 or k == N - 1):
            progress(k + 1, N)
    skip = min(max(int(skip), 0), N - 1)
    nis = np.mean(E[skip:] ** 2 / V[skip:], axis=0)
    return FilterRun(kind=kind, x=x, S=S, innovations=E, innovation_var=V, nis=nis, steps=N)
