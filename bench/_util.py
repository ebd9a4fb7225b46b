"""Small helpers shared by the benchmark scripts: machine description and tables."""

from __future__ import annotations

import gc
import os
import platform
import statistics
import time
from collections.abc import Sequence


def cpu_model() -> str:
    """CPU model name from /proc/cpuinfo (Linux), else ``platform.processor()``."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict[str, str]:
    """CPU, cores, memory and the versions that matter for the figures."""
    import numpy
    import pinocchio
    import scipy

    mem = "unknown"
    try:
        with open("/proc/meminfo") as fh:
            kb = int(next(line for line in fh if line.startswith("MemTotal")).split()[1])
            mem = f"{kb / 2**20:.1f} GiB"
    except (OSError, StopIteration, ValueError):
        pass
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 0
    return {
        "cpu": cpu_model(),
        "cores": str(cores),
        "memory": mem,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "pinocchio": pinocchio.__version__,
    }


def print_machine() -> None:
    info = machine_info()
    print("machine: " + ", ".join(f"{k} {v}" for k, v in info.items()))


def median(xs: Sequence[float]) -> float:
    return float(statistics.median(xs))


def table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table, first column left-aligned, the others right-aligned."""
    cells = [list(headers)] + [list(r) for r in rows]
    w = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["  ".join([r[0].ljust(w[0])] + [c.rjust(x) for c, x in zip(r[1:], w[1:])]) for r in cells]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


def timed(fn) -> float:
    """Seconds taken by ``fn()``, with the garbage collector off during the call."""
    gc.collect()
    gc.disable()
    try:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0
    finally:
        gc.enable()


def rounds(variants: dict, repeats: int, n: int) -> dict[str, list[float]]:
    """Microseconds per sample of each variant over ``repeats`` rounds, after a warm-up.

    Every round runs each variant once, in an order rotated from round to round so that none
    always runs first or last; the per-round figures are printed as they come."""
    names = list(variants)
    for fn in variants.values():  # warm-up
        fn()
    times: dict[str, list[float]] = {k: [] for k in names}
    for r in range(repeats):
        for k in names[r % len(names):] + names[: r % len(names)]:
            times[k].append(timed(variants[k]) / n * 1e6)
        print(f"  round {r + 1}/{repeats}: " + ", ".join(f"{k} {times[k][-1]:.2f}" for k in names) + " us/sample",
              flush=True)
    return times


def tx40_data(data, files) -> "Path | str":
    """The TX40 data folder: ``data`` if given, else ``$DYNID_SHARED_DATA/tx40``, else
    ``../shared/data/tx40`` beside the repository; returns the resolved folder, or a one-line
    message (a ``str``) naming the files that are missing."""
    from pathlib import Path

    if data is None:
        root = os.environ.get("DYNID_SHARED_DATA")
        data = Path(root) / "tx40" if root else Path(__file__).resolve().parents[2] / "shared" / "data" / "tx40"
    data = Path(data).resolve()
    missing = [f for f in files if not (data / f).is_file()]
    if missing:
        return f"TX40 data not found in {data} (missing {', '.join(missing)}); give --data"
    return data


PUMA_CONFIG = """\
# written by bench/{script}: {n} samples, train on [0, {n_train}), hold out [{n_train}, {n})
[robot]
model = "builtin:puma560"

[data]
{file_line}time = {{ column = "t" }}
position = {{ columns = "q" }}
effort = {{ columns = "tau" }}
rows = [0, {n_train}]

[validation]
rows = [{n_train}, {n}]

[processing]
lowpass = {{ cutoff_hz = 20.0, order = 4, filter_effort = false }}

[identification]
method = "wls"

[output]
plots = {plots}
"""


def puma_config(script: str, n: int, *, file: str | None = None, plots: bool = False) -> str:
    """The identify config the scaling benches use on a simulated PUMA 560 log of ``n`` samples:
    WLS on the first 80 %, held out on the rest, a 20 Hz low-pass."""
    return PUMA_CONFIG.format(script=script, n=n, n_train=int(0.8 * n),
                              file_line=f'file = "{file}"\n' if file else "", plots="true" if plots else "false")
