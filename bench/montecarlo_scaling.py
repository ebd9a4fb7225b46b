"""Benchmark (issue 7): scaling of ``dynid montecarlo`` with local workers.

100 trials of a virtual PaLiDA-like hexapod (``builtin:hexapod``, as
``examples/montecarlo/hexapod_wls.toml`` without its row selection: a 3-harmonic task-space Fourier excitation
at 0.5 Hz, 3 periods, 500 Hz computed-torque control, the log at 250 Hz; strut encoders of
1 µm, drive forces with 2 N of noise correlated 0.2), each identified by WLS after a 10 Hz
zero-phase low-pass (about 1.2 s of identification per trial on one core: the base
parameters on constraint-consistent samples, the forward kinematics of every sample, the
regressor). The study runs with 1 and with 2 local workers (joblib/loky processes), in
alternation, ``--repeats`` times each; each run is :func:`dynid.pipeline.montecarlo.run_montecarlo`
as ``dynid montecarlo`` calls it, simulation included, and the loky workers are shut down
between runs so that every 2-worker run pays for starting its processes, as a command does.

Reported per variant: the median wall time of the whole study, of the trial phase (after the
simulation, which runs once in the parent), and the speed-up ratios 1 worker / 2 workers.
The results of the two variants are checked to agree: estimates and standard deviations bit for
bit (each trial uses one BLAS thread), the chi-square statistics to 1e-6 relative (they solve
with the ill-conditioned correlation matrix of 102 base parameters, where LAPACK's last digits
depend on the process).

Run: ``.venv/bin/python bench/montecarlo_scaling.py`` (``--quick``: 10 trials, 1 repeat).
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
from _util import median, print_machine, table  # noqa: E402

from dynid.config.montecarlo import parse_montecarlo_config  # noqa: E402
from dynid.pipeline.montecarlo import run_montecarlo  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "montecarlo" / "hexapod_wls.toml"
GUARD = 'min_velocity = 0.01\nreversal_guard = "auto"\n'
# the twin of examples/montecarlo/hexapod_wls.toml without its row selection (the set-up of the
# scaling figures of bench/README §8; the selection changes which rows are kept, not the cost)
CONFIG = EXAMPLE.read_text().replace(GUARD, "").split("[montecarlo]")[0]


def _shutdown_workers() -> None:
    from joblib.externals.loky import get_reusable_executor

    get_reusable_executor().shutdown(wait=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="10 trials, 1 repeat")
    ap.add_argument("--trials", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=None)
    args = ap.parse_args(argv)
    trials = args.trials or (10 if args.quick else 100)
    repeats = args.repeats or (1 if args.quick else 3)
    print_machine()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    cfg = parse_montecarlo_config(tomllib.loads(CONFIG), Path("."))
    cfg = dataclasses.replace(cfg, trials=trials)
    times: dict[int, list[dict]] = {1: [], 2: []}
    results = {}
    for r in range(repeats):
        for workers in (1, 2) if r % 2 == 0 else (2, 1):
            _shutdown_workers()
            t0 = time.perf_counter()
            res = run_montecarlo(dataclasses.replace(cfg, workers=workers))
            wall = time.perf_counter() - t0
            t = res.timing
            times[workers].append({"wall": wall, "trials": t["trials_s"], "sim": t["simulation_s"],
                                   "identify": t["identify_median_s"]})
            results[workers] = res
            print(f"  repeat {r + 1}/{repeats}, {workers} worker(s): {wall:.1f} s (simulation {t['simulation_s']:.1f} s, "
                  f"trials {t['trials_s']:.1f} s, median identification {t['identify_median_s']:.2f} s/trial, "
                  f"{len(res.failures)} failed)", flush=True)
    a, b = results[1], results[2]
    same = (np.array_equal(a.estimates, b.estimates, equal_nan=True) and np.array_equal(a.std, b.std, equal_nan=True)
            and np.allclose(a.chi2, b.chi2, rtol=1e-6, equal_nan=True))
    rows = []
    for w in (1, 2):
        m = {k: median([x[k] for x in times[w]]) for k in ("wall", "trials", "sim", "identify")}
        rows.append([f"{w}", f"{len(times[w])}", f"{m['wall']:.1f}", f"{m['sim']:.1f}", f"{m['trials']:.1f}",
                     f"{m['trials'] / trials:.2f}", f"{m['identify']:.2f}"])
    print()
    print(f"{trials} trials of builtin:hexapod ({a.n_params} base parameters, {a.method}), median of the runs:")
    print(table(["workers", "runs", "total s", "simulation s", "trials s", "s/trial", "identify s/trial"], rows))
    w1 = median([x["wall"] for x in times[1]]) / median([x["wall"] for x in times[2]])
    t1 = median([x["trials"] for x in times[1]]) / median([x["trials"] for x in times[2]])
    print(f"\nspeed-up 1 -> 2 workers: trials {t1:.2f}x, whole study {w1:.2f}x")
    print(f"same results with 1 and 2 workers (estimates and std bit-identical, chi2 to 1e-6): {same}")
    print(f"coverage {a.overall_coverage:.1f} %, ellipsoid {a.ellipsoid_share:.0f} %, mean chi2 {a.mean_chi2:.1f} "
          f"(p = {a.n_params})")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
