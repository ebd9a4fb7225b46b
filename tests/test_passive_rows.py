"""``processing.min_velocity_passive``: samples where a passive joint with Coulomb friction sticks
or reverses are left out (issue 17, item 2). The hexapod's cardan joints share two dry-friction
coefficients (``fc_alpha``, ``fc_beta``; paper 002); a virtual hexapod is logged with its exact
actuator states, and the rows kept are counted independently from the simulator's own joint
velocities.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError
from dynid.model.loading import load_model
from dynid.model.system import as_system
from dynid.pipeline import identify
from dynid.pipeline.simulate import run_simulation

LEGS = [f"P{j}" for j in range(1, 7)]


def _log(d, name: str, seed: int):
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": "builtin:hexapod", "perturbation": 0.1, "perturbation_seed": 2},
        "trajectory": {"coordinates": "task", "kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3,
                       "fill": 0.15, "max_velocity": 0.3, "max_acceleration": 3.0, "seed": seed},
        "control": {"rate_hz": 250, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
    }, d))
    m = sim.motion
    mech = load_model("builtin:hexapod")
    act = list(mech.actuated)
    rng = np.random.default_rng(seed)
    cols = {"t": m.t}
    for k, leg in enumerate(LEGS):
        j = act[k]
        cols[f"q_{leg}"], cols[f"dq_{leg}"], cols[f"ddq_{leg}"] = m.q[:, j], m.dq[:, j], m.ddq[:, j]
        cols[f"tau_{leg}"] = m.tau_a[:, k] + 2.0 * rng.standard_normal(m.t.size)
    save_npz(d / f"{name}.npz", cols)
    return m


def _doc(d, **processing) -> dict:
    sig = lambda p, unit, **kw: {"columns": [f"{p}_{leg}" for leg in LEGS], "unit": unit, **kw}  # noqa: E731
    return {
        "robot": {"model": "builtin:hexapod"},
        "data": {"file": str(d / "train.npz"), "time": {"column": "t"}, "position": sig("q", "m"),
                 "velocity": sig("dq", "m"), "acceleration": sig("ddq", "m"), "effort": sig("tau", "N", kind="torque")},
        "validation": {"file": str(d / "valid.npz")},
        "processing": {"derivatives": "measured", "trim_samples": 0, **processing},
        "identification": {"method": "wls"},
        "output": {"plots": False},
    }


@pytest.fixture(scope="module")
def hexapod_logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("passive")
    motion = _log(d, "train", 1)
    _log(d, "valid", 2)
    return d, motion


def test_slow_passive_joints_leave_their_samples_out(hexapod_logs):
    d, motion = hexapod_logs
    system = as_system(load_model("builtin:hexapod"))
    passive = list(system.passive_friction_joints())
    names = system.model.joint_names
    assert [names[j] for j in passive] == [f"{x}{k}" for k in range(1, 7) for x in "ab"]
    full = identify(parse_config(_doc(d), d))
    thr = 0.02  # rad/s
    out = identify(parse_config(_doc(d, min_velocity_passive=thr), d))
    # independent count: the simulator's own velocities of the twelve cardan joints
    moving = np.all(np.abs(motion.dq[:, passive]) >= thr, axis=1)
    assert 0 < moving.sum() < motion.t.size
    assert out.result.n_obs.tolist() == [int(moving.sum())] * 6
    assert full.result.n_obs.tolist() == [motion.t.size] * 6
    sel = out.result.provenance["row_selection"]
    assert sel["min_velocity_passive"] == thr and sel["passive_joints"] == [names[j] for j in passive]


def test_min_velocity_passive_needs_passive_coulomb_joints(hexapod_logs, tmp_path):
    d, _ = hexapod_logs
    doc = _doc(d, min_velocity_passive=0.02)
    doc["robot"] = {"model": "builtin:rps3"}
    with pytest.raises(ConfigError, match="no Coulomb term on a passive joint"):
        identify(parse_config(doc, d))
    doc["robot"] = {"model": "builtin:cobot6r"}
    with pytest.raises(ConfigError, match="a serial arm has no passive joint"):
        identify(parse_config(doc, d))
