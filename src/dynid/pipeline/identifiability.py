"""``dynid identifiability``: the model-structure search of paper 000 on an identify config.

Mata / Farhat et al. (paper 000, §6.2) call a base parameter *properly identified* when its
relative standard deviation is below 15 % and the identified set is physically feasible, and
identify a sequence of models with fewer and fewer parameters (3-RPS: models 1–4 with 37, 24,
18 and 12 parameters; Tables 5–6). This module runs that procedure on the logs of an ordinary
``dynid identify`` configuration (``[robot]``, ``[data]``, ``[validation]``, ``[processing]``,
``[identification]``), through :mod:`dynid.estimation.identifiability`:

1. the training log is read and processed exactly as ``dynid identify`` does and compressed
   into the full base-parameter problem (model 1);
2. :func:`~dynid.estimation.identifiability.structure_search` removes the parameter of largest
   relative standard deviation and refits until every one is below the threshold; models 2
   and 3 are the steps of that sequence whose parameter counts divide the way from
   model 1 to the final model (model 4) as the paper's do (37 → 24 → 18 → 12,
   :func:`paper_models`); each of models 1–4 is checked for physical feasibility
   (:func:`~dynid.estimation.identifiability.is_feasible` on the full base vector with the
   removed parameters at zero);
3. every test log (the training log, in sample; the ``[validation]`` log; extra logs read like
   it) is processed identically and gives Table 4: the condition number of its base regressor
   and the relative absolute error ε_RA (paper 000 Eq. 33) of models 1–4, of the nominal
   model and, with a truth, of the true model (what noise and processing alone leave);
4. Table 5 lists the parameters of models 1–4 (value, relative std %, ``*`` where the value
   takes part in a violated feasibility constraint), with the truth alongside when known (the
   ``truth.json`` of ``dynid simulate``); Table 6 per model: parameters, identified by the
   15 % criterion, properly identified (also not marked), ε_RA and ε_AV (paper 000 Eq. 34).

Only estimators that report a covariance and refit sub-problems qualify: ``method = "ols"``
or ``"wls"``, without physical consistency, with linear friction (a constrained fit has no
covariance, sub-models have no map to standard parameters).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import Config, DataConfig
from dynid.errors import ConfigError, InputError
from dynid.estimation.identifiability import (
    Feasibility,
    ModelSequence,
    is_feasible,
    structure_search,
    violating_parameters,
)
from dynid.estimation.results import Summary
from dynid.io.output import staged_output
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System
from dynid.pipeline.data import (
    build_system,
    check_held_out,
    check_joint_motion,
    check_units,
    configured_estimator,
    preprocess,
    read_log,
    to_actuator_space,
)
from dynid.pipeline.rows import Progress, _chunks, _no_progress, build_problem, row_mask
from dynid.stats import average_error

__all__ = ["PAPER_COUNTS", "TestLog", "IdentifiabilityOutcome", "paper_models", "truth_base", "load_truth",
           "run_identifiability", "write_identifiability", "IDENTIFIABILITY_FILES"]

PAPER_COUNTS = (37, 24, 18, 12)
"""Parameters of paper 000's models 1–4 of the 3-RPS (Table 6)."""
IDENTIFIABILITY_FILES = ("tables.txt", "identifiability.json", "models.csv", "tests.csv")


def paper_models(sequence: ModelSequence) -> tuple[int, ...]:
    """Indices into ``sequence.steps`` of models 1–4 in the sense of paper 000 Table 6.

    Model 1 is the full model, model 4 the final one (every parameter identified). Models 2
    and 3 are the steps whose parameter counts are nearest to
    :math:`n_4 + (n_1 - n_4)\\,(c_k - 12)/(37 - 12)` with :math:`c_k` = 24 and 18, the
    paper's counts (ties: the earlier, larger model). Coinciding models are listed once.
    """
    counts = np.array([len(s.names) for s in sequence.steps])
    n1, n4 = counts[0], counts[-1]
    c1, c4 = PAPER_COUNTS[0], PAPER_COUNTS[-1]
    picks = [0]
    for c in PAPER_COUNTS[1:-1]:
        target = n4 + (n1 - n4) * (c - c4) / (c1 - c4)
        picks.append(int(np.argmin(np.abs(counts - target))))
    picks.append(len(counts) - 1)
    return tuple(sorted(set(picks)))


@dataclasses.dataclass(frozen=True, eq=False)
class TestLog:
    """One trajectory of Table 4.

    Attributes
    ----------
    name : str
    source : str
        File (or label) the log came from.
    in_sample : bool
        The training log itself.
    n_rows : int
        Equations used (samples x channels, after the processing's row selection).
    condition_number : dict model label -> float
        2-norm condition number of the trajectory's stacked base regressor restricted to the
        model's columns.
    scaled_condition_number : dict model label -> float
        The same with every column scaled to unit norm (independent of the parameters' units).
    eps_ra : dict model label -> float
        ε_RA [%] (paper 000 Eq. 33) of each model, of ``"nominal"`` (the robot description's
        parameters) and, when the truth is known, of ``"true"`` (the simulated plant's).
    """

    name: str
    source: str
    in_sample: bool
    n_rows: int
    condition_number: dict[str, float]
    scaled_condition_number: dict[str, float]
    eps_ra: dict[str, float]


def _cond(R: FloatArray, scaled: bool) -> float:
    if scaled:
        norms = np.linalg.norm(R, axis=0)
        R = R / np.where(norms > 0, norms, 1.0)
    s = np.linalg.svd(R, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def _evaluate(system: System, base: BaseParameters, ds, cfg: Config, force_model, betas: Mapping[str, FloatArray],
              columns: Mapping[str, Sequence[int]], name: str, in_sample: bool) -> TestLog:
    """ε_RA of every model and the condition numbers on one processed log, chunk by chunk."""
    pcfg, icfg = cfg.processing, cfg.identification
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    labels = list(betas)
    B = np.column_stack([betas[k] for k in labels])
    n_ch = len(system.channel_names(force_model))
    ys: list[list[FloatArray]] = [[] for _ in range(n_ch)]
    preds: list[list[FloatArray]] = [[] for _ in range(n_ch)]
    R = np.zeros((0, base.n_base))
    for c in _chunks(system, base, ds, force_model, parallel_decimate=parallel, chunk_size=icfg.chunk_size,
                     periodic=pcfg.periodic, reversal_guard=pcfg.reversal_guard_s(),
                     min_velocity=pcfg.min_velocity):
        mask = row_mask(system, force_model, c.dq, pcfg.min_velocity, joint_dq=c.joint_dq,
                        min_velocity_passive=pcfg.min_velocity_passive, reversal=c.reversal)
        n = c.y.shape[0]
        m = np.ones((n, n_ch), bool) if mask is None else (np.repeat(mask[:, None], n_ch, 1) if mask.ndim == 1 else mask)
        rows = []
        for j in range(n_ch):
            W = c.W[m[:, j], j, :]
            ys[j].append(c.y[m[:, j], j])
            preds[j].append(W @ B)
            rows.append(W)
        R = np.linalg.qr(np.vstack([R, *rows]), mode="r")
    num, den = np.zeros(len(labels)), 0.0
    n_rows = 0
    for j in range(n_ch):
        y = np.concatenate(ys[j])
        if y.size == 0:
            continue
        p = np.concatenate(preds[j])
        n_rows += y.size
        num += np.sum(np.abs(y[:, None] - p), axis=0)
        den += float(np.sum(np.abs(y - y.mean())))
    if n_rows <= base.n_base or den <= 0:
        raise InputError(f"{name}: {n_rows} equations after the row selection: too few to evaluate the models")
    eps = {k: float(100.0 * num[i] / den) for i, k in enumerate(labels)}
    cond = {k: _cond(R[:, list(cols)], False) for k, cols in columns.items()}
    scaled = {k: _cond(R[:, list(cols)], True) for k, cols in columns.items()}
    return TestLog(name, str(ds.meta.get("source", name)), in_sample, n_rows, cond, scaled, eps)


def load_truth(path: str | Path) -> dict[str, Any]:
    """A ``truth.json`` written by ``dynid simulate`` (``parameter_names``, ``true_parameters``)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as exc:
        raise InputError(f"--truth {p}: cannot read ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"--truth {p}: not JSON ({exc.msg}, line {exc.lineno})") from None
    if not (isinstance(doc, dict) and isinstance(doc.get("parameter_names"), list)
            and isinstance(doc.get("true_parameters"), list)
            and len(doc["parameter_names"]) == len(doc["true_parameters"])):
        raise InputError(f"--truth {p}: expected the truth.json of dynid simulate (parameter_names and "
                         "true_parameters of equal length)")
    return doc


def _derived(name: str, values: Mapping[str, float], model_names: set[str]) -> float | None:
    """A joint term the plant has in another parametrization (None: unknown). A plant with
    symmetric linear friction and no offset: an offset is 0; asymmetric columns carry the
    plant's ``fc`` / ``fv`` (``fc+`` = ``fc``, ``fc-`` = ``-fc``, ``fv+`` = ``fv-`` = ``fv``)
    unless the model has the symmetric term too, which then holds all of it (they are 0)."""
    head, _, joint = name.partition("_")
    if head in ("offset", "off"):
        return 0.0
    src = {"fc+": ("fc", 1.0), "fc-": ("fc", -1.0), "fv+": ("fv", 1.0), "fv-": ("fv", 1.0)}.get(head)
    if src is None or f"{src[0]}_{joint}" not in values:
        return None
    if f"{src[0]}_{joint}" in model_names:
        return 0.0
    return src[1] * float(values[f"{src[0]}_{joint}"])


def truth_base(truth: Mapping[str, Any], base: BaseParameters) -> tuple[FloatArray, list[str]]:
    """True base parameters of ``base`` from a truth document (standard names and values).

    Joint terms the plant has in another parametrization are derived (:func:`_derived`: a
    plant with symmetric Coulomb + viscous friction has ``fc+ = fc`` and ``fc- = -fc``; an
    offset it lacks is 0); any other missing standard parameter raises
    :class:`~dynid.errors.InputError`. Returns the vector and notes.
    """
    try:
        values = {str(n): float(v) for n, v in zip(truth["parameter_names"], truth["true_parameters"])}
    except (TypeError, ValueError):
        raise InputError("the truth's true_parameters are not all numbers") from None
    have = set(base.standard_names)
    derived = {n: _derived(n, values, have) for n in base.standard_names if n not in values}
    other = [n for n, v in derived.items() if v is None]
    if other:
        raise InputError(f"the truth has no value for the model's standard parameters {other[:4]}"
                         f"{' ...' if len(other) > 4 else ''} (a truth.json of another robot?)")
    pi = np.array([values[n] if n in values else float(derived[n]) for n in base.standard_names])
    notes = ([f"truth: {', '.join(derived)} absent from the simulated plant (symmetric linear friction, no "
              "offset): derived from its joint terms or 0"] if derived else [])
    return base.from_standard(pi), notes


@dataclasses.dataclass(frozen=True, eq=False)
class IdentifiabilityOutcome:
    """The model sequence, models 1–4 and the three tables of paper 000."""

    config: Config
    base: BaseParameters
    sequence: ModelSequence
    models: tuple[int, ...]  # indices into sequence.steps of models 1-4
    feasibility: tuple[Feasibility, ...]  # of models 1-4 (the removed parameters at zero)
    marked: tuple[tuple[str, ...], ...]  # per model of ``models``: parameters in a violated constraint
    tests: tuple[TestLog, ...]
    truth: FloatArray | None
    notes: tuple[str, ...]
    elapsed_s: float = float("nan")

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(f"model {k + 1}" for k in range(len(self.models)))

    def step(self, k: int):
        return self.sequence.steps[self.models[k]]

    def _truth_of(self, names: Sequence[str]) -> FloatArray | None:
        if self.truth is None:
            return None
        idx = {n: i for i, n in enumerate(self.base.names)}
        return self.truth[[idx[n] for n in names]]

    def eps_av(self, k: int) -> float | None:
        """ε_AV [%] (paper 000 Eq. 34) of model ``k``'s estimates against the true base parameters,
        over its parameters whose true value is not zero (None without a truth)."""
        s = self.step(k)
        true = self._truth_of(s.names)
        if true is None:
            return None
        keep = np.abs(true) > 1e-12 * max(float(np.max(np.abs(self.truth))), 1e-300)
        return average_error(true[keep], s.result.params[keep]) if keep.any() else None

    def properly_identified(self, k: int) -> int:
        """Parameters of model ``k`` below the threshold and in no violated feasibility constraint."""
        s = self.step(k)
        rel = s.result.rel_std
        ok = np.isfinite(rel) & (rel < self.sequence.threshold_pct)
        return int(sum(bool(o) and n not in self.marked[k] for n, o in zip(s.names, ok)))

    # ------------------------------------------------------------------ tables
    def table4(self) -> tuple[tuple[str, ...], ...]:
        labels = self.labels
        head = ("trajectory", "rows", f"cond ({labels[0]})", "scaled cond", f"cond ({labels[-1]})", "scaled cond")
        head += tuple(f"eps_RA {lab}" for lab in labels) + ("eps_RA nominal",)
        truth = self.truth is not None
        head += ("eps_RA true",) if truth else ()
        rows = [head]
        for t in self.tests:
            name = t.name + (" (in sample)" if t.in_sample else "")
            rows.append((name, str(t.n_rows), f"{t.condition_number[labels[0]]:.4g}",
                         f"{t.scaled_condition_number[labels[0]]:.4g}", f"{t.condition_number[labels[-1]]:.4g}",
                         f"{t.scaled_condition_number[labels[-1]]:.4g}")
                        + tuple(f"{t.eps_ra[lab]:.2f}" for lab in labels) + (f"{t.eps_ra['nominal']:.2f}",)
                        + ((f"{t.eps_ra['true']:.2f}",) if truth else ()))
        return tuple(rows)

    def table5(self) -> tuple[tuple[str, ...], ...]:
        labels = self.labels
        head = ("parameter",) + (("truth",) if self.truth is not None else ())
        for lab in labels:
            head += (f"{lab}", "rel std %")
        rows = [head]
        full = self.step(0).names
        truth = self._truth_of(full)
        for i, name in enumerate(full):
            row = (name,) + ((f"{truth[i]:.5g}",) if truth is not None else ())
            for k in range(len(labels)):
                s = self.step(k)
                if name in s.names:
                    j = s.names.index(name)
                    mark = "*" if name in self.marked[k] else ""
                    row += (f"{s.result.params[j]:.5g}{mark}", f"{s.result.rel_std[j]:.3g}")
                else:
                    row += ("-", "-")
            rows.append(row)
        return tuple(rows)

    def table6(self) -> tuple[tuple[str, ...], ...]:
        rows = [("model", "step", "parameters", f"rel std < {self.sequence.threshold_pct:g} %", "properly identified",
                 "feasible", "eps_RA % (held out)", "eps_AV %")]
        held = [t for t in self.tests if not t.in_sample]
        for k, lab in enumerate(self.labels):
            s = self.step(k)
            eps = np.mean([t.eps_ra[lab] for t in held]) if held else float("nan")
            feas = "yes" if self.feasibility[k].feasible else "no"
            av = self.eps_av(k)
            rows.append((lab, str(self.models[k] + 1), str(len(s.names)), str(s.n_identified),
                         str(self.properly_identified(k)), feas, f"{eps:.2f}", "-" if av is None else f"{av:.3g}"))
        return tuple(rows)

    def summary_text(self) -> str:
        held = [t.name for t in self.tests if not t.in_sample]
        lines = ["Table 4 (paper 000): condition number of each trajectory's base regressor, eps_RA [%] (Eq. 33)",
                 *Summary._fmt_table(self.table4()),
                 "", "Table 5 (paper 000): parameters of models 1-4, value and relative std [%]; "
                     "* = takes part in a violated feasibility constraint",
                 *Summary._fmt_table(self.table5()),
                 "", f"Table 6 (paper 000): eps_RA mean over the held-out logs ({', '.join(held) or 'none'}), "
                     "eps_AV (Eq. 34) against the truth",
                 *Summary._fmt_table(self.table6()),
                 "", "The whole sequence:", self.sequence.as_text()]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        steps = []
        for i, s in enumerate(self.sequence.steps):
            steps.append({"step": i + 1, "names": list(s.names), "params": s.result.params.tolist(),
                          "bse": s.result.bse.tolist(), "rel_std_pct": s.result.rel_std.tolist(),
                          "n_identified": s.n_identified, "max_rel_std_pct": s.max_rel_std, "worst": s.worst,
})
        models = []
        for k, lab in enumerate(self.labels):
            models.append({"model": lab, "step": self.models[k] + 1, "n_params": len(self.step(k).names),
                           "n_identified": self.step(k).n_identified,
                           "n_properly_identified": self.properly_identified(k),
                           "feasible": bool(self.feasibility[k].feasible),
                           "violated": list(self.feasibility[k].violated),
                           "feasibility_status": self.feasibility[k].status,
                           "marked": list(self.marked[k]), "eps_av_pct": self.eps_av(k)})
        return {
            "criterion": self.sequence.criterion, "threshold_pct": self.sequence.threshold_pct,
            "stop_reason": self.sequence.stop_reason, "base_names": list(self.base.names),
            "truth_base": None if self.truth is None else self.truth.tolist(),
            "models": models, "steps": steps,
            "tests": [dataclasses.asdict(t) for t in self.tests],
            "notes": list(self.notes), "elapsed_s": self.elapsed_s,
            "config_file": str(self.config.source) if self.config.source else None,
        }


def _check_config(cfg: Config) -> None:
    icfg = cfg.identification
    if icfg.method not in ("ols", "wls"):
        raise ConfigError(f"identifiability: identification.method = {icfg.method!r}; the structure search refits "
                          "sub-models by least squares with a covariance: use 'ols' or 'wls'")
    if icfg.physical_consistency:
        raise ConfigError("identifiability: identification.physical_consistency = true has no covariance and its "
                          "sub-models no map to standard parameters; the search checks feasibility after each fit "
                          "(paper 000 §6.2): set it to false")
    if icfg.hierarchical:
        raise ConfigError("identifiability: identification.hierarchical = true alternates nonlinear friction fits; the "
                          "search needs a linear model: remove it")
    if icfg.friction_model != "linear":
        raise ConfigError(f"identifiability: identification.friction_model = {icfg.friction_model!r}; the search "
                          "needs a linear model: use 'linear'")


def _marked(names: Sequence[str], feas: Feasibility, base: BaseParameters, smap) -> tuple[str, ...]:
    """Parameters among ``names`` whose grouping touches a constraint that :func:`is_feasible`
    found violated (a body's pseudo-inertia, a non-negative joint term)."""
    return violating_parameters(names, feas, base.names, smap)


def run_identifiability(cfg: Config, *, tests: Sequence[tuple[str, DataConfig]] = (),
                        truth: Mapping[str, Any] | None = None, threshold_pct: float = 15.0,
                        validation_name: str = "validation", progress: Progress = _no_progress) -> IdentifiabilityOutcome:
    """Paper 000's identifiability procedure on the logs of ``cfg`` (nothing is written).

    Parameters
    ----------
    cfg : Config
        An identify configuration (``method`` ``"ols"`` or ``"wls"``, no physical consistency).
    tests : sequence of (name, DataConfig)
        Further test logs for Table 4, read like ``[validation]``.
    truth : mapping, optional
        ``truth.json`` of ``dynid simulate`` (:func:`load_truth`): Table 5's truth column and ε_AV.
    threshold_pct : float
        Relative standard deviation counted as identified [%] (15 in paper 000).
    validation_name : str
        Name of the ``[validation]`` log in Table 4.
    """
    t0 = time.perf_counter()
    _check_config(cfg)
    system = build_system(cfg.robot)
    icfg, pcfg = cfg.identification, cfg.processing
    force_model = system.force_model(icfg.force_model)
    names, kinds = system.actuator_names, system.actuator_kinds()
    specs = [("training", cfg.data), (validation_name, cfg.validation), *tests]
    for label, spec in specs:
        check_units(spec, kinds, names, label)
    readers: dict = {}
    logs = []
    for label, spec in specs:
        raw = read_log(spec, system.n_actuators, names, label, readers)
        if logs:
            check_held_out(logs[0][2], raw)
        act, _ = to_actuator_space(raw, system, label)
        logs.append((label, act, raw))
    channels = system.channel_names(force_model)
    base = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    train, steps = preprocess(logs[0][1], pcfg, "data", unknowns=lambda: (base.n_base, len(channels)))
    check_joint_motion(train, system, icfg.min_joint_motion, "data")
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    problem = build_problem(system, base, train, force_model=force_model, min_velocity=pcfg.min_velocity,
                            parallel_decimate=parallel, chunk_size=icfg.chunk_size, progress=progress,
                            periodic=pcfg.periodic, min_velocity_passive=pcfg.min_velocity_passive,
                            reversal_guard=pcfg.reversal_guard_s(),
                            meta={"processing": steps})
    if problem.n_total <= base.n_base:
        raise InputError(f"data: {problem.n_total} equations are too few for the {base.n_base} base parameters")
    nominal = base.from_standard(system.nominal_parameters())
    estimator = configured_estimator(icfg, steps, tuple(channels), tuple(names), nominal)
    progress("structure search", 0, 1)
    sequence = structure_search(problem, estimator, threshold_pct=threshold_pct)
    progress("structure search", 1, 1)
    models = paper_models(sequence)
    smap = system.standard_map(base)
    labels = tuple(f"model {k + 1}" for k in range(len(models)))
    idx = {n: i for i, n in enumerate(base.names)}
    betas: dict[str, FloatArray] = {}
    columns: dict[str, list[int]] = {}
    feasibility, marked = [], []
    for lab, i in zip(labels, models):
        s = sequence.steps[i]
        beta = np.zeros(base.n_base)
        cols = [idx[n] for n in s.names]
        beta[cols] = s.result.params
        betas[lab], columns[lab] = beta, cols
        feasibility.append(is_feasible(beta, smap))  # the removed parameters at zero, as structure_search does
        marked.append(_marked(s.names, feasibility[-1], base, smap))
    betas["nominal"] = nominal
    notes: list[str] = []
    true = None
    if truth is not None:
        true, notes = truth_base(truth, base)
        betas["true"] = true
    evaluated = [_evaluate(system, base, train, cfg, force_model, betas, columns, "training", True)]
    for label, act, _ in logs[1:]:
        ds, _ = preprocess(act, pcfg, label)
        evaluated.append(_evaluate(system, base, ds, cfg, force_model, betas, columns, label, False))
    if pcfg.selects_rows:
        notes.append("every log is scored on the rows the processing keeps (processing.min_velocity, "
                     "min_velocity_passive, reversal_guard)")
    return IdentifiabilityOutcome(cfg, base, sequence, models, tuple(feasibility), tuple(marked), tuple(evaluated),
                                  true, tuple(notes),
                                  time.perf_counter() - t0)


def write_identifiability(outcome: IdentifiabilityOutcome, out_dir: str | Path) -> list[str]:
    """Write tables.txt, identifiability.json, models.csv (Table 5, long form) and tests.csv
    (Table 4) into ``out_dir``, all or nothing (:func:`dynid.io.output.staged_output`)."""
    with staged_output(out_dir) as stage:
        (stage / "tables.txt").write_text(outcome.summary_text() + "\n")
        (stage / "identifiability.json").write_text(json.dumps(outcome.to_dict(), indent=2) + "\n")
        truth = dict(zip(outcome.base.names, outcome.truth)) if outcome.truth is not None else {}
        with open(stage / "models.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["model", "step", "name", "value", "std", "rel_std_pct", "marked_infeasible", "truth"])
            for k, lab in enumerate(outcome.labels):
                s = outcome.step(k)
                for j, n in enumerate(s.names):
                    w.writerow([lab, outcome.models[k] + 1, n, repr(float(s.result.params[j])),
                                repr(float(s.result.bse[j])), f"{s.result.rel_std[j]:.6g}",
                                int(n in outcome.marked[k]), repr(float(truth[n])) if n in truth else ""])
        with open(stage / "tests.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            labels = outcome.labels
            w.writerow(["trajectory", "in_sample", "rows", *[f"cond_{lab.replace(' ', '')}" for lab in labels],
                        *[f"scaled_cond_{lab.replace(' ', '')}" for lab in labels],
                        *[f"eps_ra_{lab.replace(' ', '')}" for lab in labels], "eps_ra_nominal",
                        *(["eps_ra_true"] if outcome.truth is not None else [])])
            for t in outcome.tests:
                w.writerow([t.name, int(t.in_sample), t.n_rows, *[repr(t.condition_number[lab]) for lab in labels],
                            *[repr(t.scaled_condition_number[lab]) for lab in labels],
                            *[repr(t.eps_ra[lab]) for lab in labels], repr(t.eps_ra["nominal"]),
                        *([repr(t.eps_ra["true"])] if outcome.truth is not None else [])])
        produced = sorted(p.name for p in stage.iterdir())
    return produced
