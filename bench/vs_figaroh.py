"""dynid and FIGAROH 1.0.2 side by side on the same Staubli TX40 log: paired wall-time and peak-memory ratios.

Targets: ``dynid identify`` on its TX40 configuration takes at most 0.5x FIGAROH's wall time with
plots and at most 0.4x without (project issue 37, item 5, a cold start as a user runs it; issue 20
had asked 0.3x with plots), and at most 0.4x its peak memory (issue 20, item 10).

Method
------
* FIGAROH lives in its own virtual environment, outside the repository and outside dynid's
  dependencies (default ``~/.cache/dynid-bench/figaroh-1.0.2``). The script reuses it when it holds
  figaroh 1.0.2, else creates it with ``python -m venv`` and ``pip install figaroh==1.0.2`` under the
  pinned versions of ``FIGAROH_PINS`` (the environment this bench was recorded with); when that fails
  (no network) it says so in one line and exits 2.
* Same data for both: ``shared/data/tx40`` (FIGAROH's published TX40 log, 5 kHz, motor-side encoders
  and currents), training rows 0-24 750, held-out rows 29 250-45 000, both scored per joint at the
  full 5 kHz on the held-out rows.
* dynid: ``examples/tx40/identify.toml`` exactly as ``tests/test_real_tx40.py`` uses it (shared-data
  paths made absolute), with ``[output] plots = true`` and, separately, ``false``; run as
  ``python -m dynid.cli identify CONFIG --out DIR -q`` (what the ``dynid`` command runs).
* FIGAROH: ``bench/_figaroh_tx40.py`` in FIGAROH's environment: its TX40 identification as its
  published example does it with its 1.0-era configuration (see that file's docstring), with its
  plots on (drawn figures written to PNG, as dynid writes its plots) and, separately, off. Its
  unified config and a geometry-free copy of the URDF are written once before the rounds (not timed).
* Each measured run is a fresh interpreter started through the same small wrapper (``runpy``), which
  writes the process's ``VmHWM`` (peak resident memory, ``/proc/self/status``) at exit. ``ru_maxrss``
  is not used: after fork + exec Linux starts it at the parent's peak (``bench/identify_scaling.py``).
  "wall" is the whole subprocess measured by the parent: interpreter start, imports, reading the
  log, identification, validation, plots and outputs, as a user experiences them.
* Both get the same environment: ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS``
  = ``--blas-threads`` (1 by default: the recording machine has 2 shared cores), ``MPLBACKEND=Agg``.
  dynid also gets ``DYNID_PLOT_WORKER=0``: its figures are drawn in its own process, so that the
  process's ``VmHWM`` is the run's whole peak (the plot worker, which ``dynid identify`` starts when
  a CPU is idle, is a second process whose memory this wrapper would not see; on this shared
  machine the load rule kept it off anyway).
* ``--plot-worker``: each round also runs dynid with ``DYNID_PLOT_WORKER=1`` (its figures drawn in the
  plot worker on a second CPU, what ``dynid identify`` does when a CPU is idle): its wall time and the
  summed resident memory of both processes, sampled every 5 ms (:class:`TreeRss`), beside FIGAROH's.
  Reported with the targets; the exit status stays the one-process runs'.
* dynid runs from bytecode, as an installed dynid does (``pip install`` compiles every module;
  FIGAROH's venv holds its ``.pyc`` files): before the rounds (not timed) ``python -m compileall``
  writes the bytecode of the imported dynid package beside its sources (``__pycache__``, what any
  Python run writes unless told not to; ignored by git). Without it, a checkout run with
  ``PYTHONDONTWRITEBYTECODE=1`` (this project's machines) compiled dynid's ~80 modules from source in
  every run, 0.13-0.15 s that were counted as imports (bench/README.md, "Cold start, fourth pass").
  ``--no-bytecode`` leaves dynid's bytecode as found (on a checkout without ``__pycache__``, that way). (Not ``PYTHONPYCACHEPREFIX``: it moves every module's cache,
  numpy's, scipy's and matplotlib's too, which then compile from source in every run.)
* ``--floor`` adds, in every round, ``bench/_cold_floor.py`` with and without plots: a fresh
  interpreter that only imports what a run needs, reads the two logs and calls pinocchio's regressor
  once per training and held-out sample (its docstring); its paired ratio to FIGAROH is the lower
  bound of dynid's ratio on this numerical core.
* Rounds alternate the order: even rounds run dynid, FIGAROH (plots on), then FIGAROH, dynid (plots
  off); odd rounds the reverse. ``--repeats`` rounds (5). Reported: per tool the median wall and
  peak memory, and the medians of the PAIRED ratios dynid/FIGAROH of each round, for wall with plots,
  wall without plots and peak memory (with plots; without plots also shown).
* PASS when the median paired wall ratio is <= 0.5 with plots and <= 0.4 without, and the median
  paired memory ratio (with plots) <= 0.4; exit 1 on FAIL or when a run fails.

Run: ``.venv/bin/python bench/vs_figaroh.py`` (``--repeats 1`` for a smoke run; ``--figaroh-venv PATH``; ``--floor``;
``--no-bytecode``).
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

from _util import median, print_machine, table, tx40_data

REPO = Path(__file__).resolve().parents[1]
DRIVER = Path(__file__).resolve().with_name("_figaroh_tx40.py")
FLOOR = Path(__file__).resolve().with_name("_cold_floor.py")
DEFAULT_VENV = Path("~/.cache/dynid-bench/figaroh-1.0.2").expanduser()
TX40_FILES = ("pos_read_data.csv", "curr_data.csv", "tx40_mdh_modified.urdf", "figaroh_TX40_config.yaml")
TRAIN = (0, 24750)
VALIDATE = (29250, 45000)
WALL_TARGET = 0.5      # with plots (issue 37, item 5)
WALL_OFF_TARGET = 0.4  # without plots
MEMORY_TARGET = 0.4
FIGAROH_REF_RMSE = [6.64, 8.32, 4.28, 1.80, 2.65, 1.72]  # shared/data/README.md, FIGAROH's published held-out RMSE

# figaroh 1.0.2 and what pip resolved for it when this bench was recorded (Python 3.11, 2026-11-26)
FIGAROH_PINS = """\
figaroh==1.0.2
pin==4.1.0
libpinocchio==4.1.0
eigenpy==3.13.0
coal==3.0.3
libcoal==3.0.3
ndcurves==2.3.0
libndcurves==2.3.0
numpy==2.4.6
scipy==1.17.1
matplotlib==3.11.2
pandas==3.1.1
PyYAML==6.0.4
numdifftools==0.11.2
PICOS==2.6.2
cvxopt==1.3.3
meshcat==0.3.2
rospkg==1.6.3
"""
VERSIONS = "figaroh pin numpy scipy matplotlib pandas".split()

# A fresh interpreter: argv = "-m" MODULE ARGS... | SCRIPT ARGS...; writes its peak RSS at exit.
WRAPPER = r"""
import atexit, json, os, runpy, sys
def _peak():
    with open("/proc/self/status") as fh:
        kb = int(next(l for l in fh if l.startswith("VmHWM:")).split()[1])
    with open(os.environ["VS_FIGAROH_PEAK_FILE"], "w") as fh:
        json.dump({"peak_kb": kb}, fh)
atexit.register(_peak)
if sys.argv[1] == "-m":
    sys.argv = sys.argv[2:]
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
else:
    sys.argv = sys.argv[1:]
    runpy.run_path(sys.argv[0], run_name="__main__")
"""


def fail(msg: str) -> None:
    print(f"vs_figaroh.py: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def venv_python(venv: Path) -> Path:
    return venv / "bin" / "python"


def figaroh_version(venv: Path) -> str | None:
    py = venv_python(venv)
    if not py.exists():
        return None
    proc = subprocess.run([str(py), "-c", "import importlib.metadata as m; print(m.version('figaroh'))"],
                          capture_output=True, text=True)
    return proc.stdout.strip() if proc.returncode == 0 else None


def ensure_venv(venv: Path) -> None:
    """Reuse ``venv`` when it holds figaroh 1.0.2, else create it (pinned); exit 2 when that fails."""
    if figaroh_version(venv) == "1.0.2":
        return
    if venv.exists() and any(venv.iterdir()):
        fail(f"{venv} exists but does not hold figaroh 1.0.2; remove it or give another --figaroh-venv")
    print(f"creating FIGAROH's virtual environment in {venv} (python -m venv + pip install figaroh==1.0.2, pinned)")
    venv.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", suffix=".txt", delete=False) as fh:
        fh.write(FIGAROH_PINS)
    steps = [("python -m venv", [sys.executable, "-m", "venv", str(venv)]),
             ("pip install figaroh==1.0.2", [str(venv_python(venv)), "-m", "pip", "install", "-q", "figaroh==1.0.2",
                                             "-c", fh.name])]
    try:
        for label, cmd in steps:
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                shutil.rmtree(venv, ignore_errors=True)  # made by this call: leave nothing half-made
                last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
                fail(f"cannot make FIGAROH's virtual environment in {venv} ({label} failed: {last}); "
                     "no network? give --figaroh-venv a ready environment")
    finally:
        os.unlink(fh.name)


def run_measured(python: str, argv: list[str], env: dict[str, str], workdir: Path, tag: str, tree: bool = False) -> dict:
    """Wall (whole subprocess) and peak RSS (VmHWM at exit) of ``python WRAPPER argv``; with ``tree``, also
    the sampled peak of the summed resident memory of the process and its children (:class:`TreeRss`)."""
    peak_file = workdir / f"peak_{tag}.json"
    peak_file.unlink(missing_ok=True)
    env = dict(env, VS_FIGAROH_PEAK_FILE=str(peak_file))
    t0 = time.perf_counter()
    with subprocess.Popen([python, "-c", WRAPPER, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          env=env) as popen:
        sampler = TreeRss(popen.pid) if tree else None
        out, err = popen.communicate()
    wall = time.perf_counter() - t0
    proc = subprocess.CompletedProcess(popen.args, popen.returncode, out, err)
    if sampler is not None:
        sampler.stop()
    if proc.returncode != 0 or not peak_file.exists():
        tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-15:])
        print(f"run {tag} failed (exit {proc.returncode}):\n{tail}", file=sys.stderr)
        raise SystemExit(1)
    res = {"wall_s": wall, "peak_mb": json.loads(peak_file.read_text())["peak_kb"] / 1024.0, "stdout": proc.stdout}
    if sampler is not None:
        res |= {"tree_mb": sampler.peak_kb / 1024.0, "processes": sampler.processes}
    return res


class TreeRss:
    """The largest sum of ``VmRSS`` over a process and its descendants (``/proc/PID/task/*/children``),
    sampled every ``period`` seconds by a thread of this process until :meth:`stop`: the memory of a
    ``dynid identify`` that draws its figures in its plot worker (a second process the wrapper's own
    ``VmHWM`` does not see). Sampled, so a peak shorter than the period can be missed (both processes'
    resident sets grow over tenths of a second: imports, then arrays); shared library pages are counted
    once per process (the sum is then at or above the pages in use). ``processes``: the most processes
    seen at one sample."""

    def __init__(self, pid: int, period: float = 0.005) -> None:
        import threading

        self.pid, self.period, self.peak_kb, self.processes = pid, period, 0, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _tree(self) -> list[int]:
        pids, todo = [], [self.pid]
        while todo:
            pid = todo.pop()
            pids.append(pid)
            for task in Path(f"/proc/{pid}/task").glob("*/children"):
                try:
                    todo += [int(c) for c in task.read_text().split()]
                except OSError:
                    pass
        return pids

    def _run(self) -> None:
        while not self._stop.is_set():
            total, n = 0, 0
            try:
                for pid in self._tree():
                    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                        if line.startswith("VmRSS:"):
                            total += int(line.split()[1])
                            n += 1
            except (OSError, ValueError):
                pass  # a process that ended between the listing and the read
            self.peak_kb, self.processes = max(self.peak_kb, total), max(self.processes, n)
            self._stop.wait(self.period)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def dynid_config(plots: bool, data_dir: Path) -> str:
    text = (REPO / "examples" / "tx40" / "identify.toml").read_text()
    text = text.replace("../../../shared/data/tx40/", f"{data_dir.as_posix()}/")
    return text + f"\n[output]\nplots = {'true' if plots else 'false'}\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--figaroh-venv", type=Path, default=DEFAULT_VENV,
                    help=f"FIGAROH's virtual environment, created when absent (default {DEFAULT_VENV})")
    ap.add_argument("--repeats", type=int, default=5, help="rounds (default 5)")
    ap.add_argument("--data", type=Path, default=None,
                    help="folder with the TX40 files (default $DYNID_SHARED_DATA/tx40 or ../shared/data/tx40)")
    ap.add_argument("--blas-threads", type=int, default=1, help="BLAS/OpenMP threads in both tools (default 1)")
    ap.add_argument("--workdir", type=Path, default=None, help="keep configs and outputs here (default: a temp dir)")
    ap.add_argument("--no-bytecode", action="store_true",
                    help="do not compile dynid's bytecode before the rounds: the runs use what __pycache__ holds "
                         "(with PYTHONDONTWRITEBYTECODE=1 and none there, every run compiles dynid from source)")
    ap.add_argument("--plot-worker", action="store_true",
                    help="also run dynid with its figures in the plot worker on a second CPU (DYNID_PLOT_WORKER=1, what "
                         "`dynid identify` does when a CPU is idle) in every round: its wall time and the sampled "
                         "memory of both processes")
    ap.add_argument("--floor", action="store_true",
                    help="also run bench/_cold_floor.py in every round: imports, reading the log and one regressor "
                         "call per sample, nothing else (the lower bound of a run)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        fail(f"--repeats must be at least 1, got {args.repeats}")
    if args.blas_threads < 1:
        fail(f"--blas-threads must be at least 1, got {args.blas_threads}")
    data = tx40_data(args.data, TX40_FILES)
    if isinstance(data, str):
        fail(data)

    venv = args.figaroh_venv.expanduser().resolve()
    if REPO in venv.parents or venv == REPO:
        fail(f"--figaroh-venv {venv} is inside the repository; FIGAROH must stay outside it")
    ensure_venv(venv)
    fig_py = str(venv_python(venv))
    ver = subprocess.run([fig_py, "-c", "import importlib.metadata as m; print(' '.join(f'{p} {m.version(p)}' for p in "
                          f"{VERSIONS!r}))"], capture_output=True, text=True)
    print_machine()
    dyn = subprocess.run([sys.executable, "-c", "import dynid; print(dynid.__version__, dynid.__file__)"],
                         capture_output=True, text=True)
    print(f"dynid side: {sys.executable}: dynid {dyn.stdout.strip() or dyn.stderr.strip()}")
    print(f"FIGAROH side: {fig_py}: {ver.stdout.strip() or ver.stderr.strip()}")

    work = Path(tempfile.mkdtemp(prefix="dynid-vs-figaroh-")) if args.workdir is None else args.workdir.resolve()
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, MPLBACKEND="Agg")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(args.blas_threads)
    fig_env = {k: v for k, v in env.items() if k != "PYTHONPATH"}  # FIGAROH sees only its own environment
    env["DYNID_PLOT_WORKER"] = "0"  # one process: its VmHWM is the whole run's peak (module docstring)
    if not args.no_bytecode:  # as an installed dynid runs: from bytecode compiled once (module docstring)
        pkg = subprocess.run([sys.executable, "-c", "import dynid, os; print(os.path.dirname(dynid.__file__))"],
                             capture_output=True, text=True, env=env).stdout.strip()
        comp = subprocess.run([sys.executable, "-m", "compileall", "-q", pkg], capture_output=True, text=True, env=env)
        if not pkg or comp.returncode != 0:
            fail(f"cannot compile dynid's bytecode beside its sources in {pkg or '(dynid not found)'}: "
                 f"{(comp.stdout + comp.stderr).strip()[-300:]} (--no-bytecode runs from source)")
    print(f"dynid runs from {'source (no bytecode compiled before)' if args.no_bytecode else 'bytecode compiled before the rounds (compileall)'}")
    prep = work / "figaroh_prep"
    prep.mkdir(exist_ok=True)
    proc = subprocess.run([fig_py, str(DRIVER), "prepare", str(data), str(prep)], capture_output=True, text=True,
                          env=fig_env)
    if proc.returncode != 0:
        print(proc.stdout + proc.stderr, file=sys.stderr)
        fail("FIGAROH could not convert its TX40 configuration (see above)")
    cfgs = {}
    for plots in (True, False):
        cfgs[plots] = work / f"dynid_tx40_plots_{'on' if plots else 'off'}.toml"
        cfgs[plots].write_text(dynid_config(plots, data))

    def run(tool: str, plots: bool, r: int) -> dict:
        tag = f"{tool}_{'on' if plots else 'off'}_{r}"
        out = work / tag
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        if tool == "floor":
            res = run_measured(sys.executable, [str(FLOOR), str(data)] + (["--plots"] if plots else []), env, work, tag)
            res |= {"parts": json.loads(res["stdout"].strip().splitlines()[-1])}
        elif tool in ("dynid", "worker"):
            # "worker": the figures drawn in dynid's plot worker on a second CPU (DYNID_PLOT_WORKER=1), as
            # `dynid identify` draws them when a CPU is idle; its memory is that of both processes
            res = run_measured(sys.executable, ["-m", "dynid.cli", "identify", str(cfgs[plots]), "--out", str(out), "-q"],
                               env if tool == "dynid" else dict(env, DYNID_PLOT_WORKER="1"), work, tag,
                               tree=tool == "worker")
            doc = json.loads((out / "result.json").read_text())
            full = doc["validation_full_rate"]["identified"]
            res |= {"rmse": full["rmse_per_joint"], "n_val": full["n_samples"], "n_base": len(doc["params"]),
                    "method": doc["method"]}
        else:
            cmd = [str(DRIVER), "identify", str(data), str(prep), str(out), "--train", *map(str, TRAIN),
                   "--validate", *map(str, VALIDATE)] + ([] if plots else ["--no-plots"])
            res = run_measured(fig_py, cmd, fig_env, work, tag)
            doc = json.loads((out / "figaroh_result.json").read_text())
            res |= {"rmse": doc["rmse_per_joint"], "n_val": doc["validation_samples"], "n_base": doc["n_base"],
                    "doc": doc}
        print(f"  round {r + 1} {tool:7s} plots {'on ' if plots else 'off'}: wall {res['wall_s']:6.2f} s, "
              f"peak {res['peak_mb']:6.0f} MB" + (f" (with the plot worker: {res['tree_mb']:.0f} MB sampled over "
                                                  f"{res['processes']} processes)" if "tree_mb" in res else ""), flush=True)
        return res

    load_before = os.getloadavg()
    print(f"load average before: {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}")
    rounds = []
    for r in range(args.repeats):
        first, second = ("dynid", "figaroh") if r % 2 == 0 else ("figaroh", "dynid")
        res = {}
        res[first, True] = run(first, True, r)
        res[second, True] = run(second, True, r)
        res[second, False] = run(second, False, r)
        res[first, False] = run(first, False, r)
        if args.plot_worker:  # after the round's four runs, beside dynid's own plotted run
            res["worker", True] = run("worker", True, r)
        if args.floor:  # after the round's four runs, plots on then off
            res["floor", True] = run("floor", True, r)
            res["floor", False] = run("floor", False, r)
        rounds.append(res)
    load_after = os.getloadavg()
    print(f"load average after: {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}")

    def med(tool, plots, key):
        return median([rd[tool, plots][key] for rd in rounds])

    def paired(plots, key, tool="dynid"):
        return median([rd[tool, plots][key] / rd["figaroh", plots][key] for rd in rounds])

    ratios = {"wall_on": paired(True, "wall_s"), "wall_off": paired(False, "wall_s"),
              "mem_on": paired(True, "peak_mb"), "mem_off": paired(False, "peak_mb")}
    rows = [
        ["wall, plots on [s]", f"{med('dynid', True, 'wall_s'):.2f}", f"{med('figaroh', True, 'wall_s'):.2f}",
         f"{ratios['wall_on']:.2f}x", f"<= {WALL_TARGET}x", "PASS" if ratios["wall_on"] <= WALL_TARGET else "FAIL"],
        ["wall, plots off [s]", f"{med('dynid', False, 'wall_s'):.2f}", f"{med('figaroh', False, 'wall_s'):.2f}",
         f"{ratios['wall_off']:.2f}x", f"<= {WALL_OFF_TARGET}x", "PASS" if ratios["wall_off"] <= WALL_OFF_TARGET else "FAIL"],
        ["peak memory, plots on [MB]", f"{med('dynid', True, 'peak_mb'):.0f}", f"{med('figaroh', True, 'peak_mb'):.0f}",
         f"{ratios['mem_on']:.2f}x", f"<= {MEMORY_TARGET}x", "PASS" if ratios["mem_on"] <= MEMORY_TARGET else "FAIL"],
        ["peak memory, plots off [MB]", f"{med('dynid', False, 'peak_mb'):.0f}",
         f"{med('figaroh', False, 'peak_mb'):.0f}", f"{ratios['mem_off']:.2f}x", "-", "-"],
    ]
    if args.plot_worker:
        ratios["worker_wall"] = paired(True, "wall_s", "worker")
        ratios["worker_mem"] = median(
            [rd["worker", True]["tree_mb"] / rd["figaroh", True]["peak_mb"] for rd in rounds])
        rows.append(["wall, plots on, plot worker [s]", f"{med('worker', True, 'wall_s'):.2f}",
                     f"{med('figaroh', True, 'wall_s'):.2f}", f"{ratios['worker_wall']:.2f}x", f"<= {WALL_TARGET}x",
                     "PASS" if ratios["worker_wall"] <= WALL_TARGET else "FAIL"])
        rows.append(["peak memory, plot worker, both [MB]", f"{med('worker', True, 'tree_mb'):.0f}",
                     f"{med('figaroh', True, 'peak_mb'):.0f}", f"{ratios['worker_mem']:.2f}x", f"<= {MEMORY_TARGET}x",
                     "PASS" if ratios["worker_mem"] <= MEMORY_TARGET else "FAIL"])
    if args.floor:
        for plots in (True, False):
            rows.append([f"floor, plots {'on' if plots else 'off'} [s]", f"{med('floor', plots, 'wall_s'):.2f}",
                         f"{med('figaroh', plots, 'wall_s'):.2f}", f"{paired(plots, 'wall_s', 'floor'):.2f}x", "-",
                         "bound"])
    print(f"\nTX40, {args.repeats} rounds (medians; ratio = median over rounds of dynid/FIGAROH in the same round)")
    print(table(["", "dynid", "FIGAROH 1.0.2", "paired ratio", "target", "check"], rows))

    if args.floor:
        print("floor (bench/_cold_floor.py, its own timers; the rest of its wall is the interpreter's start and exit):")
        for r, rd in enumerate(rounds):
            for plots in (True, False):
                pt = rd["floor", plots]["parts"]
                print(f"  round {r + 1} plots {'on ' if plots else 'off'}: wall {rd['floor', plots]['wall_s']:.2f} s = "
                      f"imports {pt['import_s']:.2f} + reading the logs {pt['read_s']:.2f} + {pt['samples']} regressor "
                      f"calls {pt['regressor_s']:.2f} + the rest; FIGAROH {rd['figaroh', plots]['wall_s']:.2f} s")

    d, f = rounds[0]["dynid", True], rounds[0]["figaroh", True]
    print(f"\nheld-out torque RMSE per joint [N*m], trained on rows {TRAIN[0]}-{TRAIN[1]}, scored on rows "
          f"{VALIDATE[0]}-{VALIDATE[1]} at 5 kHz (dynid {d['n_val']} samples, FIGAROH {f['n_val']})")
    print(table(["joint", "dynid", "FIGAROH 1.0.2 (this run)", "FIGAROH published (shared/data/README)"],
                [[f"joint {j + 1}", f"{d['rmse'][j]:.2f}", f"{f['rmse'][j]:.2f}", f"{FIGAROH_REF_RMSE[j]:.2f}"]
                 for j in range(6)]))
    fdoc = f["doc"]
    print("what differs between the two runs (same log, same rows, same held-out scoring):\n"
          "  dynid  : 25 Hz order-4 zero-phase Butterworth on positions, central differences, 20 samples trimmed,\n"
          f"           parallel decimation by 100, velocity dead band, {d['method']}, smooth Coulomb sign, {d['n_base']} base\n"
          "           parameters with the coupled-wrist motor terms (Iam6, fvm6, fcm6): examples/tx40/identify.toml\n"
          f"  FIGAROH: median(5) + 100 Hz order-4 Butterworth, np.gradient, 20 samples trimmed, decimation by 10\n"
          f"           (scipy.signal.decimate), {'WLS' if fdoc['wls'] else 'OLS'}, {fdoc['n_base']} base parameters: "
          "its 1.0.2 base class never adds the example's\n"
          "           coupled-wrist columns, hence joint 5's larger held-out error")
    print(f"\nFIGAROH's identified base parameters ({fdoc['n_base']}, round 1, plots on):")
    for k, v in fdoc["base_parameters"].items():
        print(f"  {v:12.5g}  {k}")
    print("FIGAROH in-process timing (round 1): " + ", ".join(f"{k} {v:.2f} s" for k, v in fdoc["timing_s"].items()))

    ok = ratios["wall_on"] <= WALL_TARGET and ratios["wall_off"] <= WALL_OFF_TARGET and ratios["mem_on"] <= MEMORY_TARGET
    print(f"\n{'PASS' if ok else 'FAIL'}: dynid/FIGAROH wall with plots {ratios['wall_on']:.2f}x (target <= {WALL_TARGET}x), "
          f"without plots {ratios['wall_off']:.2f}x (target <= {WALL_OFF_TARGET}x), "
          f"peak memory {ratios['mem_on']:.2f}x (target <= {MEMORY_TARGET}x)"
          + (f"; with the figures in the plot worker on a second CPU: wall {ratios['worker_wall']:.2f}x, memory of "
             f"both processes {ratios['worker_mem']:.2f}x (the exit status is the one-process run's)"
             if args.plot_worker else ""))
    if args.workdir is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
