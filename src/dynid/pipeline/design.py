"""``dynid design``: an optimal (or a given) excitation for a robot, with its diagnosis.

Writes, all or nothing: ``design.json`` (trajectory coefficients, every criterion, the
feasibility verdict with the worst limit, the predicted standard deviation of each base
parameter), ``trajectory.csv`` (the design sampled at ``output.rate_hz`` over one period:
design coordinates and actuator positions, velocities, accelerations), ``params.csv``,
``summary.txt``, the plots ``trajectory.png`` and ``spectrum.png``, and ``timing.json`` (the
search's wall-clock time: the one file that differs between two equal runs).

``kind = "constant_velocity"`` (serial robots; paper 003, Sec. 3.1 and 4.4) designs the friction
experiment instead (:mod:`dynid.excitation.friction_design`) and writes ``design.json`` (the
schedule per joint, the dropped speeds with their reasons, the limits, and under ``trajectory``
what ``dynid simulate`` replays with ``[trajectory] kind = "constant_velocity"``, ``design =
"design.json"``), ``trajectory.csv`` (at ``output.rate_hz``: every joint's position, velocity and
acceleration and the label columns ``cv_joint``, ``cv_speed``, ``cv_direction``,
``cv_repetition``), ``summary.txt`` (per joint: stroke, speeds, steady seconds and samples,
duration), ``speeds.png`` (the speed schedule per joint) and ``timing.json``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from dynid._files import TIMING_FILE, write_timing
from dynid.config.design import DesignConfig
from dynid.errors import ConfigError
from dynid.excitation.optimality import predicted_std
from dynid.errors import InputError
from dynid.excitation.design import DesignLimits, ExcitationDesign, ExcitationProblem
from dynid.excitation.friction_design import FrictionDesign
from dynid.io.output import staged_output
from dynid.model.loading import load_model
from dynid.model.mechanism import Mechanism
from dynid.trajectories import CirclePath
from dynid.trajectories import FourierTrajectory

__all__ = ["ConstantVelocityOutcome", "DesignOutcome", "run_design", "simulate_snippet", "write_design"]


@dataclasses.dataclass(frozen=True, eq=False)
class DesignOutcome:
    design: ExcitationDesign
    problem: ExcitationProblem
    config: DesignConfig

    def summary_text(self) -> str:
        d = self.design
        lines = [
            f"robot       : {self.problem.robot.name}   design coordinates: {', '.join(d.coordinates)}",
            f"design      : {self.config.kind}" + (f", {self.config.harmonics} harmonics at {_f0(d):.4g} Hz" if self.config.kind == "fourier" else ""),
            f"criterion   : {d.criterion} = {d.value:.6g} (initial {d.initial_value:.6g})",
            "all criteria: " + ", ".join(f"{k} {v:.4g}" for k, v in d.criteria.items()),
            f"feasible    : {'yes' if d.success else 'NO - ' + str(d.violation)}",
            f"search      : {d.starts} start(s), seed {d.seed}, {d.evaluations} evaluations",
            "",
            "predicted standard deviations of the base parameters (one period, given noise):",
        ]
        for n, v, s, r in zip(d.base_names, d.nominal_base, d.predicted_std, d.predicted_rel_std_pct):
            lines.append(f"  {n:<14} nominal {v:12.5g}   std {s:10.3g}   {r:8.3g} %")
        return "\n".join(lines)


def _f0(d: ExcitationDesign) -> float:
    t = d.trajectory
    return t.base_frequency_hz if isinstance(t, FourierTrajectory) else getattr(getattr(t, "fourier", None), "base_frequency_hz", float("nan"))


def _limits(cfg: DesignConfig) -> DesignLimits:
    L = cfg.limits
    pos = L.get("position")
    arr = lambda k: np.asarray(L[k], float) if k in L else None  # noqa: E731
    return DesignLimits(
        position=(np.asarray(pos[0], float), np.asarray(pos[1], float)) if pos is not None else None,
        velocity=arr("velocity"), acceleration=arr("acceleration"), force=arr("force"),
        max_condition=L.get("max_condition"),
    )


def run_design(cfg: DesignConfig, progress=None) -> DesignOutcome | ConstantVelocityOutcome:
    robot = load_model(cfg.model, actuated=cfg.actuated, independent=cfg.independent, rotor_inertia=cfg.rotor_inertia)
    if cfg.kind == "constant_velocity":
        return _run_constant_velocity(cfg, robot)
    box = (np.asarray(cfg.box[0], float), np.asarray(cfg.box[1], float)) if cfg.box is not None else None
    pb = ExcitationProblem(
        robot, coordinates=cfg.coordinates, harmonics=cfg.harmonics, base_frequency_hz=cfg.base_frequency_hz,
        optimize_frequency=cfg.optimize_frequency, quintic=cfg.quintic, samples=cfg.samples, criterion=cfg.criterion,
        noise_std=cfg.noise_std, limits=_limits(cfg), box=box,
    )
    if cfg.kind == "fourier":
        design = pb.optimize(starts=cfg.starts, seed=cfg.seed, max_iter=cfg.max_iter, progress=progress)
        return DesignOutcome(design, pb, cfg)
    # paper 001: a circle of the end-effector, evaluated as given
    c = cfg.circle
    if pb.n_u != 2:
        raise ConfigError(f"design.kind = 'circle' needs 2 design coordinates; {robot.name!r} has {pb.n_u}")
    traj = CirclePath(tuple(c["centre"]), c["radius"], c["speed"], turns=c["turns"])
    ok, viol, crit = pb.check(traj, factor=8)
    if not crit:
        raise ConfigError(f"the circle cannot be evaluated: {viol}")
    W = pb.base.regressor(pb.signals(traj, pb.samples * 8, warm=False)[3])
    design = ExcitationDesign(
        trajectory=traj, coordinates=pb.names, criterion=cfg.criterion, value=crit[cfg.criterion],
        initial_value=crit[cfg.criterion], criteria=crit, base_names=pb.base.names,
        predicted_std=predicted_std(W, pb.noise, repetitions=1.0 / 8.0), nominal_base=pb.nominal_base,
        success=ok, violation=viol, starts=0, seed=cfg.seed, elapsed_s=0.0, evaluations=1,
    )
    return DesignOutcome(design, pb, cfg)


def _trajectory_doc(traj) -> dict:
    if isinstance(traj, CirclePath):
        return {"kind": "circle", "centre": list(traj.centre), "radius": traj.radius, "speed": traj.speed,
                "turns": traj.turns, "clockwise": traj.clockwise, "ramp": traj.ramp}
    four = traj if isinstance(traj, FourierTrajectory) else traj.fourier
    return {"kind": "fourier" if isinstance(traj, FourierTrajectory) else "fourier_quintic",
            "base_frequency_hz": four.base_frequency_hz, "a": four.a.tolist(), "b": four.b.tolist(), "q0": four.q0.tolist(),
            "formula": "q_j(t) = q0_j + sum_k a_jk/(w k) sin(w k t) - b_jk/(w k) cos(w k t), w = 2 pi f0"}


def simulate_snippet(outcome: DesignOutcome | ConstantVelocityOutcome, out_dir: str | Path) -> str:
    """The ``[trajectory]`` table of a ``dynid simulate`` config that replays this design from
    ``out_dir/design.json`` (its absolute path, so that the table works in any config): the
    design's kind (``fourier`` for periodic and rest-to-rest Fourier designs, ``circle``,
    ``constant_velocity``) and, for a parallel robot's platform pose, ``coordinates = "task"``."""
    path = json.dumps(str((Path(out_dir) / "design.json").resolve()))  # a JSON string is a TOML basic string
    if isinstance(outcome, ConstantVelocityOutcome):
        kind, extra = "constant_velocity", []
    else:
        traj = outcome.design.trajectory
        kind = "circle" if isinstance(traj, CirclePath) else "fourier"
        extra = ['coordinates = "task"'] if outcome.config.coordinates == "task" else []
        if isinstance(traj, FourierTrajectory):
            extra.append("# periods = 1                  # the periodic design repeated")
    return "\n".join(["[trajectory]                     # dynid simulate: replays this design (same [robot])",
                      f'kind = "{kind}"', f"design = {path}", *extra])


def write_design(outcome: DesignOutcome | ConstantVelocityOutcome, out_dir: str | Path) -> list[str]:
    if isinstance(outcome, ConstantVelocityOutcome):
        return _write_constant_velocity(outcome, out_dir)
    d, pb, cfg = outcome.design, outcome.problem, outcome.config
    traj = d.trajectory
    T = traj.period if isinstance(traj, FourierTrajectory) else traj.duration
    n = max(2, int(round(T * cfg.rate_hz)))
    t = np.arange(n) / cfg.rate_hz
    u, du, ddu = traj.sample(t)
    qa, dqa, ddqa, *_ = pb.signals(traj, n, warm=False) if isinstance(traj, FourierTrajectory) else pb.signals(traj, n, warm=False)
    names = []
    with staged_output(out_dir) as stage:
        doc = {
            "robot": pb.robot.name, "model": cfg.model, "coordinates": list(d.coordinates),
            "actuators": list(pb.act_names), "criterion": d.criterion, "value": d.value,
            "initial_value": d.initial_value, "criteria": d.criteria, "success": d.success,
            "worst_violation": None if d.violation is None else dataclasses.asdict(d.violation),
            "trajectory": _trajectory_doc(traj), "seed": d.seed, "starts": d.starts, "evaluations": d.evaluations,
            "limits": {k: (np.asarray(v).tolist() if v is not None else None)
                                                 for k, v in dataclasses.asdict(pb.limits).items()},
            "noise_std": pb.noise.tolist(),
            "predicted": {"names": list(d.base_names), "nominal": d.nominal_base.tolist(), "std": d.predicted_std.tolist(),
                          "rel_std_pct": [float(x) if np.isfinite(x) else None for x in d.predicted_rel_std_pct],
                          "note": "one period sampled at 8 x design.samples, white noise of noise_std per output channel"},
        }
        (stage / "design.json").write_text(json.dumps(doc, indent=2) + "\n")
        cols = {"t": t}
        for k, c in enumerate(d.coordinates):
            cols[f"u_{c}"], cols[f"du_{c}"], cols[f"ddu_{c}"] = u[:, k], du[:, k], ddu[:, k]
        for k, a in enumerate(pb.act_names):
            cols[f"q_{a}"], cols[f"dq_{a}"], cols[f"ddq_{a}"] = qa[:, k], dqa[:, k], ddqa[:, k]
        np.savetxt(stage / "trajectory.csv", np.column_stack(list(cols.values())), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.17g")
        with open(stage / "params.csv", "w") as fh:
            fh.write("name,nominal,predicted_std,predicted_rel_std_pct\n")
            for nm, v, s, r in zip(d.base_names, d.nominal_base, d.predicted_std, d.predicted_rel_std_pct):
                fh.write(f"{nm},{v!r},{s!r},{r!r}\n")
        (stage / "summary.txt").write_text(outcome.summary_text() + "\n")
        write_timing(stage, {"design_s": d.elapsed_s})
        names += ["design.json", "trajectory.csv", "params.csv", "summary.txt", TIMING_FILE]
        if cfg.plots:
            from dynid.report.plots import plot_design

            plot_design(t, qa, dqa, ddqa, pb.act_names, pb.limits, u, d.coordinates, stage / "trajectory.png", stage / "spectrum.png")
            names += ["trajectory.png", "spectrum.png"]
    return names


# ---------------------------------------------------------------------- kind = "constant_velocity"
@dataclasses.dataclass(frozen=True, eq=False)
class ConstantVelocityOutcome:
    """A designed constant-velocity friction experiment (paper 003, Sec. 3.1;
    :func:`dynid.excitation.friction_design.design_constant_velocity`)."""

    design: FrictionDesign
    config: DesignConfig
    robot: str
    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    elapsed_s: float = 0.0

    def summary_text(self) -> str:
        d = self.design
        e = d.experiment
        lines = [
            f"robot       : {self.robot}",
            "design      : constant_velocity (paper 003, Sec. 3.1): one joint at a time, forward and back at each speed",
            f"duration    : {d.duration:.3f} s ({len(d.joints)} joint(s), {e.repetitions} repetition(s) per speed)",
            f"windows     : at least {d.window:g} s and at most {d.max_window:g} s of steady motion per speed and "
            f"direction{'' if d.min_span is None else f', the shortest covering {d.min_span:g}'}; samples at {d.rate_hz:g} Hz, matched = after skip = {d.skip:g} s at each end "
            f"(the extraction needs {d.min_samples})",
            f"switching   : quintic, at least {e.switch:g} s, within each joint's acceleration limit; rest {e.rest:g} s",
        ]
        for j in d.joints:
            lines += ["", f"{j.name}: stroke {j.stroke:.4g} about the pose {e.pose[j.index]:.4g} "
                          f"(limits [{self.lower[j.index]:.4g}, {self.upper[j.index]:.4g}]), velocity limit "
                          f"{j.velocity_limit:g}, acceleration limit {j.acceleration_limit:g}, {j.duration:.2f} s",
                      f"  {'speed':>10} {'steady s':>9} {'span':>8} {'samples':>8} {'matched':>8}"]
            for lv in j.levels:
                lines.append(f"  {lv.speed:10.4g} {lv.window:9.3f} {lv.span:8.4g} {lv.samples:8d} {lv.matched:8d}")
            lines += [f"  {line}" for line in j.dropped]
        if not d.dropped:
            lines += ["", "no speed dropped"]
        return "\n".join(lines)


_SERIAL_ONLY = ("design.kind = 'constant_velocity' is for serial robots: an actuator of a closed chain cannot move "
                "alone (passive joints move with it, and their friction enters every actuator force, so "
                "(tau(q, v) - tau(q, -v)) / 2 is no single joint's friction)")


def _limit(cfg: DesignConfig, key: str, n: int) -> np.ndarray:
    if key not in cfg.limits:
        raise ConfigError(f"design.kind = 'constant_velocity' needs limits.{key} (the {'top speed' if key == 'velocity' else 'switching phases'} "
                          f"of each joint is sized from it)")
    arr = np.array(cfg.limits[key], dtype=float, ndmin=1)
    if arr.size not in (1, n):
        raise ConfigError(f"limits.{key} has {arr.size} entries for {n} joints")
    return np.broadcast_to(arr, (n,)).copy()


def _run_constant_velocity(cfg: DesignConfig, robot) -> ConstantVelocityOutcome:
    import time

    from dynid.excitation.friction_design import design_constant_velocity

    t0 = time.perf_counter()
    if isinstance(robot, Mechanism):
        raise ConfigError(_SERIAL_ONLY)
    names = tuple(robot.joint_names)
    n = len(names)
    lo, hi = robot.position_limits()
    if "position" in cfg.limits:
        plo, phi = (np.array(x, dtype=float) for x in cfg.limits["position"])
        if plo.size != n:
            raise ConfigError(f"limits.position has {plo.size} entries for {n} joints")
        outside = [f"{nm}: [{a:g}, {b:g}] not inside [{c:g}, {d:g}]" for nm, a, b, c, d in zip(names, plo, phi, lo, hi)
                   if a < c or b > d]
        if outside:
            raise ConfigError(f"limits.position leaves the joint limits of {'; '.join(outside)}")
        lo, hi = plo, phi
    vel, acc = _limit(cfg, "velocity", n), _limit(cfg, "acceleration", n)
    v = dict(cfg.constant_velocity or {})
    pose = 0.5 * (lo + hi)
    if "pose" in v:
        if len(v["pose"]) != n:
            raise ConfigError(f"design.pose has {len(v['pose'])} entries; {robot.name!r} has {n} joints")
        pose = np.array(v.pop("pose"), dtype=float)
    try:
        design = design_constant_velocity(names, pose, lo, hi, vel, acc, rate_hz=cfg.rate_hz, **v)
    except InputError as exc:
        raise ConfigError(f"design: {exc}") from None
    return ConstantVelocityOutcome(design, cfg, robot.name, names, lo, hi, vel, acc, time.perf_counter() - t0)


def constant_velocity_document(design: FrictionDesign) -> dict:
    """What ``dynid simulate`` needs to rebuild the experiment bit for bit (``design.json``'s
    ``trajectory``; floats written by ``repr``, which round-trips)."""
    e = design.experiment
    return {"kind": "constant_velocity", "names": list(e.names), "joints": [e.names[j] for j in e.joints],
            "plan": [[[float(v), float(w)] for v, w in p] for p in e.plan], "pose": e.pose.tolist(),
            "lower": e.lower.tolist(), "upper": e.upper.tolist(),
            "max_acceleration": np.broadcast_to(np.asarray(e.max_acceleration, float), e.pose.shape).tolist(),
            "switch": float(e.switch), "rest": float(e.rest), "repetitions": int(e.repetitions)}


def _write_constant_velocity(outcome: ConstantVelocityOutcome, out_dir: str | Path) -> list[str]:
    from dynid.trajectories.constant_velocity import LABEL_COLUMNS

    d, cfg = outcome.design, outcome.config
    e = d.experiment
    n = int(np.floor(d.duration * cfg.rate_hz + 1e-9)) + 1
    t = np.arange(n) / cfg.rate_hz
    q, dq, ddq = e.sample(t)
    labels = e.labels(t)
    doc = {
        "robot": outcome.robot, "model": cfg.model, "kind": "constant_velocity", "coordinates": list(outcome.names),
        "duration_s": d.duration,
        "rate_hz": cfg.rate_hz, "window": d.window, "max_window": d.max_window, "min_span": d.min_span,
        "skip": d.skip,
        "min_samples": d.min_samples,
        "limits": {"position": {"lower": outcome.lower.tolist(), "upper": outcome.upper.tolist()},
                   "velocity": outcome.velocity.tolist(), "acceleration": outcome.acceleration.tolist()},
        "joints": [{"name": j.name, "stroke": j.stroke, "pose": float(e.pose[j.index]), "duration_s": j.duration,
                    "velocity_limit": j.velocity_limit, "acceleration_limit": j.acceleration_limit,
                    "speeds": [dataclasses.asdict(lv) for lv in j.levels], "dropped": list(j.dropped)}
                   for j in d.joints],
        "dropped": list(d.dropped),
        "trajectory": constant_velocity_document(d),
        "replay": "dynid simulate: [trajectory] kind = \"constant_velocity\", design = \"<this file>\"",
    }
    names = []
    with staged_output(out_dir) as stage:
        (stage / "design.json").write_text(json.dumps(doc, indent=2) + "\n")
        cols = {"t": t}
        for k, a in enumerate(outcome.names):
            cols[f"q_{a}"], cols[f"dq_{a}"], cols[f"ddq_{a}"] = q[:, k], dq[:, k], ddq[:, k]
        for c in LABEL_COLUMNS:
            cols[c] = labels[c]
        np.savetxt(stage / "trajectory.csv", np.column_stack(list(cols.values())), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.17g")
        (stage / "summary.txt").write_text(outcome.summary_text() + "\n")
        write_timing(stage, {"design_s": outcome.elapsed_s})
        names += ["design.json", "trajectory.csv", "summary.txt", TIMING_FILE]
        if cfg.plots:
            from dynid.report.plots import plot_speed_schedule

            plot_speed_schedule(d, t, dq, stage / "speeds.png")
            names.append("speeds.png")
    return names
