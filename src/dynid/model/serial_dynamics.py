"""Joint-torque regressor of a serial robot, linear in the standard parameters.

The rigid-body part is pinocchio's ``computeJointTorqueRegressor`` (one call per
sample, copied block-wise into a preallocated array); the extras (rotor inertia,
viscous and Coulomb friction, offset, coupled-motor terms) are filled vectorized.
See :mod:`dynid.model.robot` for the parameter layout and the torque equation.

Shapes: ``q, dq, ddq`` are ``(n, n_v)``; the regressor is ``(n, n_v, n_params)``
(sample, output joint, parameter), so ``regressor[i] @ params`` is the joint torque
vector of sample ``i``.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError
from dynid.model.robot import RobotModel

__all__ = ["regressor", "extra_basis", "extras_torque", "inverse_dynamics", "check_states", "smooth_sign"]


def check_states(robot: RobotModel, q: FloatArray, dq: FloatArray, ddq: FloatArray) -> tuple[FloatArray, ...]:
    """Validate and return ``q, dq, ddq`` as float arrays of shape (n, n_v)."""
    nv = robot.dof
    out = []
    for name, x in (("q", q), ("dq", dq), ("ddq", ddq)):
        a = np.asarray(x, dtype=float)
        if a.ndim == 1:
            a = a[None, :]
        if a.ndim != 2 or a.shape[1] != nv:
            raise InputError(f"{name} must have shape (n, {nv}), got {np.shape(x)}")
        out.append(a)
    if not (out[0].shape[0] == out[1].shape[0] == out[2].shape[0]):
        raise InputError(f"mismatched lengths: q {out[0].shape[0]}, dq {out[1].shape[0]}, ddq {out[2].shape[0]}")
    return tuple(out)


_BLOCK = 128
"""Samples per block in :func:`regressor`: a block of ``out`` (about 0.5 MB for 6 joints
and 84 columns) stays in cache while it is zeroed, filled by pinocchio and completed
with the extras."""


def smooth_sign(v: FloatArray, width: FloatArray | None = None) -> FloatArray:
    r"""The Coulomb basis: :math:`\mathrm{sign}(v)` when ``width`` is None (or 0 for a joint), else
    :math:`\mathrm{erf}(v / (\sqrt 2\,\sigma_v))` with :math:`\sigma_v` = ``width`` (broadcast
    over the last axis: one per joint).

    Why erf: with the measured velocity :math:`v` = true velocity + Gaussian noise of std
    :math:`\sigma_v`, :math:`E[\mathrm{sign}(v_{true}) \mid v] = \mathrm{erf}(v/(\sqrt2\sigma_v))`:
    the best prediction of the Coulomb force's direction from a noisy velocity. Far from zero it
    is the sign; near zero (a joint at rest or reversing) it goes through 0 instead of chattering
    between :math:`\pm f_c` with the noise (issue 19, item 4; the dead-band alternative, a linear
    ramp, has the same effect with a kink). ``width`` comes from the data
    (:func:`dynid.pipeline.data.velocity_noise_std`) or from the user."""
    v = np.asarray(v, dtype=float)
    if width is None:
        return np.sign(v)
    from scipy.special import erf

    w = np.broadcast_to(np.asarray(width, dtype=float), v.shape[-1:])
    safe = np.where(w > 0, w, 1.0)
    return np.where(w > 0, erf(v / (np.sqrt(2.0) * safe)), np.sign(v))


def extra_basis(extra: str, dq: FloatArray, ddq: FloatArray, width: FloatArray | None = None) -> FloatArray | float:
    """The basis function of a joint extra (see :mod:`dynid.model.robot`) at ``dq``, ``ddq``;
    ``width``: the Coulomb terms' smoothing per joint (:func:`smooth_sign`)."""
    if extra == "Ia":
        return ddq
    if extra == "fv":
        return dq
    if extra == "fc":
        return smooth_sign(dq, width)
    if extra == "fv+":
        return np.maximum(dq, 0.0)
    if extra == "fv-":
        return np.minimum(dq, 0.0)
    if extra == "fc+":
        return (dq > 0).astype(float) if width is None else 0.5 * (1.0 + smooth_sign(dq, width))
    if extra == "fc-":
        return (dq < 0).astype(float) if width is None else 0.5 * (1.0 - smooth_sign(dq, width))
    return 1.0  # offset


def motor_width(width: FloatArray | None, c: FloatArray) -> float | None:
    """The velocity-noise std of a coupled motor's velocity ``dq @ c`` from the joints' (independent noise)."""
    return None if width is None else float(np.sqrt(np.sum((np.asarray(c) * np.asarray(width)) ** 2)))


def _extras_diagonal(robot: RobotModel, out: FloatArray) -> FloatArray | None:
    """Writable view ``d[i, j, k] = out[i, j, extra_index[extras[k]][j]]``, shape (n, n_v, n_extras).

    The joint extras of joint ``j`` are consecutive columns ``nb + n_extras * j + k``
    (see :class:`~dynid.model.robot.ParameterLayout`), so the entries on joint ``j``'s
    own row are a strided view. None when there are no extras or the layout differs.
    """
    lay = robot.layout
    ne, nv, nb = len(lay.extra_index), lay.nv, lay.n_body_params
    if ne == 0:
        return None
    cols = np.array([idx for idx in lay.extra_index.values()])  # (ne, nv)
    if not np.array_equal(cols, nb + ne * np.arange(nv)[None, :] + np.arange(ne)[:, None]):
        return None
    ext = out[:, :, nb:]
    s0, s1, s2 = ext.strides
    return np.lib.stride_tricks.as_strided(ext, shape=(out.shape[0], nv, ne), strides=(s0, s1 + ne * s2, s2))


def _fill_extras(
    robot: RobotModel,
    dq: FloatArray,
    ddq: FloatArray,
    out: FloatArray,
    *,
    diag: FloatArray | None = None,
    joints: bool = True,
    motors: bool = True,
) -> None:
    """Write the extras columns of ``out`` (the other entries of those columns must be zero).

    ``joints``: rotor inertia, friction and offset of each joint, on the joint's own
    row (through ``diag``, the view of :func:`_extras_diagonal`, when given);
    ``motors``: the columns of coupled motors (written whole).
    """
    lay = robot.layout
    if joints:
        rows = np.arange(lay.nv)
        for k, (e, idx) in enumerate(lay.extra_index.items()):
            value = extra_basis(e, dq, ddq, robot.coulomb_width)
            if diag is not None:
                diag[:, :, k] = value
            else:
                out[:, rows, idx] = value
    if motors and lay.coupled_motors:
        tr = robot.transmission
        assert tr is not None
        for m_pos, k in enumerate(lay.coupled_motors):
            c = tr.coupling_weights(k)
            w = dq @ c
            motor_cols = {"Ia": ddq @ c, "fv": w, "fc": smooth_sign(w[:, None], motor_width(robot.coulomb_width, c))[:, 0]}
            for e, idx in lay.motor_index.items():
                out[:, :, idx[m_pos]] = motor_cols[e][:, None] * c[None, :]


def regressor(
    robot: RobotModel,
    q: FloatArray,
    dq: FloatArray,
    ddq: FloatArray,
    *,
    data: pin.Data | None = None,
    out: FloatArray | None = None,
) -> FloatArray:
    """Standard-parameter regressor :math:`Y(q, \\dot q, \\ddot q)`.

    Parameters
    ----------
    robot : RobotModel
    q, dq, ddq : array, shape (n, n_v)
        Joint positions [rad], velocities [rad/s], accelerations [rad/s²].
    data : pinocchio.Data, optional
        Working memory to reuse across calls.
    out : array, shape (n, n_v, n_params), optional
        Preallocated output (overwritten).

    Returns
    -------
    array, shape (n, n_v, n_params)
        ``Y[i] @ params`` is the vector of joint torques of sample ``i``;
        columns follow ``robot.parameter_names``.

    Notes
    -----
    The rigid-body columns satisfy ``Y_rb @ pi_rb == pinocchio.rnea(q, dq, ddq)``
    (Atkeson et al. 1986; pinocchio ``computeJointTorqueRegressor``).

    Samples are processed in blocks of ``_BLOCK``: the block of ``out`` is zeroed, the
    pinocchio regressors of its samples are copied in with one ``np.concatenate``
    and the joint extras are written; this keeps the cost per sample close to that
    of the bare pinocchio call (see ``bench/regressor_throughput.py``).
    """
    q, dq, ddq = check_states(robot, q, dq, ddq)
    n, nv = q.shape
    p = robot.layout.n_params
    nb = robot.layout.n_body_params
    if out is None:
        out = np.empty((n, nv, p))
    elif out.shape != (n, nv, p):
        raise InputError(f"out has shape {out.shape}, expected {(n, nv, p)}")
    elif not out.flags.c_contiguous:
        out[...] = regressor(robot, q, dq, ddq, data=data)
        return out
    model = robot.pin_model
    data = model.createData() if data is None else data
    jtr = pin.computeJointTorqueRegressor
    body = out.reshape(n * nv, p)[:, :nb]  # a view: out is C-contiguous
    diag = _extras_diagonal(robot, out)
    for start in range(0, n, _BLOCK):
        stop = min(start + _BLOCK, n)
        if p > nb:
            out[start:stop] = 0.0
        blocks = [jtr(model, data, qi, vi, ai) for qi, vi, ai in zip(q[start:stop], dq[start:stop], ddq[start:stop])]
        if nv == 1:  # pinocchio returns a vector, not a 1-row matrix, for a single joint
            blocks = [b.reshape(1, -1) for b in blocks]
        np.concatenate(blocks, axis=0, out=body[start * nv : stop * nv])
        if diag is not None:
            _fill_extras(robot, dq[start:stop], ddq[start:stop], out[start:stop], diag=diag[start:stop], motors=False)
    _fill_extras(robot, dq, ddq, out, joints=diag is None)
    return out


def extras_torque(robot: RobotModel, params: FloatArray, dq: FloatArray, ddq: FloatArray) -> FloatArray:
    """Torques of the extras alone, computed term by term (not through the regressor).

    Returns
    -------
    array, shape (n, n_v)
    """
    lay = robot.layout
    params = np.asarray(params, dtype=float)
    dq = np.atleast_2d(np.asarray(dq, dtype=float))
    ddq = np.atleast_2d(np.asarray(ddq, dtype=float))
    tau = np.zeros_like(dq)
    for e, idx in lay.extra_index.items():
        tau += params[idx][None, :] * extra_basis(e, dq, ddq, robot.coulomb_width)
    for m_pos, k in enumerate(lay.coupled_motors):
        assert robot.transmission is not None
        c = robot.transmission.coupling_weights(k)
        w, dw = dq @ c, ddq @ c
        motor = {"Ia": dw, "fv": w, "fc": smooth_sign(w[:, None], motor_width(robot.coulomb_width, c))[:, 0]}
        torque_k = sum(params[idx[m_pos]] * motor[e] for e, idx in lay.motor_index.items())
        tau += np.asarray(torque_k)[:, None] * c[None, :]
    return tau


def inverse_dynamics(
    robot: RobotModel, params: FloatArray, q: FloatArray, dq: FloatArray, ddq: FloatArray
) -> FloatArray:
    """Joint torques by pinocchio's RNEA with body inertias from ``params`` plus extras.

    This is an independent route to the torques (recursive Newton–Euler on a model
    rebuilt from the parameters, rotor inertia through ``model.armature``), used to
    simulate data and to check the regressor.

    Returns
    -------
    array, shape (n, n_v)
    """
    q, dq, ddq = check_states(robot, q, dq, ddq)
    model = robot.with_parameters(params)
    data = model.createData()
    tau = np.empty_like(q)
    for i in range(q.shape[0]):
        tau[i] = pin.rnea(model, data, q[i], dq[i], ddq[i])
    no_ia = np.array(params, dtype=float, copy=True)
    if "Ia" in robot.layout.extra_index:
        no_ia[robot.layout.extra_index["Ia"]] = 0.0  # armature already in rnea
    return tau + extras_torque(robot, no_ia, dq, ddq)
