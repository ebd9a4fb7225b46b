"""Study (issue 6, item 6; paper 004 Fig. 4): how signal processing changes the identified hexapod.

A virtual PaLiDA-like hexapod (``builtin:hexapod``) follows a D-optimal periodic task-space
excitation designed by :mod:`dynid.excitation` (computed torque with the true model; strut
encoders of 1 µm; drive forces with 2 N of noise correlated 0.2 across drives), and a circle of
its platform in the x-y plane for validation. The same log is identified (WLS, ``dynid identify``) after three processings:

(a) raw: central differences of the unfiltered actuator positions;
(b) time domain: zero-phase Butterworth (order 4) + central differences;
(c) frequency domain: period averaging + exact DFT filtering and differentiation of the actuator
    positions (``[processing.periodic]``, window at ``CUTOFF`` times the fundamental; see below);
(d) frequency domain on the pose (paper 004): period averaging, forward kinematics of every
    sample, the platform pose windowed at ``CUTOFF`` times the fundamental and differentiated
    exactly (``domain = "pose"``);
(e) the same with the window at the excited band ((n_h + 0.5) f0), as in paper 004.

Each model predicts the drive forces along the circle (processed in the time domain, the same
for all three); the table gives the prediction error variance per drive. Then the leakage of
paper 004 Fig. 2: the exact DFT processing against the implicit Fourier fit at the nominal
frequency when the record's period is 0.5 % longer than nominal.

Run: ``.venv/bin/python bench/processing_study.py`` (``--quick`` for a small version: used by the
tests).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.pipeline import identify
from dynid.pipeline.data import preprocess, read_log
from dynid.model.system import as_system
from dynid.pipeline.identification import _chunks
from dynid.pipeline.simulate import run_simulation, write_simulation
from dynid.signals.periodic import fourier_filter, fourier_fit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _designs import hexapod_design  # noqa: E402


# Band of the frequency-domain processing (c) and (d), in multiples of the fundamental: above the
# excited band, so that the window keeps the closed loop's response to friction reversals, which the
# measured forces contain; (e) windows at the excited band as paper 004 does (bench/README.md §7).
CUTOFF = 10.5


def _simulate(folder: Path, trajectory: dict, rate: float, duration: float | None, seed: int) -> None:
    doc = {
        "robot": {"model": "builtin:hexapod"},
        "trajectory": trajectory,
        "control": {"rate_hz": rate, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
        "sensors": {"encoder_resolution": 1e-6, "force_noise_std": 2.0, "force_correlation": 0.2, "seed": seed},
    }
    if duration is not None:
        doc["simulation"] = {"duration": duration}
    write_simulation(run_simulation(parse_simulate_config(doc, folder)), folder)


def study(quick: bool = False) -> dict:
    f0, harmonics = (1.0, 3) if quick else (0.2, 5)
    periods, rate = (3, 500.0) if quick else (4, 500.0)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        fourier = {"kind": "fourier", "coordinates": "task", "design": str(hexapod_design(d, quick, f0, harmonics)),
                   "periods": periods}
        _simulate(d / "train", fourier, rate, None, 1)
        circle = {"kind": "circle", "coordinates": "task", "axes": ["PX", "PY"], "centre": [0.0, 0.0],
                  "radius": 0.015, "speed": 0.05, "turns": 1 if quick else 4, "ramp": 0.2}
        _simulate(d / "circle", circle, rate, None, 2)
        q = [f"q_P{j}" for j in range(1, 7)]
        tau = [f"tau_P{j}" for j in range(1, 7)]
        processings = {
            "(a) raw": {"derivatives": "central", "trim_samples": 2},
            "(b) time domain": {"lowpass": {"cutoff_hz": 4.0 * harmonics * f0, "order": 4, "filter_effort": False}},
            "(c) frequency domain": {"periodic": {"period_s": 1.0 / f0, "cutoff_hz": CUTOFF * f0}},
            "(d) frequency, pose": {"periodic": {"period_s": 1.0 / f0, "cutoff_hz": CUTOFF * f0, "domain": "pose"}},
            "(e) pose, excited band": {"periodic": {"period_s": 1.0 / f0, "cutoff_hz": (harmonics + 0.5) * f0, "domain": "pose"}},
        }
        truth = json.loads((d / "train" / "truth.json").read_text())
        rows = {}
        for label, proc in processings.items():
            doc = {
                "robot": {"model": "builtin:hexapod"},
                "data": {"file": str(d / "train" / "log.csv"), "time": {"column": "t", "unit": "s"},
                         "position": {"columns": q, "unit": "m"}, "effort": {"columns": tau, "kind": "torque", "unit": "N"}},
                # dynid identify validates on the circle with the same processing; the table below
                # re-validates every model on the circle processed in the time domain
                "validation": {"file": str(d / "circle" / "log.csv")},
                "processing": proc,
                "identification": {"method": "wls"},
                "output": {"plots": False},
            }
            trained = identify(parse_config(doc, d))
            # consistency of the processed training data with the true parameters: what the
            # processing alone leaves in the residual, before any estimation
            cfg = parse_config(doc, d)
            true_base = trained.base.from_standard(np.asarray(truth["true_parameters"]))
            res_true = np.concatenate([c.y - c.W @ true_base for c in _chunks(
                as_system(trained.robot), trained.base, trained.train, None, chunk_size=2000,
                periodic=cfg.processing.periodic)])
            # validation on the circle, processed in the time domain for every model
            vdoc = {**doc, "data": {**doc["data"], "file": str(d / "circle" / "log.csv")},
                    "validation": {"file": str(d / "train" / "log.csv")}, "processing": processings["(b) time domain"]}
            vcfg = parse_config(vdoc, d)
            raw = read_log(vcfg.data, 6, tuple(trained.robot.actuated_names), "circle")
            held, _ = preprocess(raw, vcfg.processing, "circle")
            meas, pred = [], []
            for c in _chunks(as_system(trained.robot), trained.base, held, None, chunk_size=2000):
                meas.append(c.y)
                pred.append(c.W @ trained.result.params)
            err = np.concatenate(meas) - np.concatenate(pred)
            rows[label] = {"error_variance_N2": np.var(err, axis=0).tolist(), "mean_variance_N2": float(np.var(err, axis=0).mean()),
                           "truth_residual_variance_N2": float(np.var(res_true, axis=0).mean())}
        # leakage (paper 004, Fig. 2): a record whose period is 0.5 % longer than nominal
        fs, n = 200.0, 402  # 2.01 s of a motion of nominal period 2 s
        t = np.arange(n) / fs
        k = np.arange(1, 6)
        w = 2 * np.pi * (fs / n) * k
        x = np.sin(np.outer(t, w) + k) @ (1 / k)
        ddx = -(np.sin(np.outer(t, w) + k) * w**2) @ (1 / k)
        leak = {
            "dft_rms_error_acc": float(np.sqrt(np.mean((fourier_filter(x, fs, 2.75)[2] - ddx) ** 2))),
            "implicit_fit_rms_error_acc": float(np.sqrt(np.mean((fourier_fit(x, t, 0.5, 5)[2] - ddx) ** 2))),
        }
    return {"rows": rows, "leakage": leak, "f0_hz": f0, "harmonics": harmonics, "periods": periods, "rate_hz": rate}


def table(res: dict) -> str:
    lines = ["Prediction error variance of the drive forces on the validation circle [N^2]",
             f"{'processing':<22}" + "".join(f"{'P' + str(j):>9}" for j in range(1, 7)) + f"{'mean':>10}{'truth':>9}"]
    for label, r in res["rows"].items():
        lines.append(f"{label:<22}" + "".join(f"{v:9.3f}" for v in r["error_variance_N2"]) + f"{r['mean_variance_N2']:10.3f}"
                     + f"{r['truth_residual_variance_N2']:9.3f}")
    lk = res["leakage"]
    lines += ["truth: variance of the processed training forces minus the true model's prediction (the",
              "       processing's own error, before estimation; mean over the drives)", ""]
    lines += ["", "Leakage with a 0.5 % period mismatch (RMS error of the acceleration of a 5-harmonic signal):",
              f"  exact DFT processing   {lk['dft_rms_error_acc']:.3e}",
              f"  implicit Fourier fit   {lk['implicit_fit_rms_error_acc']:.3e}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    print(table(study(quick=args.quick)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
