"""From the identified logs to the fleet: per robot the pooled estimate, its held-out error and
its verdict against the prior; per model the spread and the outliers; per dated robot the drift.

Pure functions of the :class:`~dynid.fleet.jobs.LogResult` list (no Dask, no files): the same
logs give the same :class:`FleetResult` wherever and in whatever order the jobs ran.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from dynid.errors import DynidError
from dynid.estimation.validation import ValidationMetrics, prior_comparison
from dynid.fleet import statistics as st
from dynid.fleet.jobs import LogResult, factor_sse

__all__ = ["RobotSummary", "ModelSummary", "FleetResult", "analyse", "DAYS_PER_YEAR"]

DAYS_PER_YEAR = 365.25


@dataclasses.dataclass(frozen=True, eq=False)
class RobotSummary:
    """One robot: its logs (``logs``: indices into :attr:`FleetResult.logs`), the pooled estimate
    ``params`` / ``cov`` (:func:`~dynid.fleet.statistics.fuse`) and its homogeneity test, the
    held-out errors of the pooled estimate and of the nominal model on every held-out row of its
    logs (``heldout``, ``nominal``: :class:`~dynid.estimation.validation.ValidationMetrics`
    without arrays), ``prior`` (:func:`~dynid.estimation.validation.prior_comparison` of the two),
    ``outlier`` (None: not tested) and ``drift`` (per parameter; None: fewer than 3 dated logs);
    ``error`` when none of its logs could be identified."""

    robot: str
    model: str
    logs: tuple[int, ...]
    ok_logs: tuple[int, ...]
    error: str | None = None
    fused: st.Fused | None = None
    heldout: ValidationMetrics | None = None
    nominal: ValidationMetrics | None = None
    prior: dict[str, Any] | None = None
    outlier: st.Outlier | None = None
    drift: tuple[dict[str, Any], ...] | None = None
    drift_params: tuple[str, ...] = ()
    change_params: tuple[str, ...] = ()

    @property
    def params(self) -> np.ndarray | None:
        return None if self.fused is None else self.fused.params

    @property
    def cov(self) -> np.ndarray | None:
        """The pooled estimate's covariance with the fleet's between-log scatter factors
        (:attr:`ModelSummary.factors`): what the outlier test uses."""
        return None if self.fused is None else self.fused.cov_scaled


@dataclasses.dataclass(frozen=True, eq=False)
class ModelSummary:
    """The robots of one model: base parameter ``names``, the robots with a pooled estimate and the
    spread of their estimates per parameter (:func:`~dynid.fleet.statistics.spread`), and the
    between-log scatter ``factors`` per parameter (:func:`~dynid.fleet.statistics.scatter_factors`)
    from ``factor_robots`` robots (fewer than 3: all 1, not calibrated)."""

    model: str
    names: tuple[str, ...]
    expressions: tuple[str, ...]
    robots: tuple[str, ...]
    spread: dict[str, np.ndarray]
    factors: np.ndarray = dataclasses.field(default_factory=lambda: np.ones(0))
    factor_robots: int = 0


@dataclasses.dataclass(frozen=True, eq=False)
class FleetResult:
    """Every log (in table order), every robot (in order of first appearance), every model."""

    alpha: float
    logs: tuple[LogResult, ...]
    robots: tuple[RobotSummary, ...]
    models: tuple[ModelSummary, ...]
    first_date: str | None
    timing: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def failures(self) -> list[LogResult]:
        return [log for log in self.logs if not log.ok]

    def robot(self, name: str) -> RobotSummary:
        for r in self.robots:
            if r.robot == name:
                return r
        raise KeyError(name)


def _metrics(channels: Sequence[str], sse: np.ndarray, ss: np.ndarray, rows: np.ndarray, what: str) -> ValidationMetrics:
    n = np.asarray(rows, float)
    nan = np.full(len(channels), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        return ValidationMetrics(channel_names=tuple(channels), n_samples=int(n.max(initial=0)), rmse=np.sqrt(sse / n),
                                 rms_measured=np.sqrt(ss / n), max_abs_error=nan, r2=nan, t=np.empty(0),
                                 measured=np.empty((0, len(channels))), predicted=np.empty((0, len(channels))),
                                 source={"pooled": what}, counts=np.asarray(rows, int))


def _pooled_heldout(logs: Sequence[LogResult], theta: np.ndarray) -> tuple[ValidationMetrics, ValidationMetrics]:
    """The pooled estimate and the nominal model on every held-out row of the robot's logs: the
    squared errors summed over the logs (each log's rows compressed, :func:`factor_sse`)."""
    sse = sum(factor_sse(log.factors, theta) for log in logs)
    nominal = sum(factor_sse(log.factors, log.nominal) for log in logs)
    ss = sum(np.sum(log.factors[:, :, -1] ** 2, axis=1) for log in logs)
    rows = sum(log.rows for log in logs)
    what = f"every held-out row of {len(logs)} log(s)"
    return _metrics(logs[0].channels, sse, ss, rows, what), _metrics(logs[0].channels, nominal, ss, rows, what)


def _drift(logs: Sequence[LogResult], names: Sequence[str], alpha: float, factors: np.ndarray) -> tuple[tuple[dict[str, Any], ...], tuple[str, ...], tuple[str, ...]] | None:
    dated = sorted((log for log in logs if log.days is not None), key=lambda log: (log.days, log.index))
    if len(dated) < 3 or len({log.days for log in dated}) < 2:
        return None
    t = np.array([log.days for log in dated])
    x = np.array([log.params for log in dated])
    var = np.array([np.diag(log.cov) for log in dated]) * factors**2
    p = len(names)
    rows, drifting, changing = [], [], []
    for j, name in enumerate(names):
        tr = st.trend(t, x[:, j], var[:, j], alpha / p)  # Bonferroni over the parameters: the intervals hold jointly
        cp = st.change_point(x[:, j], var[:, j])
        p_tr, p_cp = min(1.0, p * tr.p_value), min(1.0, p * cp.p_value)
        rows.append({"name": name, "slope_per_day": tr.slope, "slope_se": tr.se, "slope_interval": list(tr.interval),
                     "slope_per_year": tr.slope * DAYS_PER_YEAR, "intercept": tr.intercept, "t0_days": tr.t0,
                     "trend_p_value": tr.p_value, "trend_p_bonferroni": p_tr, "trend_chi2": tr.chi2, "trend_dof": tr.dof,
                     "trend_scale": tr.scale, "drift": bool(p_tr < alpha),
                     "change_statistic": cp.statistic, "change_after_log": dated[cp.after].index, "change_shift": cp.shift,
                     "change_se": cp.se, "change_scale": cp.scale, "change_p_value": cp.p_value, "change_p_bonferroni": p_cp,
                     "change": bool(p_cp < alpha)})
        if p_tr < alpha:
            drifting.append(name)
        if p_cp < alpha:
            changing.append(name)
    return tuple(rows), tuple(drifting), tuple(changing)


def _usable(logs: Sequence[LogResult]) -> tuple[list[LogResult], str | None]:
    ok = [log for log in logs if log.ok]
    if not ok:
        return ok, f"none of its {len(logs)} log(s) could be identified"
    if any(log.names != ok[0].names for log in ok):
        return ok, "its logs gave different base parameters (another robot description?); they cannot be pooled"
    return ok, None


def _robot(name: str, model: str, logs: Sequence[LogResult], alpha: float, factors: np.ndarray) -> RobotSummary:
    ok, error = _usable(logs)
    head = dict(robot=name, model=model, logs=tuple(log.index for log in logs), ok_logs=tuple(log.index for log in ok))
    if error is not None:
        return RobotSummary(**head, error=error)
    try:
        fused = st.fuse([log.params for log in ok], [log.cov for log in ok], factors)
    except DynidError as exc:
        return RobotSummary(**head, error=f"its estimates cannot be pooled: {exc}")
    heldout, nominal = _pooled_heldout(ok, fused.params)
    comparable = all(log.nominal_rmse is not None for log in ok)
    prior = prior_comparison(heldout, nominal, comparable, "held-out")
    drift = _drift(ok, ok[0].names, alpha, factors)
    return RobotSummary(**head, fused=fused, heldout=heldout, nominal=nominal, prior=prior,
                        drift=None if drift is None else drift[0], drift_params=() if drift is None else drift[1],
                        change_params=() if drift is None else drift[2])


def analyse(logs: Sequence[LogResult], models_of: dict[str, str], alpha: float, first_date: str | None = None) -> FleetResult:
    """The fleet of ``logs`` (any order; sorted by table index). ``models_of``: robot -> model, in
    the order the robots are reported."""
    logs = tuple(sorted(logs, key=lambda log: log.index))
    of_robot = {r: [log for log in logs if log.robot == r] for r in models_of}
    robots: list[RobotSummary] = []
    models = []
    for model in dict.fromkeys(models_of.values()):
        members = [r for r, m in models_of.items() if m == model]
        usable = {r: _usable(of_robot[r]) for r in members}
        # the model's base parameters: those of its first robot with usable logs
        names = next((ok[0].names for ok, err in usable.values() if err is None), ())
        groups = [(np.array([log.params for log in ok]), np.array([np.diag(log.cov) for log in ok]))
                  for ok, err in usable.values() if err is None and ok[0].names == names]
        factors, k = st.scatter_factors(groups) if groups else (np.ones(len(names)), 0)
        mine = [_robot(r, model, of_robot[r], alpha, factors) for r in members]
        group = [r for r in mine if r.fused is not None and logs[r.ok_logs[0]].names == names]
        if group:
            est = np.array([r.params for r in group])
            flags = st.outliers(est, np.array([r.cov for r in group]), alpha)
            for r, o in zip(group, flags):
                mine[mine.index(r)] = dataclasses.replace(r, outlier=o)
            first = logs[group[0].ok_logs[0]]
            models.append(ModelSummary(model, names, first.expressions, tuple(r.robot for r in group), st.spread(est),
                                       factors, k))
        else:
            models.append(ModelSummary(model, (), (), (), {}))
        robots += mine
    order = list(models_of)
    robots.sort(key=lambda r: order.index(r.robot))
    return FleetResult(alpha=alpha, logs=logs, robots=tuple(robots), models=tuple(models), first_date=first_date)
