"""Several experiments in one identification: ``[[data]]`` and ``[[validation]]`` (issue 35 item 1).

Each ``[[data]]`` entry is an :class:`Experiment`: read, put in actuator space and processed on its own
(its own rate, rows, filters and decimation; ``[processing]`` applies to every experiment alike), then
compressed on its own into per-channel QR factors (:class:`~dynid.estimation.problem.RegressionProblem`).
No log is ever concatenated raw with another, so no filter runs across the join of two logs.

The experiments enter the estimator as *stacked factors*: the problem whose channels are the pairs
(experiment, channel), ``"<i>:<channel>"``. Weighted least squares on it is Gautier's WLS as paper 001 writes
it (Shang, Cong, Kong 2009, Eqs. 14-16: sigma_j = ||rho_j|| / sqrt(r_j - p_j) from the least-squares residual
of each block j of equations, rows weighted by G = diag(1/sigma_j), the LS of the weighted system) with the
blocks being one channel of one experiment: a noise variance per (experiment, channel), so a noisy log weighs
less than a clean one. The residuals are those of the OLS fit pooled over every experiment (an experiment
alone need not excite every base parameter), p_j the parameters acting on the channel. The estimate is then mapped back to the robot's channels (:func:`collapse`): the per-experiment
noise levels stay in ``provenance["experiments"]``.

Methods that cannot take several experiments yet refuse them (:func:`check_several`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from dynid.config import Config, DataConfig
from dynid.errors import ConfigError
from dynid.estimation.problem import RegressionProblem, _qr_r

__all__ = ["Experiment", "check_several", "stack", "collapse", "experiment_record", "pooled_validation"]


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One ``[[data]]`` entry: its config block, its processed dataset, its compressed rows, its provenance."""

    index: int
    spec: DataConfig
    dataset: Any  # dynid.io.dataset.Dataset, processed (actuator space)
    problem: RegressionProblem
    raw_meta: dict[str, Any]
    steps: list

    @property
    def payload(self) -> bool | None:
        """``payload = true|false`` of the ``[[data]]`` entry (None: not said); the hook of payload identification."""
        return self.spec.payload


def check_several(cfg: Config, structure_decided: bool = False) -> None:
    """Refuse, in one line each, what cannot take several ``[[data]]`` experiments yet (never take the first silently)."""
    n = len(cfg.training_logs)
    if n <= 1:
        return
    icfg, pcfg = cfg.identification, cfg.processing
    why = None
    if icfg.method not in ("ols", "wls"):
        why = (f"identification.method = {icfg.method!r} (only 'ols' and 'wls' stack experiments' factors; iv/didim/cloe run "
               "the control loop over one log, ml cuts one log's filter, gm needs one log's cross-channel factor)")
    elif icfg.hierarchical:
        why = "identification.hierarchical (its friction steps read one log)"
    elif icfg.friction_model == "stribeck":
        why = "friction_model = 'stribeck' (a nonlinear fit over one log's samples)"
    elif pcfg.periodic is not None:
        why = "processing.periodic (the period averaging of one log)"
    elif cfg.learning is not None:
        why = "[learning] (the residual model trains on one log's samples)"
    elif icfg.covariance.kind != "model":
        why = f"identification.covariance = {icfg.covariance.kind!r} (its blocks are one log's consecutive samples)"
    elif structure_decided:
        why = ("identification.structure = 'auto' with identical chains (the decision cross-validates over one log's "
               "segments; name the structure)")
    if why is not None:
        raise ConfigError(f"data: {n} [[data]] experiments, but {why}; give one [data] table")


def build_experiments(cfg: Config, first: Experiment, compress, read) -> list[Experiment]:
    """Every ``[[data]]`` experiment: ``first`` (data[0], already processed by the pipeline) and the others, each
    read and processed on its own by ``read(spec, label) -> (dataset, steps, raw_meta)`` and compressed on its own
    by ``compress(dataset) -> RegressionProblem``."""
    out = [first]

    def kind(meta: dict) -> str:
        """What the efforts are once in actuator space: currents with known gains (the log's
        effort.drive_gains or robot.drive_gains) are torques; without, currents (the parameters absorb
        the unknown gains, so such a log cannot be mixed with torque logs)."""
        known = meta.get("drive_gains") is not None or cfg.robot.drive_gains is not None
        return "torque" if meta.get("effort_kind") == "torque" or known else "current (unknown gains)"

    for i, spec in enumerate(cfg.training_logs[1:], start=1):
        ds, steps, raw_meta = read(spec, f"data[{i}]")
        if kind(raw_meta) != kind(first.raw_meta):
            raise ConfigError(f"data[{i}]: its efforts are {kind(raw_meta)}, data[0]'s {kind(first.raw_meta)}; every "
                              "experiment measures the same kind (give a current log its effort.drive_gains)")
        out.append(Experiment(i, spec, ds, compress(ds), raw_meta, steps))
    return out


def stack(experiments: list[Experiment]) -> RegressionProblem:
    """The stacked factors: one channel per (experiment, channel), named ``"<i>:<channel>"``; the experiments'
    factors side by side, never their raw rows."""
    first = experiments[0].problem
    for e in experiments[1:]:
        if e.problem.names != first.names or e.problem.channel_names != first.channel_names:
            raise ConfigError(f"data[{e.index}]: its base parameters or channels differ from data[0]'s")
    factors = np.concatenate([e.problem.factors for e in experiments])
    n_obs = np.concatenate([e.problem.n_obs for e in experiments])
    names = tuple(f"{e.index}:{c}" for e in experiments for c in e.problem.channel_names)
    return RegressionProblem(first.names, names, factors, n_obs, expressions=first.expressions,
                             standard=first.standard, meta=dict(first.meta))


def collapse(result, stacked: RegressionProblem, experiments: list[Experiment]):
    """The result on the robot's channels: rows and residual sums of squares summed over the experiments,
    the channel's noise std their pooled RMS residual; the per-(experiment, channel) noise std (the WLS
    weights) and rows in ``provenance["experiments"]``."""
    n_e, channels = len(experiments), experiments[0].problem.channel_names
    n_ch = len(channels)
    n_obs = np.asarray(stacked.n_obs).reshape(n_e, n_ch)
    rss = stacked.rss_per_channel(result.params).reshape(n_e, n_ch)
    sigma = np.asarray(result.noise_std, float).reshape(n_e, n_ch)
    records = [experiment_record(e, n_obs[i], rss[i], sigma[i]) for i, e in enumerate(experiments)]
    pooled = np.sqrt(rss.sum(axis=0) / np.maximum(n_obs.sum(axis=0), 1))
    solver = {**result.solver, "experiments": n_e}
    if "sigma" in solver:
        solver["sigma"] = sigma.tolist()
    out = dataclasses.replace(result, channel_names=channels, n_obs=n_obs.sum(axis=0), rss_per_channel=rss.sum(axis=0),
                              noise_std=pooled, solver=solver)
    weighted = result.method.upper().startswith("WLS")
    note = (f"{n_e} experiments ([[data]]), each processed and compressed on its own, their factors stacked"
            + ("; weights 1/sigma^2 per experiment and channel (Gautier's WLS over the blocks (experiment, channel))"
               if weighted else "; one weight for all (OLS)") + "; noise std per channel: pooled RMS residual over "
            "the experiments (per experiment: result.json 'experiments')")
    return out.with_provenance(experiments=records).with_notes(note)


def experiment_record(e: Experiment, n_rows, rss, sigma) -> dict[str, Any]:
    """result.json's entry of one experiment: file, rate, rows, processing, rows used, noise std."""
    ds = e.dataset
    spec = e.spec
    return {
        "index": e.index,
        "files": [str(Path(f)) for f in spec.files()],
        "sha256": e.raw_meta.get("sha256"),
        "rows": None if spec.rows is None else list(spec.rows),
        "time_window": None if spec.time_window is None else list(spec.time_window),
        "samples_processed": int(ds.n_samples),
        "rate_hz": float(ds.fs),
        "processing": [str(s) if not isinstance(s, dict) else s for s in e.steps],
        "rows_used": [int(v) for v in n_rows],
        "rss": [float(v) for v in rss],
        "noise_std": [float(v) for v in sigma],
        "payload": spec.payload,
    }


def pooled_validation(per_log: list[dict[str, Any]], channels) -> dict[str, Any]:
    """The pooled held-out table over several validation logs: per channel, RMSE = sqrt(sum over the logs of the
    squared errors / their rows), i.e. RMSE^2 is the row-weighted mean of the logs' MSEs."""
    n = np.array([v["rows"] for v in per_log], float)  # (logs, channels)
    mse = np.array([np.square(v["rmse"]) for v in per_log], float)
    ms_meas = np.array([np.square(v["rms_measured"]) for v in per_log], float)
    total = n.sum(axis=0)
    rmse = np.sqrt((n * mse).sum(axis=0) / total)
    rms = np.sqrt((n * ms_meas).sum(axis=0) / total)
    return {"label": "pooled (sums of squared errors over every validation log's rows)", "channels": list(channels),
            "rows": total.astype(int).tolist(), "rmse": rmse.tolist(), "rms_measured": rms.tolist(),
            "relative_rmse": (rmse / rms).tolist()}


def validation_record(label: str, spec: DataConfig, metrics) -> dict[str, Any]:
    """One validation log's held-out table (result.json 'validation_logs')."""
    rows = np.asarray(metrics.rows_per_channel, float)
    return {"label": label, "files": [str(Path(f)) for f in spec.files()], "channels": list(metrics.channel_names),
            "rows": rows.astype(int).tolist(), "rmse": np.asarray(metrics.rmse, float).tolist(),
            "rms_measured": np.asarray(metrics.rms_measured, float).tolist(),
            "relative_rmse": (np.asarray(metrics.rmse, float) / np.asarray(metrics.rms_measured, float)).tolist()}


def summary_lines(records: list[dict[str, Any]], per_log: list[dict[str, Any]] | None,
                  pooled: dict[str, Any] | None) -> list[str]:
    """summary.txt's per-experiment and per-validation-log tables."""
    out = ["", "Experiments ([[data]])"] if records else []
    for r in records:
        out.append(f"  data[{r['index']}] {', '.join(Path(f).name for f in r['files'])}: {r['samples_processed']} samples "
                   f"at {r['rate_hz']:.6g} Hz, rows used {r['rows_used']}, noise std "
                   f"{', '.join(f'{s:.4g}' for s in r['noise_std'])}" + ("" if r["payload"] is None else f", payload {r['payload']}"))
    if per_log:
        out += ["", "Held-out error per validation log (RMSE; relative to the RMS measured)"]
        for v in [*per_log, *([pooled] if pooled else [])]:
            cells = ", ".join(f"{c} {e:.4g} ({100 * r:.1f} %)" for c, e, r in zip(v["channels"], v["rmse"], v["relative_rmse"]))
            out.append(f"  {v['label']}: {cells}")
    return out
