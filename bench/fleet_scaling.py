"""``dynid fleet`` on Dask against the single-process loop: 64 logs x 1e5 samples of a 6-DOF arm.

Targets (project issue 35, item 6), on 2 cores: with 2 process workers the identification of the
logs is at least 1.7x faster than the same jobs run one after the other in one process; its time
grows at most linearly in the number of logs (log-log slope of time against the number of logs at
most 1.05 over 16, 32, 64 logs); and each worker's peak memory is bounded by what one log needs,
not by the fleet's total data.

Method
------
* Logs (not timed; written once to a temporary folder, ``--keep DIR`` to reuse): ``builtin:puma560``,
  4 excitation trajectories (5-harmonic Fourier, period 10 s, 1 kHz, as in
  ``bench/identify_scaling.py``) with their exact torques ``regressor(q, dq, ddq) @ theta``; log ``i``
  is trajectory ``i % 4`` with its own torque noise (the demo's levels) and 2e-5 rad encoder noise
  (seed ``i``), stored as an uncompressed NPZ (``t``, ``q`` (N, 6), ``tau`` (N, 6)). 8 robots of 8
  logs each. Every log is a full identification: nothing is shared between them but the trajectory.
* Each log's job is what ``dynid fleet`` runs on a worker (:func:`dynid.fleet.jobs.run_log`: read,
  low-pass at 20 Hz, WLS on the first 80 % of rows, held-out scores and factors on the rest; one
  BLAS thread). The template is ``_util.puma_config``.
* **Loop**: the jobs of the first ``n`` logs run one after the other in this process
  (``[run_log(job) for job in jobs]``), after one warm-up job (imports, caches).
* **Dask**: a ``LocalCluster`` of 2 process workers, one thread each, started by
  :func:`dynid.fleet.run.fleet_client` as ``dynid fleet`` starts it (without Dask's
  ``MALLOC_TRIM_THRESHOLD_``, which made each job 1.6-2.4x slower on a worker:
  :func:`dynid.fleet.run.local_cluster`), started fresh for each measurement and warmed by one job on every worker (imports), then the same
  jobs through :func:`dynid.fleet.run.run_jobs` (the code ``dynid fleet`` uses: ``client.map``,
  results by key). Timed: the jobs alone; the cluster's start-up is printed beside it (a fixed cost of
  a few seconds that a fleet of 64 logs amortizes).
* Speed-up = loop time / Dask time at the largest size, both measured in this run, medians of
  ``--repeats`` runs. Slope: least squares of log(time) on log(n_logs) over the sizes (Dask).
* Memory: each worker's peak resident set (``VmHWM`` of ``/proc/<pid>/status``, read on the worker
  by ``client.run`` after the jobs; a fresh cluster per measurement, so the peak is that run's). The
  bound is derived from one log: in a fresh process, the resident set after the imports (``base``)
  and the peak after one ``run_log`` (``one``); a worker may hold ``base + 1.5 (one - base) + 100 MB``
  (Dask's own buffers). The fleet's total data is 64 x 1e5 x 13 x 8 B = 635 MiB, above that bound; a
  worker that held the logs it ran, or their regressors, would exceed it. Also printed: the ratio of
  the worker peaks at the largest and smallest sizes (near 1: memory does not grow with the logs).
* Per job, the median of its own identification time (``LogResult.seconds``, measured where it
  ran) in the loop and on the workers: equal when the 2 cores are free; larger on the workers when
  other processes take a core (then no run on this machine can show the 2-core speed-up).
* Exit status 1 when the speed-up is below 1.7, the slope above 1.05, a worker's peak above its
  bound, or a job fails.

Run: ``.venv/bin/python bench/fleet_scaling.py`` (``--quick``: 8, 16 logs of 2e4 samples, one run
each, targets printed but only a failed job fails).
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

FS = 1000.0
TORQUE_NOISE = (1.0, 1.5, 0.6, 0.08, 0.08, 0.05)  # N*m, as in `dynid demo`
POSITION_NOISE = 2e-5  # rad
TRAJECTORIES = 4
ROBOTS = 8
MIN_SPEEDUP = 1.7
MAX_SLOPE = 1.05
WORKERS = 2


# One log's footprint in a fresh interpreter: argv = fleet.toml. Prints base and peak VmHWM (kB).
ONE_LOG = r"""
import json, sys
def hwm():
    with open("/proc/self/status") as fh:
        return int(next(l for l in fh if l.startswith("VmHWM:")).split()[1])
from dynid.config.fleet import load_fleet_config
from dynid.fleet.run import build_jobs
from dynid.fleet.jobs import run_log
import dynid.pipeline
jobs, _ = build_jobs(load_fleet_config(sys.argv[1]))
base = hwm()
res = run_log(jobs[0])
print("@@BENCH " + json.dumps({"base_kb": base, "one_kb": hwm(), "ok": res.ok, "error": res.error}))
"""


def write_logs(folder: Path, n_logs: int, n: int) -> None:
    """``n_logs`` logs of ``n`` samples (module docstring) and their fleet files in ``folder``."""
    from dynid._files import save_npz
    from dynid.model import load_robot
    from dynid.model.serial_dynamics import regressor
    from dynid.simulation import FourierTrajectory

    folder.mkdir(parents=True, exist_ok=True)
    robot = load_robot("builtin:puma560")
    params = robot.nominal_parameters()
    lo, hi = robot.position_limits()
    t = np.arange(n) / FS
    base = []
    for k in range(TRAJECTORIES):
        rng = np.random.default_rng(2026 + k)
        traj = FourierTrajectory.random(robot.dof, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
        q, dq, ddq = traj.sample(t)
        tau = np.vstack([regressor(robot, q[s:s + 20000], dq[s:s + 20000], ddq[s:s + 20000]) @ params
                         for s in range(0, n, 20000)])
        base.append((q, tau))
    rows = ["robot,model,file"]
    for i in range(n_logs):
        name = f"logs/log{i:03d}.npz"
        if not (folder / name).exists():
            rng = np.random.default_rng(i)
            q, tau = base[i % TRAJECTORIES]
            (folder / "logs").mkdir(exist_ok=True)
            save_npz(folder / name, {"t": t, "q": q + POSITION_NOISE * rng.standard_normal(q.shape),
                                     "tau": tau + np.asarray(TORQUE_NOISE) * rng.standard_normal(tau.shape)})
        rows.append(f"r{i % ROBOTS},puma,{name}")
    (folder / "logs.csv").write_text("\n".join(rows) + "\n")
    (folder / "puma.toml").write_text(puma_config("fleet_scaling.py", n))
    (folder / "fleet.toml").write_text('[fleet]\nlogs = "logs.csv"\n\n[models]\npuma = "puma.toml"\n')


def one_log_footprint(fleet: Path) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", ONE_LOG, str(fleet)], capture_output=True, text=True, env=env)
    rec = [json.loads(x.split(" ", 1)[1]) for x in proc.stdout.splitlines() if x.startswith("@@BENCH ")]
    if proc.returncode != 0 or not rec or not rec[0]["ok"]:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise RuntimeError("the one-log footprint run failed")
    return rec[0]


def _worker_hwm_kb() -> int:
    with open("/proc/self/status") as fh:
        return int(next(line for line in fh if line.startswith("VmHWM:")).split()[1])


def run_loop(jobs) -> tuple[float, list]:
    from dynid.fleet.jobs import run_log

    t0 = time.perf_counter()
    res = [run_log(job) for job in jobs]
    return time.perf_counter() - t0, res


def run_dask(cfg, jobs, warm) -> tuple[float, float, list, list[int]]:
    """(jobs time, cluster start time, results, per-worker peak RSS kB) on a fresh LocalCluster,
    started as ``dynid fleet`` starts it (:func:`dynid.fleet.run.fleet_client`)."""
    from dynid.fleet.jobs import run_log
    from dynid.fleet.run import fleet_client, run_jobs

    t0 = time.perf_counter()
    with fleet_client(cfg) as (client, _, n):
        assert n == WORKERS, n
        workers = sorted(client.scheduler_info()["workers"])
        for w in workers:  # each worker imports dynid and runs one job before the clock starts
            client.submit(run_log, warm, workers=[w], pure=False, allow_other_workers=False).result()
        t1 = time.perf_counter()
        res = run_jobs(client, list(jobs), retries=1)
        t2 = time.perf_counter()
        peaks = client.run(_worker_hwm_kb)
    return t2 - t1, t1 - t0, res, [peaks[w] for w in sorted(peaks)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="8, 16 logs of 2e4 samples, one run; targets not enforced")
    ap.add_argument("--samples", type=float, default=1e5)
    ap.add_argument("--sizes", default="16,32,64", help="numbers of logs (the largest: the speed-up)")
    ap.add_argument("--repeats", type=int, default=3, help="runs of the largest size (medians); 1 at the others")
    ap.add_argument("--keep", type=Path, help="write (or reuse) the logs here instead of a temporary folder")
    args = ap.parse_args(argv)
    if args.quick:
        args.samples, args.sizes, args.repeats = 2e4, "8,16", 1
    n = int(args.samples)
    sizes = sorted(int(s) for s in args.sizes.split(","))
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # the loop's BLAS as a worker's (run_log limits it too)
    print_machine()
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    from dynid.config.fleet import load_fleet_config
    from dynid.fleet.run import build_jobs

    tmp = None
    folder = args.keep
    if folder is None:
        tmp = tempfile.mkdtemp(prefix="dynid-fleet-bench-")
        folder = Path(tmp)
    try:
        t0 = time.perf_counter()
        write_logs(folder, sizes[-1], n)
        print(f"{sizes[-1]} logs x {n} samples x 6 joints in {folder} ({time.perf_counter() - t0:.1f} s, not timed)")
        cfg = load_fleet_config(folder / "fleet.toml")  # workers = 2, the default
        jobs, _ = build_jobs(cfg)
        foot = one_log_footprint(folder / "fleet.toml")
        bound_kb = foot["base_kb"] + 1.5 * (foot["one_kb"] - foot["base_kb"]) + 100 * 1024
        from dynid.fleet.jobs import run_log

        run_log(jobs[0])  # the loop's warm-up
        rows, failed = [], 0
        loop_t: dict[int, float] = {}
        dask_t: dict[int, float] = {}
        peaks: dict[int, list[int]] = {}
        for size in sizes:
            reps = args.repeats if size == sizes[-1] else 1
            lt, dt, st, pk, lj, dj = [], [], [], [], [], []
            for _ in range(reps):
                t, res = run_loop(jobs[:size])
                failed += sum(not r.ok for r in res)
                lt.append(t)
                lj.append(median([r.seconds for r in res]))
                t, start, res, p = run_dask(cfg, jobs[:size], jobs[0])
                failed += sum(not r.ok for r in res)
                dt.append(t)
                dj.append(median([r.seconds for r in res]))
                st.append(start)
                pk.append(max(p))
            loop_t[size], dask_t[size], peaks[size] = median(lt), median(dt), pk
            rows.append([str(size), str(reps), f"{loop_t[size]:.2f}", f"{loop_t[size] / size:.3f}",
                         f"{median(lj):.3f}", f"{dask_t[size]:.2f}", f"{median(dj):.3f}", f"{median(st):.1f}",
                         f"{loop_t[size] / dask_t[size]:.2f}",
                         f"{max(pk) / 1024:.0f}"])
        print(table(["logs", "runs", "loop s", "loop s/log", "job s (loop)", "dask s (2 workers)", "job s (worker)",
                     "cluster start s", "speed-up",
                     "worker peak MB"], rows))
        x = np.log(np.array(sizes, float))
        slope = float(np.polyfit(x, np.log([dask_t[s] for s in sizes]), 1)[0]) if len(sizes) > 1 else float("nan")
        loop_slope = float(np.polyfit(x, np.log([loop_t[s] for s in sizes]), 1)[0]) if len(sizes) > 1 else float("nan")
        speedup = loop_t[sizes[-1]] / dask_t[sizes[-1]]
        worst = max(max(p) for p in peaks.values())
        growth = max(peaks[sizes[-1]]) / max(peaks[sizes[0]])
        total_mb = sizes[-1] * n * 13 * 8 / 2**20
        checks = [
            (f"speed-up at {sizes[-1]} logs (loop / dask, 2 workers)", f"{speedup:.2f}", f">= {MIN_SPEEDUP}",
             speedup >= MIN_SPEEDUP),
            (f"log-log slope of dask time over {sizes} logs", f"{slope:.3f}", f"<= {MAX_SLOPE}", slope <= MAX_SLOPE),
            ("worker peak RSS (largest of all runs)", f"{worst / 1024:.0f} MB",
             f"<= {bound_kb / 1024:.0f} MB (one log: base {foot['base_kb'] / 1024:.0f} MB, peak "
             f"{foot['one_kb'] / 1024:.0f} MB; the fleet's data: {total_mb:.0f} MB)", worst <= bound_kb),
        ]
        print(table(["check", "value", "target", "result"], [[a, b, c, "ok" if ok else "FAIL"] for a, b, c, ok in checks]))
        print(f"loop slope {loop_slope:.3f}; worker peak at {sizes[-1]} / at {sizes[0]} logs: {growth:.3f}; "
              f"failed jobs: {failed}")
        print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        if failed:
            print("FAIL: a job failed")
            return 1
        if args.quick:
            print("--quick: the targets are printed, not enforced")
            return 0
        return 0 if all(ok for *_, ok in checks) else 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
