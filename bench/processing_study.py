"""Study (issue 6, item 6; issue 17, item 5; paper 004 Fig. 4): how signal processing changes the
identified hexapod, and why paper 004's ranking does not transfer to the twin.

A virtual PaLiDA-like hexapod (``builtin:hexapod``) follows a fixed D-optimal periodic task-space
excitation (5 harmonics of 0.2 Hz, ``bench/data/hexapod_dopt_5h_0p2hz.json``: computed once by
:func:`_designs.hexapod_design` and kept, so that every machine runs the same excitation; the
optimizer's path differs between BLAS kernels) under computed torque with the true model at
500 Hz (strut encoders of 1 µm; drive forces with 2 N of noise correlated 0.2 across drives), and
a circle of its platform in the x-y plane for validation. The same log is identified (WLS, the
steps of ``dynid identify``: processing, base parameters, compressed problem, estimator) after
each processing:

(a) raw: central differences of the unfiltered actuator positions;
(b) time domain: zero-phase Butterworth (order 4) at ``4 n_h f0`` + central differences;
(c) frequency domain (paper 004 §3.3): period averaging + exact DFT filtering and differentiation
    of the actuator positions, window at ``CUTOFF`` = 10.5 f0;
(c') the same with the window at the band of (b), 20.5 f0 (the control: same band, other domain);
(d) frequency domain on the pose (paper 004): period averaging, forward kinematics of every
    sample, the platform pose windowed at ``CUTOFF`` f0 and differentiated exactly;
(e) the same with the window at the excited band ((n_h + 0.5) f0), as in paper 004.

Each model predicts the drive forces along the circle (processed in the time domain, the same
for all); the table gives the prediction error variance per drive, its mean, and ``truth``: the
variance of the processed training forces minus the *true* model's prediction (the error the
processing leaves before any estimation). Two controlled experiments explain the ranking:

* replicates: the same motion measured again with other sensor seeds (another run of the same
  experiment, as ``dynid montecarlo`` draws them), identified after (b) and (c): the mean and
  standard error of the difference of their prediction errors;
* ``no Coulomb``: the same study on the twin with every Coulomb coefficient zero (actuators and
  passive joints; training and validation runs), mean prediction error per processing.

Then the leakage of paper 004 Fig. 2: the exact DFT processing against the implicit Fourier fit
at the nominal frequency when the record's period is 0.5 % longer than nominal.

``--quick`` (the tests): the same excitation and rates, 2 periods instead of 4 and one turn of the
circle instead of 4. ``--figure PATH`` writes the figure of bench/README §7 (the full run writes
``bench/figures/processing_spectrum.png``).

Run: ``.venv/bin/python bench/processing_study.py`` (about 3 minutes; ``--quick`` about 2 minutes; the
test runs three rows of the quick version without the Coulomb-free twin, under a minute).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.estimation import ProblemBuilder
from dynid.model.robots import build_mechanism
from dynid.pipeline.data import build_system, configured_estimator, preprocess, read_log, to_actuator_space
from dynid.pipeline.identification import _chunks
from dynid.pipeline.simulate import measure_signals, run_simulation, write_simulation
from dynid.signals.periodic import fourier_filter, fourier_fit

HERE = Path(__file__).resolve().parent
DESIGN = HERE / "data" / "hexapod_dopt_5h_0p2hz.json"
FIGURE = HERE / "figures" / "processing_spectrum.png"
F0, HARMONICS, RATE, KP, KD = 0.2, 5, 500.0, 2500.0, 100.0
# Band of the frequency-domain processing (c) and (d), in multiples of the fundamental: above the
# excited band; (c') windows at the band of the time-domain filter, (e) at the excited band.
CUTOFF = 10.5
SIZES = {False: {"periods": 4, "turns": 4}, True: {"periods": 2, "turns": 1}}
SEEDS = 3  # noise replicates of (b) and (c), the first one being the main log
STRUT = 2  # strut 3: the largest Coulomb force (20 N), shown in the figure
B, C, C2 = "(b) time domain", "(c) frequency domain", "(c') frequency, band of (b)"


def processings(f0: float = F0, harmonics: int = HARMONICS) -> dict[str, dict]:
    """The ``[processing]`` table of each row of the study."""
    band = 4.0 * harmonics * f0
    per = 1.0 / f0
    return {
        "(a) raw": {"derivatives": "central", "trim_samples": 2},
        B: {"lowpass": {"cutoff_hz": band, "order": 4, "filter_effort": False}},
        C: {"periodic": {"period_s": per, "cutoff_hz": CUTOFF * f0}},
        C2: {"periodic": {"period_s": per, "cutoff_hz": band + 0.5 * f0}},
        "(d) frequency, pose": {"periodic": {"period_s": per, "cutoff_hz": CUTOFF * f0, "domain": "pose"}},
        "(e) pose, excited band": {"periodic": {"period_s": per, "cutoff_hz": (harmonics + 0.5) * f0, "domain": "pose"}},
    }


def twin(coulomb: bool = True):
    """``builtin:hexapod``, or the same with every Coulomb coefficient zero (the controlled experiment)."""
    mech = build_mechanism("hexapod")
    if coulomb:
        return mech
    zero = {t.name for t in mech.terms if t.kind == "coulomb"}
    return dataclasses.replace(mech, nominal_terms={k: 0.0 if k in zero else v for k, v in mech.nominal_terms.items()})


def _simulate(folder: Path, trajectory: dict, seed: int, robot):
    doc = {
        "robot": {"model": "builtin:hexapod"},
        "trajectory": trajectory,
        "control": {"rate_hz": RATE, "kp": KP, "kd": KD, "model": "true", "substeps": 2},
        "sensors": {"encoder_resolution": 1e-6, "force_noise_std": 2.0, "force_correlation": 0.2, "seed": seed},
    }
    out = run_simulation(parse_simulate_config(doc, folder), robot=robot)
    write_simulation(out, folder)
    return out


def _doc(log: Path, circle: Path, proc: dict) -> dict:
    q, tau = [f"q_P{j}" for j in range(1, 7)], [f"tau_P{j}" for j in range(1, 7)]
    return {"robot": {"model": "builtin:hexapod"},
            "data": {"file": str(log), "time": {"column": "t", "unit": "s"}, "position": {"columns": q, "unit": "m"},
                     "effort": {"columns": tau, "kind": "torque", "unit": "N"}},
            "validation": {"file": str(circle)}, "processing": proc, "identification": {"method": "wls"},
            "output": {"plots": False}}


def _processed(system, doc: dict, folder: Path, label: str):
    cfg = parse_config(doc, folder)
    raw = read_log(cfg.data, system.n_actuators, tuple(system.actuator_names), label)
    ds, steps = preprocess(to_actuator_space(raw, system, label)[0], cfg.processing, label)
    return cfg, ds, steps


def _fit(system, base, true_base, doc: dict, folder: Path) -> dict:
    """Process and identify one log as ``dynid identify`` does (without its own validation), and
    the residual of the processed data with the true parameters, in the same pass."""
    cfg, train, steps = _processed(system, doc, folder, "data")
    builder = ProblemBuilder(base.names, system.channel_names(None))
    res_true = []
    for c in _chunks(system, base, train, None, chunk_size=5000, periodic=cfg.processing.periodic):
        builder.add(c.W, c.y)
        res_true.append(c.y - c.W @ true_base)
    problem = builder.build(expressions=base.expressions(), standard=system.standard_map(base), meta={})
    result = configured_estimator(cfg.identification, steps, tuple(system.channel_names(None)),
                                  tuple(system.actuator_names), None).fit(problem)
    return {"params": result.params, "train": train, "res_true": np.concatenate(res_true)}


def _run(d: Path, robot, quick: bool, labels, seeds: int) -> dict:
    """One twin: the training and circle runs, every processing, the replicates of (b) and (c)."""
    size = SIZES[quick]
    train = _simulate(d / "train", {"kind": "fourier", "coordinates": "task", "design": str(DESIGN),
                                    "periods": size["periods"]}, 1, robot)
    circle = {"kind": "circle", "coordinates": "task", "axes": ["PX", "PY"], "centre": [0.0, 0.0],
              "radius": 0.015, "speed": 0.05, "turns": size["turns"], "ramp": 0.2}
    _simulate(d / "circle", circle, 2, robot)
    procs = processings()
    vdoc = _doc(d / "circle" / "log.csv", d / "train" / "log.csv", procs[B])
    system = build_system(parse_config(vdoc, d).robot)
    icfg = parse_config(vdoc, d).identification
    base = system.base_parameters(None, n_samples=icfg.base_samples, seed=icfg.base_seed)
    true_base = base.from_standard(np.asarray(train.truth["true_parameters"]))
    # the circle, processed in the time domain, validates every model (rows computed once)
    held = _processed(system, vdoc, d, "circle")[1]
    val = [(c.W, c.y) for c in _chunks(system, base, held, None, chunk_size=5000)]

    def predict(params):
        err = np.concatenate([y - W @ params for W, y in val])
        return np.var(err, axis=0)

    rows, fits = {}, {}
    for label in labels:
        fit = _fit(system, base, true_base, _doc(d / "train" / "log.csv", d / "circle" / "log.csv", procs[label]), d)
        var = predict(fit["params"])
        rows[label] = {"error_variance_N2": var.tolist(), "mean_variance_N2": float(var.mean()),
                       "truth_residual_variance_N2": float(np.var(fit["res_true"], axis=0).mean())}
        fits[label] = {"t": fit["train"].t, "res_true": fit["res_true"][:, STRUT]}
    replicates = {k: [rows[k]["mean_variance_N2"]] for k in (B, C) if k in rows}
    for s in range(1, seeds if replicates else 1):
        log = d / f"train{s}"
        write_simulation(dataclasses.replace(train, columns=measure_signals(train.signals, 1 + 1000 * s)[1]), log)
        for k in replicates:
            fit = _fit(system, base, true_base, _doc(log / "log.csv", d / "circle" / "log.csv", procs[k]), d)
            replicates[k].append(float(predict(fit["params"]).mean()))
    mot = train.motion
    return {"rows": rows, "replicates": replicates, "fits": fits, "t": mot.t, "dq": mot.dq[:, robot.actuated[STRUT]],
            "periods": size["periods"]}


def study(quick: bool = False, labels=None, coulomb_free: bool = True, seeds: int = SEEDS, keep: bool = False) -> dict:
    """Run the study; ``labels`` (default all rows of :func:`processings`) and ``coulomb_free``
    (the twin without Coulomb friction) select what runs; ``keep`` returns the arrays of the figure."""
    labels = list(processings()) if labels is None else list(labels)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        main = _run(d / "coulomb", twin(True), quick, labels, seeds)
        free = _run(d / "free", twin(False), quick, labels, 1) if coulomb_free else None
    res = {"rows": main["rows"], "replicates": main["replicates"], "f0_hz": F0, "harmonics": HARMONICS,
           "periods": main["periods"], "rate_hz": RATE, "leakage": leakage()}
    if free is not None:
        res["no_coulomb"] = {k: r["mean_variance_N2"] for k, r in free["rows"].items()}
        res["no_coulomb_truth"] = {k: r["truth_residual_variance_N2"] for k, r in free["rows"].items()}
    d_bc = np.subtract(*[main["replicates"][k] for k in (C, B)]) if {B, C} <= set(main["replicates"]) else None
    if d_bc is not None:
        res["difference_c_minus_b"] = {"values": d_bc.tolist(), "mean": float(d_bc.mean()),
                                       "se": float(d_bc.std(ddof=1) / np.sqrt(d_bc.size)) if d_bc.size > 1 else float("nan")}
    if keep:
        res["arrays"] = {"coulomb": main, "free": free}
    return res


def leakage() -> dict:
    """Paper 004, Fig. 2: a record whose period is 0.5 % longer than nominal (analytic signal)."""
    fs, n = 200.0, 402  # 2.01 s of a motion of nominal period 2 s
    t = np.arange(n) / fs
    k = np.arange(1, 6)
    w = 2 * np.pi * (fs / n) * k
    x = np.sin(np.outer(t, w) + k) @ (1 / k)
    ddx = -(np.sin(np.outer(t, w) + k) * w**2) @ (1 / k)
    return {"dft_rms_error_acc": float(np.sqrt(np.mean((fourier_filter(x, fs, 2.75)[2] - ddx) ** 2))),
            "implicit_fit_rms_error_acc": float(np.sqrt(np.mean((fourier_fit(x, t, 0.5, 5)[2] - ddx) ** 2)))}


def table(res: dict) -> str:
    free = res.get("no_coulomb", {})
    lines = [f"Prediction error variance of the drive forces on the validation circle [N^2] ({res['periods']} periods)",
             f"{'processing':<28}" + "".join(f"{'P' + str(j):>9}" for j in range(1, 7)) + f"{'mean':>10}{'truth':>9}"
             + (f"{'no Coulomb':>12}" if free else "")]
    for label, r in res["rows"].items():
        lines.append(f"{label:<28}" + "".join(f"{v:9.3f}" for v in r["error_variance_N2"]) + f"{r['mean_variance_N2']:10.3f}"
                     + f"{r['truth_residual_variance_N2']:9.3f}" + (f"{free[label]:12.3f}" if label in free else ""))
    lines += ["truth: variance of the processed training forces minus the true model's prediction (the",
              "       processing's own error, before estimation; mean over the drives)"]
    if free:
        lines.append("no Coulomb: mean prediction error of the same processing on the twin without Coulomb friction")
    if "difference_c_minus_b" in res:
        dd = res["difference_c_minus_b"]
        lines += ["", f"(c) - (b) over {len(dd['values'])} noise replicates of the training run: "
                  + ", ".join(f"{v:.3f}" for v in dd["values"]) + f" N^2; mean {dd['mean']:.3f} +- {dd['se']:.3f} (SE)"]
    lk = res["leakage"]
    lines += ["", "Leakage with a 0.5 % period mismatch (RMS error of the acceleration of a 5-harmonic signal):",
              f"  exact DFT processing   {lk['dft_rms_error_acc']:.3e}",
              f"  implicit Fourier fit   {lk['implicit_fit_rms_error_acc']:.3e}"]
    return "\n".join(lines)


def figure(res: dict, path: Path) -> Path:
    """Why the frequency-domain window of paper 004 loses here (bench/README §7): the strut's true
    acceleration at a velocity reversal against what each processing keeps, the spectrum of the
    processing's own error, and the prediction error with and without Coulomb friction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    main, free = res["arrays"]["coulomb"], res["arrays"]["free"]
    per = 1.0 / F0
    n_per = int(round(per * RATE))
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    # (1) the processing's own error in time (the processed force of strut 3 minus the true model's
    # prediction from the processed states) about a velocity reversal in the last period, with the
    # true velocity of the strut
    t0 = main["t"][-1] - per  # start of the last period
    last = (main["t"] >= t0 - 1e-9) & (main["t"] < main["t"][-1] - 1e-9)
    t_last, dq = main["t"][last] - t0, main["dq"][last]
    rev = np.flatnonzero(np.diff(np.sign(dq)) != 0)
    rev = rev[(t_last[rev] > 0.5) & (t_last[rev] < per - 0.5)]
    t_rev = t_last[rev[0]] if rev.size else 0.5 * per
    lo, hi = t_rev - 0.3, t_rev + 0.5
    win = (t_last > lo) & (t_last < hi)
    styles = {B: ("C0", "-"), C: ("C3", "-"), C2: ("C2", ":")}

    def residual(fit, **kw):
        t = fit["t"] - (fit["t"][0] if fit["t"].size <= n_per else 0.0)
        for k in range(main["periods"] - 1, -1, -1):  # the latest period the (trimmed) record covers here
            sel = (t > k * per + lo) & (t < k * per + hi)
            if sel.sum() >= 0.9 * win.sum():
                ax[0].plot(t[sel] - k * per, fit["res_true"][sel], **kw)
                return

    for label, (col, ls) in styles.items():
        if label in main["fits"]:
            residual(main["fits"][label], color=col, ls=ls, lw=1.3, label=label)
    if free is not None and C in free["fits"]:
        residual(free["fits"][C], color="0.55", ls="--", lw=1.2, label=f"{C}, no Coulomb")
    ax[0].set(xlabel="time in the period [s]", ylabel="processed force - true model [N]",
              title="strut 3 (fc = 20 N) about a velocity reversal")
    ax[0].legend(fontsize=7, loc="lower left")
    axv = ax[0].twinx()
    axv.plot(t_last[win], 1e3 * dq[win], color="k", lw=0.8, alpha=0.5)
    axv.axhline(0.0, color="k", lw=0.5, alpha=0.5)
    axv.set_ylabel("true strut velocity [mm/s] (thin black)", fontsize=8)
    # (2) where the processing's own error lies: cumulative power spectrum of the processed
    # training force of strut 3 minus the true model's prediction (period average)
    f_loop = np.sqrt(KP) / (2 * np.pi)

    def cumulative(r):
        r = r[: (r.size // n_per) * n_per].reshape(-1, n_per).mean(axis=0)  # period average
        p = 2 * np.abs(np.fft.rfft(r - r.mean())) ** 2 / n_per**2
        return np.arange(p.size) * F0, np.cumsum(p)

    for label, (col, ls) in styles.items():
        if label in main["fits"]:
            f, cp = cumulative(main["fits"][label]["res_true"])
            ax[1].plot(f, cp, color=col, ls=ls, lw=1.4, label=label)
    if free is not None and C in free["fits"]:
        f, cp = cumulative(free["fits"][C]["res_true"])
        ax[1].plot(f, cp, color="0.55", lw=1.2, ls="--", label=f"{C}, no Coulomb")
    for x, txt in ((HARMONICS * F0, "excited band"), (CUTOFF * F0, "window of (c)"), (4 * HARMONICS * F0, "band of (b), (c')"),
                   (f_loop, "loop: $\\sqrt{k_p}/2\\pi$")):
        ax[1].axvline(x, color="0.3", lw=0.8, ls="--")
        ax[1].text(x, 0.98, " " + txt, rotation=90, va="top", ha="right", fontsize=7, transform=ax[1].get_xaxis_transform())
    ax[1].set(xlim=(0, 15), xlabel="frequency [Hz]", ylabel="cumulative variance [N$^2$]",
              title="strut 3: processed force minus true model")
    ax[1].legend(fontsize=7, loc="lower right")
    # (3) prediction error on the circle, with and without Coulomb friction
    labels = list(res["rows"])
    x = np.arange(len(labels))
    ax[2].bar(x - 0.2, [res["rows"][k]["mean_variance_N2"] for k in labels], 0.4, label="twin", color="C0")
    if "no_coulomb" in res:
        ax[2].bar(x + 0.2, [res["no_coulomb"][k] for k in labels], 0.4, label="no Coulomb friction", color="C1")
    ax[2].axhline(4.0, color="k", lw=0.8, ls="--", label="force noise (4 N$^2$)")
    ax[2].set_xticks(x, [k.split(")")[0] + ")" for k in labels])
    ax[2].set(ylabel="mean prediction error variance [N$^2$]", title="validation circle")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--figure", type=Path, default=None, help=f"PNG to write (full run default: {FIGURE})")
    ap.add_argument("--json", type=Path, default=None, help="write the numbers as JSON")
    args = ap.parse_args(argv)
    path = args.figure if args.figure is not None else (None if args.quick else FIGURE)
    res = study(quick=args.quick, keep=path is not None)
    print(table(res))
    if path is not None:
        print(f"figure: {figure(res, path)}")
    if args.json is not None:
        args.json.write_text(json.dumps({k: v for k, v in res.items() if k != "arrays"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
