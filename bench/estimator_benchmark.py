"""Estimator benchmark (issue 36, item 5): every method on three twins in four situations.

In the spirit of Leboutet et al. 2021 ("Inertial parameter identification in robotics: a
survey", the study behind BIRDy): the same simulated data handed to every estimator of
``[identification] method`` and to WLS with ``physical_consistency = true`` (the LMI fit), and
each scored against the truth it was simulated from.

Robots (each a ``dynid simulate`` twin with a truth 10 % away from the nominal model, physically
consistent by construction; bench/physical_study.py's ``_simulate`` / ``_config`` and
:func:`dynid.studies.draw_seed`):

* ``cobot6r`` (serial 6R, ``builtin:cobot6r``): bench/estimator_study.py part C's set-up, a
  4-harmonic Fourier excitation at 0.5 Hz, computed torque at 500 Hz (Kp 400, Kd 40, 2 RK4
  substeps), 1 N·m of torque noise per joint (at 0.5 N·m the half-sample lag between the held
  torque and the central-difference acceleration was a visible bias: WLS's chi2/p 2.1 on 4 s);
* ``hexapod`` (``builtin:hexapod``): bench/control_loop_time.py's set-up, a 3-harmonic task-space
  excitation at 0.5 Hz, computed torque at 500 Hz (Kp 2500, Kd 100), 1 um strut encoders, 2 N of
  drive-force noise correlated 0.2;
* ``rps3`` (3-RPS, ``builtin:rps3``): examples/twins/rps3_fourier.toml with its excitation sped
  up to 0.5 Hz and 3 harmonics and a 500 Hz loop (the twin's own 0.1 Hz log takes minutes to
  simulate), 1 um encoders, 5 N of leg-force noise.

Training: ``PERIODS`` periods of 2 s (the arm 3, the parallel robots 2; ``--quick`` 1); held out:
one period of another trajectory (other seed) with the training's encoders and no force noise (the
held-out error is the model's alone), the same for every situation of a robot.

Situations (what differs from the clean training log; the same trajectory and seeds otherwise):

* ``clean``: the twin's sensors as above (white force noise, encoder quantization);
* ``position noise``: plus white Gaussian noise on the logged actuator positions,
  ``ROBOTS[robot]["position_std"]`` (5e-4 rad on the arm, 2e-5 m on the parallel robots): the derivatives the
  regressor is built from carry it (errors in the variables), the controller does not see it;
* ``outliers``: the clean log with 1 % of the force samples (each actuator's samples drawn
  independently, ``OUTLIER_SHARE``) replaced by the sample plus a spike of
  ``OUTLIER_SIZE`` = 50 force-noise standard deviations, random sign;
* ``closed loop``: an unmeasured force disturbance d enters the plant beside the controller's
  command u (the plant is driven by u + d, the log records u plus the clean sensor noise). d is
  an AR(1) process per actuator, d_k = a d_(k-1) + sqrt(1 - a^2) s e_k with a = exp(-2 pi f dt),
  ``DISTURBANCE_HZ`` = 2 Hz (inside the 10 Hz band the positions are filtered to) and s =
  ``DISTURBANCE_GAIN`` = 5 force-noise standard deviations. The controller reacts to the motion d
  causes, so the recorded effort's error (-d) is correlated with the measured motion and so with
  the regressor: the case IDIM-IV, DIDIM and CLOE exist for (Gautier, Janot and Vandanjon 2013).
  The replays of those methods run the experiment without d (the controller as configured).

Identification, the same for every method: ``dynid identify`` on the training log, a 10 Hz order-4
zero-phase low-pass of the positions (``filter_effort = false``), ``min_velocity`` (0.05 rad/s on
the arm, 3 mm/s on the hexapod, 2 mm/s on the 3-RPS: the slow rows, where the Coulomb sign of a
filtered velocity is arbitrary, left out) and ``reversal_guard = "auto"`` (docs/guide, "Which
method, when"), no decimation (time-domain ML scores every sample and the Kalman filters run sample
by sample), the parallel robots with ``structure = "full"`` (bench/physical_study.py). Method keys:

* ``ols``, ``wls``, ``gm``, ``irls``, ``tls``: defaults; ``wls+lmi``: ``wls`` with
  ``physical_consistency = true``;
* ``ml``: time-domain maximum likelihood (paper 004, Eq. 24, in the time domain) with the noise
  covariances given from the twin's sensors (forces: the configured covariance; positions: the
  encoder quantum^2 / 12 plus the position noise^2); the periodic variant needs whole averaged
  periods and is not run;
* ``iv``, ``didim``, ``cloe``: the training run's simulate config as ``experiment``, from the
  nominal model (``start = "nominal"``: bench/control_loop_time.py), ``max_iterations``
  ``LOOP_ITERATIONS`` (5; CLOE ``CLOE_ITERATIONS`` = 2, its replays per iteration are one per
  estimated direction), the parallel robots with the smooth replay (``replay_coulomb_band =
  0.05``, ``directions_rtol = 1e-3``: bench/control_loop_time.py);
* ``ekf``, ``ukf``: defaults; on the arm on the first ``SHORT_ROWS`` rows (one 2 s period) of each
  training log only (a fit on the whole log takes minutes there), on the 3-RPS on the whole log,
  not on the hexapod (``NOT_RUN``: over 6 minutes a fit on 1000 rows);
* CLOE is not run on the hexapod (``NOT_RUN``: about 100 estimated directions, one replay of the
  experiment each per iteration, over 10 minutes a fit), recorded as "n/a" with the reason.

A method that stops with a :class:`dynid.errors.DynidError` (TLS's refusal of an ill-posed problem,
a replay that fails, a method that does not apply) is recorded as "refused" with the first line of
its message: a result, not a gap.

Figures per robot x situation x method (mean over ``--draws`` draws, default 2; 1 with ``--quick``;
the recorded full run has 1 draw, each robot in its own process side by side, merged with
``--merge``: a draw of the three robots took about 20 minutes of wall time on 2 loaded cores):

* ``err %``: relative parameter error ||b_hat - b|| / ||b|| over the base parameters b of the truth;
* ``chi2/p`` and ``cover``: the truth's Mahalanobis distance under the method's own covariance,
  chi2 = (b_hat - b)^T Sigma^+ (b_hat - b), divided by p; "covered" when chi2 is at most the 95 %
  quantile of chi-square with p degrees of freedom, in at least half the draws ("-": the method
  reports no covariance, e.g. an LMI fit with an active constraint);
* ``held-out %``: the held-out relative RMSE of the forces (mean over actuators of
  ``validation.rel_rmse_pct``) and the nominal (CAD) model's on the same rows (the first baseline);
* ``s/fit``: wall time of the identification (processing, fit and held-out scoring), with the load
  average recorded beside the tables (only ratios within one run mean anything).

The rule (``RULE``) that names the best method of a robot and situation, over the methods that ran
in every draw (one that fails in some draw is not recommended): among the methods whose 95 %
ellipsoid covers the truth (above), the lowest mean held-out error divided by the nominal model's
on the same rows and processing (ML scores the held-out log at its own estimated cut-off, where the
CAD model's error differs too: only the ratio compares like with like), provided one of them beats
the nominal model's held-out error (the prior is the first baseline: a covered method that
predicts worse than the CAD model is not worth recommending); otherwise the lowest held-out error
among every method that ran, flagged "no covered method beats nominal". A method within a tie
(the larger of the standard error over the draws of its held-out difference to the lowest, paired
draw by draw since every method of a draw is scored on the same held-out log, and 0.5 % of the
lowest error, relative) of the lowest is tied with it, and the fastest of the tied wins. Where the
method so chosen does not beat the nominal model's held-out error either, the recommendation is
``nominal``: keep the CAD model (the prior is the first baseline); the best fit is still recorded
(``best_fit``) and shown in the robot's table.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/estimator_benchmark.py`` (writes
bench/data/estimator_benchmark.md and .json); ``--quick`` (``QUICK``): 1-period logs, one draw, the
arm with every method but the EKF on clean data and WLS and IV in the closed loop, the 3-RPS with WLS
and the EKF, CLOE with one iteration (what tests/test_estimator_benchmark.py runs; about 15 s);
``--robots``, ``--situations``, ``--methods``, ``--draws``, ``--first-draw``; ``--merge DIR ...``
makes one table set from single-robot runs.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO / "src"))
sys.path.insert(0, str(HERE))

import dynid.pipeline.simulate as _simulate_module  # noqa: E402
from dynid._files import save_npz  # noqa: E402
from dynid.errors import DynidError  # noqa: E402
from dynid.pipeline import identify  # noqa: E402
from dynid.studies import draw_seed  # noqa: E402

from physical_study import _config, _simulate  # noqa: E402

OUT_MD = HERE / "data" / "estimator_benchmark.md"
OUT_JSON = HERE / "data" / "estimator_benchmark.json"

METHODS = ("ols", "wls", "wls+lmi", "gm", "irls", "tls", "ml", "iv", "didim", "cloe", "ekf", "ukf")
SITUATIONS = ("clean", "position noise", "outliers", "closed loop")
LOOP_METHODS = ("iv", "didim", "cloe")
LOOP_ITERATIONS = {False: 5, True: 2}
CLOE_ITERATIONS = 2
PERIODS = {"cobot6r": 3, "hexapod": 2, "rps3": 2}
"""Training periods (2 s each) of the full run; ``--quick``: 1."""
DRAWS = {False: 2, True: 1}
OUTLIER_SHARE, OUTLIER_SIZE = 0.01, 50.0
DISTURBANCE_HZ, DISTURBANCE_GAIN = 2.0, 5.0
RULE = ("best = among the methods that ran in every draw, the lowest mean held-out relative RMSE divided by the nominal "
        "(CAD) model's on the same rows and processing, among those whose "
        "95 % ellipsoid covers the true base "
        "parameters (chi2 <= chi2_0.95(p)) in at least half the draws, if one of them beats the nominal (CAD) "
        "model's held-out error; otherwise the lowest among every method that ran ('no covered method beats "
        "nominal'); a method within max(the standard error over the draws of its held-out difference to the "
        "lowest, paired draw by draw, and 0.5 % of the lowest) of the lowest is tied, and the fastest of the tied wins; "
        "where that method does not beat the nominal model's held-out error, the recommendation is 'nominal' (keep the "
        "CAD model)")
SHORT_ROWS = {"cobot6r": 1000}
"""The EKF and UKF (sample by sample, minutes a fit on these arms' full logs under load) on the
first rows of each training log only: one 2 s period at 500 Hz; the 3-RPS runs them on its whole
log."""
SHORT_METHODS = ("ekf", "ukf")
NOT_RUN = {
    ("hexapod", "cloe"): "time budget: CLOE replays the 4 s experiment once per estimated direction and iteration "
                         "(about 100 directions on the hexapod, 3 s a replay: over 10 min a fit); see "
                         "bench/README 'Control-loop identification time' for CLOE's cost",
}
_KALMAN_TIME = ("time budget: one fit on the first 1000 rows (2 s) of the hexapod's log ran over 6 minutes on the "
                "loaded cores (the filters' state: 6 x 3 kinematic states and about 100 base parameters, a "
                "square-root update per sample); see the 3-RPS and the arm for the filters")
NOT_RUN[("hexapod", "ekf")] = NOT_RUN[("hexapod", "ukf")] = _KALMAN_TIME
"""(robot, method) -> why the full run does not run it (recorded as "n/a")."""
QUICK = {
    "cobot6r": {"clean": ("ols", "wls", "wls+lmi", "gm", "irls", "tls", "ml", "iv", "didim", "cloe", "ukf"),
                "closed loop": ("wls", "iv")},
    "rps3": {"clean": ("wls", "ekf")},
}
"""``--quick``: robot -> situation -> methods; every method runs at least once (the EKF on the 3-RPS,
where it is fastest), CLOE with one iteration."""

ROBOTS = {
    "cobot6r": {
        "model": "builtin:cobot6r", "robot": {"model": "builtin:cobot6r", "perturbation": 0.1, "perturbation_seed": 1},
        "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 4, "fill": 0.6,
                       "max_velocity": 1.5, "max_acceleration": 6.0},
        "control": {"rate_hz": 500, "kp": 400, "kd": 40, "substeps": 2},
        "sensors": {"force_noise_std": 1.0},
        "force_std": 1.0, "force_correlation": 0.0, "encoder": 0.0, "position_std": 5e-4,
        "unit": "rad", "effort_unit": "N*m", "loop": {}, "n_actuators": 6,
        "processing": {"min_velocity": 0.05, "reversal_guard": "auto"},
    },
    "hexapod": {
        "model": "builtin:hexapod", "robot": {"model": "builtin:hexapod", "perturbation": 0.1, "perturbation_seed": 4},
        "trajectory": {"kind": "fourier", "coordinates": "task", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.05,
                       "max_velocity": 0.1, "max_acceleration": 1.0},
        "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "substeps": 2},
        "sensors": {"encoder_resolution": 1e-6, "force_noise_std": 2.0, "force_correlation": 0.2},
        "force_std": 2.0, "force_correlation": 0.2, "encoder": 1e-6, "position_std": 2e-5,
        "unit": "m", "effort_unit": "N", "loop": {"replay_coulomb_band": 0.05, "directions_rtol": 1e-3}, "n_actuators": 6,
        "processing": {"min_velocity": 0.003, "reversal_guard": "auto"},
    },
    "rps3": {
        "model": "builtin:rps3", "robot": {"model": "builtin:rps3", "perturbation": 0.1, "perturbation_seed": 3},
        "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.4,
                       "max_velocity": 0.05, "max_acceleration": 0.5},
        "control": {"rate_hz": 500, "kp": 400, "kd": 40, "substeps": 2},
        "sensors": {"encoder_resolution": 1e-6, "force_noise_std": 5.0},
        "force_std": 5.0, "force_correlation": 0.0, "encoder": 1e-6, "position_std": 2e-5,
        "unit": "m", "effort_unit": "N", "loop": {"replay_coulomb_band": 0.05, "directions_rtol": 1e-3}, "n_actuators": 3,
        "processing": {"min_velocity": 0.002, "reversal_guard": "auto"},
    },
}


# ---------------------------------------------------------------------- data
def _toml(doc: dict) -> str:
    """A simulate config as TOML (tables of numbers, strings and lists of numbers)."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    return "".join(f"[{name}]\n" + "".join(f"{k} = {val(v)}\n" for k, v in t.items()) + "\n" for name, t in doc.items())


@contextlib.contextmanager
def _disturbed(std: np.ndarray, rate_hz: float, seed: int):
    """Every non-replay simulation inside drives its plant with the controller's command plus an
    AR(1) disturbance (module docstring, "closed loop"); yields the list the disturbances of the
    control periods are appended to, in order."""
    rng = np.random.default_rng(seed)
    a = float(np.exp(-2 * np.pi * DISTURBANCE_HZ / rate_hz))
    drawn: list[np.ndarray] = []
    original = _simulate_module.simulation_setup

    def setup(cfg, *args, **kwargs):
        s = original(cfg, *args, **kwargs)
        if s.replay:
            return s
        ctrl = s.controller

        def controller(dt, q, dq, ref):
            prev = drawn[-1] if drawn else np.zeros_like(std)
            d = a * prev + np.sqrt(1 - a * a) * std * rng.standard_normal(std.size)
            drawn.append(d)
            return np.asarray(ctrl(dt, q, dq, ref), dtype=float) + d

        return dataclasses.replace(s, controller=controller)

    _simulate_module.simulation_setup = setup
    try:
        yield drawn
    finally:
        _simulate_module.simulation_setup = original


@dataclasses.dataclass
class Logs:
    """The training log of each situation, the held-out log, the truth and the experiment files."""

    robot: str
    actuators: tuple[str, ...]
    train: dict[str, Path]
    experiment: dict[str, Path]
    valid: Path
    true_std: np.ndarray
    setup: dict


def simulate_robot(robot: str, situations, folder: Path, quick: bool, draw: int) -> Logs:
    """The logs of one draw of ``robot`` (module docstring)."""
    r = ROBOTS[robot]
    f0 = r["trajectory"]["base_frequency_hz"]
    setup = {"model": r["model"], "robot": r["robot"], "control": r["control"], "sensors": r["sensors"],
             "unit": r["unit"], "effort_unit": r["effort_unit"]}
    traj = {**r["trajectory"], "periods": 1 if quick else PERIODS[robot], "seed": draw_seed(11, draw)}
    sensor_seed = draw_seed(1, draw)
    # the held-out log: another trajectory, the forces without noise (the held-out error is the model's)
    quiet = {k: v for k, v in setup["sensors"].items() if k not in ("force_noise_std", "force_correlation")}
    _simulate({**setup, "sensors": quiet}, {**r["trajectory"], "periods": 1, "seed": draw_seed(41, draw)},
              draw_seed(1000, draw), folder / "valid")
    train, experiment, truth, actuators = {}, {}, None, None
    clean_sim = None
    for sit in situations:
        d = folder / sit.replace(" ", "_")
        s = setup
        if sit == "position noise":
            s = {**setup, "sensors": {**setup["sensors"], "position_noise_std": r["position_std"]}}
        if sit == "outliers" and clean_sim is not None:
            sim = clean_sim
        elif sit == "closed loop":
            std = np.full(r["n_actuators"], DISTURBANCE_GAIN * r["force_std"])
            with _disturbed(std, float(r["control"]["rate_hz"]), draw_seed(77, draw)) as drawn:
                sim = _simulate(s, traj, sensor_seed, d)
            dist = np.asarray(drawn)
            cols = dict(sim.columns)
            names = list(sim.dataset.names)
            if dist.shape != (cols["t"].size, len(names)):
                raise RuntimeError(f"disturbance of shape {dist.shape} for a log of {cols['t'].size} rows")
            for k, a in enumerate(names):  # the log records the command u; the plant got u + d
                cols[f"tau_{a}"] = cols[f"tau_{a}"] - dist[:, k]
            save_npz(d / "log.npz", cols)
        else:
            sim = _simulate(s, traj, sensor_seed, d)
        if sit == "clean":
            clean_sim = sim
        if sit == "outliers":
            cols = dict(sim.columns)
            names = list(sim.dataset.names)
            rng = np.random.default_rng(draw_seed(99, draw))
            for a in names:
                x = cols[f"tau_{a}"].copy()
                hit = rng.random(x.size) < OUTLIER_SHARE
                x[hit] += OUTLIER_SIZE * r["force_std"] * rng.choice([-1.0, 1.0], size=int(hit.sum()))
                cols[f"tau_{a}"] = x
            d.mkdir(parents=True, exist_ok=True)
            save_npz(d / "log.npz", cols)
        actuators = tuple(sim.dataset.names)
        truth = np.asarray(sim.truth["true_parameters"])
        train[sit] = d
        if robot in SHORT_ROWS:
            with np.load(d / "log.npz") as z:
                cols = {k: z[k][: SHORT_ROWS[robot]] for k in z.files}
            (d / "short").mkdir(exist_ok=True)
            save_npz(d / "short" / "log.npz", cols)
        exp = d / "experiment.toml"
        exp.write_text(_toml({"robot": s["robot"], "trajectory": traj, "control": s["control"],
                              "sensors": {**s["sensors"], "seed": sensor_seed}}))
        experiment[sit] = exp
    return Logs(robot, actuators, train, experiment, folder / "valid", truth, setup)


# ---------------------------------------------------------------------- identification
def ident_table(method: str, robot: str, logs: Logs, situation: str, quick: bool) -> tuple[dict, dict]:
    """``[identification]`` and extra ``[processing]`` keys of ``method`` (module docstring)."""
    r = ROBOTS[robot]
    proc = dict(r["processing"])
    if method == "wls+lmi":
        return {"method": "wls", "physical_consistency": True}, proc
    ident: dict = {"method": method}
    if method in LOOP_METHODS:
        ident.update(experiment=str(logs.experiment[situation]), start="nominal",
                     max_iterations=(1 if quick else CLOE_ITERATIONS) if method == "cloe" else LOOP_ITERATIONS[quick], **r["loop"])
    if method == "ml":
        n = len(logs.actuators)
        f = r["force_std"] ** 2 * ((1 - r["force_correlation"]) * np.eye(n) + r["force_correlation"])
        pos = r["encoder"] ** 2 / 12 + (r["position_std"] ** 2 if situation == "position noise" else 0.0)
        pos = max(pos, 1e-14)
        ident.update(noise_covariance=f.tolist(), position_covariance=(pos * np.eye(n)).tolist())
    return ident, proc


def true_base(outcome, true_std: np.ndarray) -> np.ndarray:
    return np.asarray(outcome.base.from_standard(true_std))


def run_method(method: str, logs: Logs, situation: str, quick: bool) -> dict:
    """One identification and its figures (module docstring)."""
    if (logs.robot, method) in NOT_RUN:
        return {"status": "n/a", "reason": NOT_RUN[(logs.robot, method)], "seconds": 0.0}
    ident, proc = ident_table(method, logs.robot, logs, situation, quick)
    t0 = time.perf_counter()
    try:
        train = logs.train[situation]
        if method in SHORT_METHODS and logs.robot in SHORT_ROWS and not quick:
            train = train / "short"
        o = identify(_config(logs.setup, logs.actuators, train, logs.valid, ident, proc))
    except DynidError as exc:
        return {"status": "refused", "reason": str(exc).splitlines()[0], "seconds": time.perf_counter() - t0}
    seconds = time.perf_counter() - t0
    res = o.result
    b = true_base(o, logs.true_std)
    nb = b.size
    e = np.asarray(res.params[:nb]) - b
    out = {"status": "ok", "seconds": seconds, "p": int(nb),
           "param_error_pct": float(100 * np.linalg.norm(e) / np.linalg.norm(b)),
           "heldout_pct": float(np.nanmean(o.validation.rel_rmse_pct)),
           "nominal_heldout_pct": float(np.nanmean(o.nominal_validation.rel_rmse_pct)),
           "chi2": None, "covered": None}
    if res.cov_params is not None and np.all(np.isfinite(res.cov_params[:nb, :nb])):
        cov = np.asarray(res.cov_params[:nb, :nb])
        chi2 = float(e @ np.linalg.pinv(cov, rcond=1e-12, hermitian=True) @ e)
        out.update(chi2=chi2, covered=bool(chi2 <= stats.chi2.ppf(0.95, nb)))
    solver = res.solver or {}
    if method in LOOP_METHODS:
        out["iterations"] = len(solver.get("iterations") or [])
        out["converged"] = solver.get("converged")
    return out


# ---------------------------------------------------------------------- aggregation and the rule
def aggregate(draws: list[dict]) -> dict:
    """Mean figures of one method over the draws (the draws where it ran)."""
    ok = [d for d in draws if d["status"] == "ok"]
    if not ok:
        return {"status": draws[0]["status"], "reason": draws[0]["reason"], "seconds": float(np.mean([d["seconds"] for d in draws]))}

    def mean_se(key):
        xs = np.array([d[key] for d in ok], dtype=float)
        return float(xs.mean()), float(xs.std(ddof=1) / np.sqrt(xs.size)) if xs.size > 1 else 0.0

    h, h_se = mean_se("heldout_pct")
    for d in ok:  # held-out error relative to the CAD model's on the same rows and processing
        d.setdefault("heldout_ratio", d["heldout_pct"] / d["nominal_heldout_pct"])
    with_cov = [d for d in ok if d["covered"] is not None]
    out = {"status": "ok", "runs": len(ok), "draws": len(draws), "param_error_pct": mean_se("param_error_pct")[0],
           "heldout_pct": h, "heldout_se": h_se, "nominal_heldout_pct": mean_se("nominal_heldout_pct")[0],
           "heldout_ratio": mean_se("heldout_ratio")[0],
           "seconds": mean_se("seconds")[0], "p": ok[0]["p"],
           "chi2_over_p": float(np.mean([d["chi2"] / d["p"] for d in with_cov])) if with_cov else None,
           "covered": (sum(d["covered"] for d in with_cov) >= len(draws) / 2) if len(with_cov) == len(ok) else None}
    if len(ok) < len(draws):
        out["refused_in"] = f"{len(draws) - len(ok)} of {len(draws)} draws: " + next(d["reason"] for d in draws if d["status"] != "ok")
    if "iterations" in ok[0]:
        out["iterations"] = float(np.mean([d["iterations"] for d in ok]))
        out["converged"] = sum(bool(d["converged"]) for d in ok)
    return out


def _paired_se(a: dict, b: dict) -> float:
    """Standard error over the draws of the held-out difference a - b, paired draw by draw (every
    method of a draw is scored on the same held-out log, whose own difficulty varies from draw to
    draw); 0 with one draw."""
    d = np.array([x["heldout_pct"] / x["nominal_heldout_pct"] - y["heldout_pct"] / y["nominal_heldout_pct"]
                  for x, y in zip(a.get("per_draw", ()), b.get("per_draw", ()))
                  if x["status"] == "ok" and y["status"] == "ok"])
    return float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else 0.0


def best_method(rows: dict[str, dict]) -> dict:
    """The rule of the module docstring (``RULE``) over one robot and situation."""
    ran = {m: r for m, r in rows.items() if r["status"] == "ok" and r["runs"] == r["draws"]}
    if not ran:
        return {"method": None, "why": "no method ran"}
    covered = {m: r for m, r in ran.items() if r["covered"]}
    # ranked by the held-out error relative to the CAD model's on the same rows and processing: ML scores
    # the held-out log at its own estimated cut-off (as `dynid predict` does), where the CAD model's error
    # differs too, so its raw percentage is not comparable with the other methods'
    useful = any(r["heldout_ratio"] < 1.0 for r in covered.values())
    pool, flag = (covered, "covered") if useful else (ran, "no covered method beats nominal")
    low = min(pool, key=lambda m: pool[m]["heldout_ratio"])
    h0 = pool[low]["heldout_ratio"]
    tied = [m for m, r in pool.items() if r["heldout_ratio"] - h0 <= max(_paired_se(r, pool[low]), 0.005 * h0)]
    best = min(tied, key=lambda m: pool[m]["seconds"])
    beats = bool(pool[best]["heldout_ratio"] < 1.0)
    # the prior is the first baseline: where no method predicts the held-out log better than the CAD
    # model, the recommendation is to keep the CAD model ("nominal"); the best fit is still recorded
    return {"method": best if beats else "nominal", "best_fit": best, "lowest": low, "tied": sorted(tied), "pool": flag,
            "heldout_pct": pool[best]["heldout_pct"], "nominal_heldout_pct": pool[best]["nominal_heldout_pct"],
            "heldout_ratio": pool[best]["heldout_ratio"], "beats_nominal": beats}


# ---------------------------------------------------------------------- tables
def table_md(robot: str, res: dict) -> str:
    """The markdown table of one robot: a row per method, per situation a column group."""
    sits = list(res["situations"])
    head = "| method | " + " | ".join(f"{s}: err % / chi2/p / held-out % / s" for s in sits) + " |"
    lines = [f"### {robot}", "", head, "|---|" + "---|" * len(sits)]

    def cell(r):
        if r is None:
            return "not run"
        if r["status"] != "ok":
            return f"{r['status']}: {r['reason'][:90]}"
        chi = "-" if r["chi2_over_p"] is None else f"{r['chi2_over_p']:.3g}{' (in)' if r['covered'] else ' (out)'}"
        it = (f", it {r['iterations']:.0f}{'' if r['converged'] == r['runs'] else ' unconv.'}"
              if "iterations" in r else "")
        part = f"; ran in {r['runs']} of {r['draws']} draws" if r["runs"] < r["draws"] else ""
        ratio = f" ({r['heldout_ratio']:.2f}x)" if "heldout_ratio" in r else ""
        return f"{r['param_error_pct']:.3g} / {chi} / {r['heldout_pct']:.3g}{ratio} / {r['seconds']:.2g}{it}{part}"

    for m in METHODS:
        if not any(m in res["situations"][s]["methods"] for s in sits):
            continue
        lines.append(f"| {m} | " + " | ".join(cell(res["situations"][s]["methods"].get(m)) for s in sits) + " |")
    lines.append("| nominal (CAD) | " + " | ".join(
        f"held-out {res['situations'][s]['nominal_heldout_pct']:.3g} %" if res["situations"][s]["nominal_heldout_pct"]
        is not None else "-" for s in sits) + " |")
    lines.append("| **best** | " + " | ".join(
        f"**{res['situations'][s]['best']['method']}** ({res['situations'][s]['best'].get('pool', '')}"
        + ("" if res["situations"][s]["best"].get("beats_nominal", True)
           else f"; the best fit, {res['situations'][s]['best'].get('best_fit')}, is worse than nominal") + ")"
        for s in sits) + " |")
    return "\n".join(lines)


def recommendation_md(results: dict) -> str:
    """The robot x situation table of the best methods (README and guide carry it verbatim)."""
    sits = [s for s in SITUATIONS if any(s in r["situations"] for r in results.values())]
    lines = ["| robot | " + " | ".join(sits) + " |", "|---|" + "---|" * len(sits)]
    for robot, r in results.items():
        lines.append(f"| {robot} | " + " | ".join(
            f"`{r['situations'][s]['best']['method']}`" if s in r["situations"] else "-" for s in sits) + " |")
    return "\n".join(lines)


def parse_recommendation(text: str) -> dict[str, dict[str, str]]:
    """The robot x situation table of :func:`recommendation_md` read back from a markdown text
    (the first such table in it): {robot: {situation: method}}."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells and cells[0] == "robot" and set(cells[1:]) <= set(SITUATIONS) and len(cells) > 1:
            out = {}
            for row in lines[i + 2:]:
                if not row.strip().startswith("|"):
                    break
                c = [x.strip() for x in row.strip().strip("|").split("|")]
                out[c[0]] = {s: v.strip("`") for s, v in zip(cells[1:], c[1:]) if v != "-"}
            return out
    raise ValueError("no robot x situation table found")


# ---------------------------------------------------------------------- run
def run(robots, situations, methods, quick: bool, draws: int, quick_plan: bool = False, first_draw: int = 0) -> dict:
    results: dict = {}
    for robot in robots:
        sits = [s for s in situations if not quick_plan or s in QUICK[robot]]
        meths = [m for m in methods if not quick_plan or any(m in v for v in QUICK[robot].values())]
        per: dict = {s: {m: [] for m in meths} for s in sits}
        for draw in range(first_draw, first_draw + draws):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                logs = simulate_robot(robot, sits, Path(tmp), quick, draw)
                print(f"{robot}, draw {draw}: simulated {len(sits)} situation(s) + held out in "
                      f"{time.perf_counter() - t0:.1f} s", flush=True)
                for s in sits:
                    for m in meths:
                        if quick_plan and m not in QUICK[robot][s]:
                            continue
                        x = run_method(m, logs, s, quick)
                        per[s][m].append(x)
                        print(f"  {robot} / {s} / {m}: " + (
                            f"err {x['param_error_pct']:.3g} %, chi2/p "
                            f"{'-' if x['chi2'] is None else format(x['chi2'] / x['p'], '.3g')}, held-out "
                            f"{x['heldout_pct']:.3g} % (nominal {x['nominal_heldout_pct']:.3g} %), {x['seconds']:.2f} s"
                            if x["status"] == "ok" else f"{x['status']} ({x['reason']})"), flush=True)
        rs: dict = {"situations": {}}
        for s in sits:
            rows = {m: {**aggregate(v), "per_draw": v} for m, v in per[s].items() if v}
            noms = [r["nominal_heldout_pct"] for r in rows.values() if r["status"] == "ok"]
            rs["situations"][s] = {"methods": rows, "best": best_method(rows),
                                   "nominal_heldout_pct": float(np.mean(noms)) if noms else None}
        results[robot] = rs
    return results


def render(results: dict, meta: dict) -> str:
    """The markdown of bench/data/estimator_benchmark.md from the results and their meta data."""
    load = meta["load_average"]
    md = [f"Estimator benchmark ({'quick' if meta['quick'] else 'full'} run): {meta['draws']} draw(s), training periods "
          f"of 2 s at 500 Hz {meta['periods']}, wall {meta['wall_s']:.0f} s, load average (1 min) "
          f"{', '.join(f'{x:.2f}' for x in load)} at the start and end of each robot's run.",
          "Cells: relative parameter error % / chi2/p of the truth under the method's covariance "
          "((in): inside the 95 % ellipsoid) / held-out relative RMSE % (noise-free held-out forces; in brackets over the "
          "nominal model's on the same rows and processing, what the rule ranks) / seconds per fit.",
          "", f"Rule: {meta['rule']}.", ""]
    for robot, r in results.items():
        md += [table_md(robot, r), ""]
    md += ["### Best method per robot and situation", "", recommendation_md(results), ""]
    return "\n".join(md)


def write(results: dict, meta: dict, out: Path) -> str:
    text = render(results, meta)
    out.mkdir(parents=True, exist_ok=True)
    (out / OUT_MD.name).write_text(text)
    (out / OUT_JSON.name).write_text(json.dumps({"meta": meta, "robots": results}, indent=1, default=float) + "\n")
    return text


def _draw_row(row: dict) -> dict:
    """A one-draw aggregate (the first recorded run kept no per-draw rows) as that draw's row."""
    if row.get("draws", 1) != 1:
        raise ValueError("a run of several draws without per-draw rows cannot be merged")
    if row["status"] != "ok":
        return {k: row[k] for k in ("status", "reason", "seconds")}
    out = {"status": "ok", "seconds": row["seconds"], "p": row["p"], "param_error_pct": row["param_error_pct"],
           "heldout_pct": row["heldout_pct"], "nominal_heldout_pct": row["nominal_heldout_pct"],
           "chi2": None if row["chi2_over_p"] is None else row["chi2_over_p"] * row["p"], "covered": row["covered"]}
    if "iterations" in row:
        out.update(iterations=row["iterations"], converged=bool(row["converged"]))
    return out


def merge(folders: list[Path], out: Path) -> str:
    """One table set from runs of single robots (``--robots R --out DIR`` run side by side)."""
    results, meta = {}, None
    for f in folders:
        doc = json.loads((f / OUT_JSON.name).read_text())
        for robot, r in doc["robots"].items():  # a robot's situations may come from several runs (and draws)
            sits = results.setdefault(robot, {"situations": {}})["situations"]
            for sit, x in r["situations"].items():
                per = sits.setdefault(sit, {})
                for m, row in x["methods"].items():
                    per.setdefault(m, []).extend(row.get("per_draw") or [_draw_row(row)])
        m = doc["meta"]
        if "load_average" not in m:  # the first runs' format
            m["load_average"] = [m["load_average_before"][0], m["load_average_after"][0]]
        if meta is None:
            meta = {**m, "periods": dict(m["periods"]), "load_average": list(m["load_average"])}
        else:
            meta["periods"].update(m["periods"])
            meta["wall_s"] = max(meta["wall_s"], m["wall_s"])
            meta["load_average"] += m["load_average"]
    assert meta is not None
    results = {r: {"situations": {s: results[r]["situations"][s] for s in SITUATIONS if s in results[r]["situations"]}}
               for r in ROBOTS if r in results}
    for r in results.values():  # the draws aggregated and the rule applied again (the same as run's)
        for name, per in r["situations"].items():
            rows = {m: {**aggregate(v), "per_draw": v} for m, v in per.items()}
            noms = [x["nominal_heldout_pct"] for x in rows.values() if x["status"] == "ok"]
            r["situations"][name] = {"methods": rows, "best": best_method(rows),
                                     "nominal_heldout_pct": float(np.mean(noms)) if noms else None}
    meta["draws"] = max(len(x["per_draw"]) for r in results.values() for sit in r["situations"].values()
                        for x in sit["methods"].values())
    meta["rule"] = RULE
    return write(results, meta, out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="1-period logs, one draw, a subset (the test's run)")
    ap.add_argument("--robots", default=",".join(ROBOTS))
    ap.add_argument("--situations", default=",".join(SITUATIONS))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--draws", type=int, default=None)
    ap.add_argument("--first-draw", type=int, default=0, help="the first draw's index (another seed set: a check of "
                    "the recorded draw 0)")
    ap.add_argument("--out", type=Path, default=None, help="folder of the .md and .json (default bench/data; "
                    "--quick: not written unless given)")
    ap.add_argument("--merge", type=Path, nargs="+", default=None,
                    help="merge the .json of single-robot runs (their --out folders) into --out")
    args = ap.parse_args(argv)
    if args.merge:
        print(merge(args.merge, args.out or OUT_MD.parent))
        return 0
    draws = args.draws or DRAWS[args.quick]
    robots = [r for r in args.robots.split(",") if r]
    if args.quick and args.robots == ",".join(ROBOTS):
        robots = list(QUICK)
    from _util import machine_info

    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    results = run(robots, [s for s in SITUATIONS if s in args.situations.split(",")],
                  [m for m in METHODS if m in args.methods.split(",")], args.quick, draws, quick_plan=args.quick,
                  first_draw=args.first_draw)
    meta = {"quick": args.quick, "draws": draws, "first_draw": args.first_draw,
            "periods": {r: 1 if args.quick else PERIODS[r] for r in robots},
            "rule": RULE, "wall_s": time.perf_counter() - t0, "load_average": [load0, os.getloadavg()[0]],
            "machine": machine_info()}
    out = args.out or (OUT_MD.parent if not args.quick else None)
    if out is not None:
        print("\n" + write(results, meta, out))
    else:
        print("\n" + render(results, meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
