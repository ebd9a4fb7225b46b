"""Shared fixtures. Real data live in ../shared/data (beside the checkout); tests that need
them skip with a clear reason when the folder is absent. DYNID_SHARED_DATA overrides the path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("DYNID_SHARED_DATA", REPO.parent / "shared" / "data"))
GUIDE = REPO / "docs" / "guide"  # the user guide: one MyST page per topic (README.md points into it)


def doc_text(name: str) -> str:
    """The text of the user guide's page ``docs/guide/<name>.md`` (a page starts with its ``#`` title;
    the README's ``##`` sections are page titles there, its ``###`` sections ``##``)."""
    return (GUIDE / f"{name}.md").read_text()


_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def pytest_configure(config):
    """Under pytest-xdist, share the cores between the workers: each worker (and each dynid
    process a test starts) gets cpu_count // workers BLAS threads, unless the caller chose a
    thread count. Two workers with two spinning OpenBLAS threads each on a 2-core machine are
    several times slower than either alone."""
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if not workers or any(v in os.environ for v in _BLAS_VARS):
        return
    n = max(1, (os.cpu_count() or 1) // int(workers))
    for var in _BLAS_VARS:
        os.environ[var] = str(n)  # for the dynid processes the tests start, and BLAS libraries loaded later
    import numpy  # noqa: F401  (load the BLAS libraries, so that the limit reaches them)
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    config._dynid_blas_limits = threadpool_limits(limits=n)  # this worker's BLAS, from now on


# The slowest modules, slowest first (minutes on a 2-core machine; `pytest --durations`). Run
# first, they spread over the xdist workers (one module per worker at a time, --dist loadfile)
# before the many short ones fill the gaps: the longest-first rule keeps the workers finishing
# together. Only the order changes, never what runs.
SLOW_MODULES = ("test_physical_study.py", "test_demo.py", "test_paper003_study.py", "test_control_loop.py",
                "test_maximum_likelihood.py", "test_table2_time.py", "test_estimator_study.py", "test_cluster_qr.py",
                "test_mujoco_twins.py", "test_stream_plots.py", "test_vendor_urdfs.py", "test_friction.py")


# ---------------------------------------------------------------- make test-robust (tools/robust.py)
# The tests marked ``numerics`` assert on the output of an iterative or solver-based method, or on
# statistics of simulated data. `make test-robust` reruns them under what another machine brings:
# another OpenBLAS kernel, one BLAS thread, numpy without its widest SIMD paths, every solver
# tolerance tightened 100x and loosened 10x (DYNID_SOLVER_TOL_SCALE, dynid.tolerances), and another
# random seed for simulated data (DYNID_TEST_SEED, through seed() below).
SEED_ENV = "DYNID_TEST_SEED"


def draw() -> int:
    """Which draw of the simulated data the tests run on: ``DYNID_TEST_SEED`` (0 when unset: the
    seeds the tests were written with)."""
    k = os.environ.get(SEED_ENV, "").strip()
    return int(k) if k else 0


def seed(base: int) -> int:
    """The seed of a test's simulated data (noise, trajectories, random draws): ``base`` itself,
    or, with ``DYNID_TEST_SEED=k`` (k != 0), a seed drawn from ``(base, k)``
    (:func:`dynid.studies.draw_seed`, as the studies' ``draw``): another draw of the same
    experiment. Every assertion on such data must hold for any draw with a stated small
    probability of a false alarm, not for one seed."""
    from dynid.studies import draw_seed

    return draw_seed(base, draw())


def sdp_norm_slack(norm: float, status: str = "optimal", safety: float = 10.0, factor: float = 1.0,
                   data_norm: float | None = None) -> float:
    """How far above its minimum Clarabel may stop on ``min ||A x - d|| (+ ...)`` (a second-order
    cone program, dynid.estimation.PhysicalLS), in the units of the norm: the duality gap
    ``tol_gap_abs + tol_gap_rel * max(1, norm)`` and the primal residual ``tol_feas * max(1, norm)``
    of the cone constraint on the norm, at which it stops (its ``reduced_`` tolerances for
    ``optimal_inaccurate``; dynid.tolerances, scaled by DYNID_SOLVER_TOL_SCALE). ``safety`` covers
    Clarabel measuring both on its equilibrated (rescaled) problem (a factor of a few); ``factor``
    the stage's ``tolerance_factor`` (a solve retried at looser tolerances, PhysicalLS._solve);
    ``status`` may be the stage's record itself (both read from it, and its ``data_norm``). The
    primal residual is relative to the data (``data_norm``, the norm of the right-hand side: the
    stage records it; default ``norm``), which can be far larger than the optimum's norm."""
    from dynid.tolerances import clarabel_tolerances

    if isinstance(status, dict):  # a solver stage's record: its status, tolerance factor and data norm
        data_norm = status.get("data_norm", data_norm)
        status, factor = status["status"], factor * status.get("tolerance_factor", 1.0)
    data_norm = norm if data_norm is None else max(norm, data_norm)
    t = {k: v * factor for k, v in clarabel_tolerances().items()}
    pre = "reduced_" if status == "optimal_inaccurate" else ""
    return safety * (t[pre + "tol_gap_abs"] + t[pre + "tol_gap_rel"] * max(1.0, norm)
                     + t[pre + "tol_feas"] * max(1.0, data_norm))


def sdp_chi2_slack(norm: float, status: str = "optimal", safety: float = 10.0, factor: float = 1.0) -> float:
    """:func:`sdp_norm_slack` in the units of the squared norm (chi^2 for a whitened problem): a
    norm at most ``g`` above its minimum ``norm`` squares to at most ``(norm + g)^2 - norm^2`` above."""
    g = sdp_norm_slack(norm, status, safety, factor)
    return (norm + g) ** 2 - norm**2


def pytest_report_header(config):
    """What make test-robust perturbs, as this process sees it (BLAS kernels and threads, numpy's
    disabled SIMD features, the solver tolerance scale, the simulated-data seed)."""
    from threadpoolctl import threadpool_info

    from dynid.tolerances import scale

    blas = ", ".join(sorted({f"{i.get('internal_api')} {i.get('architecture')} x{i.get('num_threads')}"
                             for i in threadpool_info() if i.get("user_api") == "blas"}))
    return (f"dynid numerics: BLAS {blas}; NPY_DISABLE_CPU_FEATURES={os.environ.get('NPY_DISABLE_CPU_FEATURES', '')!r}; "
            f"solver tolerance scale {scale():g}; {SEED_ENV}={os.environ.get(SEED_ENV, '0') or '0'}")


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(SLOW_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


def shared_file(*parts: str) -> Path:
    """Path inside ../shared/data, or skip the test when it is not there."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not available: {path} is absent (../shared/data is not beside the checkout)")
    return path


@pytest.fixture
def shared():
    return shared_file


def dynid_command() -> list[str]:
    """The installed ``dynid`` entry point (or ``python -m dynid.cli`` without one)."""
    script = Path(sys.executable).with_name("dynid")
    return [str(script)] if script.exists() else [sys.executable, "-m", "dynid.cli"]


def run_dynid(args: list[str], cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess:
    """``dynid <args>`` as a real process in ``cwd``, on one BLAS thread (callers run several at once)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    # report.html states the date of the run (to the day); two runs compared byte for byte must not
    # straddle midnight: fix it (the reproducible-builds convention dynid honours)
    env.setdefault("SOURCE_DATE_EPOCH", "1767225600")
    return subprocess.run(dynid_command() + args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def snapshot(path: Path) -> dict | None:
    """Every file under ``path`` with its bytes (``{"": bytes}`` for a file; None: absent), to
    check that a refused command left its output folder as it was."""
    if not path.exists():
        return None
    if path.is_file():
        return {"": path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() if p.is_file() else None for p in sorted(path.rglob("*"))}
