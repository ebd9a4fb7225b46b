"""Kalman (RTS) smoothing against the Butterworth path on the fast parallel twins (issue 36, item 4).

A comparison, not a pass/fail check: the script always exits 0 once the tables are printed.

For the 3-RPS twin (``builtin:rps3``, examples/twins/rps3_fourier.toml) and the hexapod twin
(``builtin:hexapod``, examples/twins/hexapod_fourier.toml), each run through the product
(``dynid simulate``'s ``run_simulation`` / ``write_simulation``, the helpers of
bench/physical_study.py):

1. ``dynid simulate``: the twin's perturbed truth (10 % away from the nominal model, physically
   consistent by construction), its encoders (1 um) and force noise (5 N on the 3-RPS, 2 N
   correlated 0.2 on the hexapod), computed torque with the nominal model (the twins' control
   tables). A training log (the twin's own Fourier excitation at ``TRAIN_HZ`` = 0.2 Hz, twice the
   twin files' fundamental, 3 periods) and a held-out log (another trajectory: other seed, one
   period at ``VALID_HZ`` = 0.1 Hz), 1 kHz control.
2. ``dynid init`` on the training log (:func:`dynid.pipeline.starter.starting_config`, nothing
   edited): its ``[processing]`` table (the Butterworth cut-off from the motion's band,
   ``min_velocity`` from the position noise, ``reversal_guard = "auto"`` on a parallel robot).
3. ``dynid identify`` with WLS (``structure = "full"`` as bench/physical_study.py) under two
   processings that differ only in ``derivatives``: init's table as it is (zero-phase
   Butterworth of the positions + central differences) and the same table with
   ``derivatives = "kalman"`` (the RTS smoother replaces the positions' low-pass; the trim, the
   row selection and ``reversal_guard``'s width still follow init's cut-off, so both paths keep
   the same rows up to the smoother's own settling).
4. Exact states (bench/physical_study.py's B8): the simulation's true actuator q, dq, ddq at the
   control instants with the measured (noisy) forces, ``derivatives = "measured"``, no filter.

Per robot, one table with a column per processing:

(a) the training estimate against the true base parameters: ``z`` = (estimate - truth) / the
    estimate's standard error; ``|z|/sqrt(p)`` (about 1 when the reported covariance is honest and
    the estimate unbiased), ``max |z|``, how many of the p base parameters lie inside their 95 %
    intervals, and the median of |e_i| / |b_i| over the inertial base parameters whose true
    magnitude is at least 1 % of the largest (bench/physical_study.py's ``_well_scaled``; the
    nominal model's figure is printed below the table);
(b) the held-out RMSE per actuator [N] of the identified model and of the nominal (CAD) model, on
    every processed held-out row (at the fit's rate: init decimates the 3-RPS log), and again on
    the rows the training's selection keeps (``min_velocity``, ``reversal_guard``: the product's
    ``validation_selected_rows``; "kept rows");
(c) the true parameters' held-out RMSE per actuator: the truth's base parameters scored on the
    same processed held-out rows ("truth, processed"), and on exact states at the same instants
    ("truth, exact": the floor the model class reaches, about the force noise); the gap is
    processed / exact (1 = the processing adds nothing). The exact-state column also shows the WLS
    fit on exact states (train and held out), what identification reaches without processing error.
    Both on every held-out row and on the kept rows (reversals and stops out).

Reading: the issue's observation is a gap of 1.5-2x on these robots with the Butterworth path;
the Kalman path closes it where its "truth, processed" row comes down to "truth, exact", and wins
for identification where (a) and the identified row of (b) come down with it. The sum over the
actuators is printed with every row. The all-row figures are dominated by the velocity reversals
(the plant's friction switches there, and every smoother smears the switch), the kept rows by the
smooth motion; the two paths can rank differently on the two. The figures of the last full run
and what they say are in bench/README.md.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/kalman_twins.py`` (about 2.5 minutes on 2 cores);
``--quick``: one short period of each log at 500 Hz, one draw (a smoke run, the figures mean
little; about 10 s); ``--draws N``: other trajectories and noise of the same twins (default 5),
the first draw printed in full, then the mean +- standard error of every figure over the draws
and of the paired difference Kalman - Butterworth;
``--robots rps3`` or ``hexapod`` for one twin.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO / "src"))
sys.path.insert(0, str(HERE))

from dynid.pipeline import identify  # noqa: E402
from dynid.pipeline.starter import starting_config  # noqa: E402

from physical_study import _case, _config, _exact_config, _exact_log, _inertial, _predict, _well_scaled  # noqa: E402

TWINS = REPO / "examples" / "twins"
TRAIN_HZ, VALID_HZ = 0.2, 0.1
"""Base frequencies of the training and held-out excitations [Hz]: training at twice the twins'
own 0.1 Hz (the 'fast' set-up), held out on the twins' own band with another trajectory seed."""
SIZES = {False: {"rps3": 3, "hexapod": 3}, True: {"rps3": 1, "hexapod": 1}}
"""Periods of each log (full, ``--quick``); the held-out log has one period of ``VALID_HZ``
(``--quick``: of ``TRAIN_HZ``, half as long)."""
RATE_HZ = {False: None, True: 500}
"""Control rate: the twin's own (1 kHz) in the full run, 500 Hz with ``--quick``."""
PROCESSINGS = ("Butterworth", "Kalman")
DRAWS = {False: 5, True: 1}
"""Draws per robot (:func:`dynid.studies.draw_seed`: other trajectories and sensor noise, the same
true robot); the first is printed in full, all of them in the summary."""
SUMMARY = (
    ("(a) |z|/sqrt(p)", lambda c: c["z_rms"]),
    ("(a) inside 95 %", lambda c: c["inside95"]),
    ("(b) identified, sum", lambda c: sum(c["identified"])),
    ("(b) nominal, sum", lambda c: sum(c["nominal"])),
    ("(c) truth processed, sum", lambda c: sum(c["truth_processed"])),
    ("(c) truth exact, sum", lambda c: sum(c["truth_exact"])),
    ("(c) gap, sum", lambda c: sum(c["truth_processed"]) / sum(c["truth_exact"])),
    ("(b) identified, kept, sum", lambda c: sum(c["selected"]["identified"]) if "selected" in c else None),
    ("(c) truth processed, kept, sum", lambda c: sum(c["selected"]["truth_processed"]) if "selected" in c else None),
    ("(c) gap, kept, sum", lambda c: (sum(c["selected"]["truth_processed"]) / sum(c["selected"]["truth_exact"])
                                      if "selected" in c else None)),
)


def setup(robot: str, quick: bool) -> dict:
    """bench/physical_study.py's set-up dict for the twin file of ``robot`` (its robot, control and
    sensors tables; trajectories at ``TRAIN_HZ`` / ``VALID_HZ``)."""
    doc = tomllib.loads((TWINS / f"{robot}_fourier.toml").read_text())
    traj = {k: v for k, v in doc["trajectory"].items() if k != "seed"}
    control = dict(doc["control"])
    if RATE_HZ[quick]:
        control["rate_hz"] = RATE_HZ[quick]
    periods = SIZES[quick][robot]
    return {
        "model": doc["robot"]["model"], "robot": doc["robot"], "control": control,
        "sensors": {k: v for k, v in doc["sensors"].items() if k != "seed"},
        "train": {**traj, "base_frequency_hz": TRAIN_HZ, "periods": periods},
        "valid": {**traj, "periods": 1, "seed": int(doc["trajectory"]["seed"]) + 30},
        # physical_study._case holds out at 0.1 Hz in its full version, at quick_valid_hz with --quick
        "quick_valid_hz": TRAIN_HZ,
        "unit": "m", "effort_unit": "N",
    }


def init_processing(model: str, train: Path, folder: Path) -> tuple[dict, str]:
    """``dynid init MODEL TRAIN``'s ``[processing]`` table and its text."""
    sc = starting_config(model, train / "log.npz", folder / "init.toml")
    proc = tomllib.loads(sc.text).get("processing", {})
    return proc, "\n".join(line for line in sc.text.splitlines() if line.strip())


def _rmse(e: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(e**2, axis=0))


def _rows_at(t_exact: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Indices of the instants ``t`` in ``t_exact`` (the same control instants)."""
    i = np.clip(np.searchsorted(t_exact, t - 1e-9), 0, t_exact.size - 1)
    if np.max(np.abs(t_exact[i] - t)) > 1e-9:
        raise RuntimeError("processed held-out rows are not at the simulation's control instants")
    return i


def run_robot(robot: str, quick: bool, folder: Path, draw: int = 0) -> dict:
    """One draw of one twin: simulate, init, the two processings and exact states."""
    s = setup(robot, quick)
    t0 = time.perf_counter()
    case, _ = _case(s, folder, quick, 0, draw=draw)
    sim_s = time.perf_counter() - t0
    proc, init_text = init_processing(s["model"], case.train, folder)
    ident = {"method": "wls"}
    out: dict = {"robot": robot, "draw": draw, "setup": s, "init": proc, "simulate_s": sim_s, "init_text": init_text}
    res = {}
    for name in PROCESSINGS:
        p = dict(proc) if name == "Butterworth" else {**proc, "derivatives": "kalman"}
        t0 = time.perf_counter()
        o = identify(_config(s, case.actuators, case.train, case.valid, ident, p))
        res[name] = (o, time.perf_counter() - t0)
        print(f"  {robot} {name}: identify {res[name][1]:.1f} s", flush=True)
    # exact states: the truth, and the WLS fit, with measured q, dq, ddq and no filter
    xt, xv = _exact_log(case.train_sim, folder / "exact_train"), _exact_log(case.valid_sim, folder / "exact_valid")
    t0 = time.perf_counter()
    ox = identify(_exact_config(case, xt, xv, ident))
    print(f"  {robot} exact states: identify {time.perf_counter() - t0:.1f} s", flush=True)
    base = ox.base
    true_beta, nom_beta = base.from_standard(case.true_std), base.from_standard(case.nominal_std)
    vx = ox.validation
    well = _well_scaled(true_beta, _inertial(base.B, base.standard_names))
    x_truth_pred = _predict(ox, true_beta)
    cols = {}
    for name, (o, secs) in list(res.items()) + [("exact states", (ox, None))]:
        if o.base.n_base != base.n_base or not np.allclose(o.base.B, base.B):
            raise RuntimeError("the processings gave different base parameters")
        r, v = o.result, o.validation
        beta, bse = r.params[: base.n_base], r.bse[: base.n_base]
        z = (beta - true_beta) / bse
        rows = _rows_at(np.asarray(vx.t), np.asarray(v.t))
        truth_proc = _rmse(v.measured - _predict(o, true_beta))
        truth_exact = _rmse(vx.measured[rows] - x_truth_pred[rows])
        if not np.allclose(vx.measured[rows], v.measured):
            raise RuntimeError("the exact-state and processed held-out forces differ")
        cols[name] = {
            "seconds": secs, "n_train": int(o.train.n_samples), "n_valid": int(v.n_samples),
            "z_rms": float(np.linalg.norm(z) / np.sqrt(z.size)), "z_max": float(np.abs(z).max()),
            "inside95": int(np.sum(np.abs(z) <= 1.959964)), "p": int(z.size),
            "rel_median_pct": float(np.median(100 * np.abs(beta - true_beta)[well] / np.abs(true_beta[well]))),
            "identified": v.rmse.tolist(), "nominal": _rmse(v.measured - _predict(o, nom_beta)).tolist(),
            "truth_processed": truth_proc.tolist(), "truth_exact": truth_exact.tolist(),
            "noise": _rmse(vx.measured[rows] - case.original(np.asarray(v.t))).tolist(),
        }
        sel = o.selected
        if sel is not None:  # the rows the training's selection (min_velocity, reversal_guard) keeps
            kept = sel.metrics.kept

            def on_kept(err, kept=kept):
                return np.sqrt(np.sum(np.where(kept, err, 0.0) ** 2, axis=0) / kept.sum(axis=0)).tolist()

            cols[name]["selected"] = {
                "kept_pct": (100 * kept.mean(axis=0)).tolist(), "identified": sel.metrics.rmse.tolist(),
                "nominal": sel.nominal.rmse.tolist(),
                "truth_processed": on_kept(v.measured - _predict(o, true_beta)),
                "truth_exact": on_kept(vx.measured[rows] - x_truth_pred[rows]),
                "noise": on_kept(vx.measured[rows] - case.original(np.asarray(v.t)))}
        step = next((st for st in o.train.meta.get("processing", ()) if st.get("step") == "derivatives"), {})
        if "noise_ratio" in step:
            cols[name]["kalman"] = {k: step[k] for k in ("noise_ratio", "position_noise_std", "std_velocity",
                                                         "std_acceleration")}
    out["columns"] = cols
    out["channels"] = list(vx.channel_names)
    out["nominal_rel"] = float(np.median(100 * np.abs(nom_beta - true_beta)[well] / np.abs(true_beta[well])))
    out["n_well"] = int(well.size)
    return out


def _fmt(xs, f=".2f") -> str:
    return " ".join(f"{x:{f}}" for x in xs) + f"  (sum {sum(xs):{f}})"


def print_table(out: dict) -> None:
    from _util import table

    cols = out["columns"]
    names = list(cols)
    s = out["setup"]
    print(f"\n{out['robot']}, draw {out['draw']}: training {s['train']['periods']} period(s) at {TRAIN_HZ} Hz, held out 1 period "
          f"(seed {s['valid']['seed']}), control {s['control']['rate_hz']} Hz, sensors {s['sensors']}; "
          f"simulate {out['simulate_s']:.0f} s")
    print(f"init's [processing]: {out['init']}")
    ch = ", ".join(out["channels"])
    rows = [
        ["training rows / held-out rows"] + [f"{c['n_train']} / {c['n_valid']}" for c in cols.values()],
        ["identify [s]"] + ["-" if c["seconds"] is None else f"{c['seconds']:.1f}" for c in cols.values()],
        ["(a) |z|/sqrt(p)"] + [f"{c['z_rms']:.2f}" for c in cols.values()],
        ["(a) max |z|"] + [f"{c['z_max']:.1f}" for c in cols.values()],
        ["(a) inside 95 % / p"] + [f"{c['inside95']} / {c['p']}" for c in cols.values()],
        [f"(a) median |e|/|b| %, {out['n_well']} inertial"] + [f"{c['rel_median_pct']:.1f}" for c in cols.values()],
    ]
    for key, label in (("identified", "(b) identified"), ("nominal", "(b) nominal (CAD)"),
                       ("truth_processed", "(c) truth, processed"), ("truth_exact", "(c) truth, exact states"),
                       ("noise", "    force noise")):
        rows.append([f"{label}, sum"] + [f"{sum(c[key]):.2f}" for c in cols.values()])
    rows.append(["(c) gap processed / exact, sum"] + [f"{sum(c['truth_processed']) / sum(c['truth_exact']):.3f}"
                                                     for c in cols.values()])
    sel = [c.get("selected") for c in cols.values()]
    rows.append(["rows kept by the training's selection, %"]
                + ["-" if x is None else "/".join(f"{k:.0f}" for k in x["kept_pct"]) for x in sel])
    for key, label in (("identified", "(b) identified"), ("nominal", "(b) nominal (CAD)"),
                       ("truth_processed", "(c) truth, processed"), ("truth_exact", "(c) truth, exact states"),
                       ("noise", "    force noise")):
        rows.append([f"{label}, kept rows, sum"] + ["-" if x is None else f"{sum(x[key]):.2f}" for x in sel])
    rows.append(["(c) gap, kept rows, sum"] + ["-" if x is None else f"{sum(x['truth_processed']) / sum(x['truth_exact']):.3f}"
                                              for x in sel])
    print(table(["held-out RMSE in N (" + ch + ")"] + names, rows))
    print("per actuator [N]:")
    for name, c in cols.items():
        print(f"  {name}:")
        for key in ("identified", "nominal", "truth_processed", "truth_exact", "noise"):
            print(f"    {key:<16} {_fmt(c[key])}")
        gap = np.array(c["truth_processed"]) / np.array(c["truth_exact"])
        print(f"    {'gap':<16} " + " ".join(f"{g:.3f}" for g in gap))
        if c.get("selected"):
            x = c["selected"]
            for key in ("identified", "nominal", "truth_processed", "truth_exact", "noise"):
                print(f"    {key + ', kept':<22} {_fmt(x[key])}")
            gap = np.array(x["truth_processed"]) / np.array(x["truth_exact"])
            print(f"    {'gap, kept':<22} " + " ".join(f"{g:.3f}" for g in gap))
        if c.get("kalman"):
            k = c["kalman"]
            print("    Kalman: noise ratio " + " ".join(f"{r:.3g}" for r in k["noise_ratio"]) + "; position noise std "
                  + " ".join(f"{r:.3g}" for r in k["position_noise_std"]) + "; velocity std "
                  + " ".join(f"{r:.3g}" for r in k["std_velocity"]) + "; acceleration std "
                  + " ".join(f"{r:.3g}" for r in k["std_acceleration"]))
    print(f"nominal model: median |e|/|b| = {out['nominal_rel']:.1f} % on the same {out['n_well']} inertial base parameters")


def print_summary(runs: list[dict]) -> None:
    """Mean +- standard error over the draws of each figure, and of the paired difference
    Kalman - Butterworth (the same logs)."""
    from _util import table

    n = len(runs)

    def ms(xs) -> str:
        xs = np.asarray(xs, dtype=float)
        return f"{xs.mean():.3f} +- {xs.std(ddof=1) / np.sqrt(n):.3f}"

    rows = []
    for label, f in SUMMARY:
        vals = {p: [f(r["columns"][p]) for r in runs] for p in (*PROCESSINGS, "exact states")}
        diff = np.subtract(vals["Kalman"], vals["Butterworth"])
        rows.append([label] + [ms(vals[p]) if None not in vals[p] else "-" for p in (*PROCESSINGS, "exact states")]
                    + [ms(diff), " ".join(f"{d:+.2f}" for d in diff)])
    print(f"\n{runs[0]['robot']}: {n} draws (mean +- SE; Kalman - Butterworth paired on the same logs)")
    print(table(["figure", *PROCESSINGS, "exact states", "Kalman - Butterworth", "per draw"], rows))
    print("init's cut-offs per draw [Hz]: " + ", ".join(f"{r['init']['lowpass']['cutoff_hz']:g}" for r in runs)
          + "; decimate: " + ", ".join(str(r["init"].get("decimate", 1)) for r in runs))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one short period per log at 500 Hz (a smoke run)")
    ap.add_argument("--robots", default="rps3,hexapod")
    ap.add_argument("--draws", type=int, default=None,
                    help=f"draws of the trajectories and noise per robot (default {DRAWS[False]}; --quick {DRAWS[True]})")
    args = ap.parse_args(argv)
    draws = args.draws or DRAWS[args.quick]
    from _util import print_machine

    print_machine()
    t0 = time.perf_counter()
    for robot in args.robots.split(","):
        runs = []
        for draw in range(draws):
            with tempfile.TemporaryDirectory() as tmp:
                print(f"{robot}, draw {draw}:", flush=True)
                runs.append(run_robot(robot, args.quick, Path(tmp), draw))
            if draw == 0:
                print_table(runs[0])
        if draws > 1:
            print_summary(runs)
    print(f"\nwall time {time.perf_counter() - t0:.0f} s (a comparison: no pass/fail)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
