"""Base (identifiable) parameters: a linear map from the standard parameters.

The columns of the standard regressor are linearly dependent (some parameters never
affect the torques, others only in fixed combinations). On a stack of regressors at
random states, the base parameters are

.. math::

    \\beta = \\pi_{ind} + K\\,\\pi_{dep} = B\\,\\pi, \\qquad
    Y\\,\\pi = Y_{:,ind}\\,\\beta ,

with :math:`Y_{:,dep} = Y_{:,ind} K` (Gautier 1990; Khalil & Dombre, ch. 12;
paper 003 §2.2).

Algorithm (deterministic, and independent of the seed where the structure decides it):

1. stack the regressor at ``n_samples`` random states (seeded; :func:`default_samples`),
   compressed chunk by chunk into its R factor (:math:`R^TR = W^TW`: the same column norms,
   QR diagonals and least-squares residuals, in p x p memory); scale columns to unit norm and
   drop columns that are identically zero;
2. QR **with column pivoting** gives the numerical rank ``r``: the levels ``|R_ii|`` above a
   relative tolerance, moved into the widest gap where levels crowd it (:func:`rank_cut`);
3. the independent columns are chosen in the natural parameter order: a column is
   independent when it is not in the span of the columns chosen before it, by more than a
   floor tied to the weakest identifiable direction (:func:`_independent_in_natural_order`).
   Distal parameters are thus regrouped into proximal ones (``Izz1 + Ia1 + Iyy2 + ...``), as
   in the classical grouping rules;
4. :math:`K` by least squares, entries below ``1e-10`` set to zero;
5. (:func:`compute_base_parameters`) the regrouping is checked on fresh random states; where
   it fails there, or steps 2-3 are undecided, the sample is doubled and the base recomputed
   (up to 16x) before an error.

Grouping expressions are for display only; never parse them back.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np
import scipy.linalg as sla

from dynid._typing import FloatArray, IntArray
from dynid.errors import ModelError

__all__ = [
    "BaseParameters",
    "StandardMap",
    "body_violation",
    "compute_base_parameters",
    "consistent_parameters",
    "inertia_violation",
    "format_expression",
    "parameters_from_pseudo_inertia",
    "perturb_bodies",
    "pseudo_inertia",
    "random_states",
    "robot_base_parameters",
]

RegressorFn = Callable[[FloatArray, FloatArray, FloatArray], FloatArray]


def format_expression(name: str, coeffs: FloatArray, dep_names: Sequence[str], digits: int = 4) -> str:
    """``name + 0.35*m3 - Iyy2`` style text for one base parameter (display only)."""
    parts = [name]
    for c, dn in zip(coeffs, dep_names):
        if c == 0.0:
            continue
        mag = abs(c)
        sign = "-" if c < 0 else "+"
        coef = "" if abs(mag - 1.0) < 10 ** (-digits) else f"{mag:.{digits}g}*"
        parts.append(f"{sign} {coef}{dn}")
    return " ".join(parts)


@dataclasses.dataclass(frozen=True, eq=False)
class BaseParameters:
    """The linear map between standard and base parameters.

    Attributes
    ----------
    standard_names : tuple of str
        Names of the standard parameters (length ``p``).
    independent : int array, shape (r,)
        Standard-parameter indices whose columns form the base regressor (sorted).
    dependent : int array, shape (p - r,)
        The other indices (zero columns included).
    K : array, shape (r, p - r)
        :math:`\\beta = \\pi_{ind} + K \\pi_{dep}`.
    rank_tol : float
        Relative tolerance used for the rank.
    n_samples, seed : int
        Random states used (for provenance).
    """

    standard_names: tuple[str, ...]
    independent: IntArray
    dependent: IntArray
    K: FloatArray
    rank_tol: float
    n_samples: int
    seed: int

    def __post_init__(self) -> None:
        for f in ("independent", "dependent", "K"):
            a = np.array(getattr(self, f))
            a.setflags(write=False)
            object.__setattr__(self, f, a)

    # ------------------------------------------------------------------ sizes / names
    @property
    def n_base(self) -> int:
        return int(self.independent.shape[0])

    @property
    def n_standard(self) -> int:
        return len(self.standard_names)

    @property
    def names(self) -> tuple[str, ...]:
        """Base parameter names: the name of each independent standard parameter."""
        return tuple(self.standard_names[i] for i in self.independent)

    @property
    def B(self) -> FloatArray:
        """Regrouping matrix, shape (r, p): ``beta = B @ pi``."""
        b = np.zeros((self.n_base, self.n_standard))
        b[np.arange(self.n_base), self.independent] = 1.0
        b[:, self.dependent] = self.K
        return b

    def expressions(self, digits: int = 4) -> tuple[str, ...]:
        """Grouping expressions such as ``Izz1 + Ia1 + Iyy2 + 0.1866*m3`` (display only)."""
        dep_names = [self.standard_names[i] for i in self.dependent]
        return tuple(
            format_expression(n, self.K[r], dep_names, digits) for r, n in enumerate(self.names)
        )

    # ------------------------------------------------------------------ maps
    def from_standard(self, pi: FloatArray) -> FloatArray:
        """Base parameters of a standard vector (or of each row of a 2-D array)."""
        pi = np.asarray(pi, dtype=float)
        if pi.shape[-1] != self.n_standard:
            raise ModelError(f"expected {self.n_standard} standard parameters, got {pi.shape[-1]}")
        return pi[..., self.independent] + pi[..., self.dependent] @ self.K.T

    def to_standard(self, beta: FloatArray, reference: FloatArray | None = None,
                    scale: FloatArray | None = None) -> FloatArray:
        """The standard vector closest to ``reference`` (default 0) that maps to ``beta``.

        Solves :math:`\\min \\|S^{-1}(\\pi - \\pi_{ref})\\|` subject to :math:`B\\pi = \\beta`
        (``scale``: the diagonal of :math:`S`, default ones), the minimum-norm solution of an
        underdetermined linear system: with :math:`x = S^{-1}(\\pi - \\pi_{ref})`,
        :math:`\\pi = \\pi_{ref} + S (BS)^+(\\beta - B\\pi_{ref})`. ``B`` has full row rank, so
        the result maps to ``beta`` exactly (to rounding).
        """
        beta = np.asarray(beta, dtype=float)
        if beta.shape != (self.n_base,):
            raise ModelError(f"expected {self.n_base} base parameters, got shape {beta.shape}")
        ref = np.zeros(self.n_standard) if reference is None else np.asarray(reference, dtype=float)
        s = np.ones(self.n_standard) if scale is None else np.asarray(scale, dtype=float)
        if s.shape != (self.n_standard,) or not np.all(np.isfinite(s) & (s > 0)):
            raise ModelError(f"expected {self.n_standard} positive finite scales")
        b = self.B
        return ref + s * np.linalg.lstsq(b * s, beta - b @ ref, rcond=None)[0]

    def regressor(self, Y: FloatArray) -> FloatArray:
        """Base regressor: the independent columns of a standard regressor."""
        Y = np.asarray(Y)
        if Y.shape[-1] != self.n_standard:
            raise ModelError(f"regressor has {Y.shape[-1]} columns, expected {self.n_standard}")
        return Y[..., self.independent]


def parameter_scales(names: Sequence[str], body_blocks: Sequence[IntArray], nominal: FloatArray) -> FloatArray:
    """A magnitude per standard parameter for :meth:`BaseParameters.to_standard`'s weighting, so
    that kilograms, kilogram-metres and kilogram-square-metres are not compared as numbers: the
    RMS of the nonzero nominal values of its kind (bodies: mass, first moment, inertia; a joint
    term: the letters of its name, e.g. ``fv``, ``fc+``, ``Ia``), 1 where a kind has none."""
    import re

    nominal = np.asarray(nominal, dtype=float)
    kind = [re.match(r"[A-Za-z]*[+-]?", n).group() or n for n in names]
    for blk in body_blocks:
        for k, i in enumerate(blk):
            kind[int(i)] = "body mass" if k == 0 else "body first moment" if k < 4 else "body inertia"
    out = np.ones(len(names))
    for key in set(kind):
        idx = [i for i, k in enumerate(kind) if k == key]
        v = nominal[idx][nominal[idx] != 0]
        if v.size:
            out[idx] = float(np.sqrt(np.mean(v**2)))
    return out


def random_states(
    lower: FloatArray, upper: FloatArray, n_samples: int, rng: np.random.Generator, vel_scale: float = 2.0, acc_scale: float = 5.0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Uniform positions within limits, Gaussian velocities and accelerations."""
    nv = lower.shape[0]
    q = rng.uniform(lower, upper, size=(n_samples, nv))
    dq = vel_scale * rng.standard_normal((n_samples, nv))
    ddq = acc_scale * rng.standard_normal((n_samples, nv))
    return q, dq, ddq


def rank_cut(levels: FloatArray, rank_tol: float, band: float = 100.0) -> float:
    """The relative level below which a direction of the regressor counts as not identifiable.

    ``levels``: the pivoted QR diagonal of the unit-norm regressor columns divided by its first
    entry (decreasing). Where no level lies within a factor ``band`` of ``rank_tol`` the rank is
    clear and the cut is ``rank_tol`` itself. Where some do, the rank at ``rank_tol`` would be
    decided by levels that the samples, the loop-closure solve or a BLAS kernel's rounding can
    move across it (the Gepetto delta robot: 2.6e-3, then 2.0e-7, 1.0e-7, 1.3e-8, 8.5e-10, ...;
    natural and pivoted orders disagreed about the 1.3e-8); then the cut is put in the widest gap
    between consecutive levels of which at least one lies in that band (its geometric mean), so
    that the directions below it are separated from the rest by that gap."""
    lv = np.asarray(levels, dtype=float)
    lo, hi = rank_tol / band, rank_tol * band
    if not np.any((lv >= lo) & (lv <= hi)):
        return float(rank_tol)
    a, b = lv[:-1], np.maximum(lv[1:], np.finfo(float).tiny)
    touch = ((a >= lo) & (a <= hi)) | ((b >= lo) & (b <= hi))
    k = int(np.argmax(np.where(touch, a / b, 0.0)))
    return float(np.sqrt(a[k] * b[k]))


NATURAL_FLOOR = 1e-3
"""A column joins the base in natural order only when its residual against the columns already
chosen is at least this fraction of the weakest identifiable direction (the last retained level
of the pivoted QR); see :func:`_independent_in_natural_order`."""

MAX_DOUBLINGS = 4
"""How many times :func:`compute_base_parameters` doubles its sample before giving up (16x)."""


class _Undecided(ModelError):
    """The sample does not decide the base parameters (retried with more samples)."""


def _r_factor(W: FloatArray, R: FloatArray | None = None) -> FloatArray:
    """The R factor (min(rows, p) x p) of ``W`` stacked under ``R``: :math:`R^TR = W^TW`, so every
    column norm, least-squares residual and (pivoted) QR diagonal of ``W`` is that of ``R``."""
    A = W if R is None else np.vstack([R, W])
    k = min(A.shape)
    return sla.qr(A, mode="r", check_finite=False)[0][:k]


def _orthogonal_residual(Q: FloatArray, V: FloatArray) -> FloatArray:
    """``V`` minus its projection on the orthonormal columns ``Q`` (classical Gram-Schmidt done
    twice, which is orthogonal to working precision)."""
    for _ in range(2):
        V = V - Q @ (Q.T @ V)
    return V


def _independent_in_natural_order(Rs: FloatArray, rank: int, cut: float, floor: float) -> IntArray:
    """``rank`` independent columns of the unit-norm columns ``Rs``, chosen in the natural order.

    A column joins when its residual against the columns already chosen exceeds
    ``max(cut, floor)``; if fewer than ``rank`` join, the rest come from the others by column
    pivoting (largest residual first), each above ``cut``.

    Why the floor: the plain rule (residual above ``cut``) takes a column that is independent of
    those before it only barely (romeo.urdf: 24 columns at 2e-8 to 7e-8, while the weakest
    pivoted level is 2.3e-2); the basis is then conditioned like 1e8, the residuals of later
    dependent columns are rounding errors amplified to the same 1e-8 (the plain rule counted 582
    columns for a rank of 575), and which of them pass ``cut`` is luck. With the floor those
    columns wait, and the base keeps the conditioning the pivoted QR found, up to
    1/:data:`NATURAL_FLOOR`. Where no residual lies between ``cut`` and the floor (all 66
    robots of example-robot-data but romeo.urdf, and every built-in), the choice is the plain
    rule's.
    """
    m, n = Rs.shape
    tau = max(cut, floor)
    Q = np.zeros((m, rank))
    chosen: list[int] = []
    for j in range(n):
        v = _orthogonal_residual(Q[:, : len(chosen)], Rs[:, j])
        r = float(np.linalg.norm(v))
        if r > tau:
            if len(chosen) == rank:
                raise _Undecided(f"more than {rank} columns are independent in natural order")
            Q[:, len(chosen)] = v / r
            chosen.append(j)
    if len(chosen) < rank:
        rest = np.setdiff1d(np.arange(n), chosen)
        V = _orthogonal_residual(Q[:, : len(chosen)], Rs[:, rest])
        r_piv, piv = sla.qr(V, mode="r", pivoting=True)
        need = rank - len(chosen)
        if r_piv.shape[0] < need or np.abs(r_piv[need - 1, need - 1]) <= cut:
            raise _Undecided(f"only {len(chosen)} of {rank} independent columns found")
        chosen.extend(int(rest[i]) for i in piv[:need])
    return np.sort(np.array(chosen, dtype=int))


def _base_from_r(R: FloatArray, names: Sequence[str], rank_tol: float, n_samples: int, seed: int) -> BaseParameters:
    p = R.shape[1]
    norms = np.linalg.norm(R, axis=0)
    scale = norms.max()
    if scale == 0:
        raise ModelError("the regressor is identically zero: no parameter affects the torques")
    nonzero = np.flatnonzero(norms > 1e-12 * scale)
    Rs = R[:, nonzero] / norms[nonzero]
    # (2) numerical rank from QR with column pivoting
    r_piv = sla.qr(Rs, mode="r", pivoting=True)[0]
    d_piv = np.abs(np.diag(r_piv))
    cut = rank_cut(d_piv / d_piv[0], rank_tol) * d_piv[0]
    rank = int(np.count_nonzero(d_piv > cut))
    # (3) natural-order choice of the independent columns
    indep_local = _independent_in_natural_order(Rs, rank, cut, NATURAL_FLOOR * d_piv[rank - 1])
    independent = np.sort(nonzero[indep_local])
    dependent = np.setdiff1d(np.arange(p), independent)
    Ri, Rd = R[:, independent], R[:, dependent]
    # K on unit-norm columns (K_s = D_i K D_d^-1), so that the threshold for numerical
    # zeros does not depend on the units of the parameters
    ni = np.where(norms[independent] > 0, norms[independent], 1.0)
    nd = np.where(norms[dependent] > 0, norms[dependent], 1.0)
    K_s = np.linalg.lstsq(Ri / ni, Rd / nd, rcond=None)[0]
    K = K_s / ni[:, None] * nd[None, :]
    K[(np.abs(K_s) < 1e-8) | (np.abs(K) < 1e-10)] = 0.0
    resid = np.linalg.norm(Rd - Ri @ K) / max(np.linalg.norm(Rd), 1.0)
    if resid > 1e-6:
        raise ModelError(f"base-parameter regrouping does not reproduce the regressor (relative residual {resid:.2e})")
    return BaseParameters(
        standard_names=tuple(names),
        independent=independent,
        dependent=dependent,
        K=K,
        rank_tol=rank_tol,
        n_samples=n_samples,
        seed=seed,
    )


def _base_from_stack(
    W: FloatArray, names: Sequence[str], rank_tol: float, n_samples: int, seed: int
) -> BaseParameters:
    """Base parameters of a stacked regressor ``W`` (rows x p), steps 1-4 of the module docstring."""
    try:
        return _base_from_r(_r_factor(W), names, rank_tol, n_samples, seed)
    except _Undecided as exc:
        raise ModelError(f"ambiguous base parameters ({exc}); increase the number of random samples") from None


def _holds_on(base: BaseParameters, W: FloatArray, tol: float = 1e-6) -> bool:
    """Whether the regrouping found on one sample holds on another stack ``W``: every dependent
    column equals its combination of the independent ones, to ``tol`` of its own norm (the
    regrouping check's bound) plus the level below which :func:`_base_from_r` counts a column as
    zero (1e-12 of the largest). A direction the first sample did not excite shows here as a
    column that is not its combination."""
    norms = np.linalg.norm(W, axis=0)
    Wd, fit = W[:, base.dependent], W[:, base.independent] @ base.K
    err = np.linalg.norm(Wd - fit, axis=0)
    ref = np.maximum(norms[base.dependent], np.linalg.norm(fit, axis=0))
    return bool(np.all(err <= tol * ref + 1e-12 * norms.max()))


def default_samples(n_params: int, n_q: int) -> int:
    """Random states for base parameters: at least 200 (every joint's range covered many times),
    and at least :math:`8p/n_q`, so that the stack has 8 equations per parameter (a robot gives one
    equation per joint and state). Romeo (770 parameters, 55 joints) gets 200."""
    return max(200, -(-8 * int(n_params) // max(int(n_q), 1)))


def compute_base_parameters(
    regressor_fn: RegressorFn,
    names: Sequence[str],
    lower: FloatArray,
    upper: FloatArray,
    *,
    n_samples: int | None = None,
    seed: int = 0,
    rank_tol: float = 1e-8,
) -> BaseParameters:
    """Base parameters of a regressor evaluated at random states.

    Deterministic, and the same for any seed where the structure decides it: the rank comes
    from a gap of the pivoted QR levels (:func:`rank_cut`), the independent columns from the
    natural order with a conditioning floor (:func:`_independent_in_natural_order`), and the
    regrouping is then checked on fresh random states (a quarter of the sample, at least 50):
    where it does not hold there, or the sample leaves the choice undecided, the sample is
    doubled (fresh states added) and the base recomputed, up to :data:`MAX_DOUBLINGS` times,
    before a :class:`ModelError`.

    Parameters
    ----------
    regressor_fn : callable
        ``regressor_fn(q, dq, ddq) -> (n, n_out, p)``.
    names : sequence of str
        Standard parameter names (length ``p``).
    lower, upper : array, shape (n_q,)
        Position range to sample.
    n_samples : int, optional
        Number of random states; default :func:`default_samples`.
    seed : int
        Seed of the random generator (the result is deterministic).
    rank_tol : float
        Relative tolerance on the pivoted QR diagonal.
    """
    p = len(names)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    n = int(n_samples) if n_samples is not None else default_samples(p, lower.shape[0])
    rng = np.random.default_rng(seed)

    def stack(n_new: int, R: FloatArray | None) -> FloatArray:
        q, dq, ddq = random_states(lower, upper, n_new, rng)
        per = max(1, -(-4 * p // max(lower.shape[0], 1)), 8192 // max(lower.shape[0], 1))  # ~4p rows a chunk
        for a in range(0, n_new, per):
            Y = regressor_fn(q[a : a + per], dq[a : a + per], ddq[a : a + per])
            if Y.shape[-1] != p:
                raise ModelError(f"regressor has {Y.shape[-1]} columns but {p} names were given")
            R = _r_factor(Y.reshape(-1, p), R)
        return R

    R, total = stack(n, None), n
    why = ""
    for attempt in range(MAX_DOUBLINGS + 1):
        try:
            base = _base_from_r(R, names, rank_tol, total, seed)
        except _Undecided as exc:
            why = str(exc)
        else:
            n_check = max(50, total // 4)
            q, dq, ddq = random_states(lower, upper, n_check, rng)
            if _holds_on(base, regressor_fn(q, dq, ddq).reshape(-1, p)):
                return base
            why = "the regrouping found does not hold on fresh random states"
        if attempt < MAX_DOUBLINGS:
            R, total = stack(total, R), 2 * total
    raise ModelError(f"base parameters undecided after {total} random states (seed {seed}): {why}")


def robot_base_parameters(robot, *, n_samples: int | None = None, seed: int = 0, rank_tol: float = 1e-8) -> BaseParameters:
    """Base parameters of a :class:`~dynid.model.robot.RobotModel` (random states within its limits)."""
    from dynid.model.serial_dynamics import regressor

    data = robot.create_data()
    lo, hi = robot.position_limits()
    return compute_base_parameters(
        lambda q, dq, ddq: regressor(robot, q, dq, ddq, data=data),
        robot.parameter_names,
        lo,
        hi,
        n_samples=n_samples,
        seed=seed,
        rank_tol=rank_tol,
    )


@dataclasses.dataclass(frozen=True, eq=False)
class StandardMap:
    """How base parameters relate to physical standard parameters (for constrained estimators).

    Attributes
    ----------
    standard_names : tuple of str
    B : array, shape (r, p)
        ``beta = B @ pi``.
    body_blocks : tuple of int arrays (10,)
        Indices of each body's ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``.
    nonnegative : int array
        Indices of parameters that are non-negative physically (rotor inertias,
        viscous and Coulomb friction coefficients, motor-side terms).
    reference : array, shape (p,), optional
        Nominal (CAD) standard parameters, physically consistent (:meth:`of` projects the robot
        description's onto the consistent set, :func:`consistent_parameters`): the prior of
        physically consistent estimation.
    nonpositive : int array
        Indices of parameters that are non-positive physically: the Coulomb coefficient of
        the negative direction of an asymmetric friction model (Shang 2009, Eq. 2, where
        the force for :math:`\\dot q < 0` is :math:`f_c^- + f_v^-\\dot q` with :math:`f_c^- \\le 0`).
    zero : int array
        Indices of parameters fixed at zero by a structural simplification (the symmetric
        bodies of :mod:`dynid.model.reduction`, structure ``"paper"``): physically consistent
        fits keep them at zero.
    """

    standard_names: tuple[str, ...]
    B: FloatArray
    body_blocks: tuple[IntArray, ...]
    nonnegative: IntArray
    reference: FloatArray | None = None
    nonpositive: IntArray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=int))
    zero: IntArray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def body_names(self) -> tuple[str, ...]:
        """Name of each body: the suffix of its mass parameter (``m3`` -> ``"3"``, ``m_qa1`` -> ``"qa1"``)."""
        return tuple(self.standard_names[blk[0]][1:].lstrip("_") for blk in self.body_blocks)

    @classmethod
    def of(cls, robot, base: BaseParameters) -> StandardMap:
        """The map of a :class:`~dynid.model.robot.RobotModel` and its base parameters."""
        lay = robot.layout
        nonneg = [idx for e, idx in lay.extra_index.items() if e not in ("offset", "fc-")] + list(lay.motor_index.values())
        nonpos = lay.extra_index.get("fc-", np.zeros(0, dtype=int))
        return cls(
            standard_names=lay.names,
            B=base.B,
            body_blocks=robot.body_blocks(),
            nonnegative=np.sort(np.concatenate(nonneg)).astype(int) if nonneg else np.zeros(0, dtype=int),
            reference=consistent_parameters(robot.nominal_parameters(), robot.body_blocks()),
            nonpositive=np.asarray(nonpos, dtype=int),
        )


def pseudo_inertia(block: FloatArray) -> FloatArray:
    """4x4 pseudo-inertia matrix of ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``.

    :math:`J = \\begin{bmatrix} \\tfrac12 \\mathrm{tr}(I)\\mathbf 1 - I & h \\\\ h^T & m \\end{bmatrix}`
    with :math:`I` the inertia about the frame origin and :math:`h = m c`; the
    parameters are physically consistent iff :math:`J \\succeq 0` (Wensing, Kim &
    Slotine 2017), which implies positive mass and the triangle inequalities.
    """
    m, mx, my, mz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(block, dtype=float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    out = np.zeros((4, 4))
    out[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    out[:3, 3] = out[3, :3] = (mx, my, mz)
    out[3, 3] = m
    return out


def inertia_violation(m: float, I_c: FloatArray, rtol: float = 1e-12) -> str:
    """Why a body of mass ``m`` [kg] and inertia ``I_c`` about its centre of mass (3x3 [kg m^2])
    is not physically consistent: negative mass, a negative principal inertia, or principal
    inertias that violate the triangle inequality (each beyond ``rtol`` times the largest principal
    inertia, the rounding of the parallel-axis shift); '' when it is. For a positive mass these
    are :math:`J \\succeq 0` of the pseudo-inertia (Wensing, Kim & Slotine 2017)."""
    why = []
    if m < 0.0:
        why.append(f"negative mass {m:.6g} kg")
    lam = np.linalg.eigvalsh(np.asarray(I_c, dtype=float))
    tol = rtol * max(1.0, float(np.abs(lam).max()))
    if lam[0] < -tol:
        why.append(f"inertia about the CoM has a negative eigenvalue {lam[0]:.6g} kg m^2")
    elif lam[0] + lam[1] < lam[2] - tol:
        why.append("principal inertias violate the triangle inequality")
    return "; ".join(why)


def body_violation(block: FloatArray) -> str:
    """:func:`inertia_violation` of one body's ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``
    about its joint-frame origin (inertia moved to the centre of mass, :math:`I_c = I_o -
    m(c^Tc\\,\\mathbb 1 - cc^T)`, :math:`c = h/m`); a zero mass with nonzero first moments has
    no centre of mass; '' when consistent."""
    b = np.asarray(block, dtype=float)
    m, h = float(b[0]), b[1:4]
    ixx, ixy, iyy, ixz, iyz, izz = b[4:10]
    I_o = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if m == 0.0:
        return "zero mass with nonzero first moments" if np.any(h != 0.0) else inertia_violation(0.0, I_o)
    c = h / m
    return inertia_violation(m, I_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c)))


def parameters_from_pseudo_inertia(J: FloatArray) -> FloatArray:
    """``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` of pseudo-inertia matrices (..., 4, 4):
    the inverse of :func:`pseudo_inertia` (:math:`I = \\mathrm{tr}(\\Sigma)\\mathbf 1 - \\Sigma`)."""
    J = np.asarray(J, dtype=float)
    S = J[..., :3, :3]
    return np.stack([J[..., 3, 3], J[..., 0, 3], J[..., 1, 3], J[..., 2, 3], S[..., 1, 1] + S[..., 2, 2], -S[..., 0, 1],
                     S[..., 0, 0] + S[..., 2, 2], -S[..., 0, 2], -S[..., 1, 2], S[..., 0, 0] + S[..., 1, 1]], axis=-1)


def consistent_parameters(params: FloatArray, body_blocks: Sequence[IntArray]) -> FloatArray:
    """The nearest physically consistent standard parameters: each body projected onto the set
    of pseudo-inertias :math:`J \\succeq 0` (Wensing, Kim & Slotine, RA-L 2017), other entries kept.

    Rule, per body: a body with a positive mass keeps its mass :math:`m` and centre of mass
    :math:`c`; the covariance of its mass distribution about the centre of mass,
    :math:`\\Sigma_c = J_{3\\times3} - m c c^T` (:math:`= \\tfrac12\\mathrm{tr}(I_c)\\mathbf 1 - I_c`), has its
    negative eigenvalues set to zero, :math:`\\Sigma_c \\leftarrow V\\max(\\Lambda, 0)V^T`: the nearest
    positive semi-definite :math:`\\Sigma_c` in the Frobenius norm, hence the nearest consistent
    pseudo-inertia of the same mass and centre of mass (:math:`J \\succeq 0 \\iff \\Sigma_c \\succeq 0`
    when :math:`m > 0`, by the Schur complement). It changes :math:`\\Sigma_c` by exactly its
    negative part, so a rounding-level defect changes only at rounding level. A body of zero or
    negative mass gets the nearest positive semi-definite :math:`J` (its eigenvalues clipped at 0).
    Consistent bodies are returned unchanged (bit for bit).

    Parameters
    ----------
    params : array, shape (p,)
        Standard parameters.
    body_blocks : sequence of int arrays (10,)
        Indices of each body's ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``.
    """
    pi = np.array(params, dtype=float)
    for blk in body_blocks:
        blk = np.asarray(blk, dtype=int)
        J = pseudo_inertia(pi[blk])
        m = J[3, 3]
        if m > 0:
            c = J[:3, 3] / m
            lam, V = np.linalg.eigh(J[:3, :3] - m * np.outer(c, c))
            if lam[0] >= 0:
                continue
            J[:3, :3] = (V * np.maximum(lam, 0.0)) @ V.T + m * np.outer(c, c)
        else:
            lam, V = np.linalg.eigh(J)
            if lam[0] >= 0:
                continue
            J = (V * np.maximum(lam, 0.0)) @ V.T
        pi[blk] = parameters_from_pseudo_inertia(0.5 * (J + J.T))  # m and m*c as they were (m > 0)
    return pi


def perturb_bodies(params: FloatArray, body_blocks: Sequence[IntArray], relative: float,
                   rng: np.random.Generator) -> FloatArray:
    """Standard parameters a relative amount away from ``params`` that stay physically consistent.

    Each body with a positive mass: the mass times :math:`1 + r\\varepsilon`; the second moments
    of the mass distribution about the centre of mass (:math:`\\Sigma_c`, the pseudo-inertia's
    covariance block) keep their principal axes, each principal value times
    :math:`1 + r\\varepsilon` (floored at 0, then scaled with the mass); the centre of mass
    moves by :math:`r k \\varepsilon` per axis, :math:`k = \\sqrt{\\mathrm{tr}\\,\\Sigma_c / m}` the
    radius of gyration. Every :math:`\\varepsilon \\sim N(0, 1)`, factors floored at 0.1. The
    resulting pseudo-inertia is positive semidefinite by construction (Wensing, Kim & Slotine
    2017). Other parameters (massless bodies, joint terms) are multiplied by
    :math:`1 + r\\varepsilon` as they are.
    """
    pi = np.array(params, dtype=float)
    out = pi * (1.0 + relative * rng.standard_normal(pi.shape))
    for blk in body_blocks:
        blk = np.asarray(blk, dtype=int)
        J = pseudo_inertia(pi[blk])
        m = J[3, 3]
        if m <= 0:
            out[blk] = pi[blk] * (1.0 + relative * rng.standard_normal(10))
            continue
        c = J[:3, 3] / m
        lam, V = np.linalg.eigh(J[:3, :3] - m * np.outer(c, c))
        lam = np.maximum(lam, 0.0)
        eps = rng.standard_normal(7)
        m2 = m * max(1.0 + relative * eps[0], 0.1)
        lam2 = lam * np.maximum(1.0 + relative * eps[1:4], 0.1) * (m2 / m)
        c2 = c + relative * np.sqrt(lam.sum() / m) * eps[4:7]
        J2 = np.zeros((4, 4))
        J2[:3, :3] = (V * lam2) @ V.T + m2 * np.outer(c2, c2)
        J2[:3, 3] = J2[3, :3] = m2 * c2
        J2[3, 3] = m2
        out[blk] = parameters_from_pseudo_inertia(J2)
    return out
