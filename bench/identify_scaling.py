"""End-to-end ``dynid identify`` on 1e4, 1e5 and 1e6 (``--sizes``, up to 1e7) samples x 6 joints:
time, peak memory, and the time against its floor.

Targets (project issue 20, items 8 and 9): 1e7 samples x 6 joints identify with peak RSS
< 1.5 GB and time linear in N; at 1e6 samples identify takes at most 1.5x the floor (one regressor
pass plus the per-joint QR, measured in the same script). Logs of 200 000 training rows and more take
the streamed path (``dynid.pipeline.streaming``; ``[identification] streaming = "auto"``).

Method
------
* For each size ``N`` a log of ``builtin:puma560`` is written as NPZ (keys ``t`` (N,),
  ``q`` (N, 6), ``tau`` (N, 6)): a 5-harmonic Fourier trajectory (period 10 s, the same
  for every N; the demo's excitation) sampled at 1 kHz, analytic q, dq, ddq; torques
  ``regressor(q, dq, ddq) @ robot.nominal_parameters()`` computed chunk by chunk,
  plus Gaussian noise (the demo's levels, 0.05-1.5 N*m) and 2e-5 rad encoder noise on q.
  Generation is not timed.
* The config trains on rows ``[0, 0.8 N)`` and validates on ``[0.8 N, N)`` of the same
  file, low-passes positions at 20 Hz (order 4, efforts unfiltered), WLS, and
  ``[output] plots = false`` so that plotting does not enter the figures. ``--plots`` sets
  ``plots = true`` (the default of a user's config): validation.png, processing.png and
  report.html are written, with the report's physical-consistency check, and the run streams all
  the same (``dynid.pipeline.stream_plots``); the identify/floor target (stated for plots off)
  is then printed, not enforced.
* Every run is a fresh Python process: a small wrapper imports dynid, then calls
  ``dynid.cli.main(["identify", CONFIG, "--out", DIR, "-q"])`` exactly as the
  ``dynid`` command does, and reports its peak resident memory (``VmHWM`` of
  ``/proc/self/status``: exact and per run; ``ru_maxrss`` is not used because after
  fork + exec Linux starts it at the parent's peak, which includes the generated log)
  and the time of the ``main`` call ("run"). The parent also times the whole
  subprocess ("wall", including interpreter start and imports).
* 3 runs per size (2 for 1e6 by default); medians reported. Linearity: time per
  sample at each size, the ratio ``t(10 N) / (10 t(N))``, and the marginal cost
  ``(t(N2) - t(N1)) / (N2 - N1)`` between consecutive sizes (equal marginal costs
  mean a straight line with a fixed offset).
* The log is written chunk by chunk (each array to a temporary ``.npy`` on disk, then stored
  uncompressed in ``log.npz``): the generator never holds the log either, so 1e7 samples fit.
* Floor (``--floor-size``, default 1e6; also in a fresh process, the same number of runs): on the
  same log, not timed: ``np.load`` of ``q`` and ``tau``, the base parameters; timed: for the training
  rows in chunks of 20 000, the velocities and accelerations by central differences, the standard
  regressor (``dynid.model.serial_dynamics.regressor``), its base columns and the per-joint QR update of
  ``[R_j; W_j y_j]`` (``numpy.linalg.qr``, the update ``ProblemBuilder`` does), then for the
  validation rows the regressor and the prediction ``W theta``. That is the arithmetic no
  identification can skip: it leaves out reading, filtering, validation statistics and output.
  Reported: identify/floor at that size (run times, medians), target <= 1.5.
* Exit status 1 when the peak RSS at the largest size (highest of its runs) is >= 1500 MB,
  when the time is not linear in N (log-log slope between the two largest sizes above 1.1),
  when identify/floor at the floor size is above 1.5, or when a run fails.
* ``--blas-threads K`` sets ``OPENBLAS_NUM_THREADS`` (and OMP/MKL) in the measured
  process; by default it inherits the environment, as a user's run would.
* ``--profile`` adds one cProfile run of the largest size and prints where the time goes.

Run: ``.venv/bin/python bench/identify_scaling.py`` (``--quick`` for a smoke run;
``--sizes 1e5,1e6,1e7`` for items 8-9 of issue 20).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _util import median, print_machine, puma_config, table

from dynid.model import load_robot
from dynid.model.serial_dynamics import regressor
from dynid.simulation import FourierTrajectory

FS = 1000.0
SEED = 2026
TORQUE_NOISE = (1.0, 1.5, 0.6, 0.08, 0.08, 0.05)  # N*m, as in `dynid demo`
POSITION_NOISE = 2e-5  # rad
# time linear in N: the log-log slope between the two largest sizes (1 for a line through 0, below 1 with a
# fixed offset, 1.08 for N log N from 1e5 to 1e6, 2 for quadratic): at most 1.1
MAX_SLOPE = 1.1
MEMORY_LIMIT_MB = 1500.0
MAX_FLOOR_RATIO = 1.5  # identify / (regressor pass + per-joint QR) at the floor size (issue 20 item 8)


# Runs in a fresh interpreter: argv = config, out_dir, "time" | "profile".
WRAPPER = r"""
import json, resource, sys, time
def peak_kb():
    # VmHWM: high-water mark of this process's own address space. ru_maxrss is not used:
    # after fork/vfork + exec, Linux starts it at the parent's peak RSS.
    try:
        with open("/proc/self/status") as fh:
            return int(next(l for l in fh if l.startswith("VmHWM:")).split()[1])
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
from dynid.cli import main
import dynid.pipeline  # imported lazily by the CLI; imported here so that "run" excludes imports
t1 = time.perf_counter()
rss_import = peak_kb()
argv = ["identify", sys.argv[1], "--out", sys.argv[2], "-q"]
if sys.argv[3] == "profile":
    import cProfile, pstats
    prof = cProfile.Profile()
    rc = prof.runcall(main, argv)
    st = pstats.Stats(prof, stream=sys.stdout).strip_dirs()
    st.sort_stats("cumulative").print_stats(30)
    st.sort_stats("tottime").print_stats(15)
else:
    rc = main(argv)
t2 = time.perf_counter()
print("@@BENCH " + json.dumps({"rc": rc, "import_s": t1 - t0, "run_s": t2 - t1, "peak_kb": peak_kb(),
      "rss_import_kb": rss_import, "ru_maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
"""


# The floor, in a fresh interpreter: argv = log.npz, n_train. Prints the same @@BENCH record.
FLOOR = r"""
import json, sys, time
import numpy as np
from dynid.model import load_robot
from dynid.model.serial_dynamics import regressor
from dynid.model.system import as_system
def peak_kb():
    with open("/proc/self/status") as fh:
        return int(next(l for l in fh if l.startswith("VmHWM:")).split()[1])
path, n_train = sys.argv[1], int(sys.argv[2])
robot = load_robot("builtin:puma560")
base = as_system(robot).base_parameters(None)
with np.load(path) as z:
    t, q, tau = z["t"], z["q"], z["tau"]
theta = base.from_standard(robot.nominal_parameters())
p = base.n_base
R = [np.zeros((p + 1, p + 1)) for _ in range(robot.dof)]
data = robot.create_data()
size = 20000
buf = np.empty((size, robot.dof, robot.n_standard_params))
rss_import = peak_kb()
t1 = time.perf_counter()
n = t.shape[0]
for a in range(0, n, size):
    b = min(a + size, n)
    lo, hi = max(a - 2, 0), min(b + 2, n)
    dq = np.gradient(q[lo:hi], t[lo:hi], axis=0, edge_order=2)
    ddq = np.gradient(dq, t[lo:hi], axis=0, edge_order=2)
    k = slice(a - lo, b - lo)
    W = base.regressor(regressor(robot, q[a:b], dq[k], ddq[k], data=data, out=buf[: b - a]))
    if a < n_train:
        m = min(b, n_train) - a
        for j in range(robot.dof):
            aa = np.empty((p + 1 + m, p + 1))
            aa[: p + 1] = R[j]
            aa[p + 1 :, :p] = W[:m, j, :]
            aa[p + 1 :, p] = tau[a : a + m, j]
            R[j] = np.linalg.qr(aa, mode="r")[: p + 1]
    if b > n_train:
        pred = W[max(n_train - a, 0):] @ theta
t2 = time.perf_counter()
print("@@BENCH " + json.dumps({"rc": 0, "import_s": 0.0, "run_s": t2 - t1, "peak_kb": peak_kb(), "rss_import_kb": rss_import}))
"""


def run_floor(log: Path, n_train: int, blas_threads: int | None = None) -> dict:
    """One fresh-process run of the floor (module docstring)."""
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(blas_threads or 1)  # ProblemBuilder runs its QR on one BLAS thread too
    proc = subprocess.run([sys.executable, "-c", FLOOR, str(log), str(n_train)], capture_output=True, text=True, env=env)
    rec = [json.loads(x.split(" ", 1)[1]) for x in proc.stdout.splitlines() if x.startswith("@@BENCH ")]
    if proc.returncode != 0 or not rec:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise RuntimeError(f"the floor run failed on {log}")
    return rec[0]


def write_log(path: Path, n: int, chunk: int = 50_000) -> None:
    """Simulated log of ``n`` samples (see module docstring), written chunk by chunk: each array
    goes to a temporary ``.npy`` (``open_memmap``) and is then stored uncompressed in the NPZ, as
    ``np.savez`` would; memory O(one chunk)."""
    import zipfile

    from numpy.lib.format import open_memmap

    robot = load_robot("builtin:puma560")
    params = robot.nominal_parameters()
    rng = np.random.default_rng(SEED)
    lo, hi = robot.position_limits()
    traj = FourierTrajectory.random(robot.dof, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    parts = {k: path.parent / f".{k}.npy" for k in ("t", "q", "tau")}
    t = open_memmap(parts["t"], mode="w+", dtype=float, shape=(n,))
    q = open_memmap(parts["q"], mode="w+", dtype=float, shape=(n, robot.dof))
    tau = open_memmap(parts["tau"], mode="w+", dtype=float, shape=(n, robot.dof))
    data = robot.create_data()
    buf = np.empty((min(chunk, n), robot.dof, robot.n_standard_params))
    sigma = np.asarray(TORQUE_NOISE)
    for s in range(0, n, chunk):
        e = min(s + chunk, n)
        tc = np.arange(s, e) / FS  # the values of np.arange(n) / FS
        t[s:e] = tc
        qc, dqc, ddqc = traj.sample(tc)
        Y = regressor(robot, qc, dqc, ddqc, data=data, out=buf[: e - s])
        tau[s:e] = Y @ params + rng.standard_normal((e - s, robot.dof)) * sigma
        q[s:e] = qc + rng.standard_normal(qc.shape) * POSITION_NOISE
    for arr in (t, q, tau):
        arr.flush()
    del t, q, tau
    try:
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for k, f in parts.items():
                zf.write(f, arcname=f"{k}.npy")
    finally:
        for f in parts.values():
            f.unlink(missing_ok=True)


def prepare(workdir: Path, n: int, plots: bool = False) -> tuple[Path, bool]:
    """Folder with log.npz and config.toml for ``n`` samples; returns the config path and
    whether the log was written (an existing log of the right length is reused: the
    generation is deterministic)."""
    d = workdir / f"n{n}"
    d.mkdir(parents=True, exist_ok=True)
    log = d / "log.npz"
    written = False
    try:
        with np.load(log, mmap_mode="r") as z:
            reuse = z["t"].shape == (n,) and z["tau"].shape == (n, 6)
    except (OSError, ValueError, KeyError):
        reuse = False
    if not reuse:
        write_log(log, n)
        written = True
    cfg = d / "config.toml"
    cfg.write_text(puma_config("identify_scaling.py", n, file="log.npz", plots=plots))
    return cfg, written


def run_cli(cfg: Path, out: Path, mode: str = "time", blas_threads: int | None = None) -> dict:
    """One fresh-process run of ``dynid identify``; returns the wrapper's figures + wall time."""
    env = dict(os.environ)
    if blas_threads is not None:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = str(blas_threads)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", WRAPPER, str(cfg), str(out), mode], capture_output=True, text=True,
                          env=env)
    wall = time.perf_counter() - t0
    lines = proc.stdout.splitlines()
    rec = [json.loads(x.split(" ", 1)[1]) for x in lines if x.startswith("@@BENCH ")]
    if proc.returncode != 0 or not rec or rec[0]["rc"] != 0:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        code = rec[0]["rc"] if rec else proc.returncode
        raise RuntimeError(f"dynid identify failed on {cfg} (exit {code})")
    if mode == "profile":
        print("\n".join(x for x in lines if not x.startswith("@@BENCH ")))
    return {**rec[0], "wall_s": wall}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=lambda s: [int(float(x)) for x in s.split(",")], default=[10_000, 100_000, 1_000_000],
                    help="comma-separated sample counts (default 1e4,1e5,1e6)")
    ap.add_argument("--runs", type=int, default=3, help="runs per size below 1e6 (default 3)")
    ap.add_argument("--runs-large", type=int, default=2, help="runs per size >= 1e6 (default 2)")
    ap.add_argument("--workdir", type=Path, default=None, help="keep logs and outputs here (default: a temporary folder)")
    ap.add_argument("--blas-threads", type=int, default=None,
                    help="set OPENBLAS/OMP/MKL_NUM_THREADS in the measured process (default: inherit)")
    ap.add_argument("--profile", action="store_true", help="also profile one run of the largest size")
    ap.add_argument("--floor-size", type=lambda x: int(float(x)), default=1_000_000,
                    help="size at which identify is compared with its floor (default 1e6; 0: no floor)")
    ap.add_argument("--plots", action="store_true",
                    help="[output] plots = true: figures and report written (identify/floor not enforced)")
    ap.add_argument("--quick", action="store_true", help="smoke run: sizes 1e4, 3e4; 1 run each; linearity not enforced")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.runs, args.runs_large = [10_000, 30_000], 1, 1
        args.floor_size = 30_000
    sizes = sorted(args.sizes)

    print_machine()
    print(f"[output] plots = {'true' if args.plots else 'false'}")
    print(f"BLAS threads in the measured process: {args.blas_threads or 'inherited (' + os.environ.get('OPENBLAS_NUM_THREADS', 'unset') + ')'}")
    tmp = None
    if args.workdir is None:
        tmp = tempfile.mkdtemp(prefix="dynid-bench-")
        workdir = Path(tmp)
    else:
        workdir = args.workdir
        workdir.mkdir(parents=True, exist_ok=True)
    try:
        results: dict[int, list[dict]] = {}
        for n in sizes:
            t0 = time.perf_counter()
            cfg, written = prepare(workdir, n, args.plots)
            size_mb = (cfg.parent / "log.npz").stat().st_size / 1e6
            print(f"N = {n}: log {'written' if written else 'reused'} ({size_mb:.0f} MB, "
                  f"{time.perf_counter() - t0:.1f} s, not timed)", flush=True)
            runs = args.runs_large if n >= 1_000_000 else args.runs
            results[n] = []
            for r in range(runs):
                rec = run_cli(cfg, cfg.parent / f"out{r}", blas_threads=args.blas_threads)
                results[n].append(rec)
                print(f"  run {r + 1}/{runs}: run {rec['run_s']:.2f} s, wall {rec['wall_s']:.2f} s, "
                      f"peak RSS {rec['peak_kb'] / 1024:.0f} MB (after imports {rec['rss_import_kb'] / 1024:.0f} MB)",
                      flush=True)

        floor_n = args.floor_size if args.floor_size in sizes else None
        floors: list[dict] = []
        if floor_n is not None:
            runs = args.runs_large if floor_n >= 1_000_000 else args.runs
            for r in range(runs):
                rec = run_floor(workdir / f"n{floor_n}" / "log.npz", int(0.8 * floor_n), args.blas_threads)
                floors.append(rec)
                print(f"  floor at N = {floor_n}, run {r + 1}/{runs}: {rec['run_s']:.2f} s (regressor pass + per-joint QR)",
                      flush=True)

        med = {n: {k: median([r[k] for r in results[n]]) for k in ("run_s", "wall_s", "peak_kb", "rss_import_kb")}
               for n in sizes}
        rows = []
        for i, n in enumerate(sizes):
            m = med[n]
            ratio = marginal = "-"
            if i > 0:
                p = sizes[i - 1]
                ratio = f"{m['run_s'] / (med[p]['run_s'] * n / p):.2f}"
                marginal = f"{(m['run_s'] - med[p]['run_s']) / (n - p) * 1e6:.1f}"
            rows.append((f"{n:.0e}".replace("+0", ""), str(len(results[n])), f"{m['run_s']:.2f}", f"{m['wall_s']:.2f}",
                         f"{m['run_s'] / n * 1e6:.1f}", ratio, marginal, f"{m['peak_kb'] / 1024:.0f}",
                         f"{(m['peak_kb'] - m['rss_import_kb']) / 1024:.0f}"))
        print()
        print(table(("N", "runs", "run s", "wall s", "us/sample", "t/(t_prev*N/N_prev)", "marginal us/sample",
                     "peak RSS MB", "RSS growth MB"), rows))
        print("(medians; run = dynid.cli.main in a fresh process, wall = whole subprocess incl. start-up and imports;\n"
              " RSS growth = peak RSS minus the RSS after imports)")

        if args.profile:
            n = sizes[-1]
            print(f"\nprofile of one run at N = {n} (cProfile; adds overhead):")
            run_cli(workdir / f"n{n}" / "config.toml", workdir / f"n{n}" / "out-profile", mode="profile",
                    blas_threads=args.blas_threads)

        peak_mb = max(r["peak_kb"] for r in results[sizes[-1]]) / 1024
        mem_ok = peak_mb < MEMORY_LIMIT_MB
        print(f"\npeak RSS at N = {sizes[-1]} (highest of its runs): {peak_mb:.0f} MB vs limit < {MEMORY_LIMIT_MB:.0f} MB: "
              f"{'PASS' if mem_ok else 'FAIL'}")
        lin_ok = True
        if len(sizes) >= 2:
            n1, n2 = sizes[-2], sizes[-1]
            slope = float(np.log(med[n2]["run_s"] / med[n1]["run_s"]) / np.log(n2 / n1))
            lin_ok = slope <= MAX_SLOPE or args.quick
            print(f"time against N between {n1} and {n2}: slope {slope:.2f} on log-log axes (1: linear; below 1: a fixed "
                  f"offset still shows) vs at most {MAX_SLOPE:g}: {'PASS' if slope <= MAX_SLOPE else 'FAIL'}"
                  + (" (not enforced with --quick: small sizes, one run)" if args.quick else ""))
        floor_ok = True
        if floor_n is not None:
            fl = median([r["run_s"] for r in floors])
            ratio = med[floor_n]["run_s"] / fl
            floor_ok = ratio <= MAX_FLOOR_RATIO or args.quick or args.plots
            print(f"identify / floor at N = {floor_n}: {med[floor_n]['run_s']:.2f} s / {fl:.2f} s = {ratio:.2f} vs at most "
                  f"{MAX_FLOOR_RATIO:g}: {'PASS' if ratio <= MAX_FLOOR_RATIO else 'FAIL'}"
                  + (" (not enforced with --quick)" if args.quick else "")
                  + (" (not enforced with --plots: the target is for plots = false)" if args.plots else ""))
        return 0 if mem_ok and lin_ok and floor_ok else 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
