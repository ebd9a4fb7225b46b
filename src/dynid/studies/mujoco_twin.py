"""MuJoCo as an independent engine for dynid's closed-chain identification (issue 34, item 6).

The robots of :mod:`dynid.studies.twin_robots` are simulated by MuJoCo (its own kinematics,
soft-constraint dynamics and integrator, nothing of pinocchio or dynid), and the logs it writes
are what ``dynid init`` and ``dynid identify`` read: time ``t`` [s], actuator positions
``q_<joint>`` [m or rad] and forces ``tau_<joint>`` [N or N m], named after the MJCF joints.

Experiment (:func:`simulate`). MuJoCo integrates at 4 kHz (RK4, :data:`twin_robots.TIMESTEP`);
the controller runs, and the log samples, at 1 kHz. The reference is an excitation in the
robot's workspace (:func:`stewart_reference`: the platform pose, :func:`planar_reference`: the
end-effector point), a sum of sines with seeded amplitudes and phases faded in over the first
second, mapped to actuator positions by closed-form inverse kinematics. The controller is
joint-space PD on the actuators plus the gravity feedforward of the *prior* model (the CAD file a
user would have, evaluated by MuJoCo at the measured state), both projected on the mechanism's
motion and distributed to the actuators by **minimum norm**:

.. math::

    \\tau_a = (N^T S_a^T)^+ N^T (S_a^T f_{PD} + g_{prior}(q)),

:math:`N` a basis of the closures' velocity null space (MuJoCo's connect Jacobians),
:math:`S_a` the actuator selection. For the non-redundant Stewart platform that is the PD force
plus the gravity feedforward distributed exactly; for the redundant planar robot it removes the
internal (antagonistic) part of the three PD forces. The applied forces are held for the control
period. The log holds the positions quantized to an encoder resolution and the applied forces
plus seeded Gaussian noise (:data:`NOISE`).

Cross-check (:func:`inverse_dynamics_check`): at constraint-consistent states assembled by
MuJoCo's kinematics, MuJoCo's tree inverse dynamics (``mj_inverse`` with constraints disabled:
mass matrix with armature, bias forces, damping) projected to the actuators on MuJoCo's own
constraint Jacobians, against dynid's closed-chain inverse dynamics at the actuators
(:func:`dynid.model.closed_loop.actuator_forces`) from the actuator positions, velocities and
accelerations only. MuJoCo's dry friction (``frictionloss``, a constraint there) is left out of
both sides.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from dynid._typing import FloatArray
from dynid.studies.twin_robots import PLANAR, STEWART, planar_elbows, stewart_points

__all__ = ["NOISE", "GAINS", "Twin", "load_twin", "stewart_reference", "planar_reference", "reference",
           "simulate", "write_log", "inverse_dynamics_check", "validation_into_config", "held_out_errors"]

RATE_HZ = 1000.0
"""Control and log rate."""
NOISE = {"stewart": {"force_std": 0.2, "resolution": 1e-6}, "planar": {"force_std": 0.01, "resolution": 2 * np.pi / 2**20}}
"""Measurement noise: force sensor std [N, N m] (about 1 % of the RMS forces) and encoder
resolution [m, rad] (a 1 um linear scale, a 20-bit encoder)."""
GAINS = {"stewart": (2.0e4, 600.0), "planar": (300.0, 6.0)}
"""PD gains (kp [N/m, N m/rad], kd [N s/m, N m s/rad]): natural frequency about 100 rad/s with
the legs' effective masses (1.5-3 kg) and the planar joints' inertias (about 0.03 kg m^2), damping
ratio 1-1.5; kd times the period over the inertia 0.2-0.3, far from the discrete limit of 2."""
FADE_S = 1.0
"""Fade-in of the excitation [s] (a quintic smoothstep): the robot starts at rest at home."""


def _mujoco():
    try:
        import mujoco
    except ImportError:  # pragma: no cover - the [test]/[bench] extras install it
        from dynid.errors import InputError

        raise InputError("the MuJoCo twins need mujoco: pip install 'dynid[bench]'") from None
    return mujoco


@dataclasses.dataclass(frozen=True, eq=False)
class Twin:
    """A MuJoCo model of a twin robot and its actuator bookkeeping."""

    kind: str  # "stewart" or "planar"
    path: Path
    model: object  # mujoco.MjModel
    actuated: tuple[str, ...]  # actuated joint names, actuator order
    qpos_adr: np.ndarray  # qpos address of each actuated joint
    dof_adr: np.ndarray  # dof address of each actuated joint

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    def selection(self) -> FloatArray:
        """S_a (n_a, nv): actuator velocities = S_a qvel."""
        S = np.zeros((len(self.actuated), self.nv))
        S[np.arange(len(self.actuated)), self.dof_adr] = 1.0
        return S


def load_twin(path: str | Path, kind: str | None = None) -> Twin:
    """The MuJoCo model of the MJCF file ``path``; ``kind`` from its name when not given."""
    mujoco = _mujoco()
    path = Path(path)
    kind = kind or ("planar" if "planar" in path.stem else "stewart")
    m = mujoco.MjModel.from_xml_path(str(path))
    names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0])) for a in range(m.nu))
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    return Twin(kind, path, m, names, np.array([m.jnt_qposadr[j] for j in jid]), np.array([m.jnt_dofadr[j] for j in jid]))


# ---------------------------------------------------------------------------- constraints (MuJoCo's side)
def closure_rows(twin: Twin, data) -> tuple[FloatArray, FloatArray]:
    """Residual (3 n_eq,) and Jacobian (3 n_eq, nv) of the ``<connect>`` closures at ``data``'s
    positions (kinematics computed): the point of body2 minus the point of body1 [m], each point
    MuJoCo's anchor in its body (``eq_data[0:3]``, ``eq_data[3:6]``), Jacobians by ``mj_jac``."""
    mujoco = _mujoco()
    m = twin.model
    res, rows = [], []
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for k in range(m.neq):
        pts, jac = [], []
        for body, anchor in ((m.eq_obj1id[k], m.eq_data[k, 0:3]), (m.eq_obj2id[k], m.eq_data[k, 3:6])):
            p = data.xpos[body] + data.xmat[body].reshape(3, 3) @ anchor
            mujoco.mj_jac(m, data, jp, jr, p, body)
            pts.append(p)
            jac.append(jp.copy())
        res.append(pts[1] - pts[0])
        rows.append(jac[1] - jac[0])
    return np.concatenate(res), np.vstack(rows)


def _null(J: FloatArray, dof: int) -> FloatArray:
    """Basis (nv, dof) of the null space of J (its ``dof`` smallest right singular vectors)."""
    return np.linalg.svd(J)[2][J.shape[1] - dof:].T


def _kin(twin: Twin, data) -> None:
    """Positions of the bodies and their motion subspaces (``mj_jac`` reads both)."""
    mujoco = _mujoco()
    mujoco.mj_kinematics(twin.model, data)
    mujoco.mj_comPos(twin.model, data)


def assemble(twin: Twin, data, qa: FloatArray, *, tol: float = 1e-13, max_iter: int = 50) -> None:
    """Move ``data.qpos`` (in place) to the assembly with actuator positions ``qa`` nearest it
    (Gauss-Newton on [closure residual; actuator error], steps applied by ``mj_integratePos``)."""
    mujoco = _mujoco()
    S = twin.selection()
    for _ in range(max_iter):
        _kin(twin, data)
        r, J = closure_rows(twin, data)
        ea = data.qpos[twin.qpos_adr] - qa
        F = np.concatenate([r, ea])
        if np.abs(F).max() < tol:
            return
        step = -np.linalg.lstsq(np.vstack([J, S]), F, rcond=1e-12)[0]
        mujoco.mj_integratePos(twin.model, data.qpos, step, 1.0)
    raise RuntimeError(f"{twin.path.name}: actuator positions {qa} do not assemble (residual {np.abs(F).max():.3g})")


# ---------------------------------------------------------------------------- references
def _fade(t: FloatArray) -> FloatArray:
    x = np.clip(t / FADE_S, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x**2)


def _sines(t: FloatArray, n: int, f0: float, harmonics: int, bounds: FloatArray, rng: np.random.Generator) -> FloatArray:
    """(len(t), n) sums of ``harmonics`` sines of f0, 2 f0, ... with amplitudes 1/k times a
    uniform draw and uniform phases, each scaled so that its largest value over one period is
    ``bounds``, faded in by :func:`_fade`."""
    k = np.arange(1, harmonics + 1)
    amp = rng.uniform(0.3, 1.0, (n, harmonics)) / k
    ph = rng.uniform(0.0, 2 * np.pi, (n, harmonics))
    period = np.linspace(0.0, 1.0 / f0, 2001)
    out = np.empty((t.size, n))
    for j in range(n):
        x = lambda s: np.sin(2 * np.pi * f0 * np.outer(s, k) + ph[j]) @ amp[j]  # noqa: E731
        out[:, j] = bounds[j] * x(t) / np.abs(x(period)).max()
    return out * _fade(t)[:, None]


def _rotation(rpy: FloatArray) -> FloatArray:
    """R = Rz(c) Ry(b) Rx(a) of (a, b, c) rows: (n, 3, 3)."""
    a, b, c = rpy.T
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.stack([np.stack([cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa], -1),
                     np.stack([sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa], -1),
                     np.stack([-sb, cb * sa, cb * ca], -1)], -2)


STEWART_BOUNDS = np.array([0.07, 0.07, 0.055, 0.14, 0.14, 0.17])
"""Largest excursion of the platform pose from home: x, y, z [m], roll, pitch, yaw [rad]."""
PLANAR_BOUNDS = np.array([0.06, 0.06])
"""Largest excursion of the end-effector point from home: x, z [m] (the legs stay at least 33 deg
away from their serial and parallel singularities over this box)."""


def stewart_reference(t: FloatArray, f0: float, seed: int, harmonics: int = 5) -> FloatArray:
    """Leg strokes (n, 6) [m] of a platform pose excitation (:data:`STEWART_BOUNDS`)."""
    pose = _sines(t, 6, f0, harmonics, STEWART_BOUNDS, np.random.default_rng(seed))
    B, P = stewart_points()
    C = np.array([0.0, 0.0, STEWART["height"]])
    R = _rotation(pose[:, 3:])
    Pw = C + pose[:, None, :3] + np.einsum("nij,kj->nki", R, P - C)
    return np.linalg.norm(Pw - B, axis=2) - np.linalg.norm(P - B, axis=1)


def planar_reference(t: FloatArray, f0: float, seed: int, harmonics: int = 5) -> FloatArray:
    """Actuated hinge angles (n, 3) [rad] of an end-effector point excitation (:data:`PLANAR_BOUNDS`)."""
    xz = np.array(PLANAR["point"]) + _sines(t, 2, f0, harmonics, PLANAR_BOUNDS, np.random.default_rng(seed))
    A = np.array(PLANAR["bases"])
    home = planar_elbows(PLANAR["point"]) - A
    out = np.empty((t.size, 3))
    for i, p in enumerate(xz):
        E = planar_elbows(p) - A
        # a hinge about +y turns the direction atan2(x, z) by its angle
        out[i] = np.arctan2(E[:, 0], E[:, 1]) - np.arctan2(home[:, 0], home[:, 1])
    return np.unwrap(out, axis=0)


def reference(kind: str, t: FloatArray, f0: float, seed: int) -> FloatArray:
    return (stewart_reference if kind == "stewart" else planar_reference)(t, f0, seed)


# ---------------------------------------------------------------------------- simulation
@dataclasses.dataclass(frozen=True)
class Log:
    """A simulated log: time (n,), measured actuator positions and forces (n, n_a), the
    reference (n, n_a), names of the actuated joints, largest closure residual [m]."""

    t: FloatArray
    q: FloatArray
    tau: FloatArray
    q_ref: FloatArray
    names: tuple[str, ...]
    closure_residual: float


def simulate(truth: str | Path, prior: str | Path, duration: float, f0: float, seed: int, *,
             noise_seed: int | None = None) -> Log:
    """Simulate the robot ``truth`` (MJCF) in MuJoCo for ``duration`` seconds under the controller
    of the module docstring (gravity feedforward from ``prior``), tracking the excitation of base
    frequency ``f0`` [Hz] drawn with ``seed``; noise drawn with ``noise_seed`` (default ``seed + 1``)."""
    mujoco = _mujoco()
    twin, tprior = load_twin(truth), load_twin(prior)
    m, mp = twin.model, tprior.model
    kind = twin.kind
    d, dp = mujoco.MjData(m), mujoco.MjData(mp)
    substeps = int(round(1.0 / (RATE_HZ * m.opt.timestep)))
    n = int(round(duration * RATE_HZ))
    t = np.arange(n) / RATE_HZ
    tt = np.arange(n + 2) / RATE_HZ - 1.0 / RATE_HZ
    qr = reference(kind, tt, f0, seed)
    dqr = np.gradient(qr, 1.0 / RATE_HZ, axis=0)
    qr, dqr = qr[1:-1], dqr[1:-1]
    kp, kd = GAINS[kind]
    noise = NOISE[kind]
    rng = np.random.default_rng(seed + 1 if noise_seed is None else noise_seed)
    S = twin.selection()
    dof = 6 if kind == "stewart" else 2
    Q, TAU = np.empty((n, S.shape[0])), np.empty((n, S.shape[0]))
    worst = 0.0
    res = noise["resolution"]
    for k in range(n):
        _kin(twin, d)
        r, J = closure_rows(twin, d)
        worst = max(worst, float(np.abs(r).max()))
        N = _null(J, dof)
        qa = np.round(d.qpos[twin.qpos_adr] / res) * res  # the encoders
        dqa = d.qvel[twin.dof_adr]
        dp.qpos[:] = d.qpos
        dp.qvel[:] = 0.0
        mujoco.mj_forward(mp, dp)  # the prior's gravity at the measured pose
        f_pd = kp * (qr[k] - qa) + kd * (dqr[k] - dqa)
        A = N.T @ S.T
        tau = np.linalg.pinv(A) @ (N.T @ (S.T @ f_pd + dp.qfrc_bias))
        d.ctrl[:] = tau
        Q[k], TAU[k] = qa, tau
        for _ in range(substeps):
            mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qpos)):
            raise RuntimeError(f"{twin.path.name}: the simulation diverged at t = {t[k]:.3f} s")
    TAU = TAU + rng.normal(0.0, noise["force_std"], TAU.shape)
    return Log(t, Q, TAU, qr, twin.actuated, worst)


def write_log(log: Log, path: str | Path) -> Path:
    """The log as CSV: ``t``, ``q_<joint>``..., ``tau_<joint>``... (the names ``dynid init`` matches)."""
    path = Path(path)
    header = ["t"] + [f"q_{n}" for n in log.names] + [f"tau_{n}" for n in log.names]
    np.savetxt(path, np.column_stack([log.t, log.q, log.tau]), delimiter=",", header=",".join(header), comments="",
               fmt="%.10g")
    return path


# ---------------------------------------------------------------------------- the engines' cross-check
def _consistent_states(twin: Twin, n: int, seed: int, f0: float = 0.3) -> tuple[FloatArray, FloatArray, FloatArray]:
    """MuJoCo states (qpos, qvel, qacc) satisfying the closures to 1e-13 at ``n`` poses of an
    excitation (Gauss-Newton :func:`assemble`), with random velocities in the closures' null
    space and accelerations :math:`N z - J^+ \\dot J \\dot q` (:math:`\\dot J\\dot q` by a central
    difference of MuJoCo's Jacobians along the velocity, step 1e-6: error ~1e-12 relative)."""
    mujoco = _mujoco()
    m = twin.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    dof = 6 if twin.kind == "stewart" else 2
    t = np.linspace(FADE_S, FADE_S + 1.0 / f0, n, endpoint=False)
    qa_all = reference(twin.kind, t, f0, seed)
    out = []
    for qa in qa_all:
        assemble(twin, d, qa)
        _kin(twin, d)
        J = closure_rows(twin, d)[1]
        N = _null(J, dof)
        qvel = N @ rng.normal(0.0, 0.5, dof)
        h = 1e-6
        Js = []
        for sgn in (1.0, -1.0):
            e = mujoco.MjData(m)
            e.qpos[:] = d.qpos
            mujoco.mj_integratePos(m, e.qpos, qvel, sgn * h)
            _kin(twin, e)
            Js.append(closure_rows(twin, e)[1])
        drift = (Js[0] - Js[1]) @ qvel / (2 * h)
        qacc = N @ rng.normal(0.0, 2.0, dof) - np.linalg.pinv(J, rcond=1e-10) @ drift
        out.append((d.qpos.copy(), qvel, qacc))
    return tuple(np.array(x) for x in zip(*out))


def inverse_dynamics_check(path: str | Path, n: int = 8, seed: int = 0) -> dict[str, FloatArray]:
    """Actuator forces of the robot file ``path`` by MuJoCo and by dynid at ``n`` consistent states.

    Returns ``{"mujoco": (n, n_a), "dynid": (n, n_a), "scale": (n_a,)}``: MuJoCo's
    ``mj_inverse`` tree forces (constraints, hence ``frictionloss``, disabled) projected on its
    closures' null space :math:`N` and distributed by minimum norm,
    :math:`\\tau_a = (N^T S_a^T)^+ N^T \\tau_{tree}` (the forces themselves for the non-redundant
    robot); dynid's :func:`~dynid.model.closed_loop.actuator_forces` of the file's parameters with
    the Coulomb terms at 0, from the actuator positions, velocities and accelerations alone
    (``actuator_states``; ``min_norm`` for the redundant robot); scale: the RMS of MuJoCo's forces.
    """
    mujoco = _mujoco()
    from dynid.model.closed_loop import actuator_forces
    from dynid.model.loop_kinematics import actuator_states
    from dynid.model.mechanism_files import load_mechanism_mjcf

    twin = load_twin(path)
    m = twin.model
    qpos, qvel, qacc = _consistent_states(twin, n, seed)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    d = mujoco.MjData(m)
    S = twin.selection()
    dof = 6 if twin.kind == "stewart" else 2
    tau_mj = []
    for qp, qv, qa in zip(qpos, qvel, qacc):
        d.qpos[:], d.qvel[:], d.qacc[:] = qp, qv, qa
        mujoco.mj_inverse(m, d)
        N = _null(closure_rows(twin, d)[1], dof)
        tau_mj.append(np.linalg.pinv(N.T @ S.T) @ (N.T @ d.qfrc_inverse))
    mech = load_mechanism_mjcf(path)
    params = mech.nominal_parameters().copy()
    for i, name in enumerate(mech.parameter_names):
        if name.startswith("fc_"):
            params[i] = 0.0
    state, _ = actuator_states(mech, qpos[:, twin.qpos_adr], qvel[:, twin.dof_adr], qacc[:, twin.dof_adr])
    tau_dy = actuator_forces(mech, params, state, distribution="min_norm" if mech.redundant else None)
    tau_mj = np.array(tau_mj)
    return {"mujoco": tau_mj, "dynid": tau_dy, "scale": np.sqrt(np.mean(tau_mj**2, axis=0))}


# ---------------------------------------------------------------------------- dynid init without --validation
def validation_into_config(config: str | Path, validation: str | Path) -> None:
    """Give the config ``dynid init`` wrote a held-out log of its own, as ``dynid init ... --validation
    VALID`` does (for a ``dynid init`` that lacks the flag): the training log whole (the ``rows`` of
    ``[data]`` dropped) and ``[validation] file = VALID`` (path relative to the config) instead
    of the last quarter's ``rows``. Nothing else changes."""
    import json
    import os

    config = Path(config)
    rel = os.path.relpath(Path(validation).resolve(), config.resolve().parent)
    out, section = [], None
    for line in config.read_text().splitlines():
        s = line.strip()
        if s.startswith("["):
            section = s.split("]")[0] + "]"
        if s.startswith("[data]"):
            line = line.replace("the first three quarters", "all of it (validation: another run)")
        if section in ("[data]", "[validation]") and s.startswith("rows ="):
            if section == "[validation]":
                out.append(f"file = {json.dumps(rel)}                 # another run: held out, never used for training")
            continue
        out.append(line)
    config.write_text("\n".join(out) + "\n")


def held_out_errors(config: str | Path, robot: str | Path | None = None) -> dict[str, list]:
    """Held-out relative RMSE per channel [%] of ``dynid identify CONFIG`` run in this process
    with plots off: ``identified``, and ``nominal`` (the robot file's parameters, through dynid's
    model, on the same processed rows). ``robot``: another robot file in place of the config's
    (the true MJCF: ``nominal`` is then the true-parameter error); ``other_*``: the per-actuator
    view of a redundant robot, when identify gives one."""
    from dynid.config import load_config
    from dynid.pipeline import identify

    cfg = load_config(config)
    if robot is not None:
        cfg = dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, model=str(Path(robot).resolve())))
    cfg = dataclasses.replace(cfg, output=dataclasses.replace(cfg.output, plots=False))
    out = identify(cfg)
    v, nom = out.validation, out.nominal_validation
    res = {"channels": list(v.channel_names), "identified": [float(x) for x in v.rel_rmse_pct],
           "nominal": [float(x) for x in nom.rel_rmse_pct]}
    if out.other_view is not None:
        res.update(other_channels=list(out.other_view.metrics.channel_names),
                   other_identified=[float(x) for x in out.other_view.metrics.rel_rmse_pct],
                   other_nominal=[float(x) for x in out.other_view.nominal.rel_rmse_pct])
    return res
