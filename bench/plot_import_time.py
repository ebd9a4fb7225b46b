"""TX40 identify run: what the plots and the imports cost (dynid issue 20, item 8).

What is measured
----------------
* ``dynid identify examples/tx40/identify.toml`` (shared-data paths made absolute) with
  ``[output] plots = true`` and ``false``, each run in a fresh process
  (``python -X importtime -m dynid.cli identify ... -q``), as a user runs it.
* Rounds alternate the order (even rounds: plots on first; odd rounds: plots off first) so that a
  drift in machine load falls on both; the paired ratio plotted/unplotted is taken per round and its
  median reported.
* Import share: the sum of the top-level entries of ``-X importtime`` (every module the run
  imports, at the moment it imports it, lazy imports included) over the process's wall time. The
  ``-X importtime`` bookkeeping itself costs a few per cent and is paid by every run alike.
* ``import dynid.cli`` alone: cumulative time of that entry in a fresh process (median over rounds).
* ``--src DIR`` (repeatable) measures other checkouts' ``src`` folders in the same rounds (e.g. main
  against a branch): each gets its own PYTHONPATH, the same Python, the same data.
  ``--src DIR,VAR=VALUE,...`` sets environment variables for that entry (e.g.
  ``--src src,DYNID_PLOT_WORKER=0``: this checkout with the figures drawn in process).
* CPU time (user + system of the run and its children, the plot worker included), which other
  jobs on a shared machine disturb less than wall time.

Criterion: exit 1 when the median paired ratio plotted/unplotted of the first ``--src`` (default
this checkout) exceeds 1.3.

Usage::

    OPENBLAS_NUM_THREADS=1 python bench/plot_import_time.py [--repeats 5] [--src ../main/src --src src]
"""

from __future__ import annotations

import argparse
import os
import resource
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _util import median, print_machine, table, tx40_data

REPO = Path(__file__).resolve().parents[1]
TX40_FILES = ("pos_read_data.csv", "curr_data.csv", "tx40_mdh_modified.urdf")
LIMIT = 1.3
_IMPORT_LINE = re.compile(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)")


def fail(msg: str) -> None:
    print(f"plot_import_time: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def config_text(plots: bool, data_dir: Path) -> str:
    text = (REPO / "examples" / "tx40" / "identify.toml").read_text()
    text = text.replace("../../../shared/data/tx40/", f"{data_dir.as_posix()}/")
    return text + f"\n[output]\nplots = {'true' if plots else 'false'}\n"


def import_seconds(stderr: str) -> tuple[float, dict[str, float]]:
    """Total of the top-level ``-X importtime`` entries [s] and the cumulative time per top-level module."""
    tops: dict[str, float] = {}
    for line in stderr.splitlines():
        m = _IMPORT_LINE.match(line)
        if m and len(m[3]) == 1:  # one space: imported by the program itself, not by another module
            tops[m[4]] = tops.get(m[4], 0.0) + int(m[2]) * 1e-6
    return sum(tops.values()), tops


def parse_src(text: str) -> tuple[Path, dict[str, str]]:
    """``DIR`` or ``DIR,VAR=VALUE,...``: the src folder and the environment variables of that entry."""
    path, *pairs = text.split(",")
    extra = {}
    for pair in pairs:
        if "=" not in pair:
            fail(f"--src {text!r}: {pair!r} is not VAR=VALUE")
        k, v = pair.split("=", 1)
        extra[k] = v
    return Path(path).resolve(), extra


def env_for(src: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env.update(extra or {})
    env["PYTHONPATH"] = str(src)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("MPLBACKEND", "Agg")
    return env


def run_identify(src: Path, cfg: Path, out: Path, extra: dict[str, str] | None = None) -> dict:
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "dynid.cli", "identify", str(cfg), "--out", str(out), "-q"],
                          capture_output=True, text=True, env=env_for(src, extra))
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the plot worker is waited for by the run: counted
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if proc.returncode != 0:
        tail = [ln for ln in proc.stderr.splitlines() if not ln.startswith("import time:")][-5:]
        fail(f"dynid identify failed with {src}: " + " | ".join(tail))
    imp, tops = import_seconds(proc.stderr)
    return {"wall": wall, "cpu": cpu, "imports": imp, "tops": tops}


def cli_import_seconds(src: Path) -> float:
    proc = subprocess.run([sys.executable, "-X", "importtime", "-c", "import dynid.cli"],
                          capture_output=True, text=True, env=env_for(src))
    if proc.returncode != 0:
        fail(f"import dynid.cli failed with {src}: {proc.stderr.strip().splitlines()[-1:]}")
    return import_seconds(proc.stderr)[1].get("dynid.cli", float("nan"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--repeats", type=int, default=5, help="rounds (default 5)")
    ap.add_argument("--src", type=str, action="append", default=None,
                    help="a checkout's src folder to measure (repeatable; default this checkout's src); "
                         "the first one decides the exit status")
    ap.add_argument("--data", type=Path, default=None,
                    help="folder with the TX40 files (default $DYNID_SHARED_DATA/tx40 or ../shared/data/tx40)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        fail(f"--repeats must be at least 1, got {args.repeats}")
    entries = [parse_src(s) for s in (args.src or [str(REPO / "src")])]
    srcs = [s for s, _ in entries]
    extras = [e for _, e in entries]
    for s in srcs:
        if not (s / "dynid" / "cli.py").is_file():
            fail(f"--src {s} has no dynid/cli.py")
    data = tx40_data(args.data, TX40_FILES)
    if isinstance(data, str):
        fail(data)

    print_machine()
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    res: dict[tuple[int, bool], list[dict]] = {(i, p): [] for i in range(len(srcs)) for p in (True, False)}
    cli: dict[int, list[float]] = {i: [] for i in range(len(srcs))}
    with tempfile.TemporaryDirectory(prefix="dynid_plotimport_") as tmp:
        work = Path(tmp)
        cfgs = {}
        for plots in (True, False):
            cfgs[plots] = work / f"tx40_plots_{'on' if plots else 'off'}.toml"
            cfgs[plots].write_text(config_text(plots, data))
        for r in range(args.repeats):
            order = (True, False) if r % 2 == 0 else (False, True)
            for i, src in enumerate(srcs):
                cli[i].append(cli_import_seconds(src))
                for plots in order:
                    m = run_identify(src, cfgs[plots], work / f"out_{i}_{int(plots)}_{r}", extras[i])
                    res[(i, plots)].append(m)
                    print(f"  round {r + 1} src {i} plots {'on ' if plots else 'off'}: wall {m['wall']:6.2f} s, "
                          f"cpu {m['cpu']:6.2f} s, imports {m['imports']:5.2f} s", flush=True)
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")

    rows = []
    ratios = {}
    for i, src in enumerate(srcs):
        on, off = res[(i, True)], res[(i, False)]
        ratio = median([a["wall"] / b["wall"] for a, b in zip(on, off)])
        cpu_ratio = median([a["cpu"] / b["cpu"] for a, b in zip(on, off)])
        ratios[i] = ratio
        for plots, ms in ((True, on), (False, off)):
            wall = median([m["wall"] for m in ms])
            imp = median([m["imports"] for m in ms])
            share = median([m["imports"] / m["wall"] for m in ms])
            label = f"{i}: {src}" + "".join(f",{k}={v}" for k, v in extras[i].items())
            rows.append([label, "on" if plots else "off", f"{wall:.2f}", f"{median([m['cpu'] for m in ms]):.2f}",
                         f"{imp:.2f}", f"{100 * share:.0f} %", f"{ratio:.2f}" if plots else "",
                         f"{cpu_ratio:.2f}" if plots else "", f"{median(cli[i]):.3f}" if plots else ""])
        heavy = {}
        for m in on:
            for name, t in m["tops"].items():
                heavy.setdefault(name, []).append(t)
        top = sorted(((median(v), k) for k, v in heavy.items()), reverse=True)[:6]
        print(f"src {i}: heaviest top-level imports of a plotted run (median s): "
              + ", ".join(f"{k} {t:.2f}" for t, k in top))
    print(table(["src", "plots", "wall [s]", "cpu [s]", "imports [s]", "import share", "on/off wall (paired)",
                 "on/off cpu", "import dynid.cli [s]"], rows))
    ok = ratios[0] <= LIMIT
    print(f"{'PASS' if ok else 'FAIL'}: median paired wall ratio plotted/unplotted {ratios[0]:.2f} (limit {LIMIT})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
