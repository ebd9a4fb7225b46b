"""The output files of ``dynid identify`` (issue 35: the pipeline split by concern): :func:`write_outputs`
(staged: all files or none), result.json / npz / params.csv / summary.txt / report, the exported model.
Re-exported by :mod:`dynid.pipeline.identification`."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from dynid._files import TIMING_FILE, write_timing
from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.estimation.validation import ValidationMetrics, prior_comparison
from dynid.io.output import staged_output
from dynid.model.system import as_system
from dynid.pipeline import stribeck
from dynid.pipeline.outcome import FullRate, IdentifyOutcome, SelectedRows
from dynid.pipeline.reporting import parameter_flags, run_facts


OUTPUT_FILES = ("result.json", "result.npz", "params.csv", "summary.txt", "validation.png", "processing.png", "report.html",
                "hierarchical.png", "model.urdf", "model.mjcf", TIMING_FILE, "result_learning.pt")


def write_outputs(outcome: IdentifyOutcome, out_dir: str | Path) -> dict[str, Path]:
    """Write result.json, result.npz, params.csv, summary.txt, timing.json (+ plots, report.html).

    Files are staged and moved into ``out_dir`` only when all were written; dynid
    outputs of an earlier run that this run did not produce are removed. Returns the
    files of this run.
    """
    out = Path(out_dir)
    try:
        with staged_output(out) as stage:
            write_files(outcome, stage)
            produced = sorted(p.name for p in stage.iterdir())
    except BaseException:
        if outcome.jobs is not None:  # the figures still under way are no longer wanted
            outcome.jobs.close(kill=True)
        raise
    if outcome.jobs is not None:  # every figure collected: the worker is idle and ends
        outcome.jobs.close()
    # outputs of an earlier run that this run did not write (e.g. plots now switched off)
    # would describe another identification: remove them
    for name in OUTPUT_FILES:
        if name not in produced and (out / name).is_file():
            (out / name).unlink()
    return {name: out / name for name in produced}


ONE_OF_MANY = ("one of many: the data fix only the base parameters; these standard parameters are the physically "
               "consistent vector (every body's pseudo-inertia positive semidefinite: positive mass, inertia within the "
               "triangle inequalities) closest to the nominal one (min ||S^-1 (pi - pi_nom)||, S the RMS nominal "
               "magnitude of each kind of parameter: mass, first moment, inertia, each joint term) that gives the "
               "estimated base parameters; every other vector with these base parameters predicts the same forces")


def standard_vector(outcome: IdentifyOutcome) -> tuple[FloatArray, list[str]] | None:
    """The standard vector of a result (the system's parameters), and notes for the exported file.

    A physically consistent fit's recovered vector as it is (consistent by construction; with
    regularization it is the estimate itself). For every other result whose parameters start with
    the base parameters (OLS, WLS, Gauss-Markov, IV, DIDIM, maximum likelihood; the rigid-body part
    of a Stribeck or hierarchical fit), the rule of
    :func:`~dynid.estimation.consistent_standard.consistent_standard`: the physically consistent
    vector closest to the nominal one, :math:`\\min\\lVert S^{-1}(\\pi - \\pi_{nom})\\rVert`
    (:func:`~dynid.model.base_parameters.parameter_scales`) subject to :math:`B\\pi = \\hat\\beta`
    and every body's pseudo-inertia :math:`\\succeq 0` (Wensing, Kim & Slotine 2017); when no
    consistent vector gives :math:`\\hat\\beta`, the one that misses it least (in standard
    deviations of the estimate), which a note says. Joint terms pass through. The nominal vector is
    the description's projected onto the physically consistent set
    (:func:`~dynid.model.base_parameters.consistent_parameters`; unchanged for a consistent
    description). None: no base parameters."""
    from dynid.estimation.consistent_standard import consistent_standard
    from dynid.model.base_parameters import consistent_parameters, parameter_scales

    res = outcome.result
    system = outcome.system if outcome.system is not None else as_system(outcome.robot)
    names = system.parameter_names
    std = res.solver.get("standard_params")
    if std:
        missing = [n for n in names if n not in std]
        if missing:
            raise InputError(f"the result's standard parameters do not match the robot (missing {missing[:3]})")
        return np.array([std[n] for n in names], dtype=float), []
    base = outcome.base
    if tuple(res.names[: base.n_base]) != base.names or tuple(base.standard_names) != tuple(names):
        return None
    nominal = consistent_parameters(system.nominal_parameters(), system.body_blocks())
    scale = parameter_scales(names, system.body_blocks(), nominal)
    beta = np.array(res.params[: base.n_base], dtype=float)
    notes = [ONE_OF_MANY]
    if "stribeck" in res.solver:  # its curves replace the linear Coulomb and viscous columns (stribeck.predict)
        fj = stribeck.friction_joints(system, base)
        beta[list(fj.coulomb) + list(fj.viscous)] = 0.0
        notes.append("the Stribeck friction curves (result.json solver.stribeck) replace the linear Coulomb and "
                     "viscous terms, written here as 0")
    cov = None if res.cov_params is None else np.asarray(res.cov_params, dtype=float)[: base.n_base, : base.n_base]
    found = consistent_standard(beta, system.standard_map(base), nominal, scale, cov)
    pi = found.params
    if found.projected:
        notes.append("the closest vector without the consistency constraints was not physically consistent; "
                     "the constraints bind (a semidefinite program, Clarabel)")
    if not found.exact:
        notes.append(f"no physically consistent standard vector gives the estimated base parameters: this one "
                     f"misses them by {found.mismatch:.3g} ({found.metric}; the least any consistent vector misses "
                     f"them by is {found.stages['mismatch_min']:.3g}), and its forces differ from the estimate's "
                     "accordingly")
    notes += list(found.notes)
    if "hierarchical" in res.solver:
        notes.append("the hierarchical fit's friction curves are in result.json (solver.hierarchical), not in this file")
    return pi, notes


def export_model(outcome: IdentifyOutcome, folder: Path,
                 found: tuple[FloatArray, list[str]] | None | bool = False) -> Path | None:
    """The result's standard parameters (:func:`standard_vector`, or ``found``, its value when the
    caller has it) as a robot description: ``model.urdf`` for a serial robot, ``model.mjcf`` for a
    closed-loop mechanism (None when the result has no base parameters to reproduce); a body that
    is not physically consistent is an :class:`~dynid.errors.InputError` and no file is written
    (:func:`dynid.io.export.write_model`)."""
    if found is False:
        found = standard_vector(outcome)
    if found is None:
        return None
    from dynid.io.export import write_model

    pi, notes = found
    robot = outcome.robot
    system = outcome.system if outcome.system is not None else as_system(robot)
    # a reduced structure (identification.structure): every tied body gets its group's values
    params = system.expand_parameters(pi)
    return write_model(robot, params, folder, name=f"{robot.name}_identified", notes=notes)


def export_warnings(outcome: IdentifyOutcome, factor: float = 10.0,
                    found: tuple[FloatArray, list[str]] | None | bool = False) -> list[str]:
    """Lines for summary.txt when the exported standard parameters are far from the model's
    nominal ones: a body mass more than ``factor`` times above or below its nominal value. The
    base parameters fix only combinations of the standard ones; without regularization the rest
    comes from the tie-break, and a constrained fit on weak data can push it far (e.g. legs of
    hundreds of tonnes that give the same actuator forces). ``found``: :func:`standard_vector`'s
    value when the caller has it."""
    if found is False:
        found = standard_vector(outcome)
    robot = outcome.system if outcome.system is not None else as_system(outcome.robot)
    if found is None:
        return []
    nominal = robot.nominal_parameters()
    names = robot.parameter_names
    far = []
    for blk in robot.body_blocks():
        i = blk[0]
        m, m0 = float(found[0][i]), float(nominal[i])
        if m0 > 0 and not (m0 / factor <= m <= m0 * factor):
            far.append(f"{names[i]} = {m:.4g} kg (nominal {m0:.4g} kg)")
    if not far:
        return []
    return [f"warning: the exported model's masses are far from the nominal ones: {', '.join(far)}. The data fix "
            "the base parameters only; regularization towards the nominal model (identification.regularization) "
            "gives standard parameters a simulator can trust."]


def _nominal_dict(v: ValidationMetrics) -> dict[str, Any]:
    """The nominal model's errors for result.json (its rows, source and overlap are the validation's)."""
    d = v.to_dict()
    return {k: d[k] for k in ("joints", "n_samples", "rmse_per_joint", "rel_rmse_pct_per_joint", "max_abs_error_per_joint",
                              "r2_per_joint")}


def _selected_dict(sel: SelectedRows) -> dict[str, Any]:
    """:class:`SelectedRows` for result.json."""
    d = sel.metrics.to_dict()
    ident = {k: d[k] for k in ("joints", "n_samples", "rows_per_joint", "rmse_per_joint", "rel_rmse_pct_per_joint",
                               "max_abs_error_per_joint", "r2_per_joint", "kind")}
    return {"rule": sel.rule, "identified": ident,
            **({"nominal": {**_nominal_dict(sel.nominal), "rows_per_joint": ident["rows_per_joint"]}}
               if sel.nominal is not None else {}),
            **({"prior_comparison": sel.prior} if sel.prior is not None else {}),
            **({"floor": sel.floor.to_dict(), "floor_all_rows": sel.floor_all.to_dict()} if sel.floor is not None else {})}


def _full_rate_dict(fr: FullRate) -> dict[str, Any]:
    """:class:`FullRate` for result.json."""
    d = fr.metrics.to_dict()
    ident = {k: d[k] for k in ("joints", "n_samples", "rmse_per_joint", "rel_rmse_pct_per_joint",
                               "max_abs_error_per_joint", "r2_per_joint")}
    return {"decimate_in_fit": fr.decimate, "identified": ident,
            **({"nominal": _nominal_dict(fr.nominal)} if fr.nominal is not None else {}),
            **({"prior_comparison": fr.prior} if fr.prior is not None else {})}


def write_files(outcome: IdentifyOutcome, stage: Path) -> None:
    """Write the output files into an existing folder (see :func:`write_outputs`)."""
    res = outcome.result
    expressions = res.expressions if res.expressions is not None else outcome.base.expressions()
    system = outcome.system if outcome.system is not None else as_system(outcome.robot)
    # the physical-consistency check (a semidefinite program) runs with the report only
    jobs = outcome.jobs if outcome.config.output.plots else None
    flags = outcome.flags
    res.save(
        stage / "result",
        extra={
            "validation": {**outcome.validation.to_dict(), **({"units_per_joint": list(outcome.units)}
                                                              if outcome.units else {})},
            "parameter_flags": flags,
            "robot": {"name": outcome.robot.name, "source": getattr(outcome.robot, "source", "")},
            "warnings": [w.to_dict() for w in outcome.warnings],
            **({"nominal_validation": _nominal_dict(outcome.nominal_validation), "prior_comparison": outcome.prior}
               if outcome.nominal_validation is not None else {}),
            **({"validation_other_view": {"label": outcome.other_view.label,
                                          "identified": _nominal_dict(outcome.other_view.metrics),
                                          **({"nominal": _nominal_dict(outcome.other_view.nominal)}
                                             if outcome.other_view.nominal is not None else {})}}
               if outcome.other_view is not None else {}),
            **({"validation_selected_rows": _selected_dict(outcome.selected)} if outcome.selected is not None else {}),
            **({"validation_full_rate": _full_rate_dict(outcome.full_rate)} if outcome.full_rate is not None else {}),
            **({"learning": outcome.learning.to_dict()} if outcome.learning is not None else {}),
            "training": {"n_samples": outcome.n_train, "rmse_per_joint": res.rmse_per_channel.tolist()},
            **({"data_path": outcome.data_path} if outcome.data_path is not None else {}),
            **({"prediction_inputs": outcome.prediction} if outcome.prediction is not None else {}),
            **({"structure": outcome.structure} if outcome.structure is not None else {}),
            "base_parameters": {
                "names": list(outcome.base.names),
                "expressions": list(expressions),
                "standard_names": list(outcome.base.standard_names),
            },
        },
    )
    with open(stage / "params.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "value", "std", "rel_std_pct", "ci_low", "ci_high", "expression", "covariance"])
        if res.cov_params is not None:
            ci, bse, rel = res.conf_int(), res.bse, res.rel_std
            stats = [(repr(float(bse[i])), f"{rel[i]:.6g}", repr(float(ci[i, 0])), repr(float(ci[i, 1]))) for i in range(len(res.names))]
        else:  # the method gives no covariance (see the result's notes): leave the columns empty
            stats = [("", "", "", "")] * len(res.names)
        for i, n in enumerate(res.names):
            w.writerow([n, repr(float(res.params[i])), *stats[i], expressions[i], res.covariance_kind or ""])
    found = standard_vector(outcome)  # a consistency failure raises here: no output at all (exit 2)
    warn = export_warnings(outcome, found=found)
    try:
        exported = export_model(outcome, stage, found)
    except ModelError as exc:  # what a format cannot hold (a joint type): the estimate is kept, the file is not written
        exported = None
        warn = [f"no robot description exported: {exc}", *warn]
    if exported is not None and found is not None and found[1]:
        warn = [f"exported {exported.name}: " + "; ".join(found[1]), *warn]
    (stage / "summary.txt").write_text(outcome.summary_text() + "\n" + "".join(f"\n{w}\n" for w in warn))
    if outcome.payload is not None:  # the joint arm + payload mode (dynid.pipeline.joint_payload)
        from dynid.pipeline.payload_outcome import write_payload_files

        write_payload_files(outcome.payload, stage, "payload_summary.txt")
    if outcome.learning is not None:
        from dynid.pipeline.learning import LEARNING_FILE

        outcome.learning.networks.save(stage / LEARNING_FILE)
    write_timing(stage, {"identify_s": outcome.elapsed_s, "solver": res.timing})
    if outcome.config.output.plots:
        from dynid.report import plot_validation, write_html_report

        if jobs is not None and "validation.png" in jobs:
            jobs.write_figure("validation.png", stage / "validation.png")
        else:
            plot_validation(outcome.validation, stage / "validation.png", units=outcome.units or None)
        images = {"validation.png": "Validation: measured against predicted"}
        if "hierarchical" in res.solver:
            from dynid.pipeline.hierarchical import plot_history

            plot_history(res.solver["hierarchical"], tuple(res.channel_names), stage / "hierarchical.png")
            images["hierarchical.png"] = "Hierarchical iterations"
        raw, proc = (outcome.raw_train, outcome.train) if outcome.raw_train is not None else (outcome.streamed_plots
                                                                                              or (None, None))
        if raw is not None:
            if jobs is not None and "processing.png" in jobs:
                jobs.write_figure("processing.png", stage / "processing.png")
            else:
                from dynid.report.plots import plot_processing

                plot_processing(raw, proc, stage / "processing.png", steps=proc.meta.get("processing"))
            images["processing.png"] = "Processing: raw and processed training signals"
        write_html_report(res, outcome.validation, stage / "report.html",
                          images={stage / name: title for name, title in images.items()},
                          nominal=outcome.nominal_validation, prior=outcome.prior, other_view=outcome.other_view,
                          selected=outcome.selected, units=outcome.units or None, flags=flags, facts=run_facts(),
                          structure=outcome.structure)
