"""``dynid design``: an optimal (or a given) excitation for a robot, with its diagnosis.

Writes, all or nothing: ``design.json`` (trajectory coefficients, every criterion, the
feasibility verdict with the worst limit, the predicted standard deviation of each base
parameter), ``trajectory.csv`` (the design sampled at ``output.rate_hz`` over one period:
design coordinates and actuator positions, velocities, accelerations), ``params.csv``,
``summary.txt``, the plots ``trajectory.png`` and ``spectrum.png``, and ``timing.json`` (the
search's wall-clock time: the one file that differs between two equal runs).
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
from dynid.excitation.design import DesignLimits, ExcitationDesign, ExcitationProblem
from dynid.io.output import staged_output
from dynid.model.loading import load_model
from dynid.trajectories import CirclePath
from dynid.trajectories import FourierTrajectory

__all__ = ["DesignOutcome", "run_design", "write_design"]


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


def run_design(cfg: DesignConfig, progress=None) -> DesignOutcome:
    robot = load_model(cfg.model, actuated=cfg.actuated, independent=cfg.independent)
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


def write_design(outcome: DesignOutcome, out_dir: str | Path) -> list[str]:
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
