"""Identifiability analysis: which parameters the data determine, and which model to keep.

Four tools on top of any linear estimator (``fit(problem) -> IdentificationResult``):

- :func:`identified` — the criterion of Mata / Farhat et al. (paper 000, §6.2): a base
  parameter is *properly identified* when its relative standard deviation
  :math:`\\sigma_{\\hat p_i}\\% = 100\\,\\sigma_{\\hat p_i}/|\\hat p_i|` (paper 001, Eq. 20) is
  below 15 % *and* the parameter set is physically feasible (:func:`is_feasible`).
- :func:`is_feasible` — whether a base-parameter vector is the image :math:`B\\pi` of a
  physically consistent standard vector :math:`\\pi` (paper 000 §6.2 checks feasibility
  after the identification, following Yoshida et al. 1996).
- :func:`structure_search` — the model sequence of paper 000 (models 1–4 of the 3-RPS,
  37 → 24 → 18 → 12 parameters, Table 6): drop the least certain parameter and refit
  until every remaining parameter is identified; :func:`essential_parameters` — the
  backward elimination of Pham & Gautier (essential parameters), stopped by the
  residual instead of the relative standard deviation.
- :func:`select_friction_structure` — rank candidate friction parametrizations by the
  condition number of the correlation matrix of the estimates (paper 004, Eq. 11).

Sub-models are exact: :meth:`RegressionProblem.select` re-triangularizes the kept columns
of the compressed factors, so each refit equals a least-squares fit on the raw data with
the dropped parameters fixed at zero.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from typing import Protocol

import numpy as np

from dynid._typing import BoolArray, FloatArray
from dynid.errors import InputError
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult, Summary
from dynid.estimation.feasibility import Feasibility, is_feasible, violating_parameters  # noqa: F401  (re-exported)

__all__ = [
    "Feasibility",
    "ModelStep",
    "ModelSequence",
    "RankedStructure",
    "StructureRanking",
    "identified",
    "identified_names",
    "is_feasible",
    "structure_search",
    "essential_parameters",
    "violating_parameters",
    "select_friction_structure",
]


class Estimator(Protocol):
    def fit(self, problem: RegressionProblem) -> IdentificationResult: ...


def _check_threshold(threshold_pct: float) -> float:
    t = float(threshold_pct)
    if not (np.isfinite(t) and t > 0):
        raise InputError(f"threshold_pct must be a positive number of percent, got {threshold_pct!r}")
    return t


# ---------------------------------------------------------------------- relative std criterion
def identified(result: IdentificationResult, *, threshold_pct: float = 15.0) -> BoolArray:
    """Mask of the parameters whose relative standard deviation is below ``threshold_pct``.

    Parameters
    ----------
    result : IdentificationResult
        A result with a covariance (others raise :class:`~dynid.errors.InputError`).
    threshold_pct : float
        Threshold on :math:`100\\,\\sigma_{\\hat p_i}/|\\hat p_i|` [%]; 15 % in paper 000 §6.2.

    Returns
    -------
    bool array, shape (p,)
        True where :math:`\\sigma_{\\hat p_i}\\% <` ``threshold_pct`` (a zero estimate, of
        infinite relative std, is never identified). Names: ``np.array(result.names)[mask]``
        or :func:`identified_names`.

    Notes
    -----
    Paper 000 calls a parameter properly identified when this holds *and* the parameter
    set is physically feasible; check the latter with :func:`is_feasible`.
    """
    t = _check_threshold(threshold_pct)
    rel = result.rel_std
    return np.isfinite(rel) & (rel < t)


def identified_names(result: IdentificationResult, *, threshold_pct: float = 15.0) -> tuple[str, ...]:
    """Names of the parameters :func:`identified` accepts, in the result's order."""
    mask = identified(result, threshold_pct=threshold_pct)
    return tuple(n for n, ok in zip(result.names, mask) if ok)


# ---------------------------------------------------------------------- physical feasibility
@dataclasses.dataclass(frozen=True, eq=False)
class ModelStep:
    """One model of a :class:`ModelSequence`.

    Attributes
    ----------
    names : tuple of str
        Parameters of this model.
    result : IdentificationResult
        Its fit.
    max_rel_std : float
        Largest relative standard deviation [%] of the parameters that may be dropped
        (all but ``always_keep``); ``nan`` when there are none.
    worst : str or None
        The parameter with that relative standard deviation.
    n_identified : int
        Parameters with relative standard deviation below the threshold.
    residual_growth_pct : float
        :math:`100 \\max_j (\\sqrt{\\mathrm{RSS}_j / \\mathrm{RSS}_{j,0}} - 1)`: how much the
        worst channel's residual norm grew relative to the first model [%].
    feasibility : Feasibility or None
        Physical feasibility of the full base vector with the dropped parameters at zero
        (only when asked for).
    """

    names: tuple[str, ...]
    result: IdentificationResult
    max_rel_std: float
    worst: str | None
    n_identified: int
    residual_growth_pct: float
    feasibility: Feasibility | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class ModelSequence:
    """The models visited by :func:`structure_search` or :func:`essential_parameters`.

    ``str()`` gives a table, one row per model, as paper 000 Table 6 (parameters /
    identified).

    Attributes
    ----------
    steps : tuple of ModelStep
        From the full model to the final one.
    criterion : str
        How parameters were removed and when the search stopped.
    threshold_pct : float
        Relative standard deviation counted as identified [%].
    always_keep : tuple of str
        Parameters never removed.
    stop_reason : str
        Why the search ended.
    """

    steps: tuple[ModelStep, ...]
    criterion: str
    threshold_pct: float
    always_keep: tuple[str, ...]
    stop_reason: str

    @property
    def final(self) -> ModelStep:
        return self.steps[-1]

    @property
    def names(self) -> tuple[str, ...]:
        """Parameters of the final model."""
        return self.final.names

    @property
    def result(self) -> IdentificationResult:
        """Fit of the final model."""
        return self.final.result

    @property
    def dropped(self) -> tuple[str, ...]:
        """Removed parameters, in the order they were removed."""
        out = []
        for a, b in zip(self.steps, self.steps[1:]):
            out += [n for n in a.names if n not in b.names]
        return tuple(out)

    @property
    def all_identified(self) -> bool:
        """Every parameter of the final model is below the threshold."""
        return self.final.n_identified == len(self.final.names)

    def table(self) -> tuple[tuple[str, ...], ...]:
        """Rows of strings, the first being the header."""
        feas = any(s.feasibility is not None for s in self.steps)
        head = ("model", "parameters", "identified", "max rel std %", "worst", "resid. growth %")
        head += ("feasible",) if feas else ()
        rows = [head + ("removed next",)]
        drops = [[n for n in a.names if n not in b.names] for a, b in zip(self.steps, self.steps[1:])] + [[]]
        for k, (s, d) in enumerate(zip(self.steps, drops)):
            row = (str(k + 1), str(len(s.names)), str(s.n_identified), f"{s.max_rel_std:.3g}", s.worst or "-",
                   f"{s.residual_growth_pct:.3g}")
            if feas:
                row += ("-" if s.feasibility is None else ("yes" if s.feasibility.feasible else "no"),)
            rows.append(row + (", ".join(d) or "-",))
        return tuple(rows)

    def as_text(self) -> str:
        lines = [self.criterion, ""] + Summary._fmt_table(self.table()) + ["", f"stopped: {self.stop_reason}"]
        if self.always_keep:
            lines.append(f"always kept: {', '.join(self.always_keep)}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.as_text()


def _check_keep(problem: RegressionProblem, always_keep: Iterable[str]) -> tuple[str, ...]:
    keep = tuple(always_keep)
    unknown = [n for n in keep if n not in problem.names]
    if unknown:
        raise InputError(f"always_keep names unknown parameters {unknown}")
    return keep


def _growth_pct(rss: FloatArray, rss0: FloatArray) -> float:
    rss, rss0 = np.asarray(rss, dtype=float), np.asarray(rss0, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(rss0 > 0, rss / rss0, np.where(rss > rss0, np.inf, 1.0))
    return float(100.0 * (np.sqrt(np.max(ratio)) - 1.0))


class _Fitter:
    """Fits sub-models of one root problem and records them as :class:`ModelStep`."""

    def __init__(self, problem: RegressionProblem, estimator: Estimator, threshold: float,
                 keep: tuple[str, ...], feasibility: bool, tol: float) -> None:
        if feasibility and problem.standard is None:
            raise InputError("a feasibility check needs the problem's map to standard parameters")
        self.problem, self.estimator, self.threshold, self.keep = problem, estimator, threshold, keep
        self.feasibility, self.tol = feasibility, tol
        self.rss0: FloatArray | None = None

    def fit(self, names: Sequence[str]) -> ModelStep:
        names = tuple(names)
        sub = self.problem if names == self.problem.names else self.problem.select(names)
        res = self.estimator.fit(sub)
        rel = res.rel_std  # raises for estimators that give no covariance
        if self.rss0 is None:
            self.rss0 = res.rss_per_channel
        free = [i for i, n in enumerate(names) if n not in self.keep]
        if free:
            rel_free = np.where(np.isnan(rel[free]), np.inf, rel[free])
            w = free[int(np.argmax(rel_free))]
            worst, max_rel = names[w], float(rel[w])
        else:
            worst, max_rel = None, float("nan")
        feas = None
        if self.feasibility:
            full = np.zeros(self.problem.n_params)
            idx = {n: i for i, n in enumerate(self.problem.names)}
            full[[idx[n] for n in names]] = res.params
            feas = is_feasible(full, self.problem.standard, tol=self.tol)
        return ModelStep(
            names=names,
            result=res,
            max_rel_std=max_rel,
            worst=worst,
            n_identified=int(np.count_nonzero(np.isfinite(rel) & (rel < self.threshold))),
            residual_growth_pct=_growth_pct(res.rss_per_channel, self.rss0),
            feasibility=feas,
        )


def structure_search(
    problem: RegressionProblem,
    estimator: Estimator,
    *,
    threshold_pct: float = 15.0,
    always_keep: Iterable[str] = (),
    feasibility: bool = False,
    feasibility_tol: float = 1e-6,
) -> ModelSequence:
    """Model-structure search by relative standard deviation (paper 000 §6.2, Table 6).

    Parameters
    ----------
    problem : RegressionProblem
        The full model (paper 000's model 1).
    estimator : object with ``fit(problem) -> IdentificationResult``
        A linear estimator that reports a covariance (:class:`~dynid.estimation.OLS`,
        :class:`~dynid.estimation.WLS`, ...). Sub-models have no standard map, so
        :class:`~dynid.estimation.PhysicalLS` cannot refit them.
    threshold_pct : float
        A parameter is identified when its relative standard deviation is below this
        [%] (15 % in paper 000).
    always_keep : iterable of str
        Parameters never removed (e.g. friction terms the controller needs); they may
        stay above the threshold.
    feasibility : bool
        Also check each model's physical feasibility (:func:`is_feasible` on the full
        base vector with the removed parameters at zero; needs ``problem.standard``).
    feasibility_tol : float
        ``tol`` of :func:`is_feasible`.

    Returns
    -------
    ModelSequence
        Every model fitted, from the full one to the final one, in which every parameter
        not in ``always_keep`` is identified.

    Notes
    -----
    Algorithm: fit; if some parameter outside ``always_keep`` has a relative standard
    deviation :math:`\\ge` ``threshold_pct``, remove the one with the largest (a zero
    estimate counts as infinite) and refit the exact sub-problem
    (:meth:`RegressionProblem.select`); repeat. Removing one parameter at a time matters:
    the relative standard deviations of the others change when a correlated parameter
    goes. Paper 000 reports models of 37, 24, 18 and 12 parameters for the 3-RPS, with
    4, 12, 12 and 12 identified (Table 6); its intermediate models are hand-chosen
    groups, this search produces the one-at-a-time sequence. The search stops with a
    single parameter left even if that one is not identified.
    """
    t = _check_threshold(threshold_pct)
    keep = _check_keep(problem, always_keep)
    fitter = _Fitter(problem, estimator, t, keep, feasibility, feasibility_tol)
    steps = [fitter.fit(problem.names)]
    while True:
        s = steps[-1]
        if s.worst is None or not s.max_rel_std >= t:
            if s.n_identified == len(s.names):
                reason = f"every parameter is below {t:g} % relative std"
            else:
                above = [n for n, r in zip(s.names, s.result.rel_std) if not r < t]
                reason = (f"every removable parameter is below {t:g} % relative std; "
                          f"always_keep parameters above it: {', '.join(above)}")
            break
        if len(s.names) == 1:
            reason = f"one parameter left ({s.worst}, {s.max_rel_std:.3g} % relative std)"
            break
        steps.append(fitter.fit([n for n in s.names if n != s.worst]))
    criterion = (f"structure search (paper 000 §6.2): remove the parameter of largest relative std while it is "
                 f">= {t:g} %, refit")
    return ModelSequence(steps=tuple(steps), criterion=criterion, threshold_pct=t, always_keep=keep, stop_reason=reason)


def essential_parameters(
    problem: RegressionProblem,
    estimator: Estimator,
    *,
    tol_pct: float = 2.0,
    threshold_pct: float = 15.0,
    always_keep: Iterable[str] = (),
) -> ModelSequence:
    """Essential parameters by backward elimination (after Pham & Gautier 1991).

    Parameters
    ----------
    problem : RegressionProblem
        The full model.
    estimator : object with ``fit(problem) -> IdentificationResult``
        A linear estimator that reports a covariance.
    tol_pct : float
        Largest accepted growth [%] of any channel's residual norm relative to the full
        model (default 2 %).
    threshold_pct : float
        Only used to count identified parameters in the table [%].
    always_keep : iterable of str
        Parameters never removed.

    Returns
    -------
    ModelSequence
        The accepted models; the final one holds the essential parameters.

    Notes
    -----
    Criterion: starting from the full model, the parameter with the largest relative
    standard deviation (outside ``always_keep``) is removed and the model refitted,
    as long as the residual stays close to the full model's on every output channel:

    .. math::

        \\max_j \\sqrt{\\mathrm{RSS}_j(\\text{reduced}) / \\mathrm{RSS}_j(\\text{full})} - 1
        \\le \\mathrm{tol}.

    The first candidate whose removal exceeds ``tol_pct`` is not removed and the search
    stops. Unlike :func:`structure_search` it may remove parameters that are well
    determined but contribute little to the outputs, and keeps uncertain ones that do
    contribute; comparing to the *full* model (not the previous step) keeps small
    increases from accumulating. The criterion is per channel and so independent of the
    channels' units and weights.
    """
    t = _check_threshold(threshold_pct)
    tol = float(tol_pct)
    if not (np.isfinite(tol) and tol >= 0):
        raise InputError(f"tol_pct must be a non-negative number of percent, got {tol_pct!r}")
    keep = _check_keep(problem, always_keep)
    fitter = _Fitter(problem, estimator, t, keep, False, 0.0)
    steps = [fitter.fit(problem.names)]
    while True:
        s = steps[-1]
        if s.worst is None:
            reason = "only parameters in always_keep are left"
            break
        if len(s.names) == 1:
            reason = f"one parameter left ({s.names[0]})"
            break
        trial = fitter.fit([n for n in s.names if n != s.worst])
        if trial.residual_growth_pct > tol:
            reason = (f"removing {s.worst} would raise a channel's residual norm by "
                      f"{trial.residual_growth_pct:.3g} % > {tol:g} %")
            break
        steps.append(trial)
    criterion = (f"essential parameters (Pham & Gautier): remove the parameter of largest relative std while no "
                 f"channel's residual norm grows by more than {tol:g} % over the full model")
    return ModelSequence(steps=tuple(steps), criterion=criterion, threshold_pct=t, always_keep=keep, stop_reason=reason)


# ---------------------------------------------------------------------- friction structure
@dataclasses.dataclass(frozen=True, eq=False)
class RankedStructure:
    """One candidate of :func:`select_friction_structure`.

    Attributes
    ----------
    name : str
    result : IdentificationResult
    correlation_condition_number : float
        :math:`\\upsilon = \\mathrm{cond}(\\varrho)` (paper 004, Eq. 11).
    max_rel_std : float
        Largest relative standard deviation [%].
    worst : str
        Parameter with that relative standard deviation.
    """

    name: str
    result: IdentificationResult
    correlation_condition_number: float
    max_rel_std: float
    worst: str


@dataclasses.dataclass(frozen=True, eq=False)
class StructureRanking:
    """Candidates ordered by increasing correlation condition number (best first)."""

    entries: tuple[RankedStructure, ...]

    @property
    def best(self) -> RankedStructure:
        return self.entries[0]

    def table(self) -> tuple[tuple[str, ...], ...]:
        rows = [("rank", "structure", "parameters", "cond(rho)", "max rel std %", "worst", "train RMSE per channel")]
        for k, e in enumerate(self.entries):
            rmse = ", ".join(f"{v:.3g}" for v in e.result.rmse_per_channel)
            rows.append((str(k + 1), e.name, str(len(e.result.names)), f"{e.correlation_condition_number:.4g}",
                         f"{e.max_rel_std:.3g}", e.worst, rmse))
        return tuple(rows)

    def as_text(self) -> str:
        head = "friction structures ranked by the condition number of the correlation matrix (paper 004, Eq. 11)"
        return "\n".join([head, ""] + Summary._fmt_table(self.table()))

    def __str__(self) -> str:
        return self.as_text()


def select_friction_structure(candidates: Mapping[str, RegressionProblem], estimator: Estimator) -> StructureRanking:
    """Rank candidate model structures by the condition number of the correlation matrix.

    Parameters
    ----------
    candidates : mapping name -> RegressionProblem
        The same data with different parameter sets (e.g. friction of the passive joints
        left out, viscous only, Coulomb and viscous, ...); all must have the same output
        channels.
    estimator : object with ``fit(problem) -> IdentificationResult``
        A linear estimator that reports a covariance.

    Returns
    -------
    StructureRanking
        Candidates sorted by increasing :math:`\\upsilon` (ties keep the given order);
        ``str()`` gives the table.

    Notes
    -----
    Abdellatif & Heimann (paper 004), Eq. 11: with :math:`P` the covariance of the
    estimates, :math:`\\varrho_{ij} = P_{ij}/\\sqrt{P_{ii}P_{jj}}` and the eligibility
    criterion of a model is :math:`\\upsilon = \\mathrm{cond}(\\varrho)`. Because
    :math:`\\varrho` has unit diagonal, :math:`\\upsilon` compares models of different
    dimensions; a friction parametrization whose terms the data cannot separate from
    the others shows as strongly correlated estimates and a large :math:`\\upsilon`.
    Judge the fit too (the table gives the training RMSE): a structure that leaves
    friction out entirely has a small :math:`\\upsilon` but a worse fit.
    """
    if not candidates:
        raise InputError("select_friction_structure needs at least one candidate")
    channels = {name: p.channel_names for name, p in candidates.items()}
    first = next(iter(channels.values()))
    odd = [name for name, ch in channels.items() if ch != first]
    if odd:
        raise InputError(f"candidates {odd} have other output channels than {first}")
    entries = []
    for name, prob in candidates.items():
        res = estimator.fit(prob)
        rel = res.rel_std
        w = int(np.argmax(np.where(np.isnan(rel), np.inf, rel)))
        entries.append(RankedStructure(name=str(name), result=res,
                                       correlation_condition_number=res.correlation_condition_number,
                                       max_rel_std=float(rel[w]), worst=res.names[w]))
    order = sorted(range(len(entries)), key=lambda i: (entries[i].correlation_condition_number, i))
    return StructureRanking(entries=tuple(entries[i] for i in order))
