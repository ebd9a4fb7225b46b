"""The rows of a nonlinear friction fit (:class:`SampleProblem`) and the 5-parameter Stribeck
basis (paper 000 Eq. 32): what :class:`~dynid.estimation.nonlinear.StribeckLS` fits and how its
result predicts. See :mod:`dynid.estimation.nonlinear` for the model and the estimator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
import scipy.linalg as sla

from dynid._typing import BoolArray, FloatArray
from dynid.errors import InputError
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult
from dynid.model.base_parameters import StandardMap

__all__ = ["SampleProblem", "stribeck_basis", "stribeck_predict"]


# ---------------------------------------------------------------------- the Stribeck basis
def _basis(v: FloatArray, vs: FloatArray, delta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:math:`g`, :math:`\\partial g/\\partial \\log v_S`, :math:`\\partial g/\\partial\\delta`, each (n, n_f)."""
    u = np.abs(v) / vs
    pw = u**delta
    g = np.exp(-pw) * np.sign(v)
    return g, g * delta * pw, -g * pw * np.log(np.where(u > 0, u, 1.0))


def stribeck_basis(velocity: FloatArray, vs: FloatArray, delta: FloatArray) -> FloatArray:
    """Stribeck regressor :math:`g(v) = e^{-|v/v_S|^{\\delta}}\\mathrm{sign}(v)` [-], shape (n, n_f), of
    velocities (n, n_f) [rad/s or m/s], Stribeck velocities ``vs`` (n_f,) (> 0, same units) and
    exponents ``delta`` (n_f,): joint :math:`k`'s friction is :math:`F_C\\mathrm{sign}(v) + F_v v + \\Delta F_k g_k`."""
    return _basis(np.atleast_2d(np.asarray(velocity, dtype=float)), np.asarray(vs, float), np.asarray(delta, float))[0]


def _identity_projection(n: int, n_f: int) -> FloatArray:
    p = np.zeros((n, n_f, n_f))
    p[:, np.arange(n_f), np.arange(n_f)] = 1.0
    return p


def _finite(name: str, a: FloatArray) -> None:
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} contains NaN/inf")


# ---------------------------------------------------------------------- the problem
@dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
class SampleProblem:
    """The uncompressed rows a nonlinear friction fit needs (the linear part plus velocities).

    Attributes
    ----------
    names : tuple of str
        Base parameter names (columns of ``W``), with the Coulomb and viscous coefficient of
        every Stribeck joint.
    channel_names : tuple of str
        Output channels, length ``n_ch``.
    W : array, shape (n, n_ch, p)
        Base regressor.
    y : array, shape (n, n_ch)
        Measured outputs [N·m or N].
    velocity : array, shape (n, n_f)
        Velocities of the joints with Stribeck friction [rad/s or m/s].
    friction_names : tuple of str
        Names of those joints (length ``n_f``).
    coulomb, viscous : tuple of int
        Index into ``names`` of each friction joint's :math:`F_C` and :math:`F_v` (their columns
        must be :math:`P\\,\\mathrm{sign}(v)` and :math:`P v`).
    standard : StandardMap
        Map to the physical standard parameters (``beta = B @ pi``).
    mask : bool array, shape (n, n_ch), optional
        Rows to use per channel (False: the equation of that channel at that sample is left
        out, e.g. a joint below ``processing.min_velocity``, where it sticks); ``None``: all.
    projection : array, shape (n, n_ch, n_f), optional
        :math:`P`, how joint friction enters each channel; ``None``: identity (channel ``j`` is
        joint ``j``, ``n_f == n_ch``).
    meta : mapping
        Provenance.
    """

    names: tuple[str, ...]
    channel_names: tuple[str, ...]
    W: FloatArray
    y: FloatArray
    velocity: FloatArray
    friction_names: tuple[str, ...]
    coulomb: tuple[int, ...]
    viscous: tuple[int, ...]
    standard: StandardMap
    projection: FloatArray | None = None
    mask: BoolArray | None = None
    meta: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        W, y, v = (np.array(getattr(self, k), dtype=float) for k in ("W", "y", "velocity"))
        names, chans, fnames = tuple(self.names), tuple(self.channel_names), tuple(self.friction_names)
        if W.ndim != 3 or W.shape[1:] != (len(chans), len(names)):
            raise InputError(f"W has shape {W.shape}, expected (n, {len(chans)}, {len(names)}) (channels, names)")
        n = W.shape[0]
        if y.shape != (n, len(chans)):
            raise InputError(f"y has shape {y.shape}, expected {(n, len(chans))}")
        if v.ndim != 2 or v.shape[0] != n or v.shape[1] == 0:
            raise InputError(f"velocity has shape {v.shape}, expected ({n}, n_f) with n_f >= 1")
        n_f = v.shape[1]
        if len(fnames) != n_f or len(set(fnames)) != n_f:
            raise InputError(f"friction_names must be {n_f} distinct names, got {list(fnames)}")
        for what in ("coulomb", "viscous"):
            idx = tuple(int(i) for i in getattr(self, what))
            if len(idx) != n_f or any(not 0 <= i < len(names) for i in idx):
                raise InputError(f"{what} must hold {n_f} indices into the {len(names)} names, got {list(idx)}")
            object.__setattr__(self, what, idx)
        if len(set(self.coulomb + self.viscous)) != 2 * n_f:
            raise InputError("the coulomb and viscous columns must be distinct")
        proj = None if self.projection is None else np.array(self.projection, dtype=float)
        mask = None
        if self.mask is not None:
            mask = np.array(self.mask, dtype=bool)
            if mask.shape != (n, len(chans)):
                raise InputError(f"mask has shape {mask.shape}, expected {(n, len(chans))}")
            empty = [c for c, k in zip(chans, mask.sum(axis=0)) if k == 0]
            if empty:
                raise InputError(f"the row mask leaves no sample on channels {empty}")
        arrays = {"W": W, "y": y, "velocity": v, "projection": proj}
        for name, a in arrays.items():
            if a is not None:
                _finite(name, a)
        if proj is None and n_f != len(chans):
            raise InputError(f"{n_f} friction joints and {len(chans)} channels: give the projection (n, n_ch, n_f)")
        if proj is not None and proj.shape != (n, len(chans), n_f):
            raise InputError(f"projection has shape {proj.shape}, expected {(n, len(chans), n_f)}")
        if not isinstance(self.standard, StandardMap) or self.standard.B.shape[0] != len(names):
            raise InputError(f"standard must be a StandardMap with {len(names)} base parameters")
        P = _identity_projection(n, n_f) if proj is None else proj
        for k, fn in enumerate(fnames):
            for what, col, x in (("Coulomb", self.coulomb[k], np.sign(v[:, k])), ("viscous", self.viscous[k], v[:, k])):
                want = P[:, :, k] * x[:, None]
                if not np.allclose(W[:, :, col], want, rtol=1e-6, atol=1e-9 * max(1.0, float(np.abs(want).max()))):
                    raise InputError(f"column {names[col]!r} is not the {what} column of friction joint {fn!r} "
                                     f"({'sign(v)' if what == 'Coulomb' else 'v'} projected on the channels)")
        for key, a in {**arrays, "mask": mask, "names": names, "channel_names": chans, "friction_names": fnames,
                       "meta": MappingProxyType(dict(self.meta))}.items():
            if isinstance(a, np.ndarray):
                a.setflags(write=False)
            object.__setattr__(self, key, a)

    @property
    def n_samples(self) -> int:
        return int(self.W.shape[0])

    @property
    def row_mask(self) -> BoolArray:
        """The rows used, (n, n_ch) (all True without a ``mask``)."""
        return np.ones(self.y.shape, dtype=bool) if self.mask is None else self.mask

    @property
    def n_obs(self) -> FloatArray:
        """Rows used per channel, (n_ch,)."""
        return self.row_mask.sum(axis=0).astype(float)

    def row_weights(self, sw: FloatArray) -> FloatArray:
        """Per-row factors (n, n_ch): ``sw`` (n_ch,) on the rows used, 0 on the others."""
        return np.asarray(sw, dtype=float)[None, :] * self.row_mask

    @property
    def n_friction(self) -> int:
        return int(self.velocity.shape[1])

    @property
    def rms_velocity(self) -> FloatArray:
        """RMS velocity of each friction joint, shape (n_f,)."""
        return np.sqrt(np.mean(self.velocity**2, axis=0))

    def stribeck_names(self, prefix: str) -> tuple[str, ...]:
        """``<prefix>_<joint>`` for every friction joint."""
        return tuple(f"{prefix}_{f}" for f in self.friction_names)

    def projection_array(self) -> FloatArray:
        """:math:`P` as an array (n, n_ch, n_f) (the identity expanded when ``projection`` is None)."""
        return _identity_projection(self.n_samples, self.n_friction) if self.projection is None else self.projection

    def friction_columns(self, vs: FloatArray, delta: FloatArray) -> FloatArray:
        """Regressor columns of :math:`\\Delta F` at fixed :math:`(v_S, \\delta)`, shape (n, n_ch, n_f)."""
        return self.projection_array() * stribeck_basis(self.velocity, vs, delta)[:, None, :]

    def compressed(self) -> RegressionProblem:
        """The linear part (Coulomb + viscous friction) as a compressed :class:`RegressionProblem`."""
        return RegressionProblem.from_arrays(self.W, self.y, self.names, self.channel_names, self.mask,
                                             standard=self.standard, meta=self.meta)

    def augmented(self, vs: FloatArray, delta: FloatArray, *, weights: FloatArray | None = None) -> RegressionProblem:
        """The problem linear in :math:`(\\beta, \\Delta F)` at fixed :math:`(v_S, \\delta)`, compressed.

        Parameters ``dFs_<joint>`` are appended; the standard map gains one identity column per
        :math:`\\Delta F` (non-negative, reference 0). ``weights`` (n_ch,) whiten the rows
        (``sqrt(w_j)`` per channel) before compression.
        """
        n_f, smap = self.n_friction, self.standard
        vs, delta = (np.broadcast_to(np.asarray(a, dtype=float), (n_f,)) for a in (vs, delta))
        if np.any(vs <= 0) or not np.all(np.isfinite(np.r_[vs, delta])):
            raise InputError(f"Stribeck velocities must be positive and finite, got {vs.tolist()}")
        Wa, y = np.concatenate([self.W, self.friction_columns(vs, delta)], axis=2), self.y
        if weights is not None:
            sw = np.sqrt(np.asarray(weights, dtype=float))
            Wa, y = Wa * sw[None, :, None], y * sw[None, :]
        p_std = smap.B.shape[1]
        aug = StandardMap(standard_names=tuple(smap.standard_names) + self.stribeck_names("dFs"),
                          B=sla.block_diag(smap.B, np.eye(n_f)), body_blocks=smap.body_blocks,
                          nonnegative=np.r_[smap.nonnegative, p_std + np.arange(n_f)].astype(int),
                          reference=None if smap.reference is None else np.r_[smap.reference, np.zeros(n_f)],
                          nonpositive=smap.nonpositive)
        return RegressionProblem.from_arrays(Wa, y, self.names + self.stribeck_names("dFs"), self.channel_names,
                                             self.mask, standard=aug, meta=self.meta)

    @classmethod
    def from_robot(cls, robot, q: FloatArray, dq: FloatArray, ddq: FloatArray, y: FloatArray, *, base=None,
                   friction_joints: Sequence[str] | None = None, meta: Mapping[str, Any] | None = None) -> SampleProblem:
        """The problem of a serial :class:`~dynid.model.robot.RobotModel` (channels = joints).

        ``q, dq, ddq, y`` are (n, n_v) [rad, rad/s, rad/s², N·m]; ``base`` defaults to
        :func:`~dynid.model.base_parameters.robot_base_parameters`, ``friction_joints`` (names)
        to every joint. The robot needs the ``fv`` and ``fc`` extras.
        """
        from dynid.model.base_parameters import robot_base_parameters
        from dynid.model.serial_dynamics import regressor

        joints, ext = tuple(robot.joint_names), robot.layout.extra_index
        chosen = joints if friction_joints is None else tuple(friction_joints)
        if not chosen or any(j not in joints for j in chosen):
            raise InputError(f"unknown friction joints {[j for j in chosen if j not in joints]}; joints: {', '.join(joints)}")
        if "fc" not in ext or "fv" not in ext:
            raise InputError("the robot has no fv/fc parameters: load it with extras including 'fv' and 'fc'")
        base = robot_base_parameters(robot) if base is None else base
        jidx = [joints.index(j) for j in chosen]
        std = {e: [robot.parameter_names[ext[e][j]] for j in jidx] for e in ("fc", "fv")}
        absent = [n for e in std for n in std[e] if n not in base.names]
        if absent:
            raise InputError(f"friction columns {absent} are not base parameters")
        cols = {e: tuple(base.names.index(n) for n in std[e]) for e in std}
        dq = np.asarray(dq, dtype=float)
        W = base.regressor(regressor(robot, q, dq, ddq))
        proj = None
        if len(jidx) != len(joints):
            proj = np.zeros((W.shape[0], len(joints), len(jidx)))
            proj[:, jidx, np.arange(len(jidx))] = 1.0
        return cls(names=base.names, channel_names=joints, W=W, y=y, velocity=dq[:, jidx], friction_names=chosen,
                   coulomb=cols["fc"], viscous=cols["fv"], standard=StandardMap.of(robot, base), projection=proj,
                   meta=dict(meta or {}))


def _friction_rows(sp: SampleProblem, Pw: FloatArray, dF, vs, delta, jac: bool):
    """Whitened Stribeck term (N,) and, with ``jac``, its Jacobian in (dF, log vs, delta), (N, 3 n_f)."""
    g, d_logvs, d_delta = _basis(sp.velocity, vs, delta)
    term = np.einsum("nck,nk->nc", Pw, dF * g).reshape(-1)
    if not jac:
        return term, None
    cols = [Pw * c[:, None, :] for c in (g, dF * d_logvs, dF * d_delta)]
    return term, np.concatenate(cols, axis=2).reshape(term.size, -1)


def stribeck_predict(result: IdentificationResult, W: FloatArray, velocity: FloatArray,
                     projection: FloatArray | None = None) -> FloatArray:
    """Outputs :math:`W\\beta + \\sum_k P_{:,:,k}\\,\\Delta F_k\\, g(v_k)` (n, n_ch) [N·m or N] of a
    :class:`StribeckLS` result on other data (validation): base regressor ``W`` (n, n_ch, p),
    friction-joint ``velocity`` (n, n_f), ``projection`` (n, n_ch, n_f) as in :class:`SampleProblem`."""
    if "n_base" not in result.solver or "friction_names" not in result.solver:
        raise InputError(f"not a StribeckLS result (method {result.method!r})")
    p, n_f = int(result.solver["n_base"]), len(result.solver["friction_names"])
    W, v = np.asarray(W, dtype=float), np.asarray(velocity, dtype=float)
    if W.ndim != 3 or W.shape[2] != p:
        raise InputError(f"W has shape {W.shape}, expected (n, n_ch, {p})")
    if v.shape != (W.shape[0], n_f):
        raise InputError(f"velocity has shape {v.shape}, expected {(W.shape[0], n_f)}")
    if projection is None and W.shape[1] != n_f:
        raise InputError(f"{n_f} friction joints and {W.shape[1]} channels: give the projection")
    P = _identity_projection(W.shape[0], n_f) if projection is None else np.asarray(projection, dtype=float)
    if P.shape != (W.shape[0], W.shape[1], n_f):
        raise InputError(f"projection has shape {P.shape}, expected {(W.shape[0], W.shape[1], n_f)}")
    for name, a in (("W", W), ("velocity", v), ("projection", P)):
        _finite(name, a)
    th = np.asarray(result.params)
    beta, dF, vs, delta = th[:p], th[p : p + n_f], th[p + n_f : p + 2 * n_f], th[p + 2 * n_f :]
    return W @ beta + np.einsum("nck,nk->nc", P, dF * stribeck_basis(v, vs, delta))
