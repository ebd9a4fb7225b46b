"""The path a newcomer takes from `dynid design` to `dynid simulate`: the design command ends by
printing the [trajectory] table that replays it, and simulate accepts that table for every kind
of design that design makes (periodic Fourier, rest-to-rest Fourier + quintic, paper 001's
circle, the constant-velocity friction experiment), commanding exactly the designed motion."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from dynid.cli import main

GENERIC6R_DESIGN = """
[robot]
model = "builtin:generic6r"
[design]
harmonics = 2
base_frequency_hz = 0.5
samples = 16
starts = 1
max_iter = 5
{extra}
[limits]
velocity = 1.0
acceleration = 4.0
[output]
rate_hz = 50
plots = false
"""

CIRCLE_DESIGN = """
[robot]
model = "builtin:shang2dof"
[design]
kind = "circle"
centre = [0.29, 0.25]
radius = 0.04
speed = 0.2
turns = 0.5
criterion = "weighted_cond"
samples = 16
[limits]
velocity = 10.0
acceleration = 100.0
[output]
rate_hz = 50
plots = false
"""

TASK_DESIGN = """
[robot]
model = "builtin:rps3"
[design]
coordinates = "task"
harmonics = 1
base_frequency_hz = 1.0
samples = 16
starts = 1
max_iter = 5
[limits]
velocity = 0.5
acceleration = 5.0
[output]
rate_hz = 50
plots = false
"""

CV_DESIGN = """
[robot]
model = "builtin:generic6r"
[design]
kind = "constant_velocity"
joints = ["joint_6"]
speeds = [0.2, 0.5]
window = 1.0
max_window = 1.0
skip = 0.2
[limits]
velocity = 1.0
acceleration = 5.0
[output]
rate_hz = 50
plots = false
"""


def _run(argv: list[str]) -> str:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    assert code == 0, err.getvalue()
    return out.getvalue()


def _csv(path: Path) -> dict[str, np.ndarray]:
    names = path.read_text().split("\n", 1)[0].split(",")
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {n: table[:, k] for k, n in enumerate(names)}


@pytest.mark.parametrize("name, design, model, control, prefix", [
    ("fourier", GENERIC6R_DESIGN.format(extra=""), "builtin:generic6r", 'model = "true"', "u_"),
    ("fourier_quintic", GENERIC6R_DESIGN.format(extra="quintic = true"), "builtin:generic6r", 'model = "true"', "u_"),
    ("circle", CIRCLE_DESIGN, "builtin:shang2dof", 'kp = 35000\nkd = 300\nmodel = "true"', "u_"),
    ("fourier", TASK_DESIGN, "builtin:rps3", 'kp = 2000\nkd = 80\nmodel = "true"', "u_"),  # the platform pose
    ("constant_velocity", CV_DESIGN, "builtin:generic6r", 'model = "true"', "q_"),
])
def test_every_design_kind_is_simulated_from_the_printed_table(tmp_path, name, design, model, control, prefix):
    (tmp_path / "design.toml").write_text(design)
    printed = _run(["design", str(tmp_path / "design.toml"), "--out", str(tmp_path / "d"), "-q"])
    table = printed[printed.index("[trajectory]"):]  # what the command ends with
    assert str((tmp_path / "d" / "design.json").resolve()) in table
    doc = json.loads((tmp_path / "d" / "design.json").read_text())
    assert doc["trajectory"]["kind"] == name
    # the table pasted as it is into a simulate config, the log at the design's sampling rate
    (tmp_path / "sim.toml").write_text(f'[robot]\nmodel = "{model}"\n\n{table}\n[control]\nrate_hz = 200\n{control}\n'
                                       '[sensors]\nlog_rate_hz = 50\n')
    _run(["simulate", str(tmp_path / "sim.toml"), "--out", str(tmp_path / "s"), "-q"])
    log, designed = _csv(tmp_path / "s" / "log.csv"), _csv(tmp_path / "d" / "trajectory.csv")
    coords = [c[len(prefix):] for c in designed if c.startswith(prefix)]
    n = min(log["t"].size, designed["t"].size)
    assert n >= designed["t"].size - 1  # the whole design is commanded (a periodic one's end is its start)
    # the same instants (k / 50 s, up to the rounding of k * dt) and the same commanded motion: both are the
    # design's formula at those instants, so they agree to rounding (1e-10 of a motion of order 1)
    np.testing.assert_allclose(log["t"][:n], designed["t"][:n], rtol=0, atol=1e-12)
    for c in coords:
        np.testing.assert_allclose(log[f"ref_{c}"][:n], designed[f"{prefix}{c}"][:n], rtol=0, atol=1e-10, err_msg=c)


def test_a_design_file_sets_its_own_trajectory(tmp_path):
    """The design file decides what it replays: its rest-to-rest quintic is not a simulate key then,
    a circle design takes no circle keys beside it, and a design given to the other kind says which
    kind replays it."""
    from dynid.config.simulate import parse_simulate_config
    from dynid.errors import ConfigError
    from dynid.pipeline.simulate import run_simulation

    robot = {"model": "builtin:shang2dof"}
    with pytest.raises(ConfigError, match="the design file says whether its excitation is rest-to-rest"):
        parse_simulate_config({"robot": robot, "trajectory": {"kind": "fourier", "design": "d.json", "quintic": True}},
                              tmp_path)
    with pytest.raises(ConfigError, match=r"\['radius'\] are set by the design file"):
        parse_simulate_config({"robot": robot, "trajectory": {"kind": "circle", "design": "d.json", "radius": 0.1}},
                              tmp_path)
    (tmp_path / "design.toml").write_text(CIRCLE_DESIGN)
    _run(["design", str(tmp_path / "design.toml"), "--out", str(tmp_path / "d"), "-q"])
    cfg = parse_simulate_config({"robot": robot, "trajectory": {"kind": "fourier", "design": "d/design.json"}}, tmp_path)
    with pytest.raises(ConfigError, match="a 'circle' design; trajectory.kind = 'fourier' replays fourier or "
                                          "fourier_quintic designs; replay it with trajectory.kind = 'circle'"):
        run_simulation(cfg)
