"""The outcome of ``dynid identify`` (issue 35: the pipeline split by concern): :class:`IdentifyOutcome`
(the estimate, its validations, the prior comparison, notes, what predict needs) and its parts
(:class:`RowSelection`, :class:`SelectedRows`, :class:`OtherView`, :class:`FullRate`); its summary text.
Re-exported by :mod:`dynid.pipeline.identification`."""

from __future__ import annotations

import dataclasses
import functools
import platform
from typing import Any

import numpy as np

from dynid import __version__
from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.estimation import IdentificationResult
from dynid.estimation.validation import ValidationMetrics, prior_comparison
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System, as_system
from dynid.pipeline import experiments as _experiments
from dynid.pipeline.reporting import effort_units, git_commit, parameter_flags


@dataclasses.dataclass(frozen=True)
class RowSelection:
    """The training's row selection (``processing.min_velocity``, ``min_velocity_passive``,
    ``reversal_guard`` in seconds) as :func:`~dynid.pipeline.identification.row_mask` applies it (per equation, Gauss–Markov
    included); ``rule`` says it in words."""

    min_velocity: tuple[float, ...] | None
    min_velocity_passive: float | None
    reversal_guard: float | None
    rule: str


@dataclasses.dataclass(frozen=True)
class SelectedRows:
    """The held-out errors on the rows the training's row selection keeps (applied to the
    processed held-out log exactly as to the training log), for the identified model and, on
    the same rows, the nominal one: how well the model predicts where it claims to be valid.
    The all-row errors stay the headline; these do not replace them. ``prior``: the
    :func:`~dynid.estimation.validation.prior_comparison` of the two (set by :func:`~dynid.pipeline.identification.identify`).
    ``floor`` / ``floor_all``: the held-out-fit floor on these rows / on every held-out row
    (:class:`~dynid.pipeline.held_out_floor.HeldOutFloor`: the same base-parameter structure fitted by
    least squares to those held-out rows themselves, what no model of the structure beats there in
    pooled RMS; None for a model not linear in its parameters)."""

    rule: str
    metrics: ValidationMetrics
    nominal: ValidationMetrics | None = None
    prior: dict[str, Any] | None = None
    floor: Any = None
    floor_all: Any = None

    def floor_lines(self, validation: ValidationMetrics, nominal: ValidationMetrics | None) -> list[str]:
        """summary.txt: the floor beside the identified and the nominal model, per channel and pooled,
        on these rows and on every held-out row (``validation``, ``nominal``: the all-row errors)."""
        if self.floor is None:
            return []
        from dynid.pipeline.held_out_floor import pooled_rmse

        def block(title, ident, nom, fl) -> list[str]:
            rows = [("channel", "identified", "nominal", "floor", "rows")]
            for i, c in enumerate(ident.channel_names):
                rows.append((c, f"{ident.rmse[i]:.4g}", "-" if nom is None else f"{nom.rmse[i]:.4g}", f"{fl.rmse[i]:.4g}",
                             str(int(fl.rows_per_channel[i]))))
            pool = lambda m: pooled_rmse(m.rmse, m.rows_per_channel)  # noqa: E731
            rows.append(("pooled RMS", f"{pool(ident):.4g}", "-" if nom is None else f"{pool(nom):.4g}", f"{fl.pooled:.4g}",
                         str(int(np.sum(fl.rows_per_channel)))))
            w = [max(len(r[i]) for r in rows) for i in range(5)]
            text = ["  ".join([r[0].ljust(w[0])] + [x.rjust(y) for x, y in zip(r[1:], w[1:])]) for r in rows]
            return [title, text[0], "-" * len(text[0]), *text[1:]]

        return (["", "Held-out-fit floor: the same base-parameter structure fitted by least squares to the held-out rows "
                 "themselves and scored on them (no model of this structure, from any training log, has a smaller pooled "
                 f"RMS there; rank {self.floor.rank} of {self.floor.n_params})"]
                + block(f"RMSE on the rows the row selection keeps ({self.rule})", self.metrics, self.nominal, self.floor)
                + block("RMSE on every held-out row", validation, nominal, self.floor_all))

    def heading(self) -> str:
        rows = ", ".join(f"{c} {int(k)}" for c, k in zip(self.metrics.channel_names, self.metrics.rows_per_channel))
        return (f"On the {self.metrics.label} rows the training's row selection keeps ({self.rule}): {rows} of "
                f"{self.metrics.n_samples} rows")


@dataclasses.dataclass(frozen=True)
class OtherView:
    """A redundantly actuated robot's held-out errors in the other form of its equations (issue 18
    item 5): per actuator when the identification used the projected equations, projected when it
    used actuator forces under a distribution. ``label`` says which, and what it assumes."""

    label: str
    metrics: ValidationMetrics
    nominal: ValidationMetrics | None = None


def _other_view(Ga: FloatArray, tau: FloatArray, predicted: FloatArray, prior: FloatArray | None,
                force_model: str | None) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """(measured, predicted, nominal-predicted) in the other form: projected outputs y (n, n_u) ->
    actuator forces (G_a^T)^+ y (minimum norm); actuator forces f (n, n_a) -> G_a^T f, which is the
    projected model exactly for every distribution (G_a^T (G_a^T)^+ = I; an actuator's local terms
    project onto themselves)."""
    if force_model == "projected":
        D = np.linalg.pinv(Ga.transpose(0, 2, 1))  # (n, n_a, n_u)
        def f(y):
            return np.einsum("nau,nu->na", D, y)
        return tau, f(predicted), None if prior is None else f(prior)

    def g(x):
        return np.einsum("nau,na->nu", Ga, x)
    return g(tau), g(predicted), None if prior is None else g(prior)


@dataclasses.dataclass(frozen=True)
class FullRate:
    """The held-out errors at the log's own rate when the processing decimates: the same
    low-pass and derivatives, no decimation (neither ``decimate_method = "samples"`` nor
    ``"parallel"``), every held-out row after the filter's trim, the measured outputs as logged
    (``filter_effort`` as configured). The decimated scores are what the fit saw; these are what a
    tool that predicts every logged sample is compared with (FIGAROH publishes its TX40 figures
    so). ``prior``: the :func:`~dynid.estimation.validation.prior_comparison` of the two."""

    metrics: ValidationMetrics
    nominal: ValidationMetrics | None = None
    prior: dict[str, Any] | None = None
    decimate: int = 1

    def heading(self) -> str:
        return (f"Validation at the log's full rate (no decimation; the fit used 1 sample in {self.decimate}): "
                f"{self.metrics.n_samples} samples")


@dataclasses.dataclass(frozen=True, eq=False)
class IdentifyOutcome:
    config: Config
    robot: Any  # the RobotModel or Mechanism identified
    base: BaseParameters
    result: IdentificationResult
    validation: ValidationMetrics
    train: Dataset
    held_out: Dataset
    notes: tuple[str, ...]
    raw_train: Dataset | None = None  # the training log before processing (for the processing plot)
    elapsed_s: float = float("nan")  # wall-clock time of the identification (timing.json)
    nominal_validation: ValidationMetrics | None = None  # the nominal (CAD) model on the same held-out rows
    prior: dict[str, Any] | None = None  # prior_comparison of the two
    system: Any = None  # the System identified (its parameters: the model's, or reduced by identification.structure)
    other_view: OtherView | None = None  # redundant mechanisms: the held-out errors in the other form of the equations
    selected: SelectedRows | None = None  # with a row selection: the errors on the held-out rows it keeps
    full_rate: FullRate | None = None  # with decimation: the held-out errors at every logged sample
    learning: Any = None  # [learning]: dynid.pipeline.learning.LearningOutcome (the residual network)
    units: tuple[str, ...] = ()  # unit of each output channel, from the log (effort_units)
    prediction: dict[str, Any] | None = None  # what dynid predict needs (result.json "prediction_inputs")
    structure: dict[str, Any] | None = None  # parallel robots: the parameter structure and, for "auto", its evidence
    # which path ran (result.json "data_path"): "in-memory", or "streamed" (dynid.pipeline.streaming: then
    # train, held_out and raw_train are None and the validation metrics keep no arrays)
    data_path: dict[str, Any] | None = None
    # the joint arm + payload mode: dynid.pipeline.payload.PayloadOutcome (payload.json/.urdf/.xml), None without
    payload: Any = None
    # the report's figures, under way beside the run (dynid.report.worker; plots only)
    jobs: Any = dataclasses.field(default=None, repr=False, compare=False)
    # a streamed run with plots: (raw, processed) training signals for plot_processing, thinned and with Welch
    # spectra (dynid.pipeline.stream_plots.StreamedSignals); the validation figure's series are in validation.thinned
    streamed_plots: tuple[Any, Any] | None = None
    # what the log looks like against the description and the nominal model: units, sign, column order
    # (dynid.pipeline.diagnostics.Alarm; console, summary.txt, result.json "warnings")
    warnings: tuple[Any, ...] = ()

    @property
    def n_train(self) -> int:
        """Processed training samples."""
        return self.train.n_samples if self.train is not None else int(self.data_path["training_samples"])

    @functools.cached_property
    def flags(self) -> dict[str, Any]:
        """:func:`~dynid.pipeline.reporting.parameter_flags` of the result (computed once: the
        physical-consistency check, a semidefinite program, runs with the report only)."""
        system = self.system if self.system is not None else as_system(self.robot)
        return parameter_flags(self.result, self.base, system, physical=self.config.output.plots)

    def robot_line(self) -> str:
        """The robot identified: its name and its description's file (or ``builtin:<name>``)."""
        source = getattr(self.robot, "source", "") or str(self.config.robot.model)
        return f"Robot: {self.robot.name} ({source})"

    def flags_line(self) -> str:
        """How many parameters are flagged (paper 000 Sec. 6.2), and how many of them are
        physically inconsistent, as the report counts them (:func:`parameter_flags`)."""
        f = self.flags
        n = len(self.result.names)
        above, undet = list(f.get("rel_std_above", ())), list(f.get("undetermined", ()))
        phys = f.get("physical") or {}
        inconsistent = list(phys.get("parameters", ())) if phys.get("checked") else []
        flagged = dict.fromkeys([*above, *undet, *inconsistent])
        if not f.get("assessed", True):
            head = f"Flagged parameters: relative standard deviations not assessed ({f.get('reason')})"
        else:
            head = (f"Flagged parameters: {len(flagged)} of {n} ({len(above)} with relative standard deviation >= "
                    f"{f['rel_std_limit_pct']:g} %, {len(undet)} undetermined")
            head += (f", {len(inconsistent)} physically inconsistent)" if phys.get("checked") else ")")
            if flagged:
                head += ": " + ", ".join(flagged)
        if phys.get("checked"):
            head += ("; the base parameters are physically consistent" if phys.get("feasible") else
                     f"; the base parameters are physically INCONSISTENT ({len(phys.get('violated', ()))} constraint(s) "
                     "violated)")
        else:
            head += f"; physical consistency not checked: {phys.get('reason', 'no check')}"
        return head

    def summary_text(self) -> str:
        v = self.validation
        lines = [
            self.robot_line(),
            "",
            str(self.result.summary()),
            "",
            self.flags_line(),
            "",
            v.heading(),
            v.table(),
        ]
        if self.nominal_validation is not None and self.prior is not None:
            lines += ["", "Nominal model (the robot description's parameters: the prior) on the same data",
                      self.nominal_validation.table(), "", self.prior["verdict"]]
            if self.warnings:
                lines.append(f"(not to be trusted before the {len(self.warnings)} warning"
                             f"{'s' if len(self.warnings) > 1 else ''} at the end are resolved: a linear fit absorbs a "
                             "wrong unit, sign or column order into its parameters)")
        sel = self.selected
        if sel is not None:
            lines += ["", sel.heading(), sel.metrics.table()]
            if sel.nominal is not None:
                lines += ["nominal model, the same rows", sel.nominal.table()]
                if sel.prior is not None:
                    lines += ["", sel.prior["verdict"]]
            lines += sel.floor_lines(v, self.nominal_validation)
        fr = self.full_rate
        if fr is not None:
            lines += ["", fr.heading(), fr.metrics.table()]
            if fr.nominal is not None:
                lines += ["nominal model, the same samples", fr.nominal.table()]
                if fr.prior is not None:
                    lines += ["", fr.prior["verdict"]]
        o = self.other_view
        if o is not None:
            lines += ["", f"The same predictions {o.label}", o.metrics.table()]
            if o.nominal is not None:
                lines += ["nominal model, the same view", o.nominal.table()]
        if self.learning is not None:
            lines += self.learning.summary_lines()
        prov = self.result.provenance
        if "experiments" in prov or "validation_logs" in prov:
            lines += _experiments.summary_lines(prov.get("experiments", []), prov.get("validation_logs"),
                                                prov.get("validation_pooled"))
        if self.data_path is not None:
            lines += ["", f"Data path: {self.data_path['mode']} ({self.data_path['reason']})"]
            cl = self.data_path.get("cluster")
            if cl is not None:  # dynid.pipeline.cluster_qr
                lines.append(f"on the cluster: {cl['where']}, {cl['chunks']} chunk{'s' * (cl['chunks'] != 1)} of "
                             f"{cl['chunk_rows']} processed rows on {cl['workers']} workers, QR factors tree-reduced in "
                             f"{cl['tree_levels']} level{'s' * (cl['tree_levels'] != 1)}")
        if self.warnings:
            lines += ["", f"{len(self.warnings)} warning{'s' if len(self.warnings) > 1 else ''} about the logs "
                          "(dynid.pipeline.diagnostics):"] + [str(w) for w in self.warnings]
        if self.structure is not None:
            from dynid.report.html import structure_lines

            lines += structure_lines(self.structure)
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """A notebook's view: the estimates with their standard deviations
        (:meth:`IdentificationResult.summary`), and the held-out errors of the identified model
        beside the nominal model's on the same rows, with the verdict of :func:`prior_comparison`."""
        import html

        v, nom = self.validation, self.nominal_validation
        head = ["channel", "RMSE", "rel RMSE %", "R^2"] + (["nominal RMSE", "nominal rel RMSE %"] if nom is not None else [])
        rows = []
        for j, c in enumerate(v.channel_names):
            cells = [c, f"{v.rmse[j]:.4g}", f"{v.rel_rmse_pct[j]:.3g}", f"{v.r2[j]:.4f}"]
            if nom is not None:
                cells += [f"{nom.rmse[j]:.4g}", f"{nom.rel_rmse_pct[j]:.3g}"]
            rows.append("<tr>" + "".join(f"<td>{html.escape(x)}</td>" for x in cells) + "</tr>")
        table = ("<table><thead><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr></thead><tbody>"
                 + "".join(rows) + "</tbody></table>")
        verdict = f"<p>{html.escape(self.prior['verdict'])}</p>" if self.prior is not None else ""
        return (f"<div class='dynid-outcome'>{self.result.summary().as_html()}"
                f"<h4>{html.escape(v.heading())}</h4>{table}{verdict}</div>")


def _versions() -> dict[str, str]:
    from importlib import metadata

    import numpy
    import pinocchio
    import scipy

    try:
        cvxpy = metadata.version("cvxpy")
    except metadata.PackageNotFoundError:
        cvxpy = "not installed"
    return {
        "dynid": __version__,
        "git_commit": git_commit() or "not a git checkout",
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "pinocchio": pinocchio.__version__,
        "cvxpy": cvxpy,
    }


