"""Staubli TX40, FIGAROH's real log (../shared/data/tx40): estimates against FIGAROH's reference
OLS values, and held-out torque RMSE against FIGAROH's published figures.

Parameterization: dynid models the coupled wrist physically (motor 6 turns with q5 + q6, its
inertia and friction act on both joints: Iam6, fvm6, fcm6 on the motor velocity q5' + q6'),
with joint-side Ia, fv, fc on every joint. FIGAROH's model spans the same columns except a
joint-6 rotor term, written differently: its fv5 is the total viscous coefficient of q5' in
joint 5's equation, which in dynid's terms is fv5 + fvm6 (likewise fv6 + fvm6, Ia5 + Iam6).
Coulomb terms and fvm6, fcm6 coincide directly.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest
from _realdata import example_config, example_text, show, table
from conftest import shared_file

from dynid.estimation import OLS
from dynid.model import robot_base_parameters
from dynid.pipeline.data import build_robot, preprocess, read_log, to_joint_space
from dynid.pipeline.identification import build_problem

pytestmark = pytest.mark.realdata

REF_FV = [8.107, 5.601, 1.978, 1.107, 1.858, 0.644]
REF_FC = [6.967, 8.123, 6.307, 2.484, 3.026, 0.244]
REF_IA = {"Ia3": 0.0921, "Ia4": 0.0318, "Ia5": 0.0436}
REF_MOTOR = {"fvm6": 0.597, "fcm6": 2.033}
REF_RMSE = [6.64, 8.32, 4.28, 1.80, 2.65, 1.72]


@pytest.fixture(scope="module")
def tx40_files():
    for f in ("pos_read_data.csv", "curr_data.csv", "tx40_mdh_modified.urdf"):
        shared_file("tx40", f)


def test_tx40_parameters_match_figaroh(tx40_files, capsys):
    # FIGAROH's reference values come from the whole log: identify on all 45 000 rows
    cfg = example_config("tx40")
    cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, rows=None))
    robot = build_robot(cfg.robot)
    raw = read_log(cfg.data, robot.dof, robot.joint_names, "data")
    assert raw.n_samples == 45000
    ds, _ = to_joint_space(raw, robot, "data")
    ds, _ = preprocess(ds, cfg.processing, "data")
    base = robot_base_parameters(robot)
    assert base.n_base == 61  # FIGAROH's 60 + the joint-6 rotor inertia, same groupings
    problem = build_problem(robot, base, ds, min_velocity=cfg.processing.min_velocity, parallel_decimate=100)
    res = OLS().fit(problem)
    # dynid's value of each compared quantity as a linear combination c of its base parameters
    combos = {f"fv{j}": {f"fv{j}": 1.0} for j in range(1, 5)}
    combos |= {"fv5": {"fv5": 1.0, "fvm6": 1.0}, "fv6": {"fv6": 1.0, "fvm6": 1.0}}
    combos |= {f"fc{j}": {f"fc{j}": 1.0} for j in range(1, 7)}
    combos |= {"Ia3": {"Ia3": 1.0}, "Ia4": {"Ia4": 1.0}, "Ia5": {"Ia5": 1.0, "Iam6": 1.0}}
    combos |= {"fvm6": {"fvm6": 1.0}, "fcm6": {"fcm6": 1.0}}
    ref = {f"fv{j + 1}": v for j, v in enumerate(REF_FV)} | {f"fc{j + 1}": v for j, v in enumerate(REF_FC)}
    ref |= REF_IA | REF_MOTOR
    rows, worst = [], {}
    for name, r in ref.items():
        c = np.zeros(len(res.names))
        for n, w in combos[name].items():
            c[res.names.index(n)] = w
        value, std = float(c @ res.params), float(np.sqrt(c @ res.cov_params @ c))
        worst[name] = abs(100 * (value / r - 1))
        rows.append([name, f"{r:.4g}", f"{value:.4g}", f"{100 * (value / r - 1):+.1f}", f"{std:.3g}", f"{(r - value) / std:+.2f}"])
    show(capsys, table("TX40: dynid OLS (whole log) vs FIGAROH reference OLS", ["param", "FIGAROH", "dynid", "dev %", "dynid std", "z"], rows))
    for name in ref:
        limit = 10.0 if name.startswith("Ia") else 5.0
        assert worst[name] < limit, f"{name} deviates {worst[name]:.1f} % from FIGAROH's {ref[name]}"


def test_tx40_held_out_rmse_no_worse_than_figaroh(tx40_files, capsys, tmp_path):
    # the real command line on the example configuration
    cfg_path = tmp_path / "tx40.toml"
    cfg_path.write_text(example_text("tx40") + "\n[output]\nplots = false\n")
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "dynid.cli", "identify", str(cfg_path), "--out", str(out), "-q"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "result.json").read_text())
    assert doc["method"] == "OLS"
    assert example_config("tx40").validation.rows == (29250, 45000)
    # like for like: FIGAROH's published figures score every held-out sample at the log's 5 kHz
    full = doc["validation_full_rate"]["identified"]
    assert doc["validation_full_rate"]["decimate_in_fit"] == 100
    assert full["n_samples"] > 15000  # rows 29250-45000 less the filter's trim
    rmse = np.array(full["rmse_per_joint"])
    dec = np.array(doc["validation"]["rmse_per_joint"])
    assert doc["validation"]["n_samples"] > 100
    smoothing = doc["provenance"]["coulomb_smoothing"]
    assert smoothing["source"].startswith("auto") and all(0 < w < 0.01 for w in smoothing["width"])
    rows = [[f"joint {j + 1}", f"{REF_RMSE[j]:.2f}", f"{rmse[j]:.2f}", f"{dec[j]:.2f}"] for j in range(6)]
    show(capsys, table("TX40 held-out torque RMSE [N*m] (train rows 0-24750, validate 29250-45000)",
                       ["joint", "FIGAROH (full rate)", "dynid full rate", "dynid decimated x100"], rows))
    assert np.all(rmse <= np.array(REF_RMSE)), f"dynid full-rate RMSE {rmse} exceeds FIGAROH's {REF_RMSE}"
