"""``dynid friction``: friction curves from bidirectional constant-velocity runs (paper 003, Sec. 3.1, 4.4).

Reads the log of a constant-velocity experiment (``dynid simulate`` with ``[trajectory] kind =
"constant_velocity"``, or a measured one with the same label columns), extracts one friction
point per joint, speed and repetition (:mod:`dynid.signals.friction_points`), fits the
configured curves to each joint's points (:mod:`dynid.estimation.friction_curves`) and
compares them on held-out points. Writes, all or nothing:

* ``friction.json``: the points; per joint and model the coefficients fitted to all points
  with standard errors, the fit's RMSE and reduced chi-square, and the held-out RMSE (fitted on
  the other points); the Table 4-style sums over the joints; notes;
* ``summary.txt``: the same as tables;
* ``points.csv``: the extracted points (with the seconds each window lost to ``skip`` and the
  steady-state rule, ``dropped_fwd_s``, ``dropped_bwd_s``);
* ``friction.png`` (paper 003, Fig. 7 in kind): per joint the points with 95 % error bars
  (held-out ones open) and the fitted curves;
* ``config.toml``: the configuration used.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from dynid import __version__
from dynid.config import TIME_UNITS
from dynid.config.friction import FrictionConfig
from dynid.errors import ConfigError, InputError
from dynid.estimation.friction_curves import MODELS, CurveFit, fit_curve, held_out_split
from dynid.io.output import staged_output
from dynid.io.readers import TableReader
from dynid.pipeline.data import build_system, read_log, to_actuator_space
from dynid.signals.friction_points import FrictionPoints, extract_friction_points

__all__ = ["FrictionOutcome", "JointFriction", "run_friction", "write_friction", "FRICTION_FORMAT"]

FRICTION_FORMAT = "dynid-friction-1"
Progress = Callable[[str, int, int], None]


@dataclasses.dataclass(frozen=True, eq=False)
class JointFriction:
    """One joint: its points, each model's fit to all of them, and the held-out comparison
    (``held_out``: mask of the points held out; ``held_out_rmse``: model -> RMSE of the fit to
    the other points on them, NaN when too few points remain to fit that model)."""

    name: str
    points: FrictionPoints
    fits: dict[str, CurveFit]
    held_out: np.ndarray
    held_out_rmse: dict[str, float]


@dataclasses.dataclass(frozen=True, eq=False)
class FrictionOutcome:
    joints: tuple[JointFriction, ...]
    config: FrictionConfig
    robot: str
    notes: tuple[str, ...]
    robot_source: str = ""  # the description's file (or builtin:<name>) the robot comes from

    def table4(self, key: str = "held_out") -> dict[str, dict]:
        """Per model: RMSE per joint and their sum (paper 003, Table 4), of the fits to all points
        (``key = "fit"``) or on the held-out points (``"held_out"``)."""
        out = {}
        for m in self.config.models:
            per = {j.name: (j.fits[m].rmse if key == "fit" else j.held_out_rmse.get(m, float("nan"))) for j in self.joints}
            out[m] = {"per_joint": per, "total": float(sum(per.values()))}
        return out

    def summary_text(self) -> str:
        cfg = self.config
        lines = [f"robot   : {self.robot}" + (f" ({self.robot_source})" if self.robot_source else ""),
                 f"points  : {sum(len(j.points) for j in self.joints)} friction points on {len(self.joints)} joint(s); "
                 f"held out: {cfg.held_out}"]
        for j in self.joints:
            p = j.points
            lines += ["", f"{j.name}: {len(p)} points, speeds {p.speed.min():.3g} to {p.speed.max():.3g}; seconds left out "
                          f"per window (skip{' + settling' if cfg.settle else ''}): forward {p.dropped_fwd.min():.2g} to "
                          f"{p.dropped_fwd.max():.2g}, backward {p.dropped_bwd.min():.2g} to {p.dropped_bwd.max():.2g}"]
            for m in cfg.models:
                f = j.fits[m]
                coef = ", ".join(f"{n} {v:.4g}" + (" (at bound)" if b else f" ± {s:.2g}")
                                 for n, v, s, b in zip(f.names, f.params, f.std, f.at_bound))
                lines.append(f"  {MODEL_LABELS[m]:<24} {coef}")
        for key, title in (("fit", "fitting RMSE (all points)"), ("held_out", "held-out RMSE")):
            table = self.table4(key)
            names = [j.name for j in self.joints]
            lines += ["", f"{title} [N*m or N], per joint and total (paper 003, Table 4):",
                      f"  {'model':<24}" + "".join(f"{n:>11}" for n in names) + f"{'total':>11}"]
            for m in cfg.models:
                row = table[m]
                lines.append(f"  {MODEL_LABELS[m]:<24}" + "".join(f"{row['per_joint'][n]:11.4g}" for n in names)
                             + f"{row['total']:11.4g}")
        if self.notes:
            lines += [""] + [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


MODEL_LABELS = {"coulomb_viscous": "1 Coulomb-viscous", "stribeck": "2 Stribeck", "power_law": "3 power law",
                "smooth_stribeck": "4 improved Stribeck", "arctan_stribeck": "arctan Stribeck (a=1)"}


def _window_slice(cfg: FrictionConfig, reader: TableReader, n_rows: int) -> slice:
    """The rows ``[data]`` selects (as :func:`dynid.pipeline.data.read_log` cuts them)."""
    spec = cfg.data
    if spec.rows is not None:
        return slice(*spec.rows)
    if spec.time_window is None:
        return slice(None)
    if spec.time is not None:
        t = TableReader(spec.time.file or spec.file).columns([spec.time.column])[:, 0] * TIME_UNITS[spec.time.unit]
    else:
        t = np.arange(n_rows) / spec.sample_rate_hz
    idx = np.flatnonzero((t >= spec.time_window[0]) & (t < spec.time_window[1]))
    return slice(int(idx[0]), int(idx[-1]) + 1)


def _labels(cfg: FrictionConfig, n_rows: int) -> dict[str, np.ndarray]:
    spec = cfg.data
    reader = TableReader(spec.position.file or spec.file)
    cols = [cfg.labels[k] for k in ("joint", "speed", "direction", "repetition")]
    try:
        arr = reader.columns(cols)
    except InputError as exc:
        raise InputError(f"{exc} (dynid friction reads the label columns of a constant-velocity log, "
                         "friction.labels; dynid simulate writes them for trajectory kind 'constant_velocity')") from None
    arr = arr[_window_slice(cfg, reader, arr.shape[0])]
    if arr.shape[0] != n_rows:
        raise InputError(f"data: the label columns have {arr.shape[0]} rows, the positions {n_rows}")
    return dict(zip(("joint", "speed", "direction", "repetition"), arr.T))


def run_friction(cfg: FrictionConfig, progress: Progress | None = None) -> FrictionOutcome:
    """Extract the points, fit the curves, compare them on held-out points (nothing is written)."""
    system = build_system(cfg.robot)
    if system.kind != "serial":
        raise ConfigError(f"robot.model: {system.model.name!r} is a closed-loop mechanism; dynid friction is for serial "
                          "robots (an actuator of a closed chain cannot move alone, and passive joints' friction enters "
                          "every actuator force)")
    names = tuple(system.actuator_names)
    n = len(names)
    unknown = [j for j in cfg.joints or () if j not in names]
    if unknown:
        raise ConfigError(f"friction.joints: {unknown} are not joints of {system.model.name!r} ({', '.join(names)})")
    ds = read_log(cfg.data, n, names, "data")
    ds, notes = to_actuator_space(ds, system, "data")
    lab = _labels(cfg, ds.n_samples)
    pts = extract_friction_points(ds.t, ds.q, ds.tau, lab["joint"], lab["speed"], lab["direction"], lab["repetition"],
                                  skip=cfg.skip, min_samples=cfg.min_samples, names=names, settle=cfg.settle,
                                  settle_block=cfg.settle_block, settle_k=cfg.settle_k, settle_tol=cfg.settle_tol)
    notes = list(notes) + list(pts.notes)
    tested = sorted(set(pts.joint.tolist()))
    if cfg.joints is not None:
        missing = [j for j in cfg.joints if names.index(j) not in tested]
        if missing:
            raise ConfigError(f"friction.joints: the log has no friction point of {missing} "
                              f"(it tests {[names[k] for k in tested]})")
        tested = [names.index(j) for j in cfg.joints]
    off = np.abs(pts.speed / pts.speed_cmd - 1) > 0.02
    for k in np.flatnonzero(off):
        notes.append(f"{names[pts.joint[k]]} at {pts.speed_cmd[k]:g}: measured {pts.speed[k]:.3g} "
                     f"({100 * (pts.speed[k] / pts.speed_cmd[k] - 1):+.0f} %): the loop does not hold this speed in the "
                     "window; the point is likely biased (a longer window or skip, or a stiffer loop)")
    out = []
    total = len(tested) * len(cfg.models) * (1 if cfg.held_out == "none" else 2)
    done = 0
    for k in tested:
        p = pts.select(pts.joint == k)
        fits, rmse = {}, {}
        held = np.zeros(len(p), dtype=bool) if cfg.held_out == "none" else held_out_split(p.speed_cmd, p.repetition,
                                                                                           cfg.held_out)
        for m in cfg.models:
            try:
                fits[m] = fit_curve(m, p.speed, p.force, p.sigma)
            except InputError as exc:
                raise InputError(f"{names[k]}: {exc}") from None
            done += 1
            if progress:
                progress("friction fits", done, total)
            if cfg.held_out == "none":
                continue
            train = ~held
            if train.sum() < len(MODELS[m]) or not held.any():
                notes.append(f"{names[k]}: {int(train.sum())} points left to fit {m} after holding out "
                             f"{int(held.sum())}; no held-out RMSE")
                rmse[m] = float("nan")
            else:
                fit = fit_curve(m, p.speed[train], p.force[train], p.sigma[train])
                rmse[m] = float(np.sqrt(np.mean((fit.force(p.speed[held]) - p.force[held]) ** 2)))
            done += 1
            if progress:
                progress("friction fits", done, total)
        out.append(JointFriction(name=names[k], points=p, fits=fits, held_out=held, held_out_rmse=rmse))
    return FrictionOutcome(joints=tuple(out), config=cfg, robot=system.model.name, notes=tuple(notes),
                           robot_source=getattr(system.model, "source", "") or str(cfg.robot.model))


def _json(outcome: FrictionOutcome) -> dict:
    cfg = outcome.config
    joints = {}
    points = []
    for j in outcome.joints:
        p = j.points
        for i in range(len(p)):
            points.append({"joint": j.name, "speed_cmd": float(p.speed_cmd[i]), "speed": float(p.speed[i]),
                           "force": float(p.force[i]), "sigma": float(p.sigma[i]), "spread": float(p.spread[i]),
                           "n_samples": int(p.n[i]), "stroke": float(p.stroke[i]), "repetition": int(p.repetition[i]),
                           "dropped_fwd_s": float(p.dropped_fwd[i]), "dropped_bwd_s": float(p.dropped_bwd[i]),
                           "held_out": bool(j.held_out[i])})
        models = {}
        for m, f in j.fits.items():
            models[m] = {
                "coefficients": {n: {"value": float(v), "std": (None if not np.isfinite(s) else float(s)),
                                     "at_bound": bool(b)} for n, v, s, b in zip(f.names, f.params, f.std, f.at_bound)},
                "rmse": f.rmse, "chi2_red": f.chi2_red, "n_points": f.n_points, "solver": f.message,
                "held_out_rmse": j.held_out_rmse.get(m),
            }
        joints[j.name] = {"n_points": len(p), "n_held_out": int(j.held_out.sum()), "models": models}
    return {
        "format": FRICTION_FORMAT,
        "dynid_version": __version__,
        "robot": outcome.robot,
        "robot_source": outcome.robot_source,
        "method": "paper 003 Sec. 3.1: F_f = (tau(q, v) - tau(q, -v)) / 2 at matched positions of the windows' steady "
                  "parts; bounded weighted least squares, std from the Jacobian scaled by the reduced chi-square",
        "settings": {"models": list(cfg.models), "skip_s": cfg.skip, "min_samples": cfg.min_samples,
                     "settle": cfg.settle, "settle_block_s": cfg.settle_block, "settle_k": cfg.settle_k,
                     "settle_tol": cfg.settle_tol,
                     "held_out": cfg.held_out, "labels": dict(cfg.labels)},
        "units": "speeds rad/s (m/s for prismatic joints), friction N*m (N)",
        "joints": joints,
        "table4_fit_rmse": outcome.table4("fit"),
        "table4_held_out_rmse": outcome.table4("held_out") if cfg.held_out != "none" else None,
        "points": points,
        "notes": list(outcome.notes),
    }


def write_friction(outcome: FrictionOutcome, out_dir: str | Path) -> list[str]:
    """Write the files of the module docstring into ``out_dir`` (all or nothing)."""
    cfg = outcome.config
    names = ["friction.json", "summary.txt", "points.csv"]
    with staged_output(out_dir) as stage:
        (stage / "friction.json").write_text(json.dumps(_json(outcome), indent=2, allow_nan=True) + "\n")
        (stage / "summary.txt").write_text(outcome.summary_text() + "\n")
        rows = ["joint,speed_cmd,speed,force,sigma,spread,n_samples,repetition,held_out,dropped_fwd_s,dropped_bwd_s"]
        for j in outcome.joints:
            p = j.points
            rows += [f"{j.name},{p.speed_cmd[i]:.17g},{p.speed[i]:.17g},{p.force[i]:.17g},{p.sigma[i]:.17g},"
                     f"{p.spread[i]:.17g},{p.n[i]},{p.repetition[i]},{int(j.held_out[i])},{p.dropped_fwd[i]:.6g},"
                     f"{p.dropped_bwd[i]:.6g}" for i in range(len(p))]
        (stage / "points.csv").write_text("\n".join(rows) + "\n")
        if cfg.plots:
            from dynid.report.plots import plot_friction

            plot_friction(outcome.joints, cfg.models, stage / "friction.png", labels=MODEL_LABELS)
            names.append("friction.png")
        if cfg.source is not None:
            (stage / "config.toml").write_text(Path(cfg.source).read_text())
            names.append("config.toml")
    return names
