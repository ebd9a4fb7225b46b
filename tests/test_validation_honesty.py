"""Honest validation: a copy of the training log is refused as held-out data, and a validation
motion that retraces the training motion is called in-sample, in the summary and in result.json.

The logs are a generic 6R arm along a periodic Fourier excitation (period 10 s) with white
torque noise; the repeated-motion case is the classic trap: training on the first periods and
"validating" on the last one of the same periodic excitation.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from dynid.config import parse_config
from dynid.errors import InputError
from dynid.model import load_robot
from dynid.pipeline import identify, write_outputs
from dynid.simulation import FourierTrajectory, simulate_serial
from dynid.stats import REPEAT_THRESHOLD, nearest_distances

ROBOT = load_robot("builtin:generic6r")
FS = 100.0
Q = [f"q{j}" for j in range(1, 7)]
TAU = [f"tau{j}" for j in range(1, 7)]


def _log(path, seed: int, periods: float):
    rng = np.random.default_rng(seed)
    lo, hi = ROBOT.position_limits()
    traj = FourierTrajectory.random(6, 4, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    sim = simulate_serial(ROBOT, ROBOT.nominal_parameters(), traj, fs=FS, duration=periods * traj.period,
                          torque_noise_std=np.array([0.5, 0.5, 0.3, 0.05, 0.05, 0.03]), position_noise_std=1e-5, rng=rng)
    np.savetxt(path, np.column_stack([sim.t, sim.q, sim.tau]), delimiter=",", header=",".join(["t", *Q, *TAU]),
               comments="", fmt="%.17g")
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("honesty")
    _log(d / "periodic.csv", seed=3, periods=4)  # 40 s: four periods of one excitation
    _log(d / "other.csv", seed=4, periods=1)  # another excitation
    shutil.copyfile(d / "periodic.csv", d / "copy_of_periodic.csv")
    return d


def _doc(train_rows, validation: dict) -> dict:
    return {
        "robot": {"model": "builtin:generic6r"},
        "data": {"file": "periodic.csv", "time": {"column": "t"}, "position": {"columns": Q}, "effort": {"columns": TAU},
                 "rows": train_rows},
        "validation": validation,
        "processing": {"lowpass": {"cutoff_hz": 5.0, "order": 4, "filter_effort": False}},
        "identification": {"method": "ols"},
        "output": {"plots": False},
    }


def test_nearest_distances_in_training_standard_deviations():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((500, 3)) * [1.0, 10.0, 0.1]
    # |a|^2 + |b|^2 - 2 a.b cancels to rounding: ~sqrt(eps * |a|^2) ~ 1e-7 for unit-scaled rows
    assert np.all(nearest_distances(a, a) < 1e-6)
    shifted = a + 0.5 * a.std(axis=0)  # every channel moved by half its standard deviation
    d = nearest_distances(a, shifted[:50])
    assert np.all(d <= np.sqrt(3) * 0.5 + 1e-12)  # a bound: the shifted point's own origin
    far = np.full((4, 3), 100.0) * a.std(axis=0)
    assert np.all(nearest_distances(a, far) > 90)
    with pytest.raises(InputError):
        nearest_distances(a, a[:, :2])


def test_a_copy_of_the_training_log_is_refused(logs):
    doc = _doc([0, 3000], {"file": "copy_of_periodic.csv", "rows": [2000, 4000]})
    with pytest.raises(InputError, match="same content \\(SHA-256\\) as the training log") as exc:
        identify(parse_config(doc, logs))
    assert "copy_of_periodic.csv = periodic.csv" in str(exc.value) and "\n" not in str(exc.value)
    # the same copy over a window that training does not use is held-out data (the samples differ)
    doc = _doc([0, 3000], {"file": "copy_of_periodic.csv", "rows": [3000, 4000]})
    assert identify(parse_config(doc, logs)).validation.n_samples > 0


def test_the_copy_is_refused_on_the_command_line_in_one_line(logs, tmp_path):
    doc = _doc([0, 3000], {"file": "copy_of_periodic.csv"})
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(_toml(doc, logs))
    exe = [sys.executable, "-m", "dynid.cli"]
    r = subprocess.run(exe + ["identify", str(cfg), "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith("dynid: error: validation:"), r.stderr
    assert not (tmp_path / "out").exists()


def _toml(doc: dict, folder) -> str:
    d = doc["data"]
    v = doc["validation"]
    val = f'file = "{folder / v["file"]}"' + (f'\nrows = {v["rows"]}' if "rows" in v else "")
    return f"""[robot]
model = "builtin:generic6r"
[data]
file = "{folder / d['file']}"
time = {{ column = "t" }}
position = {{ columns = {json.dumps(Q)} }}
effort = {{ columns = {json.dumps(TAU)} }}
rows = {d['rows']}
[validation]
{val}
[processing]
lowpass = {{ cutoff_hz = 5.0, order = 4, filter_effort = false }}
[identification]
method = "ols"
[output]
plots = false
"""


def test_the_last_period_of_a_periodic_excitation_is_in_sample(logs, tmp_path):
    """Train on periods 1-3, validate on period 4 of the same excitation: the configuration is
    legal (no sample is shared) but the motion is the training motion again."""
    o = identify(parse_config(_doc([0, 3000], {"rows": [3000, 4000]}), logs))
    ov = o.validation.overlap
    assert o.validation.in_sample and o.validation.label == "in-sample"
    assert ov["repeats_training"] and ov["median_distance"] < REPEAT_THRESHOLD
    assert "IN-SAMPLE" in o.summary_text() and "held-out data" not in o.summary_text()
    write_outputs(o, tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    assert doc["validation"]["kind"] == "in-sample" and doc["validation"]["motion_overlap"]["repeats_training"]
    assert "repeats the training motion" in doc["validation"]["warning"]
    assert "IN-SAMPLE" in (tmp_path / "out" / "summary.txt").read_text()


def test_another_trajectory_is_held_out(logs, tmp_path):
    o = identify(parse_config(_doc([0, 3000], {"file": "other.csv"}), logs))
    ov = o.validation.overlap
    assert not o.validation.in_sample and o.validation.label == "held-out"
    # a new excitation lies of the order of a standard deviation away, far above the threshold
    assert ov["median_distance"] > 4 * REPEAT_THRESHOLD, ov
    assert "Validation on held-out data" in o.summary_text()
    write_outputs(o, tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    assert doc["validation"]["kind"] == "held-out" and "warning" not in doc["validation"]
