"""Several experiments in one identification: ``[[data]]`` / ``[[validation]]`` (issue 35 item 1).

Two virtual experiments of the serial arm arm3 (its URDF's parameters perturbed by 10 %: the truth) under
computed torque, logged with their exact states (derivatives "measured") and efforts with different noise
levels (0.02 and 0.4 N*m). The [[data]] estimate must be the WLS of the two experiments' rows stacked with a
weight per (experiment, joint) from the pooled OLS residuals, computed here with dense numpy rows; the truth
must lie within the reported 95 % intervals; the naive concatenation of the two logs, filtered across the join,
must give another estimate; the pooled held-out table must be the row-weighted mean of the per-log MSEs;
methods that cannot stack experiments refuse them in one line.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import seed
from scipy import stats

from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError
from dynid.pipeline import identify
from dynid.pipeline.data import build_system
from dynid.pipeline.simulate import run_simulation

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "examples" / "several_logs" / "arm3.urdf"
SIGMAS = (0.02, 0.4)  # N*m: a clean and a noisy log
JOINTS = ("j1", "j2", "j3")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("several")
    rng = np.random.default_rng(seed(35))
    truth = None
    names = {}
    for name, k, sigma in (("a", 1, SIGMAS[0]), ("b", 2, SIGMAS[1]), ("va", 3, SIGMAS[0]), ("vb", 4, SIGMAS[1])):
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": str(URDF), "rotor_inertia": [0.05, 0.04, 0.02], "perturbation": 0.1,
                      "perturbation_seed": 1},
            "trajectory": {"kind": "fourier", "base_frequency_hz": 0.2, "harmonics": 3, "fill": 0.5,
                           "max_velocity": 1.5, "max_acceleration": 6.0, "periods": 1, "seed": seed(k)},
            "control": {"rate_hz": 200, "kp": 400, "kd": 40, "model": "true"},
        }, d))
        m = sim.motion
        truth = sim.truth
        cols = {"t": m.t}
        for j, jn in enumerate(JOINTS):
            cols[f"q_{jn}"], cols[f"dq_{jn}"], cols[f"ddq_{jn}"] = m.q[:, j], m.dq[:, j], m.ddq[:, j]
            cols[f"tau_{jn}"] = m.tau[:, j] + sigma * rng.standard_normal(len(m.t))
        save_npz(d / f"{name}.npz", cols)
        names[name] = cols
    return d, truth, names


def _table(path) -> dict:
    sig = lambda p: {"columns": [f"{p}_{j}" for j in JOINTS]}  # noqa: E731
    return {"file": str(path), "time": {"column": "t"}, "position": sig("q"), "velocity": sig("dq"),
            "acceleration": sig("ddq"), "effort": sig("tau")}


def _doc(d, **identification) -> dict:
    return {"robot": {"model": str(URDF), "rotor_inertia": [0.05, 0.04, 0.02]},
            "data": [_table(d / "a.npz"), {**_table(d / "b.npz"), "payload": False}],
            "validation": [_table(d / "va.npz"), _table(d / "vb.npz")],
            "processing": {"derivatives": "measured", "trim_samples": 0},
            "identification": {"method": "wls", **identification}, "output": {"plots": False}}


def test_smoke(logs):
    d, truth, _ = logs
    out = identify(parse_config(_doc(d), d))
    print(out.summary_text())
