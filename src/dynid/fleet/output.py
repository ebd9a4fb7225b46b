"""The outputs of ``dynid fleet``, written all at once (staged): ``fleet.json``, ``robots.csv``,
``logs.csv``, ``estimates.npz``, ``summary.txt``, ``report.html``, ``spread.png``, ``drift.png``,
``fleet.toml`` (the configuration) and ``timing.json``. Every file but ``timing.json`` depends on
the logs' results alone: a rerun with the same inputs writes the same bytes."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from dynid import __version__
from dynid._files import TIMING_FILE, save_npz, write_timing
from dynid.fleet.analysis import DAYS_PER_YEAR, FleetResult, RobotSummary
from dynid.io.output import staged_output

__all__ = ["FLEET_FILES", "fleet_dict", "summary_text", "write_fleet"]

FLEET_FILES = ("fleet.json", "robots.csv", "logs.csv", "estimates.npz", "summary.txt", "report.html", "spread.png",
               "drift.png", "fleet.toml", TIMING_FILE)


def _num(x: Any) -> Any:
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_num(v) for v in np.asarray(x, float).tolist()] if np.ndim(x) else _num(float(x))
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    v = float(x)
    return v if np.isfinite(v) else None


def _plain(d: Any) -> Any:
    if isinstance(d, dict):
        return {str(k): _plain(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_plain(v) for v in d]
    if isinstance(d, np.ndarray):
        return _num(d)
    if isinstance(d, (float, np.floating)):
        return _num(d)
    if isinstance(d, (np.integer,)):
        return int(d)
    if isinstance(d, np.bool_):
        return bool(d)
    return d


def _robot_dict(r: RobotSummary, result: FleetResult) -> dict[str, Any]:
    out: dict[str, Any] = {"robot": r.robot, "model": r.model, "logs": list(r.logs), "identified_logs": list(r.ok_logs),
                           "failed_logs": [{"index": i, "file": result.logs[i].file, "error": result.logs[i].error}
                                           for i in r.logs if not result.logs[i].ok]}
    if r.error is not None:
        return {**out, "error": r.error}
    f = r.fused
    out.update({
        "params": _num(f.params), "std": _num(np.sqrt(np.diag(f.cov_scaled))),
        "std_reported": _num(np.sqrt(np.diag(f.cov))),
        "homogeneity": {"chi2": f.chi2, "dof": f.dof, "p_value": f.p_value,
                        "test": "the robot's logs estimate one parameter vector (with their reported covariances)"},
        "heldout": r.heldout.to_dict() | {"rows_per_joint": _num(r.heldout.rows_per_channel)},
        "nominal_heldout": r.nominal.to_dict() | {"rows_per_joint": _num(r.nominal.rows_per_channel)},
        "prior_comparison": r.prior,
        "outlier": None if r.outlier is None else {
            "d2": r.outlier.d2, "dof": r.outlier.dof, "threshold": r.outlier.threshold,
            "chi2_threshold": r.outlier.chi2_threshold, "p_value": r.outlier.p_value,
            "outlier": r.outlier.outlier, "contributions": _num(r.outlier.contributions)},
        "drift": None if r.drift is None else list(r.drift),
        "drifting_parameters": list(r.drift_params),
        "changed_parameters": list(r.change_params),
    })
    return out


def fleet_dict(result: FleetResult, source: Path | None = None) -> dict[str, Any]:
    """The content of ``fleet.json`` (no timings)."""
    models = [{"model": m.model, "names": list(m.names), "expressions": list(m.expressions), "robots": list(m.robots),
               "spread": {k: _num(v) for k, v in m.spread.items()},
               "scatter_factors": _num(m.factors), "scatter_factor_robots": m.factor_robots} for m in result.models]
    logs = [{"index": log.index, "robot": log.robot, "file": log.file, "days": log.days, "ok": log.ok, "error": log.error,
             "sha256": log.sha256, "method": log.method, "n_train": log.n_train,
             "heldout_rmse": None if log.rmse is None else _num(log.rmse),
             "heldout_rel_rmse_pct": None if log.rmse is None else _num(100 * log.rmse / log.rms),
             "nominal_rmse": None if log.nominal_rmse is None else _num(log.nominal_rmse),
             "verdict": log.verdict or None, "beats_nominal": log.beats_nominal if log.ok else None}
            for log in result.logs]
    return _plain({
        "dynid_version": __version__,
        "config_file": None if source is None else str(source),
        "alpha": result.alpha,
        "first_date": result.first_date,
        "days_per_year": DAYS_PER_YEAR,
        "n_logs": len(result.logs), "n_failed": len(result.failures),
        "methods": {
            "pooling": "information fusion of the robot's logs: (sum C_i^-1)^-1 sum C_i^-1 theta_i, the WLS of their "
                       "stacked compressed factors (dynid.fleet.statistics.fuse)",
            "scatter_factors": "per parameter, the median over robots of the logs' scatter about their robot's mean "
                               "relative to their variances (>= 1); the variances of the drift tests and the pooled "
                               "covariance are scaled by it (dynid.fleet.statistics.scatter_factors)",
            "outliers": "Mahalanobis distance to the other robots' median with the robot's own (scaled) covariance "
                        "plus the others' robust spread, against the 1 - alpha quantile of the largest such distance of "
                        "simulated homogeneous fleets (parametric bootstrap, single-step max-T, fixed seed; the "
                        "population spread at its 95 % upper bound: conservative); p_value family-wise over the robots",
            "drift": "per parameter a weighted linear trend over the dated logs (interval at 1 - alpha / p) and a "
                     "change-point test (max of the standardized mean shifts, Bonferroni bound), each Bonferroni over "
                     "the p parameters",
        },
        "models": models, "robots": [_robot_dict(r, result) for r in result.robots], "logs": logs,
    })


def _csv(rows: list[list[Any]]) -> str:
    import csv

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    for row in rows:
        w.writerow(["" if v is None else (f"{v:.10g}" if isinstance(v, float) else v) for v in row])
    return buf.getvalue()


def robots_csv(result: FleetResult) -> str:
    """One row per robot and base parameter: estimate, std, fleet median, outlier, drift."""
    rows: list[list[Any]] = [["robot", "model", "parameter", "estimate", "std", "fleet_median", "fleet_spread",
                              "slope_per_year", "slope_low_per_year", "slope_high_per_year", "drift", "change",
                              "outlier_robot", "logs_identified", "logs_failed"]]
    medians = {m.model: m for m in result.models}
    for r in result.robots:
        if r.error is not None:
            rows.append([r.robot, r.model, "", None, None, None, None, None, None, None, "", "", "", len(r.ok_logs),
                         len(r.logs) - len(r.ok_logs)])
            continue
        m = medians[r.model]
        std = np.sqrt(np.diag(r.cov))
        for j, name in enumerate(result.logs[r.ok_logs[0]].names):
            d = r.drift[j] if r.drift is not None else None
            rows.append([r.robot, r.model, name, float(r.params[j]), float(std[j]),
                         float(m.spread["median"][j]) if name in m.names else None,
                         float(m.spread["std"][j]) if name in m.names else None,
                         None if d is None else d["slope_per_year"],
                         None if d is None else d["slope_interval"][0] * DAYS_PER_YEAR,
                         None if d is None else d["slope_interval"][1] * DAYS_PER_YEAR,
                         "" if d is None else ("yes" if d["drift"] else "no"),
                         "" if d is None else ("yes" if d["change"] else "no"),
                         "" if r.outlier is None else ("yes" if r.outlier.outlier else "no"),
                         len(r.ok_logs), len(r.logs) - len(r.ok_logs)])
    return _csv(rows)


def logs_csv(result: FleetResult) -> str:
    rows: list[list[Any]] = [["index", "robot", "file", "days", "ok", "heldout_mean_rel_rmse_pct", "beats_nominal", "error"]]
    for log in result.logs:
        rel = None if log.rmse is None else float(np.nanmean(100 * log.rmse / log.rms))
        rows.append([log.index, log.robot, log.file, log.days, "yes" if log.ok else "no", rel,
                     "" if not log.ok else ("yes" if log.beats_nominal else "no"), log.error])
    return _csv(rows)


def estimates_arrays(result: FleetResult) -> dict[str, np.ndarray]:
    """``estimates.npz``: per log (index order) and per robot (report order) the estimates and
    covariances (NaN where a log failed or a robot has none), with their names."""
    p = max((len(log.names) for log in result.logs if log.ok), default=0)

    def pad(v, shape):
        out = np.full(shape, np.nan)
        if v is not None and np.shape(v) == shape:
            out[...] = v
        return out

    ok = [r for r in result.robots]
    return {
        "log_index": np.array([log.index for log in result.logs]),
        "log_robot": np.array([log.robot for log in result.logs], dtype=str),
        "log_days": np.array([np.nan if log.days is None else log.days for log in result.logs]),
        "log_ok": np.array([log.ok for log in result.logs]),
        "log_params": np.array([pad(log.params, (p,)) for log in result.logs]).reshape(len(result.logs), p),
        "log_cov": np.array([pad(log.cov, (p, p)) for log in result.logs]).reshape(len(result.logs), p, p),
        "robot": np.array([r.robot for r in ok], dtype=str),
        "robot_params": np.array([pad(r.params, (p,)) for r in ok]).reshape(len(ok), p),
        "robot_cov": np.array([pad(r.cov, (p, p)) for r in ok]).reshape(len(ok), p, p),
        "robot_cov_reported": np.array([pad(None if r.fused is None else r.fused.cov, (p, p)) for r in ok]).reshape(len(ok), p, p),
    }


def summary_text(result: FleetResult) -> str:
    """What the CLI prints: per robot its logs, verdict, outlier and drift; the failed logs."""
    lines = [f"Fleet: {len(result.robots)} robots, {len(result.logs)} logs ({len(result.failures)} failed), "
             f"alpha = {result.alpha:g}", ""]
    rows = [("robot", "model", "logs ok", "held-out rel RMSE %", "nominal %", "vs prior", "outlier d2 / thr", "drift",
             "change")]
    for r in result.robots:
        if r.error is not None:
            rows.append((r.robot, r.model, f"0/{len(r.logs)}", "-", "-", "-", "-", "-", "-"))
            continue
        pr = r.prior
        vs = "beats" if pr["beats_nominal"] else ("ties" if pr["tie"] else "loses")
        out = "-" if r.outlier is None else f"{r.outlier.d2:.1f} / {r.outlier.threshold:.1f}" + (" OUTLIER" if r.outlier.outlier else "")
        drift = "-" if r.drift is None else (", ".join(r.drift_params) or "none")
        change = "-" if r.drift is None else (", ".join(r.change_params) or "none")
        rows.append((r.robot, r.model, f"{len(r.ok_logs)}/{len(r.logs)}", f"{pr['identified_mean_rel_rmse_pct']:.3g}",
                     f"{pr['nominal_mean_rel_rmse_pct']:.3g}", vs, out, drift, change))
    w = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    table = ["  ".join(c.ljust(x) for c, x in zip(row, w)).rstrip() for row in rows]
    table.insert(1, "-" * len(table[0]))
    lines += table
    for r in result.robots:
        if r.drift is None:
            continue
        for d in r.drift:
            if d["drift"]:
                lo, hi = (v * DAYS_PER_YEAR for v in d["slope_interval"])
                lines.append(f"drift {r.robot} {d['name']}: {d['slope_per_year']:+.4g} per year "
                             f"[{lo:+.4g}, {hi:+.4g}] (p = {d['trend_p_bonferroni']:.2g}, Bonferroni over the parameters)")
            if d["change"]:
                lines.append(f"change {r.robot} {d['name']}: a step of {d['change_shift']:+.4g} from log "
                             f"{d['change_after_log']} on (p <= {d['change_p_bonferroni']:.2g})")
    for r in result.robots:
        if r.outlier is not None and r.outlier.outlier:
            names = result.logs[r.ok_logs[0]].names
            top = np.argsort(r.outlier.contributions)[::-1][:3]
            lines.append(f"outlier {r.robot}: d2 = {r.outlier.d2:.1f} > {r.outlier.threshold:.1f}; furthest in "
                         + ", ".join(f"{names[i]} ({r.outlier.contributions[i]:.0f})" for i in top))
    for r in result.robots:
        if r.error is not None:
            lines.append(f"robot {r.robot}: {r.error}")
    for log in result.failures:
        lines.append(f"failed log {log.index} ({log.robot}, {log.file}): {log.error}")
    return "\n".join(lines)


def write_fleet(result: FleetResult, out_dir: str | Path, source: Path | None = None) -> list[str]:
    """Write every output of ``result`` into ``out_dir``, all or nothing."""
    from dynid.fleet.report import plot_drift, plot_spread, write_fleet_html

    names = []
    with staged_output(out_dir) as stage:
        doc = fleet_dict(result, source)
        (stage / "fleet.json").write_text(json.dumps(doc, indent=2) + "\n")
        (stage / "robots.csv").write_text(robots_csv(result))
        (stage / "logs.csv").write_text(logs_csv(result))
        save_npz(stage / "estimates.npz", estimates_arrays(result))
        (stage / "summary.txt").write_text(summary_text(result) + "\n")
        plot_spread(result, stage / "spread.png")
        plot_drift(result, stage / "drift.png")
        write_fleet_html(result, doc, stage / "report.html", [stage / "spread.png", stage / "drift.png"])
        names += ["fleet.json", "robots.csv", "logs.csv", "estimates.npz", "summary.txt", "spread.png", "drift.png",
                  "report.html"]
        if source is not None:
            (stage / "fleet.toml").write_text(Path(source).read_text())
            names.append("fleet.toml")
        write_timing(stage, result.timing)
        names.append(TIMING_FILE)
    return names
