"""bench/vs_figaroh.py without FIGAROH: its one-line errors (exit 2) and its per-process peak memory.

FIGAROH never enters the test suite: these checks stop before the FIGAROH environment is used, or
measure plain Python children.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "bench" / "vs_figaroh.py"
sys.path.insert(0, str(REPO / "bench"))


def _run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=cwd, timeout=60)


def _one_line_error(proc: subprocess.CompletedProcess, words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vs_figaroh.py: error: "), proc.stderr
    assert words in lines[0]
    assert "Traceback" not in proc.stderr


def _fake_tx40(tmp_path: Path) -> Path:
    data = tmp_path / "tx40"
    data.mkdir()
    for name in ("pos_read_data.csv", "curr_data.csv", "tx40_mdh_modified.urdf", "figaroh_TX40_config.yaml"):
        (data / name).write_text("x\n")
    return data


def test_bad_arguments_one_line(tmp_path):
    _one_line_error(_run("--repeats", "0"), "--repeats")
    _one_line_error(_run("--blas-threads", "0"), "--blas-threads")
    _one_line_error(_run("--data", str(tmp_path)), "TX40 data not found")


def test_figaroh_environment_stays_outside_repo(tmp_path):
    data = _fake_tx40(tmp_path)
    _one_line_error(_run("--data", str(data), "--figaroh-venv", str(REPO / "bench" / "figaroh-venv")),
                    "inside the repository")
    assert not (REPO / "bench" / "figaroh-venv").exists()


def test_unusable_environment_is_refused_not_replaced(tmp_path):
    # a folder that is not a FIGAROH 1.0.2 environment: refused in one line, left as it is
    data = _fake_tx40(tmp_path)
    venv = tmp_path / "venv"
    venv.mkdir()
    (venv / "keep.txt").write_text("mine")
    _one_line_error(_run("--data", str(data), "--figaroh-venv", str(venv)), "does not hold figaroh 1.0.2")
    assert [p.name for p in venv.iterdir()] == ["keep.txt"]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="VmHWM needs Linux /proc")
def test_peak_memory_is_the_child_own(tmp_path):
    # the parent holds ~300 MB; a child that touches ~80 MB must report its own peak, not the
    # parent's (ru_maxrss after fork + exec would start at the parent's peak)
    import numpy as np
    from vs_figaroh import run_measured

    ballast = np.ones(300 * 2**20 // 8)
    script = tmp_path / "child.py"
    script.write_text("import sys\nb = bytearray(int(sys.argv[1]) * 2**20)\nb[::4096] = b'x' * len(b[::4096])\n")
    small = run_measured(sys.executable, [str(script), "1"], {"PATH": "/usr/bin:/bin"}, tmp_path, "small")
    big = run_measured(sys.executable, [str(script), "80"], {"PATH": "/usr/bin:/bin"}, tmp_path, "big")
    assert ballast.sum() > 0
    assert small["peak_mb"] < 100, small  # a bare interpreter: ~10 MB, far below the parent's 300 MB
    # the 80 MB buffer shows up in full, on top of the bare interpreter (page size granularity)
    assert 78 < big["peak_mb"] - small["peak_mb"] < 90, (small, big)
    assert big["wall_s"] > 0


def test_no_package_index_is_one_line_exit_2(tmp_path):
    # pip without any index (as without network): the venv cannot be made; one line, exit 2, and
    # the half-made environment is removed
    data = _fake_tx40(tmp_path)
    venv = tmp_path / "figaroh-venv"
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PIP_NO_INDEX": "1", "PIP_FIND_LINKS": str(tmp_path),
           "PIP_CONFIG_FILE": "/dev/null"}
    proc = subprocess.run([sys.executable, str(SCRIPT), "--data", str(data), "--figaroh-venv", str(venv)],
                          capture_output=True, text=True, env=env, timeout=120)
    _one_line_error(proc, "cannot make FIGAROH's virtual environment")
    assert "pip install figaroh==1.0.2 failed" in proc.stderr
    assert not venv.exists()


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="VmRSS needs Linux /proc")
def test_tree_memory_counts_a_child_process(tmp_path):
    # --plot-worker's memory: a measured process that starts a child holding 120 MB while it holds
    # 60 MB itself, both for 0.5 s (100 sampling periods of 5 ms: the sampler cannot miss it). The
    # process's own VmHWM sees its 60 MB only; the tree's sampled peak sees both buffers (page-size
    # granularity; two bare interpreters ~10-30 MB on top).
    from vs_figaroh import run_measured

    child = ("import sys, time\nb = bytearray(120 * 2**20)\nb[::4096] = b'x' * len(b[::4096])\n"
             "sys.stdout.write('up\\n'); sys.stdout.flush(); time.sleep(0.5)\n")
    script = tmp_path / "parent.py"
    script.write_text("import subprocess, sys\nb = bytearray(60 * 2**20)\nb[::4096] = b'x' * len(b[::4096])\n"
                      f"p = subprocess.Popen([sys.executable, '-c', {child!r}], stdout=subprocess.PIPE)\n"
                      "p.stdout.readline(); p.wait()\n")
    res = run_measured(sys.executable, [str(script)], {"PATH": "/usr/bin:/bin"}, tmp_path, "tree", tree=True)
    assert 58 < res["peak_mb"] < 100, res  # the parent's own peak: its 60 MB, not the child's
    assert res["processes"] >= 2, res
    assert 178 < res["tree_mb"] < 240, res  # 60 + 120 MB held at once, plus two interpreters
