"""``dynid predict``: a saved identification scored on a new log, beside the nominal model.

The result folder of ``dynid identify`` holds, in result.json's ``prediction_inputs`` section
(:func:`dynid.pipeline.identification.prediction_inputs`, versioned by
:data:`~dynid.pipeline.identification.PREDICTION_FORMAT`), what the model was identified with:
the robot description and drive train, the processing (maximum likelihood: at the estimated
cut-off), the ``[identification]`` table (structure, force model, base-parameter seed,
hierarchical friction), the Coulomb smoothing widths of the fit and the base-parameter
definition. The new log is read and processed exactly as ``identify`` processed its validation
log, and scored by the same function (:func:`~dynid.pipeline.identification.score_held_out`):
the per-joint RMSE on a log equals what ``identify`` reports for that log as its validation.

The log config is a TOML file with a ``[data]`` table (the keys of ``identify``'s ``[data]``:
file, time or sample rate, position, effort, windows) and optionally a ``[robot]`` table, which
must describe the robot the result was identified on. No other table: the processing and the
model come from the result, so the prediction cannot silently differ from the identification.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from dynid.config import (Config, CouplingConfig, LowpassConfig, PeriodicConfig, ProcessingConfig, RobotConfig,
                          _parse_data, _parse_identification, _parse_robot)
from dynid.config._schema import read_toml
from dynid.errors import ConfigError, InputError
from dynid.estimation import IdentificationResult
from dynid.estimation.validation import ValidationMetrics, prior_comparison
from dynid.io.output import staged_output
from dynid.pipeline.data import build_system, check_units, preprocess, read_log, to_actuator_space
from dynid.pipeline.rows import Progress, _model_rows, _no_progress
from dynid.pipeline.run_record import PREDICTION_FORMAT
from dynid.pipeline.validation import score_held_out

__all__ = ["PredictOutcome", "load_saved", "predict", "write_prediction", "PREDICT_FILES"]

PREDICT_FILES = ("summary.txt", "predict.json", "predict.png")


@dataclasses.dataclass(frozen=True)
class Saved:
    """A result folder read for prediction."""

    folder: Path
    result: IdentificationResult
    inputs: dict[str, Any]
    doc: dict[str, Any]


def load_saved(path: str | Path) -> Saved:
    """The result of ``dynid identify`` in ``path`` (its folder or its result.json), refused in
    one line when missing, foreign or written before prediction inputs were saved."""
    p = Path(path)
    jpath = p / "result.json" if p.is_dir() else p
    if not jpath.is_file():
        raise InputError(f"{path}: no result.json (give the --out folder of dynid identify or its result.json)")
    try:
        doc = json.loads(jpath.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{jpath}: not readable as a dynid result ({type(exc).__name__})") from None
    if not isinstance(doc, dict) or doc.get("format") is None or "params" not in doc:
        raise InputError(f"{jpath}: not a dynid result")
    inputs = doc.get("prediction_inputs")
    version = inputs.get("format_version") if isinstance(inputs, dict) else None
    if version != PREDICTION_FORMAT:
        have = "none" if version is None else f"version {version}"
        raise InputError(f"{jpath}: written by another dynid version (prediction inputs: {have}, this dynid needs "
                         f"version {PREDICTION_FORMAT}); run dynid identify again with this version")
    result = IdentificationResult.load(jpath)
    return Saved(jpath.parent, result, inputs, doc)


def _robot_config(d: dict[str, Any]) -> RobotConfig:
    def tup(v):
        return None if v is None else tuple(v)

    return RobotConfig(model=d["model"], extras=tuple(d["extras"]), gear_ratios=tup(d["gear_ratios"]),
                       couplings=tuple(CouplingConfig(motor=c["motor"], joints=tuple(c["joints"]),
                                                      weights=tuple(c["weights"])) for c in d["couplings"]),
                       drive_gains=tup(d["drive_gains"]), position_offset=tup(d["position_offset"]),
                       extras_given=d["extras_given"], actuated=tup(d["actuated"]), independent=tup(d["independent"]))


def _processing_config(d: dict[str, Any]) -> ProcessingConfig:
    d = dict(d)
    d["lowpass"] = None if d["lowpass"] is None else LowpassConfig(**d["lowpass"])
    d["periodic"] = None if d["periodic"] is None else PeriodicConfig(**d["periodic"])
    d["min_velocity"] = None if d["min_velocity"] is None else tuple(d["min_velocity"])
    return ProcessingConfig(**d)


def log_count(path: str | Path) -> int:
    """How many logs the log config names: 1 for ``[data]``, the entries of ``[[data]]``."""
    data = read_toml(Path(path)).get("data")
    return len(data) if isinstance(data, list) else 1


def _read_log_config(path: str | Path, saved_robot: RobotConfig, index: int | None = None):
    """The ``[data]`` table of the log config, or entry ``index`` of its ``[[data]]`` array (and its ``[robot]``
    table, checked against the result's)."""
    path = Path(path)
    doc = read_toml(path)
    where = "data"
    if isinstance(doc.get("data"), list):
        if not doc["data"]:
            raise ConfigError(f"{path}: an empty [[data]] array")
        if index is None and len(doc["data"]) > 1:
            raise ConfigError(f"{path}: {len(doc['data'])} [[data]] logs; score them with predict_logs (dynid predict does)")
        where = f"data[{index or 0}]"
        doc = {**doc, "data": doc["data"][index or 0]}
    other = sorted(set(doc) - {"data", "robot"})
    if other:
        raise ConfigError(f"{path}: [{other[0]}] is not read by dynid predict: the processing and the model are the "
                          "result's; give [data] (the new log) and optionally [robot]")
    if "data" not in doc:
        raise ConfigError(f"{path}: no [data] table (the new log: file, time or sample_rate_hz, position, effort)")
    base = path.resolve().parent
    if "robot" in doc:
        given = _parse_robot(doc["robot"], base)
        if given.model != saved_robot.model:
            raise ConfigError(f"{path}: robot.model {given.model} is not the robot the result was identified on "
                              f"({saved_robot.model})")
        diff = [f.name for f in dataclasses.fields(RobotConfig)
                if f.name not in ("extras_given",) and getattr(given, f.name) != getattr(saved_robot, f.name)
                and not (f.name == "extras" and not given.extras_given)]
        if diff:
            raise ConfigError(f"{path}: [robot] {diff[0]} differs from the result's robot ({getattr(saved_robot, diff[0])!r}); "
                              "leave [robot] out to use the result's")
    return _parse_data(doc["data"], where, base)


@dataclasses.dataclass(frozen=True, eq=False)
class PredictOutcome:
    """The saved model and the nominal one on the new log (the scores of
    :func:`~dynid.pipeline.identification.score_held_out`), and the identified model with its
    learned residual network when the result has one."""

    result_dir: Path
    method: str
    source: dict[str, Any]
    metrics: ValidationMetrics
    nominal: ValidationMetrics | None
    prior: dict[str, Any] | None
    selected: Any = None
    full_rate: Any = None
    other_view: Any = None
    learned: ValidationMetrics | None = None
    notes: tuple[str, ...] = ()
    robot: str = ""  # the robot's name and its description's file
    # the new log against the description's limits and the nominal model (dynid.pipeline.diagnostics)
    warnings: tuple[Any, ...] = ()

    def per_joint(self) -> list[dict[str, Any]]:
        rows = []
        for j, c in enumerate(self.metrics.channel_names):
            r = {"joint": c, "rmse": float(self.metrics.rmse[j]), "rel_rmse_pct": float(self.metrics.rel_rmse_pct[j]),
                 "r2": float(self.metrics.r2[j])}
            if self.nominal is not None:
                n = self.nominal
                r.update(nominal_rmse=float(n.rmse[j]), nominal_rel_rmse_pct=float(n.rel_rmse_pct[j]),
                         nominal_r2=float(n.r2[j]),
                         better=("identified" if self.metrics.rmse[j] < n.rmse[j]
                                 else "nominal" if n.rmse[j] < self.metrics.rmse[j] else "equal"))
            if self.learned is not None:
                r.update(with_network_rmse=float(self.learned.rmse[j]), with_network_r2=float(self.learned.r2[j]))
            rows.append(r)
        return rows

    def table(self) -> str:
        head = f"{'joint':<10} {'RMSE':>11} {'rel %':>7} {'R2':>8}"
        if self.nominal is not None:
            head += f"   {'nominal RMSE':>12} {'rel %':>7} {'R2':>8}  better"
        lines = [head]
        for r in self.per_joint():
            line = f"{r['joint']:<10} {r['rmse']:>11.4g} {r['rel_rmse_pct']:>7.3g} {r['r2']:>8.4f}"
            if self.nominal is not None:
                line += (f"   {r['nominal_rmse']:>12.4g} {r['nominal_rel_rmse_pct']:>7.3g} {r['nominal_r2']:>8.4f}  "
                         f"{r['better']}")
            lines.append(line)
        return "\n".join(lines)

    def summary_text(self) -> str:
        files = self.source.get("source", {})
        src = ", ".join(sorted(set(map(str, files.values())))) if isinstance(files, dict) and files else "?"
        lines = [f"dynid predict: the {self.method} result of {self.result_dir} on a new log ({src})",
                 *([f"robot: {self.robot}"] if self.robot else []),
                 f"{self.metrics.n_samples} processed samples, processed as at identification", "",
                 "Per joint: the identified model, and the nominal model (the robot description's parameters)",
                 self.table()]
        if self.prior is not None:
            lines += ["", self.prior["verdict"]]
        sel = self.selected
        if sel is not None:
            lines += ["", sel.heading(), sel.metrics.table()]
            if sel.nominal is not None:
                lines += ["nominal model, the same rows", sel.nominal.table()]
        fr = self.full_rate
        if fr is not None:
            lines += ["", fr.heading(), fr.metrics.table()]
            if fr.nominal is not None:
                lines += ["nominal model, the same samples", fr.nominal.table()]
        o = self.other_view
        if o is not None:
            lines += ["", f"The same predictions {o.label}", o.metrics.table()]
        if self.learned is not None:
            lines += ["", "The identified model plus its learned residual network", self.learned.table()]
        lines += [f"note: {n}" for n in self.notes]
        if self.warnings:
            lines += ["", f"{len(self.warnings)} warning{'s' if len(self.warnings) > 1 else ''} about the new log "
                          "(dynid.pipeline.diagnostics):"] + [str(w) for w in self.warnings]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        from dynid.pipeline.outputs import _full_rate_dict, _nominal_dict, _selected_dict

        return {"format_version": PREDICTION_FORMAT, "result": str(self.result_dir), "method": self.method,
                "log": self.source, "per_joint": self.per_joint(),
                "identified": self.metrics.to_dict(),
                **({"nominal": _nominal_dict(self.nominal)} if self.nominal is not None else {}),
                **({"prior_comparison": self.prior} if self.prior is not None else {}),
                **({"selected_rows": _selected_dict(self.selected)} if self.selected is not None else {}),
                **({"full_rate": _full_rate_dict(self.full_rate)} if self.full_rate is not None else {}),
                **({"with_network": _nominal_dict(self.learned)} if self.learned is not None else {}),
                "robot": self.robot, "warnings": [w.to_dict() for w in self.warnings],
                "notes": list(self.notes)}


def _hierarchical_curves(result: IdentificationResult, joints: tuple[str, ...]):
    """The friction curves of a hierarchical result, as saved in its solver section."""
    from dynid.estimation.friction_curves import CurveFit
    from dynid.pipeline.hierarchical import HierarchicalFriction

    info = result.solver["hierarchical"]
    fits = []
    for j in joints:
        coeffs = info["friction"][j]
        names = tuple(coeffs)
        values = np.array([coeffs[n]["value"] for n in names], dtype=float)
        nan = np.full(len(names), np.nan)
        fits.append(CurveFit(info["model"], names, values, nan, np.zeros(len(names), bool), np.diag(nan), float("nan"),
                             float("nan"), 0, True, "read from result.json"))
    projection = info.get("mechanism", {}).get("projection", "identity")
    return HierarchicalFriction(info["family"], info["model"], joints, tuple(fits), projection)



def result_system(system, icfg, inp: dict, model: str, since: str):
    """The system a result was identified with: ``system`` (built from its robot config) with the
    result's parameter structure and force model, checked against the result's actuators.
    Returns ``(system, force_model, actuator names)``; ``since`` names the identification in the
    message ("identification", "the arm's identification")."""
    # "auto" here: a record that names no structure (before "auto" was the default, a streamed log, or a
    # mechanism without identical chains): the result was identified with every body its own parameters
    auto = icfg.structure == "auto"
    system = system.with_structure("full" if auto else icfg.structure, None if auto else icfg.identical_chains)
    names = system.actuator_names
    if list(names) != list(inp["actuators"]):
        raise InputError(f"the robot description {model} changed since {since}: actuators "
                         f"{list(names)}, the result's {inp['actuators']}")
    return system, system.force_model(icfg.force_model), names

def predict(result_path: str | Path, log_config: str | Path, progress: Progress = _no_progress, *,
            index: int | None = None, processing_from: str | Path | None = None) -> PredictOutcome:
    """Score the saved model of ``result_path`` on the log of ``log_config`` (module docstring); ``index``: that
    entry of a ``[[data]]`` array (:func:`predict_logs` scores them all).

    ``processing_from``: another result of ``dynid identify`` on the same robot whose processing
    (filters, derivatives, decimation, row selection) is used instead of this result's own: two
    models identified with different processing are then scored on the same processed rows, by the
    same metric (a comparison like for like; ``dynid predict --processing-from``). The model (its
    parameters, base parameters and Coulomb law) stays this result's."""
    saved = load_saved(result_path)
    inp = saved.inputs
    if processing_from is not None:
        other = load_saved(processing_from)
        if list(other.inputs["actuators"]) != list(inp["actuators"]):
            raise InputError(f"--processing-from {processing_from}: identified on actuators {other.inputs['actuators']}, "
                             f"the result on {inp['actuators']}")
        if other.inputs["processing"].get("periodic") or inp["processing"].get("periodic"):
            raise InputError(f"--processing-from {processing_from}: periodic processing (period averaging) is not "
                             "exchangeable between results")
        inp = {**inp, "processing": other.inputs["processing"]}
    # paths recorded relative (dynid demo: to the folder of result.json) are read from there
    robot = dict(inp["robot"])
    if not robot["model"].startswith("builtin:") and not Path(robot["model"]).is_absolute():
        robot["model"] = str((saved.folder / robot["model"]).resolve())
    robot_cfg = _robot_config(robot)
    data = _read_log_config(log_config, robot_cfg, index)
    base_dir = Path(inp["config_dir"]) if inp.get("config_dir") else saved.folder
    if not base_dir.is_absolute():
        base_dir = (saved.folder / base_dir).resolve()
    icfg = _parse_identification(inp["identification"], base_dir)
    pcfg = _processing_config(inp["processing"])
    periodic = pcfg.periodic
    cfg0 = Config(robot=robot_cfg, data=data, validation=data, processing=pcfg, identification=icfg)
    cfg = cfg0
    if icfg.hierarchical:
        from dynid.pipeline.hierarchical import rigid_robot_config, rigid_system

        cfg = dataclasses.replace(cfg0, robot=rigid_robot_config(robot_cfg))
    if not robot_cfg.model.startswith("builtin:") and not Path(robot_cfg.model).exists():
        raise InputError(f"the robot description the result was identified on is gone: {robot_cfg.model}")
    system = build_system(cfg.robot)
    if icfg.hierarchical:
        system = rigid_system(system)
    system, force_model, names = result_system(system, icfg, inp, robot_cfg.model, "identification")
    check_units(data, system.actuator_kinds(), names, "data")
    raw = read_log(data, system.n_actuators, names, "data", {})
    log_a, _ = to_actuator_space(raw, system, "data")
    held_out, _ = preprocess(log_a, pcfg, "data")
    if inp["coulomb_width"] is not None:
        system = system.with_coulomb_width(inp["coulomb_width"])
    base = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    saved_base = inp["base_parameters"]
    if list(base.names) != saved_base["names"] or not np.allclose(base.B, np.array(saved_base["B"]), rtol=1e-9,
                                                                    atol=1e-12):
        raise InputError(f"the base parameters of {robot_cfg.model} are not those the result was identified with "
                         "(the robot description changed since identification); run dynid identify again")
    result = saved.result
    fj = None
    if icfg.hierarchical:
        fj = _hierarchical_curves(result, tuple(names))
    elif icfg.friction_model == "stribeck":
        from dynid.pipeline import stribeck

        fj = stribeck.friction_joints(system, base)
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    metrics, prior, other, selected, full = score_held_out(cfg0, cfg, system, base, result, force_model, pcfg,
                                                           held_out, log_a, fj, periodic, parallel, progress)
    tr = system.transmission
    comparable = not (raw.meta["effort_kind"] == "current" and (tr is None or np.all(tr.drive_gains == 1.0)))
    comparison = None if prior is None else prior_comparison(metrics, prior, comparable, "new-log")
    notes = []
    if processing_from is not None:
        notes.append(f"scored with the processing of {Path(processing_from).resolve()} (not this result's own)")
    learned = None
    if inp.get("learning") is not None:
        from dynid.pipeline.learning import load_networks

        nets = load_networks(saved.folder)
        y, p = _model_rows(system, base, result.params, held_out, icfg.chunk_size)
        if fj is not None and icfg.hierarchical:
            p = p + fj.force(held_out.dq)
        learned = ValidationMetrics.of(tuple(names), np.asarray(held_out.t), y, p + nets.predict(held_out.dq, held_out.ddq),
                                       held_out.meta.get("source"))
    if not comparable:
        notes.append("the efforts are motor currents with unit drive gains: the nominal model is not comparable")
    from dynid.pipeline.diagnostics import limit_alarms, nominal_alarms

    alarms = limit_alarms(log_a.q, log_a.tau if comparable else None, names, system.actuator_kinds(), system, "data")
    if prior is not None and comparable:
        alarms += nominal_alarms(prior, "new-log")
    return PredictOutcome(saved.folder, result.method, dict(raw.meta), metrics, prior, comparison, selected, full,
                          other, learned, tuple(notes),
                          robot=f"{system.model.name} ({getattr(system.model, 'source', '') or robot_cfg.model})",
                          warnings=tuple(alarms))


def plot_prediction(outcome: PredictOutcome, path: Path) -> Path:
    """Per joint: measured, identified and nominal predictions over time, with both RMSEs."""
    from dynid.report.plots import _pyplot

    plt = _pyplot()
    m, nom = outcome.metrics, outcome.nominal
    n = m.measured.shape[1]
    step = max(1, m.t.shape[0] // 4000)
    t = m.t[::step] - m.t[0]
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.9 * n + 0.6), sharex=True, squeeze=False)
    for j, ax in enumerate(axes[:, 0]):
        ax.plot(t, m.measured[::step, j], lw=0.9, color="0.35", label="measured")
        ax.plot(t, m.predicted[::step, j], lw=0.9, color="tab:blue", label="identified")
        text = f"identified RMSE {m.rmse[j]:.3g}"
        if nom is not None:
            ax.plot(t, nom.predicted[::step, j], lw=0.8, color="tab:orange", alpha=0.9, label="nominal")
            text += f", nominal {nom.rmse[j]:.3g}"
        ax.text(0.995, 0.95, text, transform=ax.transAxes, ha="right", va="top", fontsize=8)
        ax.set_ylabel(m.channel_names[j], fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[0, 0].legend(loc="upper left", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle("dynid predict: measured outputs, the identified and the nominal model", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def predict_logs(result_path: str | Path, log_config: str | Path, progress: Progress = _no_progress):
    """Every log of a ``[[data]]`` log config, each read, processed and scored on its own (:func:`predict`), and
    the pooled table (:func:`dynid.pipeline.experiments.pooled_validation`: the squared errors summed over
    every log's rows)."""
    from dynid.pipeline.experiments import pooled_validation, validation_record

    outcomes = [predict(result_path, log_config, progress, index=i) for i in range(log_count(log_config))]
    specs = [_read_log_config(log_config, _robot_config_of(result_path), i) for i in range(len(outcomes))]
    per_log = [validation_record(f"data[{i}]", spec, o.metrics) for i, (spec, o) in enumerate(zip(specs, outcomes))]
    return outcomes, per_log, pooled_validation(per_log, outcomes[0].metrics.channel_names)


def _robot_config_of(result_path: str | Path) -> RobotConfig:
    saved = load_saved(result_path)
    robot = dict(saved.inputs["robot"])
    if not robot["model"].startswith("builtin:") and not Path(robot["model"]).is_absolute():
        robot["model"] = str((saved.folder / robot["model"]).resolve())
    return _robot_config(robot)


def write_predictions(outcomes, per_log, pooled, out_dir: str | Path, plots: bool = True) -> list[str]:
    """Several logs: summary.txt (each log's, then the per-log and pooled tables), predict.json
    (``logs``, ``validation_logs``, ``validation_pooled``), predict_<i>.png; all written or none."""
    from dynid.pipeline.experiments import summary_lines

    with staged_output(out_dir) as stage:
        text = "\n\n".join(f"== data[{i}]\n{o.summary_text()}" for i, o in enumerate(outcomes))
        (stage / "summary.txt").write_text(text + "\n" + "\n".join(summary_lines([], per_log, pooled)) + "\n")
        doc = {"logs": [o.to_dict() for o in outcomes], "validation_logs": per_log, "validation_pooled": pooled}
        (stage / "predict.json").write_text(json.dumps(_finite(doc), indent=2, allow_nan=False))
        if plots:
            for i, o in enumerate(outcomes):
                plot_prediction(o, stage / f"predict_{i}.png")
        written = sorted(p.name for p in stage.iterdir())
    return written


def write_prediction(outcome: PredictOutcome, out_dir: str | Path, plots: bool = True) -> list[str]:
    """summary.txt, predict.json and predict.png, all written or none."""
    with staged_output(out_dir) as stage:
        (stage / "summary.txt").write_text(outcome.summary_text() + "\n")
        (stage / "predict.json").write_text(json.dumps(_finite(outcome.to_dict()), indent=2, allow_nan=False))
        if plots:
            plot_prediction(outcome, stage / "predict.png")
        written = sorted(p.name for p in stage.iterdir())
    return written


def _finite(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, np.ndarray):
        return _finite(x.tolist())
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
