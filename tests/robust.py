"""``make test-robust``: the numerically sensitive tests under the perturbations another machine brings.

The tests marked ``numerics`` (they assert on the output of an iterative or solver-based method,
or on statistics of simulated data) are rerun with:

==============  ===========================================================================
perturbation    what changes, and why it matters
==============  ===========================================================================
threads-1       ``OPENBLAS_NUM_THREADS=1`` (and OMP/MKL): BLAS calls split over no threads,
                so reductions sum in another order than on a many-core machine
kernel-K        ``OPENBLAS_CORETYPE=K`` for two OpenBLAS kernels this CPU supports other than
                its own (one with FMA, one without where possible): other blocking and
                rounding in every BLAS/LAPACK call (the AMD EPYC machine of issue 33 ran
                Haswell)
simd            ``NPY_DISABLE_CPU_FEATURES`` = every SIMD target numpy dispatches to above its
                baseline here (the widest first): numpy's own loops take other code paths
tol-tight       ``DYNID_SOLVER_TOL_SCALE=0.01``: every solver tolerance of
                :mod:`dynid.tolerances` tightened 100x
tol-loose       ``DYNID_SOLVER_TOL_SCALE=10``: loosened 10x (still valid settings)
seed            ``DYNID_TEST_SEED=1``: another random seed for simulated data (tests route their
                seeds through ``conftest.seed``)
==============  ===========================================================================

The default plan (``--plan combined``) applies them in two runs, so that the suite fits in a few
minutes on two cores: each perturbation is applied to every marked test once, and the two
exclusive ones (the two kernels; the two tolerance scales) fall in different runs:

- run A: threads-1, kernel-K1, tol-tight
- run B: kernel-K2, simd, tol-loose, seed

When a run fails, its failed tests are rerun under each of the run's perturbations alone, so the
report says which perturbation breaks which test. ``--plan separate`` runs each perturbation on
its own (seven runs). Every run first checks, in a fresh process, that its perturbations took
effect (the OpenBLAS kernels and threads threadpoolctl reports, numpy's disabled features, the
tolerance scale); a perturbation this machine cannot apply is said in one line and fails the run.

Usage: ``python tests/robust.py [--plan combined|separate] [--only NAME ...] [-- PYTEST ARGS]``
(``make test-robust``; ``TEST_WORKERS`` as for ``make test``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable

# OpenBLAS kernels from the widest down, with the CPU flags each needs (/proc/cpuinfo names).
# "Zen" runs Haswell's kernels, so it counts as Haswell.
_KERNELS = (
    ("SkylakeX", {"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}),
    ("Haswell", {"avx2", "fma"}),
    ("Sandybridge", {"avx"}),
    ("Nehalem", {"sse4_2"}),
    ("Prescott", {"sse3"}),
)
_SAME_KERNEL = {"zen": "haswell", "cooperlake": "skylakex", "sapphirerapids": "skylakex"}


@dataclass(frozen=True)
class Perturbation:
    name: str
    env: dict[str, str]
    what: str
    expect: dict = field(default_factory=dict)  # what the probe must see


def _probe(env: dict[str, str]) -> dict:
    """What a fresh Python process sees under ``env``: BLAS kernels and threads, numpy's CPU
    features, dynid's tolerance scale."""
    code = (
        "import json, numpy, scipy.linalg, threadpoolctl\n"
        "from numpy._core import _multiarray_umath as m\n"
        "from dynid.tolerances import scale\n"
        "blas = [i for i in threadpoolctl.threadpool_info() if i.get('user_api') == 'blas']\n"
        "print(json.dumps({'arch': sorted({str(i.get('architecture')) for i in blas}),\n"
        "                  'threads': sorted({int(i.get('num_threads')) for i in blas}),\n"
        "                  'features': {k: bool(v) for k, v in m.__cpu_features__.items()},\n"
        "                  'dispatch': list(m.__cpu_dispatch__), 'baseline': list(m.__cpu_baseline__),\n"
        "                  'scale': scale()}))\n"
    )
    r = subprocess.run([PY, "-c", code], env={**os.environ, **env}, capture_output=True, text=True, cwd=REPO)
    if r.returncode != 0:
        raise SystemExit(f"robust: error: the probe failed under {env}: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout)


def _cpu_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def perturbations() -> dict[str, Perturbation]:
    """The perturbations this machine supports, by name (module docstring)."""
    base = _probe({})
    current = {_SAME_KERNEL.get(a.lower(), a.lower()) for a in base["arch"]}
    flags = _cpu_flags()
    kernels = [k for k, need in _KERNELS if need <= flags and k.lower() not in current]
    # one kernel with FMA and one without where the CPU allows it: they round differently
    fma = [k for k in kernels if k in ("SkylakeX", "Haswell")]
    plain = [k for k in kernels if k not in fma]
    chosen = ([fma[0]] if fma else []) + ([plain[0]] if plain else [])
    chosen += [k for k in kernels if k not in chosen][: 2 - len(chosen)]
    if len(chosen) < 2:
        raise SystemExit(f"robust: error: this CPU offers {len(chosen)} OpenBLAS kernel(s) besides its own "
                         f"({', '.join(base['arch'])}); two are needed")
    # numpy's dispatched SIMD targets available here, widest first (numpy lists them narrow to wide)
    simd = [f for f in reversed(base["dispatch"]) if base["features"].get(f)]
    if not simd:
        raise SystemExit("robust: error: numpy dispatches to no SIMD target above its baseline on this CPU: "
                         "there is nothing for NPY_DISABLE_CPU_FEATURES to disable")
    threads = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    out = [
        Perturbation("threads-1", threads, "OPENBLAS_NUM_THREADS=1", {"threads": [1]}),
        Perturbation(f"kernel-{chosen[0]}", {"OPENBLAS_CORETYPE": chosen[0]}, f"OPENBLAS_CORETYPE={chosen[0]}",
                     {"arch": chosen[0]}),
        Perturbation(f"kernel-{chosen[1]}", {"OPENBLAS_CORETYPE": chosen[1]}, f"OPENBLAS_CORETYPE={chosen[1]}",
                     {"arch": chosen[1]}),
        Perturbation("simd", {"NPY_DISABLE_CPU_FEATURES": " ".join(simd)},
                     f"NPY_DISABLE_CPU_FEATURES={' '.join(simd)}", {"disabled": simd}),
        Perturbation("tol-tight", {"DYNID_SOLVER_TOL_SCALE": "0.01"}, "solver tolerances x0.01", {"scale": 0.01}),
        Perturbation("tol-loose", {"DYNID_SOLVER_TOL_SCALE": "10"}, "solver tolerances x10", {"scale": 10.0}),
        Perturbation("seed", {"DYNID_TEST_SEED": "1"}, "simulated data seed 1 (conftest.seed)"),
    ]
    return {p.name: p for p in out}


def plan(kind: str, ps: dict[str, Perturbation], only: list[str]) -> list[tuple[str, list[Perturbation]]]:
    names = list(ps)
    if only:
        unknown = [n for n in only if n not in ps]
        if unknown:
            raise SystemExit(f"robust: error: unknown perturbation(s) {unknown}; known: {names}")
        return [(n, [ps[n]]) for n in only]
    if kind == "separate":
        return [(n, [ps[n]]) for n in names]
    k1, k2 = (n for n in names if n.startswith("kernel-"))
    return [("A", [ps["threads-1"], ps[k1], ps["tol-tight"]]),
            ("B", [ps[k2], ps["simd"], ps["tol-loose"], ps["seed"]])]


def _env(parts: list[Perturbation]) -> dict[str, str]:
    env: dict[str, str] = {}
    for p in parts:
        env.update(p.env)
    return env


def _check(parts: list[Perturbation]) -> None:
    """Each perturbation took effect in a fresh process (else one line, exit 2)."""
    seen = _probe(_env(parts))
    for p in parts:
        e = p.expect
        ok = True
        if "threads" in e:
            ok = seen["threads"] == e["threads"]
        if "arch" in e:
            ok = [a.lower() for a in seen["arch"]] == [e["arch"].lower()]
        if "disabled" in e:
            ok = not any(seen["features"].get(f) for f in e["disabled"])
        if "scale" in e:
            ok = seen["scale"] == e["scale"]
        if not ok:
            raise SystemExit(f"robust: error: {p.name} ({p.what}) did not take effect here: the process sees "
                             f"BLAS {seen['arch']} x{seen['threads']}, tolerance scale {seen['scale']}")


def _pytest(env: dict[str, str], args: list[str], xml: Path, workers: str) -> tuple[int, float]:
    cmd = [PY, "-m", "pytest", "-q", "-m", "numerics", "-p", "no:cacheprovider", f"--junitxml={xml}"]
    if workers != "0":
        cmd += ["-n", workers, "--dist", "loadfile"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd + args, env={**os.environ, **env}, cwd=REPO)
    return r.returncode, time.perf_counter() - t0


def _results(xml: Path) -> tuple[int, list[str]]:
    """(tests run, failed node ids) of a junit XML file."""
    if not xml.is_file():
        return 0, []
    root = ET.parse(xml).getroot()
    n, failed = 0, []
    for case in root.iter("testcase"):
        n += 1
        if case.find("failure") is not None or case.find("error") is not None:
            path = case.get("file") or case.get("classname", "").replace(".", "/") + ".py"
            failed.append(f"{path}::{case.get('name')}")
    return n, failed


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(prog="tests/robust.py", description=__doc__.splitlines()[0])
    ap.add_argument("--plan", choices=("combined", "separate"), default="combined")
    ap.add_argument("--only", action="append", default=[], help="run this perturbation alone (repeatable)")
    a = ap.parse_args(argv)
    workers = os.environ.get("TEST_WORKERS", "2")
    ps = perturbations()
    runs = plan(a.plan, ps, a.only)
    print("make test-robust: tests marked 'numerics', runs:")
    for name, parts in runs:
        print(f"  {name}: " + "; ".join(p.what for p in parts))
    rows, bad = [], False
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for name, parts in runs:
            _check(parts)
            print(f"\n=== run {name}: {', '.join(p.name for p in parts)}", flush=True)
            xml = Path(tmp) / f"{name}.xml"
            rc, wall = _pytest(_env(parts), extra, xml, workers)
            n, failed = _results(xml)
            rows.append((name, parts, n, failed, wall, rc))
            if rc != 0:
                bad = True
                if failed and len(parts) > 1:
                    print(f"\n--- run {name} failed {len(failed)} test(s); rerunning them under each perturbation alone",
                          flush=True)
                    for p in parts:
                        x = Path(tmp) / f"{name}-{p.name}.xml"
                        _pytest(p.env, failed, x, "0")
                        print(f"    {p.name}: fails {_results(x)[1] or 'nothing'}", flush=True)
    print("\nmake test-robust summary")
    for name, parts, n, failed, wall, rc in rows:
        state = "passed" if rc == 0 else (f"FAILED {len(failed)}" if failed else f"exit {rc}")
        print(f"  run {name:<22} {n:4d} tests  {state:<10} {wall:7.1f} s   ({', '.join(p.name for p in parts)})")
    print(f"  total {time.perf_counter() - t_all:.1f} s; load average {os.getloadavg()[0]:.2f}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
