"""``dynid montecarlo``: repeated virtual experiments with known truth (paper 002 §5, Figs. 8–9).

Each trial is one virtual experiment and its identification by ``dynid identify``; the truth
in base parameters is the simulation's true standard parameter vector mapped with the
identification's own base map. Per trial and base parameter: the estimate, its standard
deviation, whether the ``100(1-alpha)`` % interval (paper 002 Eq. 30) contains the truth; per
trial the statistic

.. math:: \\chi^2 = (\\hat\\theta - \\theta)^T \\Sigma^{-1} (\\hat\\theta - \\theta)

against the radius :math:`\\chi^2_{p,1-\\alpha}` of the confidence ellipsoid (Eq. 29). If the
reported covariance is right, the intervals cover the truth in ``100(1-alpha)`` % of the
trials, the statistic averages ``p`` and stays inside the ellipsoid in ``100(1-alpha)`` % of
the trials.

By default **the motion is simulated once; each trial redraws the sensor noise** (the
controller never sees the sensors, so this is an exact repetition of the experiment):
trial ``k`` measures the motion with sensor seed ``seed + k``. With ``resimulate = true``
each trial runs the whole simulation again with every seed of the simulation offset by ``k``
(sensor noise, perturbation of the true robot, random Fourier trajectory): the trials then also
differ in the true robot and the excitation. Trial 0 is, in both modes, the experiment of
``dynid simulate`` on the same ``[simulate]`` configuration (with the default ``seed``).

Trials run on local processes (joblib, loky backend) or on a Dask cluster (joblib's
``dask`` backend); every trial uses one BLAS thread, so its numbers do not depend on where it
runs. A trial whose identification fails on its data (:class:`~dynid.errors.IdentifiabilityError`,
:class:`~dynid.errors.InputError`, :class:`~dynid.errors.ModelError`, a singular matrix) is
counted and reported with its error; a configuration error stops the study.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from dynid import __version__
from dynid._files import TIMING_FILE, save_npz, write_timing
from dynid.config.montecarlo import MonteCarloConfig
from dynid.errors import ConfigError, IdentifiabilityError, InputError, ModelError
from dynid.io.output import staged_output

__all__ = ["MonteCarloResult", "TrialOutcome", "chi2_statistic", "run_montecarlo", "run_trial", "write_montecarlo", "MONTECARLO_FILES",
           "SCHEDULER_TIMEOUT_S"]

MONTECARLO_FILES = ("trials.npz", "montecarlo.json", "history.png", "chi2.png", "timing.json", "config.toml")
SCHEDULER_TIMEOUT_S = 10.0
"""Seconds to wait for a Dask scheduler before giving up."""

TRIAL_ERRORS = (IdentifiabilityError, InputError, ModelError, np.linalg.LinAlgError)
"""Errors that fail one trial (counted and reported); any other error stops the study."""

MODE_TEXT = {
    False: "the motion is simulated once; each trial redraws the sensor noise (sensor seed = seed + trial)",
    True: "each trial reruns the whole simulation with every seed offset by the trial number "
          "(sensor noise, true robot perturbation, random Fourier trajectory)",
}

Progress = Callable[[str, int, int], None]


def _no_progress(task: str, done: int, total: int) -> None:
    return None


# ---------------------------------------------------------------------- one trial
@dataclasses.dataclass(frozen=True, eq=False)
class TrialOutcome:
    """One trial: estimates, standard deviations, intervals (p, 2) and truth of the base
    parameters, the chi-square statistic; ``error`` when the identification failed."""

    trial: int
    seed: int
    names: tuple[str, ...] = ()
    expressions: tuple[str, ...] = ()
    method: str = ""
    params: np.ndarray | None = None
    std: np.ndarray | None = None
    ci: np.ndarray | None = None
    truth: np.ndarray | None = None
    chi2: float = float("nan")
    seconds: float = float("nan")
    error: str | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class _Plan:
    """What every trial needs; sent once to each worker."""

    config: MonteCarloConfig
    signals: Any = None  # TrueSignals of the motion simulated once (None: resimulate)
    truth: dict | None = None  # the simulation's truth.json content


def _trial_simulation(cfg: MonteCarloConfig, k: int):
    """The ``[simulate]`` configuration of trial ``k`` with ``resimulate``: every seed + k."""
    sim = cfg.simulate
    values = dict(sim.trajectory.values)
    if "seed" in values:
        values["seed"] = values["seed"] + k
    return dataclasses.replace(
        sim,
        robot=dataclasses.replace(sim.robot, perturbation_seed=sim.robot.perturbation_seed + k),
        trajectory=dataclasses.replace(sim.trajectory, values=values),
        sensors=dataclasses.replace(sim.sensors, seed=cfg.seed + k),
    )


def _true_base(outcome, truth: dict) -> np.ndarray:
    names = tuple(truth["parameter_names"])
    system = outcome.system
    model_names = tuple(system.model.parameter_names) if system is not None else tuple(outcome.base.standard_names)
    if model_names != names:
        raise ConfigError(
            "identify: the identified model's standard parameters differ from the simulated robot's "
            f"({len(model_names)} against {len(names)}); the truth cannot be mapped "
            "(identify the simulated model with its default extras)"
        )
    true = np.asarray(truth["true_parameters"], dtype=float)
    # a reduced structure (identification.structure) maps the truth by T^+ (tied bodies averaged): exact only
    # when the simulated robot satisfies the structure's assumptions
    return outcome.base.from_standard(true if system is None else system.reduce_parameters(true))


def run_trial(plan: _Plan, k: int) -> TrialOutcome:
    """Trial ``k`` of ``plan``: measure (or simulate) and identify (one BLAS thread)."""
    from threadpoolctl import threadpool_limits

    from dynid.pipeline.identification import identify
    from dynid.pipeline.simulate import measure_signals, run_simulation

    cfg = plan.config
    seed = cfg.seed + k
    with threadpool_limits(limits=1), tempfile.TemporaryDirectory(prefix="dynid-mc-") as tmp:
        try:
            signals, truth = plan.signals, plan.truth
            if cfg.resimulate:
                sim = run_simulation(_trial_simulation(cfg, k))
                signals, truth = sim.signals, sim.truth
            meas, columns = measure_signals(signals, seed)
            log = Path(tmp) / "log.npz"
            save_npz(log, columns)
            icfg = cfg.identify_config(log, signals.actuators, meas.effort_kind, int(meas.t.size))
            t0 = time.perf_counter()
            outcome = identify(icfg)
            seconds = time.perf_counter() - t0
        except TRIAL_ERRORS as exc:
            return TrialOutcome(trial=k, seed=seed, error=f"{type(exc).__name__}: {exc}")
    res = outcome.result
    true = _true_base(outcome, truth)
    common = dict(trial=k, seed=seed, names=tuple(res.names), expressions=tuple(outcome.base.expressions()),
                  method=res.method, params=np.array(res.params), truth=true, seconds=seconds)
    if res.cov_params is None:  # e.g. physically consistent estimate on the boundary: no interval
        return TrialOutcome(**common)
    return TrialOutcome(**common, std=np.array(res.bse), ci=np.array(res.conf_int(cfg.alpha)),
                        chi2=chi2_statistic(res.params, true, res.cov_params))


def chi2_statistic(estimate: np.ndarray, truth: np.ndarray, cov: np.ndarray) -> float:
    """:func:`dynid.stats.ellipsoid_statistic` (paper 002 Eq. 29) on the correlation matrix (the
    covariance of base parameters spans many decades); NaN when the covariance is singular."""
    from dynid.stats import ellipsoid_statistic

    std = np.sqrt(np.diag(cov))
    if not np.all(std > 0):
        return float("nan")
    try:
        return float(ellipsoid_statistic((estimate - truth) / std, np.zeros(std.size), cov / np.outer(std, std)))
    except InputError:
        return float("nan")


# ---------------------------------------------------------------------- the study
@dataclasses.dataclass(frozen=True, eq=False)
class MonteCarloResult:
    """All trials of a study (arrays over trials ``n`` and base parameters ``p``; NaN where a
    trial failed or gave no covariance).

    Attributes
    ----------
    names, expressions : tuple of str
        Base parameters (expressions for display only).
    trial, seed : int arrays (n,)
    ok : bool array (n,)
        The identification succeeded.
    estimates, std, truth : arrays (n, p)
    ci : array (n, p, 2)
        ``100(1-alpha)`` % intervals.
    chi2 : array (n,)
    seconds : array (n,)
        Identification time of each trial [s].
    failures : tuple of dict
        ``trial``, ``seed``, ``error`` of each failed trial.
    """

    names: tuple[str, ...]
    expressions: tuple[str, ...]
    method: str
    alpha: float
    trial: np.ndarray
    seed: np.ndarray
    ok: np.ndarray
    estimates: np.ndarray
    std: np.ndarray
    ci: np.ndarray
    truth: np.ndarray
    chi2: np.ndarray
    seconds: np.ndarray
    failures: tuple[dict, ...]
    settings: dict
    timing: dict
    notes: tuple[str, ...] = ()

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def with_cov(self) -> np.ndarray:
        """Trials with an interval (identification succeeded and gave a covariance)."""
        return self.ok & np.isfinite(self.std).all(axis=1)

    @property
    def radius(self) -> float:
        """:math:`\\chi^2_{p,1-\\alpha}`, the radius of the confidence ellipsoid."""
        from scipy.stats import chi2

        return float(chi2.ppf(1.0 - self.alpha, self.n_params))

    @property
    def inside(self) -> np.ndarray:
        """(n, p) bool: the interval of the trial contains the truth (False where none)."""
        with np.errstate(invalid="ignore"):
            return (self.ci[..., 0] <= self.truth) & (self.truth <= self.ci[..., 1])

    @property
    def coverage(self) -> np.ndarray:
        """Per parameter: share of the trials whose interval contains the truth [%]."""
        m = self.with_cov
        return 100.0 * self.inside[m].mean(axis=0) if m.any() else np.full(self.n_params, np.nan)

    @property
    def overall_coverage(self) -> float:
        m = self.with_cov
        return float(100.0 * self.inside[m].mean()) if m.any() else float("nan")

    @property
    def ellipsoid_share(self) -> float:
        """Share of the trials whose statistic lies inside the ellipsoid [%]."""
        c = self.chi2[self.with_cov & np.isfinite(self.chi2)]
        return float(100.0 * np.mean(c <= self.radius)) if c.size else float("nan")

    @property
    def mean_chi2(self) -> float:
        c = self.chi2[self.with_cov & np.isfinite(self.chi2)]
        return float(c.mean()) if c.size else float("nan")

    def parameter_table(self) -> list[dict[str, Any]]:
        """Per parameter: truth (mean over trials), mean and std of the estimates, their bias,
        the mean reported std, the coverage."""
        ok, m = self.ok, self.with_cov
        est, tru = self.estimates[ok], self.truth[ok]
        cov = self.coverage
        rows = []
        for i, name in enumerate(self.names):
            rows.append({
                "name": name,
                "expression": self.expressions[i] if self.expressions else name,
                "truth": float(tru[:, i].mean()),
                "mean": float(est[:, i].mean()),
                "std": float(est[:, i].std(ddof=1)) if est.shape[0] > 1 else float("nan"),
                "bias": float((est[:, i] - tru[:, i]).mean()),
                "mean_reported_std": float(self.std[m, i].mean()) if m.any() else float("nan"),
                "coverage_pct": float(cov[i]),
            })
        return rows

    def to_dict(self) -> dict[str, Any]:
        """The content of ``montecarlo.json``."""
        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        params = [{k: (num(v) if isinstance(v, float) else v) for k, v in row.items()} for row in self.parameter_table()]
        c = self.chi2[self.with_cov & np.isfinite(self.chi2)]
        return {
            "dynid_version": __version__,
            "settings": self.settings,
            "n_trials": int(self.trial.size),
            "n_succeeded": int(self.ok.sum()),
            "n_with_covariance": int(self.with_cov.sum()),
            "method": self.method,
            "alpha": self.alpha,
            "coverage_pct": num(self.overall_coverage),
            "coverage_expected_pct": 100.0 * (1.0 - self.alpha),
            "ellipsoid": {
                "p": self.n_params,
                "radius": self.radius,
                "share_inside_pct": num(self.ellipsoid_share),
                "mean_chi2": num(self.mean_chi2),
                "median_chi2": num(float(np.median(c))) if c.size else None,
            },
            "parameters": params,
            "failures": {"count": len(self.failures), "trials": list(self.failures)},
            "notes": list(self.notes),
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """The content of ``trials.npz``."""
        return {
            "names": np.array(self.names, dtype=str),
            "trial": self.trial,
            "seed": self.seed,
            "ok": self.ok,
            "estimates": self.estimates,
            "std": self.std,
            "ci_low": self.ci[..., 0],
            "ci_high": self.ci[..., 1],
            "truth": self.truth,
            "inside": self.inside,
            "chi2": self.chi2,
            "radius": np.array(self.radius),
            "alpha": np.array(self.alpha),
        }

    def timing_record(self) -> dict[str, Any]:
        """The content of ``timing.json``: wall-clock seconds and where the trials ran (the
        one output that differs between equal runs)."""
        return {**self.timing, "identify_s_per_trial": self.seconds}

    def summary_text(self) -> str:
        """Coverage per parameter, overall coverage, ellipsoid share (the CLI prints it)."""
        rows = [("parameter", "truth", "mean est.", "std est.", "mean rep. std", "coverage %")]
        for r in self.parameter_table():
            rows.append((r["name"], f"{r['truth']:.4g}", f"{r['mean']:.4g}", f"{r['std']:.3g}",
                         f"{r['mean_reported_std']:.3g}", f"{r['coverage_pct']:.0f}"))
        w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines = ["  ".join([r[0].ljust(w[0])] + [c.rjust(x) for c, x in zip(r[1:], w[1:])]) for r in rows]
        lines.insert(1, "-" * len(lines[0]))
        level = 100.0 * (1.0 - self.alpha)
        n, n_cov = int(self.trial.size), int(self.with_cov.sum())
        lines += [
            "",
            f"trials           : {n} ({int(self.ok.sum())} identified, {len(self.failures)} failed"
            + (f", {int(self.ok.sum()) - n_cov} without covariance" if int(self.ok.sum()) != n_cov else "") + f"), {self.method}"
            + f", {self.settings.get('covariance', 'model')} covariance",
            f"coverage         : {self.overall_coverage:.1f} % of the {level:g} % intervals contain the truth",
            f"ellipsoid        : {self.ellipsoid_share:.1f} % of the trials inside chi2({self.n_params}, {level:g} %) = "
            f"{self.radius:.2f}; mean chi2 {self.mean_chi2:.2f} (expected {self.n_params})",
            f"time             : {self.timing['total_s']:.1f} s ({self.timing['backend']}, "
            f"{self.timing['workers']} workers; median identification {self.timing['identify_median_s']:.2f} s per trial)",
        ]
        for f in self.failures[:5]:
            lines.append(f"failed trial {f['trial']} (seed {f['seed']}): {f['error']}")
        if len(self.failures) > 5:
            lines.append(f"... and {len(self.failures) - 5} more failed trials (montecarlo.json)")
        lines += [f"note: {s}" for s in self.notes]
        return "\n".join(lines)


@contextlib.contextmanager
def _parallel(cfg: MonteCarloConfig) -> Iterator[tuple[Any, str, int]]:
    """A joblib ``Parallel`` yielding trial outcomes as they finish, its backend, its workers."""
    import joblib

    if cfg.scheduler is None:
        n = max(1, min(cfg.n_workers, cfg.trials))
        yield (joblib.Parallel(n_jobs=n, backend="loky", batch_size=1, return_as="generator_unordered"),
               "local processes (joblib/loky)" if n > 1 else "this process", n)
        return
    from dynid.errors import require

    distributed = require("distributed", "montecarlo")
    try:
        client = distributed.Client(cfg.scheduler, timeout=SCHEDULER_TIMEOUT_S, set_as_default=True)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {cfg.scheduler!r} ({exc})") from None
    try:
        n = max(1, sum(client.nthreads().values()))
        with joblib.parallel_config(backend="dask"):
            yield (joblib.Parallel(n_jobs=-1, batch_size=1, return_as="generator_unordered"),
                   f"Dask scheduler {cfg.scheduler}", n)
    finally:
        client.close()


def _notes(cfg: MonteCarloConfig) -> list[str]:
    r = cfg.simulate.robot
    notes = []
    if r.friction is not None:
        notes.append(f"the true friction is a {r.friction['model']!r} model, not the identified linear joint terms: "
                     "their 'truth' is the nominal joint terms, so coverage measures the model error too")
    if r.payload is not None:
        notes.append("the simulated robot carries a payload that the truth (the robot's parameters) does not include")
    return notes


def _check_identify_robot(cfg: MonteCarloConfig) -> None:
    """Load the robot of ``[identify.robot]`` once before anything runs: a model that cannot be
    loaded is a configuration error, not a failure of every trial."""
    if "robot" not in cfg.identify:
        return
    from dynid.pipeline.data import build_robot

    robot_cfg = cfg.identify_config(cfg.base_dir / "trial.npz", ["a"], "torque", 1000).robot
    try:
        build_robot(robot_cfg)
    except (ModelError, InputError, ConfigError) as exc:
        raise type(exc)(f"identify.robot.model: {exc}") from None


def run_montecarlo(cfg: MonteCarloConfig, progress: Progress = _no_progress) -> MonteCarloResult:
    """Run the study of ``cfg`` (nothing is written; see module docstring)."""
    from joblib import delayed

    from dynid.pipeline.simulate import run_simulation

    _check_identify_robot(cfg)
    t_start = time.perf_counter()
    with _parallel(cfg) as (parallel, backend, workers):
        sim_s = 0.0
        plan = _Plan(cfg)
        if not cfg.resimulate:
            progress("simulate", 0, 1)
            t0 = time.perf_counter()
            sim = run_simulation(cfg.simulate)
            sim_s = time.perf_counter() - t0
            progress("simulate", 1, 1)
            plan = _Plan(cfg, sim.signals, sim.truth)
        t0 = time.perf_counter()
        outcomes: list[TrialOutcome] = []
        progress("trials", 0, cfg.trials)
        for out in parallel(delayed(run_trial)(plan, k) for k in range(cfg.trials)):
            outcomes.append(out)
            progress("trials", len(outcomes), cfg.trials)
        trials_s = time.perf_counter() - t0
    outcomes.sort(key=lambda o: o.trial)
    good = [o for o in outcomes if o.error is None]
    failures = tuple({"trial": o.trial, "seed": o.seed, "error": o.error} for o in outcomes if o.error is not None)
    if not good:
        raise IdentifiabilityError(f"all {cfg.trials} trials failed (trial {failures[0]['trial']}: {failures[0]['error']})")
    names = good[0].names
    if any(o.names != names for o in good):
        raise ModelError("the trials identified different base parameters; cannot compare them")
    n, p = len(outcomes), len(names)

    def stack(attr: str, shape: tuple[int, ...]) -> np.ndarray:
        out = np.full((n, *shape), np.nan)
        for i, o in enumerate(outcomes):
            v = getattr(o, attr)
            if v is not None:
                out[i] = v
        return out

    ok = np.array([o.error is None for o in outcomes])
    seconds = np.array([o.seconds for o in outcomes])
    settings = {
        "config_file": str(cfg.source) if cfg.source else None,
        "trials": cfg.trials,
        "seed": cfg.seed,
        "resimulate": cfg.resimulate,
        "mode": MODE_TEXT[cfg.resimulate],
        "alpha": cfg.alpha,
        "covariance": str(cfg.identify.get("identification", {}).get("covariance", "model")),  # the intervals' covariance
        "robot": cfg.simulate.robot.model,
        "identify": cfg.identify,
    }
    timing = {
        "total_s": time.perf_counter() - t_start,
        "simulation_s": sim_s,
        "trials_s": trials_s,
        "identify_median_s": float(np.nanmedian(seconds)),
        "identify_total_s": float(np.nansum(seconds)),
        "backend": backend,
        "workers": workers,
        "scheduler": cfg.scheduler,
    }
    return MonteCarloResult(
        names=names, expressions=good[0].expressions, method=good[0].method, alpha=cfg.alpha,
        trial=np.array([o.trial for o in outcomes]), seed=np.array([o.seed for o in outcomes]), ok=ok,
        estimates=stack("params", (p,)), std=stack("std", (p,)), ci=stack("ci", (p, 2)), truth=stack("truth", (p,)),
        chi2=np.array([o.chi2 for o in outcomes]), seconds=seconds, failures=failures, settings=settings,
        timing=timing, notes=tuple(_notes(cfg)),
    )


def write_montecarlo(result: MonteCarloResult, out_dir: str | Path, source: Path | None = None) -> list[str]:
    """Write ``trials.npz``, ``montecarlo.json``, ``history.png``, ``chi2.png`` (and the
    configuration ``source`` as ``config.toml``) into ``out_dir``, all or nothing."""
    from dynid.report.plots import plot_montecarlo_chi2, plot_montecarlo_history

    names = []
    with staged_output(out_dir) as stage:
        save_npz(stage / "trials.npz", result.arrays())
        (stage / "montecarlo.json").write_text(json.dumps(result.to_dict(), indent=2, default=str) + "\n")
        plot_montecarlo_history(result, stage / "history.png")
        plot_montecarlo_chi2(result, stage / "chi2.png")
        write_timing(stage, result.timing_record())
        names += ["trials.npz", "montecarlo.json", "history.png", "chi2.png", TIMING_FILE]
        if source is not None:
            (stage / "config.toml").write_text(Path(source).read_text())
            names.append("config.toml")
    return names
