"""Closed-loop simulation against MuJoCo (issue 37, item 2): the hexapod exported by dynid to MJCF,
simulated by MuJoCo and by dynid under the same controller, reference and control period.

A speed anchor and an independent check of dynid's simulator in one script. MuJoCo shares nothing
with dynid but the MJCF file: its own kinematics, soft-constraint dynamics, friction and integrator.

Targets (issue 37, item 2), paired in the same run:

* speed: dynid's wall time at most :data:`TARGET_RATIO` (10) times MuJoCo's for the same simulated
  span (the median over ``--rounds`` paired rounds, against each MuJoCo integrator below);
* agreement: actuator forces within 2 % RMS (per actuator, RMS of the difference over the RMS of
  dynid's force) and actuator positions within 1e-4 m (largest difference over the run).

Method
------
* **Model.** ``builtin:hexapod`` with its nominal parameters (bodies, viscous and Coulomb friction
  of the 14 joint terms), written by :func:`dynid.io.export.write_mjcf` with
  ``range_convention="mujoco"`` (MuJoCo's joint ``range`` bounds the absolute ``qpos``). Three
  settings are added to the file (:func:`mujoco_file`): ``<compiler boundmass="1e-9"
  boundinertia="1e-12">`` because MuJoCo refuses moving bodies without mass (the five massless
  bodies of the platform's joint chain PX..RY: 1e-9 kg against the platform's 4.2 kg is a 2e-10
  change of the composite inertia they carry); the integrator and step; stiff constraints (below).
* **Same mechanism first.** At :data:`ID_STATES` states assembled by MuJoCo's own kinematics
  (:func:`dynid.studies.mujoco_twin.assemble`, Gauss-Newton to 1e-13 m on MuJoCo's ``<connect>``
  residuals) with random velocities in the null space of MuJoCo's closure Jacobians and
  consistent accelerations, MuJoCo's tree inverse dynamics (``mj_inverse``, constraints and hence
  ``frictionloss`` disabled) projected on MuJoCo's closure Jacobians equals dynid's closed-chain
  inverse dynamics at the actuators (:func:`dynid.model.closed_loop.actuator_forces`, Coulomb terms
  at 0) from the actuator positions, velocities and accelerations alone: the style of
  :func:`dynid.studies.mujoco_twin.inverse_dynamics_check`. Threshold :data:`ID_TOL` (1e-7 of the
  RMS force; the drift term's central difference leaves ~1e-10).
* **Reference** (as bench/simulate_hexapod.py): a 3-harmonic Fourier motion of the six strut
  lengths (0.5 Hz, about +-2 cm, seed 2026), turned into actuator positions, velocities and
  feedforward forces by :class:`dynid.simulation.closed_loop.ActuatorReference` (dynid's inverse
  dynamics with the nominal parameters) **once, before either engine runs**.
* **Controller, the same for both engines** (:class:`ActuatorPD`): actuator-space PD plus the
  tabulated feedforward, :math:`\\tau_k = \\tau_{ff,k} + K_p(q_{a,k}^d - q_a) + K_d(\\dot q_{a,k}^d
  - \\dot q_a)`, Kp = 2e4 N/m, Kd = 600 N s/m (the gains of the MuJoCo Stewart twin,
  :data:`dynid.studies.mujoco_twin.GAINS`: about 80 rad/s with the legs' 3 kg, damping ratio
  1.2), at 1 kHz with zero-order hold. It costs the same few microseconds for both (six positions
  and velocities read, one table row), so the wall-time ratio measures the simulators, not the
  controller (bench/simulate_hexapod.py's model-based :class:`AugmentedPD` makes a period 0.9 ms
  against 0.5 ms with this one, bench/README.md). Same initial state: dynid's assembly at the reference's start
  with its velocity, written into MuJoCo's ``qpos``/``qvel`` (the two files' joint coordinates are
  the same). Same span: ``--duration`` (default 10 s).
* **dynid** (:func:`dynid.simulation.closed_loop.simulate_mechanism_control`,
  :class:`~dynid.simulation.closed_loop.ConstrainedSimulator`) with its default settings --
  pinocchio's ``constraintDynamics`` (proximal KKT, mu = 1e-12, accuracy 1e-14, 100 iterations),
  no Baumgarte stabilization, the state projected on the closures after every period, the
  discontinuous Coulomb law ``fc sign(v)`` -- except the substeps: 2 RK4 substeps per period
  (0.5 ms, as bench/simulate_hexapod.py; the default is 4) so that both engines take the same
  integration step.
* **MuJoCo**, two integrators at the same 0.5 ms step (:data:`MUJOCO_RUNS`): ``RK4``, dynid's
  method, the accuracy reference; ``Euler`` (MuJoCo's default, semi-implicit), the cheapest.
  Constraints made stiff (:data:`SOLREF`, :data:`SOLIMP`, the settings of
  :mod:`dynid.studies.twin_robots` scaled to the step): ``solref="0.001 1"`` -- time constant 1 ms,
  MuJoCo's floor of two steps, critical damping -- and ``solimp="0.9999 0.9999 0.001"`` --
  impedance 0.9999 at any violation, so a closure keeps 1e-4 of MuJoCo's softness (its constraint
  force is regularized by R = (1 - d)/d A_ii). The same for ``frictionloss`` (``solreffriction``,
  ``solimpfriction``), which then sticks and slips like ``fc sign(v)``. With MuJoCo's defaults
  (``solref="0.02 1"``, ``solimp="0.9 0.95 0.001"``) the loops are soft enough to miss both
  targets (bench/README.md: 1.9e-4 m, 5.8 %, closure gaps of 0.5 mm). Newton solver, tolerance 1e-8 (defaults).
* **Timing**: one core (BLAS limited to 1 thread; pinocchio and MuJoCo single-threaded), only the
  simulation loops timed (models, data and the reference table built before), the engines
  alternated in each of ``--rounds`` rounds (default 3); reported: median wall times, time per
  simulated second, and the median of the per-round ratios.
* **Sensitivity** (not a target): the same closed loop on MuJoCo with the platform's mass 10 %
  heavier in the file shows what a model difference does to the two agreement figures.

Exit status 1 when a target fails (not with ``--quick``: 1 s, 1 round).

Run: ``.venv/bin/python bench/simulate_vs_mujoco.py`` (``--quick`` for a smoke run).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from _util import median, print_machine, table

from dynid.io.export import write_mjcf
from dynid.model.robots import build_mechanism
from dynid.simulation.closed_loop import ActuatorReference, ConstrainedSimulator, simulate_mechanism_control
from dynid.trajectories import FourierTrajectory

TARGET_RATIO = 10.0
"""dynid wall time / MuJoCo wall time, same simulated span (issue 37, item 2)."""
TARGET_FORCE = 0.02
"""Actuator forces: RMS difference / RMS force, per actuator."""
TARGET_POSITION = 1e-4
"""Actuator positions: largest difference [m]."""
DT = 1e-3
"""Control period [s] (1 kHz, zero-order hold)."""
STEP = 5e-4
"""Integration step of both engines [s]: 2 RK4 substeps per period in dynid, MuJoCo's timestep."""
KP, KD = 2.0e4, 600.0
"""Actuator PD gains [N/m, N s/m]."""
SOLREF = "0.001 1"
"""MuJoCo closures and dry friction: time constant 2 steps (MuJoCo's floor), critical damping."""
SOLIMP = "0.9999 0.9999 0.001"
"""MuJoCo closures and dry friction: impedance 0.9999 (1e-4 of the constraint force left soft)."""
BOUNDMASS, BOUNDINERTIA = 1e-9, 1e-12
"""Mass [kg] and inertia [kg m^2] given by MuJoCo's compiler to the massless platform-chain bodies."""
MUJOCO_RUNS = ("RK4", "Euler")
"""MuJoCo's integrators compared (same step, same constraint settings)."""
ID_STATES = 6
ID_TOL = 1e-7
"""Inverse-dynamics cross-check: largest |MuJoCo - dynid| over the RMS force, per actuator."""
SENSITIVITY_MASS = 1.10
"""Platform mass factor of the sensitivity run's MuJoCo file."""


def _mujoco():
    import mujoco

    return mujoco


# ---------------------------------------------------------------------------- the model in MuJoCo
def mujoco_file(mech, params, path: Path, integrator: str, *, platform_mass: float = 1.0) -> Path:
    """The MJCF of ``write_mjcf`` with MuJoCo's simulation settings (module docstring) added:
    compiler bounds on mass and inertia, ``integrator`` at :data:`STEP`, stiff closures and dry
    friction; the platform's mass times ``platform_mass`` (the sensitivity run)."""
    write_mjcf(mech, params, path, range_convention="mujoco")
    tree = ET.parse(path)
    root = tree.getroot()
    root.find("compiler").attrib.update(boundmass=f"{BOUNDMASS:g}", boundinertia=f"{BOUNDINERTIA:g}")
    root.find("option").attrib.update(timestep=f"{STEP:g}", integrator=integrator)
    default = ET.Element("default")
    ET.SubElement(default, "equality", solref=SOLREF, solimp=SOLIMP)
    ET.SubElement(default, "joint", solreffriction=SOLREF, solimpfriction=SOLIMP)
    root.insert(list(root).index(root.find("option")) + 1, default)
    if platform_mass != 1.0:
        inertial = root.find(".//body[@name='RX_link']/inertial")
        inertial.set("mass", repr(float(inertial.get("mass")) * platform_mass))
    tree.write(path)
    return path


def load(path: Path):
    """:class:`dynid.studies.mujoco_twin.Twin` of the file (actuators and their addresses)."""
    from dynid.studies.mujoco_twin import load_twin

    return load_twin(path, kind="hexapod")


# ---------------------------------------------------------------------------- same mechanism?
def _null(J: np.ndarray, dof: int) -> np.ndarray:
    return np.linalg.svd(J)[2][J.shape[1] - dof:].T


def _closures(twin, d):
    from dynid.studies.mujoco_twin import closure_rows

    mujoco = _mujoco()
    mujoco.mj_kinematics(twin.model, d)
    mujoco.mj_comPos(twin.model, d)
    return closure_rows(twin, d)


def inverse_dynamics_check(mech, params, twin, qa_all: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """Actuator forces by MuJoCo and by dynid at the MuJoCo-assembled states of actuator positions
    ``qa_all`` (n, 6) (module docstring): ``{"mujoco", "dynid": (n, 6), "scale": (6,)}``, the
    scale the RMS of MuJoCo's forces. Coulomb terms are left out of both (MuJoCo's are constraints)."""
    mujoco = _mujoco()
    from dynid.model.closed_loop import actuator_forces
    from dynid.model.loop_kinematics import actuator_states
    from dynid.studies.mujoco_twin import assemble

    m = twin.model
    rng = np.random.default_rng(seed)
    d = mujoco.MjData(m)
    dof = mech.dof
    states = []
    for qa in qa_all:
        assemble(twin, d, qa)
        J = _closures(twin, d)[1]
        N = _null(J, dof)
        qvel = N @ rng.normal(0.0, 0.1, dof)
        h = 1e-6  # J'(q) qdot by a central difference along qvel: error ~1e-12 relative
        Js = []
        for sgn in (1.0, -1.0):
            e = mujoco.MjData(m)
            e.qpos[:] = d.qpos
            mujoco.mj_integratePos(m, e.qpos, qvel, sgn * h)
            Js.append(_closures(twin, e)[1])
        drift = (Js[0] - Js[1]) @ qvel / (2 * h)
        qacc = N @ rng.normal(0.0, 1.0, dof) - np.linalg.pinv(J, rcond=1e-10) @ drift
        states.append((d.qpos.copy(), qvel, qacc))
    qpos, qvel, qacc = (np.array(x) for x in zip(*states))
    flags = m.opt.disableflags
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    try:
        S = twin.selection()
        tau_mj = []
        for qp, qv, qa in zip(qpos, qvel, qacc):
            d.qpos[:], d.qvel[:], d.qacc[:] = qp, qv, qa
            mujoco.mj_inverse(m, d)
            N = _null(_closures(twin, d)[1], dof)
            tau_mj.append(np.linalg.solve(N.T @ S.T, N.T @ d.qfrc_inverse))
    finally:
        m.opt.disableflags = flags
    p = np.array(params, dtype=float)
    p[[i for i, n in enumerate(mech.parameter_names) if n.startswith("fc_")]] = 0.0
    state, _ = actuator_states(mech, qpos[:, twin.qpos_adr], qvel[:, twin.dof_adr], qacc[:, twin.dof_adr])
    tau_dy = actuator_forces(mech, p, state)
    tau_mj = np.array(tau_mj)
    return {"mujoco": tau_mj, "dynid": tau_dy, "scale": np.sqrt(np.mean(tau_mj**2, axis=0))}


# ---------------------------------------------------------------------------- the closed loop
@dataclasses.dataclass(frozen=True)
class ActuatorPD:
    """:math:`\\tau = \\tau_{ff} + K_p(q^d - q_a) + K_d(\\dot q^d - \\dot q_a)`, one row of the
    reference table per period: the one controller of both engines."""

    kp: float
    kd: float

    def force(self, qa, dqa, qd, dqd, ff):
        return ff + self.kp * (qd - qa) + self.kd * (dqd - dqa)


class _DynidController:
    """:class:`ActuatorPD` in dynid's controller signature ``(dt, q, dq, row)``; ``row`` is one row
    of :class:`ActuatorReference` (``u, du, ddu, qa_d, dqa_d, ddqa_d, ff``)."""

    def __init__(self, pd: ActuatorPD, actuated) -> None:
        self.pd, self.act = pd, np.array(actuated)

    def __call__(self, dt, q, dq, row):
        return self.pd.force(q[self.act], dq[self.act], row[3], row[4], row[6])


@dataclasses.dataclass
class Run:
    """One engine's closed-loop run: actuator positions and applied forces per control instant
    (n, 6), all joint positions (n, nv), the initial joint velocities (nv,), wall time of the loop [s]."""

    qa: np.ndarray
    tau: np.ndarray
    q: np.ndarray
    dq0: np.ndarray
    wall: float


def run_dynid(mech, params, pd: ActuatorPD, aref: ActuatorReference, duration: float) -> Run:
    sim = ConstrainedSimulator(mech, params)
    ctrl = _DynidController(pd, mech.actuated)
    t0 = time.perf_counter()
    m = simulate_mechanism_control(sim, ctrl, aref, duration=duration, dt=DT, substeps=int(round(DT / STEP)))
    wall = time.perf_counter() - t0
    return Run(m.q[:, list(mech.actuated)], m.tau_a, m.q, m.dq[0], wall)


def run_mujoco(twin, pd: ActuatorPD, rows, q0: np.ndarray, v0: np.ndarray) -> Run:
    """The closed loop in MuJoCo: the controller reads ``qpos``/``qvel`` of the actuated joints,
    its force is held (``ctrl``) over ``DT / timestep`` steps (``mj_step`` with ``nstep``)."""
    mujoco = _mujoco()
    m = twin.model
    d = mujoco.MjData(m)
    qd, dqd, ff = rows[3], rows[4], rows[6]
    n = len(ff)
    nstep = int(round(DT / m.opt.timestep))
    qadr, vadr = twin.qpos_adr, twin.dof_adr
    QA, TAU, Q = np.empty((n, len(qadr))), np.empty((n, len(qadr))), np.empty((n, m.nq))
    force, step = pd.force, mujoco.mj_step
    t0 = time.perf_counter()
    d.qpos[:], d.qvel[:] = q0, v0
    for k in range(n):
        qa = d.qpos[qadr]
        tau = force(qa, d.qvel[vadr], qd[k], dqd[k], ff[k])
        QA[k], TAU[k], Q[k] = qa, tau, d.qpos
        if k == n - 1:
            break
        d.ctrl[:] = tau
        step(m, d, nstep)
    wall = time.perf_counter() - t0
    if not np.all(np.isfinite(Q)):
        raise RuntimeError("MuJoCo's simulation diverged")
    return Run(QA, TAU, Q, v0, wall)


def agreement(a: Run, b: Run) -> tuple[float, float]:
    """(largest RMS force difference / RMS force over the actuators, largest position difference [m])."""
    rms = np.sqrt(np.mean((a.tau - b.tau) ** 2, axis=0)) / np.sqrt(np.mean(a.tau**2, axis=0))
    return float(rms.max()), float(np.abs(a.qa - b.qa).max())


def closure_residual(twin, q: np.ndarray, samples: int = 50) -> float:
    """Largest ``<connect>`` gap [m] of MuJoCo's run over ``samples`` instants."""
    d = _mujoco().MjData(twin.model)
    worst = 0.0
    for qk in q[:: max(1, len(q) // samples)]:
        d.qpos[:] = qk
        worst = max(worst, float(np.abs(_closures(twin, d)[0]).max()))
    return worst


@dataclasses.dataclass
class Setup:
    mech: object
    params: np.ndarray
    aref: ActuatorReference
    rows: tuple
    twins: dict
    sensitivity: object


def setup(duration: float, folder: Path, *, coulomb: bool = True) -> Setup:
    """Model, files, reference table (everything the timed loops do not do). ``coulomb=False``:
    the Coulomb terms set to 0 in both engines' parameters (the smooth dynamics, for the test)."""
    mech = build_mechanism("hexapod")
    params = mech.nominal_parameters().copy()
    if not coulomb:
        params[[i for i, n in enumerate(mech.parameter_names) if n.startswith("fc_")]] = 0.0
    u0 = mech.coordinates(mech.q_ref)[0]
    rng = np.random.default_rng(2026)
    ref = FourierTrajectory.random(6, 3, 0.5, rng, u0 - 0.02, u0 + 0.02, max_velocity=0.1, max_acceleration=1.0)
    aref = ActuatorReference(mech, ref.sample, params)
    n = int(round(duration / DT)) + 1
    rows = aref(np.arange(n) * DT)  # the table, kept by aref: simulate_mechanism_control asks for the same instants
    twins = {i: load(mujoco_file(mech, params, folder / f"hexapod_{i}.xml", i)) for i in MUJOCO_RUNS}
    sens = load(mujoco_file(mech, params, folder / "hexapod_heavy.xml", "RK4", platform_mass=SENSITIVITY_MASS))
    return Setup(mech, params, aref, rows, twins, sens)


def check_same_mechanism(s: Setup) -> float:
    """Largest inverse-dynamics difference over the RMS force (:func:`inverse_dynamics_check`)."""
    idx = np.linspace(0, len(s.rows[3]) - 1, ID_STATES).astype(int)
    r = inverse_dynamics_check(s.mech, s.params, s.twins["RK4"], s.rows[3][idx])
    return float((np.abs(r["mujoco"] - r["dynid"]).max(axis=0) / r["scale"]).max())


@dataclasses.dataclass
class Comparison:
    """What :func:`compare` measured: the inverse-dynamics check, wall times per round per engine,
    and per MuJoCo run (its integrators and the sensitivity run) the agreement with dynid
    (force RMS ratio, position difference [m]) and its largest closure gap [m]; dynid's tracking
    error and closure residual [m]."""

    id_error: float
    walls: dict
    agreement: dict
    closure_gap: dict
    tracking: float
    dynid_closure: float

    def ratio(self, name: str) -> float:
        """Median over the rounds of dynid's wall time over ``name``'s."""
        return median([a / b for a, b in zip(self.walls["dynid"], self.walls[name])])


SENSITIVITY = "MuJoCo RK4, heavier platform"


def compare(duration: float, rounds: int, folder: Path, *, coulomb: bool = True, log=print) -> Comparison:
    """The check of the module docstring: ``rounds`` paired rounds of ``duration`` simulated seconds."""
    with threadpool_limits(1):
        s = setup(duration, folder, coulomb=coulomb)
        id_err = check_same_mechanism(s)
        log(f"inverse dynamics at {ID_STATES} MuJoCo-assembled states: largest |MuJoCo - dynid| / RMS force "
            f"{id_err:.1e} (<= {ID_TOL:g}: {'same mechanism' if id_err <= ID_TOL else 'DIFFERENT'})")
        pd = ActuatorPD(KP, KD)
        walls: dict[str, list[float]] = {"dynid": [], **{f"MuJoCo {i}": [] for i in MUJOCO_RUNS}}
        runs: dict[str, Run] = {}
        for r in range(rounds):
            runs["dynid"] = run_dynid(s.mech, s.params, pd, s.aref, duration)
            walls["dynid"].append(runs["dynid"].wall)
            q0, v0 = runs["dynid"].q[0], runs["dynid"].dq0  # the same initial state
            for i in MUJOCO_RUNS:
                runs[f"MuJoCo {i}"] = run_mujoco(s.twins[i], pd, s.rows, q0, v0)
                walls[f"MuJoCo {i}"].append(runs[f"MuJoCo {i}"].wall)
            log(f"  round {r + 1}/{rounds}: " + ", ".join(f"{k} {v[-1]:.3f} s" for k, v in walls.items()))
        runs[SENSITIVITY] = run_mujoco(s.sensitivity, pd, s.rows, q0, v0)
        dy = runs["dynid"]
        twins = {**{f"MuJoCo {i}": s.twins[i] for i in MUJOCO_RUNS}, SENSITIVITY: s.sensitivity}
        return Comparison(
            id_error=id_err,
            walls=walls,
            agreement={k: agreement(dy, runs[k]) for k in twins},
            closure_gap={k: closure_residual(t, runs[k].q) for k, t in twins.items()},
            tracking=float(np.abs(dy.qa - s.rows[3]).max()),
            dynid_closure=float(np.abs(s.mech.constraint_residual(dy.q[:: max(1, len(dy.q) // 50)])).max()),
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds (default 10)")
    ap.add_argument("--rounds", type=int, default=3, help="paired rounds (default 3)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 1 s, 1 round; the targets are not enforced")
    args = ap.parse_args(argv)
    if args.quick:
        args.duration, args.rounds = 1.0, 1
    if not (np.isfinite(args.duration) and args.duration > 0 and args.rounds >= 1):
        ap.error("--duration must be positive and --rounds at least 1")
    print_machine()
    print(f"mujoco {_mujoco().__version__}; {args.duration:g} s simulated at {1 / DT:g} Hz, {args.rounds} round(s)")
    with tempfile.TemporaryDirectory() as tmp:
        c = compare(args.duration, args.rounds, Path(tmp), log=lambda x: print(x, flush=True))
    print(f"\ndynid: tracking error {c.tracking:.1e} m, closure residual {c.dynid_closure:.1e} m")
    rows = [("dynid", f"{median(c.walls['dynid']):.3f}", f"{median(c.walls['dynid']) / args.duration:.4f}",
             "-", "-", "-", "-")]
    checks = [("inverse dynamics at MuJoCo-assembled states (same mechanism)", f"{c.id_error:.1e}", f"<= {ID_TOL:g}",
               c.id_error <= ID_TOL)]
    for name in (*(f"MuJoCo {i}" for i in MUJOCO_RUNS), SENSITIVITY):
        force, pos = c.agreement[name]
        if name == SENSITIVITY:
            rows.append((f"{name} (mass x{SENSITIVITY_MASS:g}; not a target)", "-", "-", "-", f"{force * 100:.3f}",
                         f"{pos:.2e}", f"{c.closure_gap[name]:.1e}"))
            continue
        w, ratio = median(c.walls[name]), c.ratio(name)
        rows.append((name, f"{w:.3f}", f"{w / args.duration:.4f}", f"{ratio:.2f}", f"{force * 100:.3f}", f"{pos:.2e}",
                     f"{c.closure_gap[name]:.1e}"))
        checks += [(f"dynid / {name} wall time (median of paired ratios)", f"{ratio:.2f}", f"<= {TARGET_RATIO:g}",
                    ratio <= TARGET_RATIO),
                   (f"forces vs {name}: RMS difference / RMS force (worst actuator)", f"{force * 100:.3f} %",
                    f"<= {TARGET_FORCE * 100:g} %", force <= TARGET_FORCE),
                   (f"positions vs {name}: largest difference", f"{pos:.2e} m", f"<= {TARGET_POSITION:g} m",
                    pos <= TARGET_POSITION)]
    print()
    print(table(["engine", f"median s for {args.duration:g} s", "s per simulated s", "dynid / it (paired)",
                 "force RMS diff %", "position max diff m", "MuJoCo closure gap m"], rows))
    print()
    print(table(["check", "value", "target", "result"], [(n, v, t, "ok" if ok else "FAIL") for n, v, t, ok in checks]))
    ok = all(x[3] for x in checks)
    print(f"\nall targets {'met' if ok else 'NOT met'}" + (" (--quick: not enforced)" if args.quick else ""))
    return 0 if ok or args.quick else 1


if __name__ == "__main__":
    sys.exit(main())
