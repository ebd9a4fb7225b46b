"""Study (issue 17, items 2 and 5): do the 95 % intervals cover the truth on the hexapod twin?

The twin of ``bench/montecarlo_scaling.py`` (``builtin:hexapod`` with 10 % prior error, a
3-harmonic task-space Fourier excitation at 0.5 Hz, 3 periods, 500 Hz computed torque, the log
at 250 Hz; 1 µm strut encoders, 2 N of drive-force noise correlated 0.2 across the struts;
WLS with 102 base parameters after a 10 Hz zero-phase low-pass), identified ``--trials`` times
by ``dynid montecarlo`` (:func:`dynid.pipeline.montecarlo.run_montecarlo`) with each row
selection of the processing:

* none (the figure of bench/README §8 before issue 17);
* ``min_velocity = 0.01`` m/s (the slow rows out);
* ``min_velocity = 0.01`` and ``reversal_guard = "auto"``: also every row within the low-pass's
  settling time (0.12 s at 10 Hz, order 4) of a reversal or a slow row of that strut; what the
  README recommends when the controller is unknown;
* the same with ``resimulate = true``: every trial a new trajectory, a new perturbation of the
  robot and a new simulation (does it hold beyond one motion?).

Reported per variant: coverage of the 95 % intervals over all parameters and trials (95 % if
honest), the median over the parameters of the median |error| / reported std (0.67 if honest),
the share of trials whose truth lies inside the 95 % ellipsoid and the mean chi-square of the
truth (p if honest), the failed trials, the time.

``--figure PATH`` draws where the bias lives instead: the same twin with noise-free forces, the
residual of the true parameters on the processed rows of strut 3 over time (all of it is
processing error), with the rows each selection keeps.

``--table2`` runs the twin of paper 004 Table II instead (``bench/estimator_study.py`` part B: the
nominal hexapod as the truth, the stored D-optimal design of 5 harmonics of 0.2 Hz
(``bench/data/hexapod_dopt_5h_0p2hz.json``, as ``bench/processing_study.py``), 8 periods at 500 Hz, 5 µm position noise,
the papers' 24 parameters, ``structure = "paper"``) in the time domain: WLS after the 10 Hz
low-pass with and without ``min_velocity = 0.01`` + ``reversal_guard = "auto"``, GM with the guard
(each sample whitened with the covariance of the struts it keeps), and maximum likelihood in the
time domain (the low-pass cut-off searched over 5-20 Hz and 5-80 Hz, the simulation's own noise
covariances given; the force covariance includes the propagated encoder noise and the estimates
are corrected for it, :mod:`dynid.estimation.likelihood`; its cost profile is printed); how many of
the 24 rows have the truth within 3 std.

Run: ``.venv/bin/python bench/hexapod_coverage.py`` (``--quick``: 10 trials, no resimulation;
``--trials N``; ``--workers K``; ``--figure bench/figures/hexapod_reversal_guard.png``;
``--table2``, about 25 minutes; ``--table2-methods wls gm`` for a subset; ``--table2-smoothing none auto``
runs every row with and without ``coulomb_smoothing = "auto"``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import print_machine, table  # noqa: E402
from montecarlo_scaling import CONFIG  # noqa: E402  (examples/montecarlo/hexapod_wls.toml without its row selection)

from dynid.config.montecarlo import parse_montecarlo_config  # noqa: E402
from dynid.pipeline.montecarlo import run_montecarlo  # noqa: E402

LOWPASS = 'lowpass = { cutoff_hz = 10.0, order = 4, filter_effort = false }'
VARIANTS = {
    "none": (LOWPASS, False),
    "min_velocity 0.01": (LOWPASS + "\nmin_velocity = 0.01", False),
    "min_velocity 0.01 + reversal_guard auto": (LOWPASS + '\nmin_velocity = 0.01\nreversal_guard = "auto"', False),
    "the same, resimulated per trial": (LOWPASS + '\nmin_velocity = 0.01\nreversal_guard = "auto"', True),
}


def config_for(processing: str, resimulate: bool, trials: int, workers: int):
    text = CONFIG.replace(LOWPASS, processing)
    assert processing in text
    cfg = parse_montecarlo_config(tomllib.loads(text), Path("."))
    return dataclasses.replace(cfg, trials=trials, workers=workers, resimulate=resimulate)


def figure(path: Path, strut: int = 2) -> None:
    """Residual of the truth on the processed rows of one strut, noise-free forces (module docstring)."""
    import tempfile

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynid._files import save_npz
    from dynid.pipeline.data import reversal_keep
    from dynid.pipeline.identification import _chunks, identify
    from dynid.pipeline.montecarlo import _true_base
    from dynid.pipeline.simulate import measure_signals, run_simulation

    cfg = config_for(LOWPASS, False, 1, 1)
    cfg = dataclasses.replace(cfg, simulate=dataclasses.replace(
        cfg.simulate, sensors=dataclasses.replace(cfg.simulate.sensors, force_noise_std=0.0)))
    sim = run_simulation(cfg.simulate)
    with tempfile.TemporaryDirectory() as tmp:
        meas, columns = measure_signals(sim.signals, cfg.seed)
        save_npz(Path(tmp) / "log.npz", columns)
        icfg = cfg.identify_config(Path(tmp) / "log.npz", sim.signals.actuators, meas.effort_kind, int(meas.t.size))
        out = identify(icfg)
    true = _true_base(out, sim.truth)
    ds = out.train
    r = np.concatenate([c.y - c.W @ true for c in _chunks(out.system, out.base, ds, None)])[:, strut]
    v = ds.dq[:, strut]
    slow = np.abs(v) < 0.01
    guard = dataclasses.replace(icfg.processing, reversal_guard="auto").reversal_guard_s()
    keep = reversal_keep(ds.dq, ds.t, guard, (0.01,))[:, strut]
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(9, 5.5))
    a1.plot(ds.t, v, "k-", lw=0.8)
    a1.axhspan(-0.01, 0.01, color="0.85", label="|velocity| < min_velocity = 0.01 m/s")
    a1.set_ylabel(f"strut {strut + 1} velocity [m/s]")
    a1.legend(loc="upper right", fontsize=8)
    a2.plot(ds.t, r, "-", color="0.6", lw=0.8, label="every row (no selection)")
    a2.plot(ds.t[~slow], r[~slow], ".", ms=2.5, color="tab:orange", label="kept by min_velocity")
    a2.plot(ds.t[keep], r[keep], ".", ms=2.5, color="tab:blue",
            label=f"kept by min_velocity + reversal_guard ({guard:.2f} s)")
    a2.axhspan(-2.0, 2.0, color="tab:green", alpha=0.12, label="±1 std of the force noise of the Monte Carlo (2 N)")
    a2.set_ylabel("residual of the truth [N]")
    a2.set_xlabel("time [s]")
    a2.legend(loc="upper right", fontsize=8)
    rms = lambda m: float(np.sqrt(np.mean(r[m] ** 2)))  # noqa: E731
    a2.set_title(f"noise-free forces: processing error RMS {rms(np.ones_like(slow)):.2f} N (all rows), "
                 f"{rms(~slow):.2f} N (min_velocity), {rms(keep):.2f} N (+ guard)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"figure: {path}")


TABLE2_PERIODS = 8
"""Periods of the Table II twin's log after the start-up one: all but the last train, the last is held out."""
TABLE2_LOWPASS = {"cutoff_hz": 10.0, "order": 4, "filter_effort": False}
TABLE2_GUARD = {"lowpass": TABLE2_LOWPASS, "min_velocity": 0.01, "reversal_guard": "auto"}
TABLE2_NOISE = {"noise_covariance": (4.0 * (0.2 * np.ones((6, 6)) + 0.8 * np.eye(6))).tolist(),
                "position_covariance": (25e-12 * np.eye(6)).tolist()}
"""The simulation's own noise: 2 N correlated 0.2 across the drives; 5 um position noise (ML is given them)."""


def table2_log(d: Path, periods: int = TABLE2_PERIODS, draw: int = 0) -> tuple[dict, dict]:
    """Simulate the Table II twin into ``d/log.npz``: the nominal hexapod (its truth) on the stored
    D-optimal design (bench/README §7: the optimizer ends in another design on every BLAS kernel
    and rounding, and the table changed with it), ``periods`` + 1 periods at 500 Hz, the first
    (start-up) dropped; ``draw`` > 0: other sensor noise (:func:`dynid.studies.draw_seed`). Returns
    the identify document (without processing and identification) and the simulation's truth."""
    from processing_study import DESIGN

    from dynid._files import save_npz
    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation
    from dynid.studies import draw_seed

    f0 = 0.2
    traj = {"kind": "fourier", "coordinates": "task", "design": str(DESIGN), "periods": periods + 1}
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": "builtin:hexapod"}, "trajectory": traj,
        "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
        "sensors": {"encoder_resolution": 1e-6, "position_noise_std": 5e-6, "force_noise_std": 2.0,
                    "force_correlation": 0.2, "seed": draw_seed(1, draw)},
    }, d))
    n_per = int(round(500 / f0))  # the first period (start-up) is dropped, as in estimator_study
    cols = {k: v[n_per:] for k, v in sim.columns.items()}
    cols["t"] = cols["t"] - cols["t"][0]
    save_npz(d / "log.npz", cols)
    q = [f"q_P{j}" for j in range(1, 7)]
    doc = {"robot": {"model": "builtin:hexapod"},
           "data": {"file": str(d / "log.npz"), "time": {"column": "t", "unit": "s"},
                    "position": {"columns": q, "unit": "m"},
                    "effort": {"columns": [c.replace("q_", "tau_") for c in q], "kind": "torque", "unit": "N"},
                    "rows": [0, (periods - 1) * n_per]},
           "validation": {"rows": [(periods - 1) * n_per, periods * n_per]}, "output": {"plots": False}}
    return doc, sim.truth


def table2_z(out, truth: dict) -> tuple[list[str], np.ndarray]:
    """|estimate - truth| / std of Table II's 24 rows of an identify outcome."""
    from estimator_study import PAPER_TABLE2, TABLE2_PARAMS

    true = out.base.from_standard(out.system.reduce_parameters(np.asarray(truth["true_parameters"])))
    names = list(out.result.names)
    idx = [names.index(TABLE2_PARAMS[n]) for n in PAPER_TABLE2]
    return list(PAPER_TABLE2), np.abs(out.result.params - true)[idx] / out.result.bse[idx]


def table2(methods: list[str] | None = None, smoothing: list[str] | None = None, draw: int = 0) -> None:
    """Paper 004 Table II's twin in the time domain, with and without the guard (module docstring)."""
    import tempfile

    from dynid.config import parse_config
    from dynid.errors import DynidError
    from dynid.pipeline.identification import identify

    lp, guard = TABLE2_LOWPASS, TABLE2_GUARD
    variants = [("WLS, no selection", {"lowpass": lp}, "wls"), ("WLS, min_velocity + reversal_guard", guard, "wls"),
                ("GM, min_velocity + reversal_guard (per strut, Sigma_KK)", guard, "gm"),
                ("ML (f_c in 5-20 Hz), min_velocity + reversal_guard", guard, "ml"),
                ("ML (f_c in 5-80 Hz), min_velocity + reversal_guard", guard, "ml")]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        doc, truth = table2_log(d, draw=draw)
        rows = []
        runs = [(f"{label}{'' if sm is None else f', coulomb_smoothing {sm}'}", proc, method, sm)
                for label, proc, method in variants for sm in (smoothing or [None])
                if not methods or method in methods]
        for label, proc, method, sm in runs:
            t0 = time.perf_counter()
            try:
                ident = {"method": method, "structure": "paper"}
                if sm is not None:
                    ident["coulomb_smoothing"] = sm
                if method == "ml":
                    ident.update(**TABLE2_NOISE, cutoff_range_hz=[5.0, 20.0] if "5-20" in label else [5.0, 80.0])
                out = identify(parse_config({**doc, "processing": proc, "identification": ident}, d))
            except DynidError as exc:
                rows.append([label, "refused", "", "", "", str(exc)[:90]])
                continue
            rows_names, z = table2_z(out, truth)
            worst = ", ".join(f"{n} {zz:.1f}" for n, zz in sorted(zip(rows_names, z), key=lambda x: -x[1])[:3])
            fc = ""
            if method == "ml":
                sv = out.result.solver
                fc = f"f_c {sv['cutoff_hz']:.3g} Hz (neighbours {sv['cutoff_interval_hz'][0]:.3g}, {sv['cutoff_interval_hz'][1]:.3g}); "
                print(f"{label}: cost profile (cut-off Hz, position cost, force cost, of it the log-determinant of "
                      "S_k Sigma_eta^-1, total; propagated force noise std N, mean over the struts):")
                for r in sv["profile"]:
                    prop = r.get("propagated_std")
                    print(f"  {r['cutoff_hz']:8.3f} {r['position_cost']:14.1f} {r['force_cost'] or float('nan'):14.1f} "
                          f"{r.get('log_det', float('nan')):12.1f} {r['cost'] or float('nan'):14.1f} "
                          f"{float(np.mean(prop)) if prop else float('nan'):8.3f}" + (f"  ({r['error'][:70]})" if 'error' in r else ""))
                print(f"  residual variance factor at f_c: {out.result.scale:.3f} (1 if S_k is the whole residual)")
            rows.append([label, f"{int((z < 3).sum())} of 24", f"{z.max():.1f}", f"{np.median(z):.2f}",
                         f"{int(np.median(out.result.n_obs))}", f"{fc}worst: {worst}; held-out rel. RMSE % "
                         + " ".join(f"{x:.1f}" for x in out.validation.rel_rmse_pct) + f"; {time.perf_counter() - t0:.0f} s"])
            print("  " + " | ".join(rows[-1]), flush=True)  # as it comes (the ML rows take minutes)
    print("paper 004 Table II twin, time domain (24 parameters, truth = the nominal model):")
    print(table(["estimate", "truth within 3 std", "max |z|", "median |z|", "rows/strut", "notes"], rows))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="10 trials, no resimulated variant")
    ap.add_argument("--trials", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--figure", type=Path, default=None, help="draw where the bias lives (no Monte Carlo)")
    ap.add_argument("--table2", action="store_true", help="paper 004 Table II's twin in the time domain (no Monte Carlo)")
    ap.add_argument("--table2-methods", nargs="+", default=None, help="with --table2: only these methods (wls gm ml)")
    ap.add_argument("--table2-smoothing", nargs="+", default=None, choices=("none", "auto"),
                    help="with --table2: run every row with each of these identification.coulomb_smoothing values")
    ap.add_argument("--draw", type=int, default=0, help="with --table2: another draw of the sensor noise (0: the recorded one)")
    args = ap.parse_args(argv)
    if args.table2:
        print_machine()
        table2(args.table2_methods, args.table2_smoothing, args.draw)
        return 0
    if args.figure is not None:
        figure(args.figure)
        return 0
    trials = args.trials or (10 if args.quick else 100)
    print_machine()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows = []
    for label, (processing, resim) in VARIANTS.items():
        if resim and args.quick:
            continue
        t0 = time.perf_counter()
        res = run_montecarlo(config_for(processing, resim, trials, args.workers))
        wall = time.perf_counter() - t0
        ok = res.with_cov
        err = np.abs(res.estimates[ok] - res.truth[ok]) / res.std[ok]
        rows.append([label, f"{res.overall_coverage:.1f}", f"{np.median(np.median(err, axis=0)):.2f}",
                     f"{res.ellipsoid_share:.0f}", f"{res.mean_chi2:.1f}", f"{len(res.failures)}", f"{wall:.0f}"])
        print(f"  {label}: coverage {res.overall_coverage:.1f} %, mean chi2 {res.mean_chi2:.1f} (p = {res.n_params}), "
              f"{wall:.0f} s", flush=True)
    print()
    print(f"{trials} trials of builtin:hexapod (WLS, model covariance):")
    print(table(["row selection", "coverage %", "median |err|/std", "in ellipsoid %", "mean chi2", "failed", "s"], rows))
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
