"""The report's figures drawn in a worker process
(:mod:`dynid.report.worker`, issue 20 item 8) give the same files as drawn in process, and a
failure there ends the run as one line, with no output.

- a PUMA 560 twin logged with its exact states and noise-free torques, identified with plots,
  once with ``DYNID_PLOT_WORKER=0`` (in process) and once with ``1`` (worker): processing.png,
  validation.png, report.html and result.json (the physical-consistency flags included) are the
  same bytes;
- a figure that fails in the worker: ``dynid: error: ...`` on one line, status 2, no output folder;
  a worker that dies: a :class:`~dynid.errors.DynidError` naming the job, not a hang;
- the worker runs nothing of the caller's ``__main__`` (a script without a main guard runs once);
- by default the worker is used only with a second CPU idle (one-minute load average);
- the numpy frequency response the processing figure draws equals ``scipy.signal.sosfreqz``'s to
  rounding (the same polynomials evaluated in another order).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from dynid.errors import DynidError
from dynid.model import load_robot
from dynid.report.worker import InProcessJobs, WorkerJobs, report_jobs
from dynid.simulation import FourierTrajectory, simulate_serial

pytest.importorskip("matplotlib")

JOINTS = 6
FS = 100.0
Q = [f"q{j + 1}" for j in range(JOINTS)]
TAU = [f"tau{j + 1}" for j in range(JOINTS)]


@pytest.fixture(scope="module")
def config(tmp_path_factory) -> Path:
    robot = load_robot("builtin:puma560")
    truth = robot.nominal_parameters()
    rng = np.random.default_rng(8)
    lo, hi = robot.position_limits()
    folder = tmp_path_factory.mktemp("worker")
    for name, seconds in (("train", 20.0), ("valid", 8.0)):
        traj = FourierTrajectory.random(JOINTS, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
        sim = simulate_serial(robot, truth, traj, duration=seconds, fs=FS, torque_noise_std=0.0, rng=rng)
        np.savez(folder / f"{name}.npz", t=sim.t, **{k: sim.q[:, j] for j, k in enumerate(Q)},
                 **{k: sim.tau[:, j] for j, k in enumerate(TAU)})
    cfg = folder / "cfg.toml"
    cfg.write_text(f"""\
[robot]
model = "builtin:puma560"

[data]
file = "{(folder / 'train.npz').as_posix()}"
time = {{ column = "t", unit = "s" }}
position = {{ columns = {json.dumps(Q)}, unit = "rad" }}
effort = {{ columns = {json.dumps(TAU)}, kind = "torque", unit = "N*m" }}

[validation]
file = "{(folder / 'valid.npz').as_posix()}"

[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
derivatives = "central"

[identification]
method = "ols"
""")
    return cfg


def _run(cfg: Path, out: Path, worker: str, monkeypatch, capsys) -> int:
    from dynid.cli import main

    monkeypatch.setenv("DYNID_PLOT_WORKER", worker)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764000000")  # the report's date: the same for both runs
    rc = main(["identify", str(cfg), "--out", str(out), "-q"])
    capsys.readouterr()
    return rc


def test_worker_writes_the_same_files_as_in_process(config, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DYNID_PLOT_WORKER", "0")
    assert type(report_jobs()) is InProcessJobs
    monkeypatch.setenv("DYNID_PLOT_WORKER", "1")
    jobs = report_jobs()
    assert type(jobs) is WorkerJobs
    jobs.close()
    assert _run(config, tmp_path / "inproc", "0", monkeypatch, capsys) == 0
    assert _run(config, tmp_path / "worker", "1", monkeypatch, capsys) == 0
    for name in ("processing.png", "validation.png", "report.html", "result.json", "params.csv"):
        a, b = (tmp_path / "inproc" / name).read_bytes(), (tmp_path / "worker" / name).read_bytes()
        assert a == b, f"{name} differs between in-process and worker rendering"
    flags = json.loads((tmp_path / "worker" / "result.json").read_text())["parameter_flags"]["physical"]
    if flags["checked"]:  # cvxpy installed: noise-free torques of the true (CAD) parameters are consistent
        assert flags["feasible"] is True, flags
    else:
        assert "cvxpy" in flags["reason"], flags


def test_failure_in_the_worker_is_one_line_and_leaves_no_output(config, tmp_path, monkeypatch, capsys):
    from dynid.cli import main
    from dynid.pipeline import identification

    # the validation figure gets data it cannot draw: the worker's AttributeError must come back
    monkeypatch.setattr(identification, "_validation_series", lambda v: SimpleNamespace(t=v.t))
    monkeypatch.setenv("DYNID_PLOT_WORKER", "1")
    out = tmp_path / "nested" / "out"
    rc = main(["identify", str(config), "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dynid: error: validation.png failed in the plot worker: "
                                                   "AttributeError"), err
    assert "Traceback" not in err
    assert not out.exists() and not out.parent.exists()


def test_a_dead_worker_is_an_error_not_a_hang():
    jobs = WorkerJobs()
    try:
        jobs.submit_call("root", "math:sqrt", 6.25)
        assert jobs.result("root") == 2.5
        jobs._proc.kill()
        jobs._proc.wait()
        jobs.submit_call("again", "math:sqrt", 4.0)
        with pytest.raises(DynidError, match="ended before it sent again"):
            jobs.result("again")
    finally:
        jobs.close()
    assert not jobs._folder.exists()


def test_worker_does_not_run_the_callers_main(tmp_path):
    marker = tmp_path / "ran.txt"
    script = tmp_path / "no_guard.py"
    script.write_text(f"""\
from pathlib import Path
with open({str(marker)!r}, "a") as fh:
    fh.write("x")
from dynid.report.worker import WorkerJobs
jobs = WorkerJobs()
jobs.submit_call("r", "math:sqrt", 9.0)
print(jobs.result("r"))
jobs.close()
""")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "3.0"
    assert marker.read_text() == "x"


def test_bad_worker_setting_is_an_error(monkeypatch):
    monkeypatch.setenv("DYNID_PLOT_WORKER", "yes")
    with pytest.raises(DynidError, match="DYNID_PLOT_WORKER must be 0 or 1"):
        report_jobs()


@pytest.mark.parametrize("order, cutoff, fs", [(4, 10.0, 100.0), (8, 20.0, 5000.0), (4, 25.0, 5000.0)])
def test_filter_gain_matches_scipy(order, cutoff, fs):
    from scipy import signal
    from dynid.report.plots import _sos_power_gain
    from dynid.signals import butter_sos

    sos = butter_sos(order, cutoff, fs)
    f = np.geomspace(0.01, 0.5 * fs * 0.999, 400)
    _, h = signal.sosfreqz(sos, worN=f, fs=fs)
    ref = np.abs(h) ** 2
    got = _sos_power_gain(sos, f, fs)
    # |H|^2 spans ~1 to ~1e-30 over these frequencies: agreement relative to each value, to the
    # rounding of a product of `order/2` ratios of quadratics near the unit circle (poles close to it)
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-300)
    assert abs(_sos_power_gain(sos, [cutoff], fs)[0] - 0.5) < 1e-9  # |H|^2 = 1/2 at the cut-off (Butterworth)


@pytest.mark.parametrize("cpus, load, worker", [(1, 0.0, False), (2, 1.5, False), (2, 0.3, True), (8, 6.5, True)])
def test_worker_only_with_an_idle_cpu(monkeypatch, cpus, load, worker):
    import os

    monkeypatch.delenv("DYNID_PLOT_WORKER", raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cpus)), raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    jobs = report_jobs()
    try:
        assert (type(jobs) is WorkerJobs) == worker
    finally:
        jobs.close()
