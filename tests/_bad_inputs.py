"""The known-good inputs that each case of tests/test_bad_inputs.py changes in one place, and the
check of a refusal: a two-joint revolute + prismatic robot in a DH table, a 3 s log of it, and a
good configuration of each command (identify, simulate, design, montecarlo), all written into the
case's folder by :class:`Work`; a URDF and an MJCF five-bar for ``dynid info``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import snapshot


ROBOT = """\
name = "rp2"
convention = "modified"
gravity = [0.0, 0.0, -9.81]

[[joints]]
name = "shoulder"
alpha = "pi/2"
a = 0.0
d = 0.0
lower = -2.5
upper = 2.5
mass = 2.0
com = [0.1, 0.0, 0.0]
inertia = [0.01, 0.02, 0.02, 0.0, 0.0, 0.0]
fv = 0.5
fc = 0.3

[[joints]]
name = "slide"
type = "prismatic"
alpha = "-pi/2"
a = 0.3
d = 0.0
lower = 0.1
upper = 0.5
mass = 1.0
com = [0.0, 0.0, 0.05]
inertia = [0.005, 0.005, 0.002, 0.0, 0.0, 0.0]
fv = 2.0
fc = 1.0
"""

IDENTIFY = """\
[robot]
model = "rp2.toml"

[data]
file = "log.csv"
time = { column = "t", unit = "s" }
rows = [0, 240]
position = { columns = ["q1", "q2"], unit = ["rad", "m"] }
effort = { columns = ["tau1", "tau2"], unit = ["N*m", "N"] }

[validation]
rows = [240, 300]

[processing]
lowpass = { cutoff_hz = 10.0, order = 2, filter_effort = false }

[identification]
method = "ols"
min_joint_motion = 0.001

[output]
plots = false
"""

SIMULATE = """\
[robot]
model = "rp2.toml"
perturbation = 0.05

[trajectory]
kind = "fourier"
base_frequency_hz = 1.0
harmonics = 2
seed = 1

[control]
kind = "computed_torque"
rate_hz = 100
kp = 100
kd = 20

[sensors]
force_noise_std = 0.01
position_noise_std = 0.0
seed = 1

[simulation]
duration = 0.5

[output]
format = "csv"
"""

DESIGN = """\
[robot]
model = "rp2.toml"

[design]
criterion = "cond"
harmonics = 1
base_frequency_hz = 0.5
samples = 8
starts = 1
max_iter = 3
seed = 1

[limits]
velocity = 2.0
acceleration = 10.0

[output]
rate_hz = 20
plots = false
"""

MONTECARLO = """\
[simulate]
file = "sim.toml"

[identify.identification]
method = "ols"

[montecarlo]
trials = 2
workers = 1
alpha = 0.05
"""

URDF = """\
<robot name="arm">
  <link name="base"/>
  <link name="upper"><inertial><mass value="1.5"/><inertia ixx="0.02" iyy="0.02" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
</robot>
"""

FIVEBAR = """\
<mujoco model="fivebar">
  <worldbody>
    <body name="base">
      <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
      <body name="prox1" pos="-0.15 0 0">
        <joint name="qa1" type="hinge" axis="0 1 0"/>
        <inertial pos="-0.06 0 0.08" mass="0.5" diaginertia="0.002 0.002 0.0002"/>
        <body name="dist1" pos="-0.12 0 0.16">
          <joint name="qb1" type="hinge" axis="0 1 0"/>
          <inertial pos="0.135 0 0.18" mass="0.35" diaginertia="0.006 0.006 0.0002"/>
        </body>
      </body>
      <body name="prox2" pos="0.15 0 0">
        <joint name="qa2" type="hinge" axis="0 1 0"/>
        <inertial pos="0.06 0 0.08" mass="0.5" diaginertia="0.002 0.002 0.0002"/>
        <body name="dist2" pos="0.12 0 0.16">
          <joint name="qb2" type="hinge" axis="0 1 0"/>
          <inertial pos="-0.135 0 0.18" mass="0.35" diaginertia="0.006 0.006 0.0002"/>
        </body>
      </body>
    </body>
  </worldbody>
  <equality>
    <connect name="P" body1="dist1" body2="dist2" anchor="0.27 0 0.36"/>
  </equality>
  <actuator>
    <motor joint="qa1"/>
    <motor joint="qa2"/>
  </actuator>
</mujoco>
"""

CONFIGS = {"identify": IDENTIFY, "simulate": SIMULATE, "design": DESIGN, "montecarlo": MONTECARLO}
HEADER = ["t", "q1", "q2", "tau1", "tau2"]


def make_table() -> np.ndarray:
    """300 samples (3 s at 100 Hz) of the robot of ``ROBOT`` along a random Fourier excitation:
    columns t, q1 [rad], q2 [m], tau1 [N*m], tau2 [N]."""
    import tempfile

    from dynid.model import load_robot
    from dynid.simulation import FourierTrajectory, simulate_serial

    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "rp2.toml").write_text(ROBOT)
        robot = load_robot(str(Path(tmp) / "rp2.toml"))
    rng = np.random.default_rng(1)
    lo, hi = robot.position_limits()
    traj = FourierTrajectory.random(2, 3, 0.5, rng, lo, hi, max_velocity=1.5, max_acceleration=6.0, fill=0.6)
    ds = simulate_serial(robot, robot.nominal_parameters(), traj, duration=3.0, fs=100.0, torque_noise_std=0.01, rng=rng)
    return np.column_stack([ds.t, ds.q, ds.tau])


class Work:
    """A case's folder holding the good inputs; helpers write changed copies."""

    def __init__(self, folder: Path, table: np.ndarray) -> None:
        self.dir, self.table = folder, table
        self.out = folder / "out"
        self.write("rp2.toml", ROBOT)
        self.log("log.csv")
        self.write("sim.toml", SIMULATE)

    def write(self, name: str, content: str | bytes) -> Path:
        path = self.dir / name
        path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
        return path

    def log(self, name: str, table: np.ndarray | None = None, header: list[str] = HEADER, sep: str = ",") -> Path:
        rows = self.table if table is None else table
        lines = [sep.join(header)] + [sep.join(repr(float(v)) for v in row) for row in rows]
        return self.write(name, "\n".join(lines) + "\n")

    def config(self, command: str, old: str = "", new: str = "", name: str = "cfg.toml") -> Path:
        """The good configuration of ``command`` with ``old`` replaced by ``new`` (``old`` must be in it)."""
        text = CONFIGS[command]
        if old:
            assert old in text, f"{old!r} is not in the good {command} configuration"
            text = text.replace(old, new, 1)
        return self.write(name, text)

    def run(self, command: str, old: str = "", new: str = "", *extra: str) -> list[str]:
        return [command, str(self.config(command, old, new)), "--out", str(self.out), *extra]

    def set_log(self, value: float, rows=slice(None), cols=slice(None)) -> None:
        """log.csv with ``table[rows, cols] = value``."""
        t = self.table.copy()
        t[rows, cols] = value
        self.log("log.csv", t)

    def set_log_text(self, text: str, row: int, col: int) -> None:
        """log.csv with the cell of data row ``row`` (0-based), column ``col`` replaced by ``text``."""
        lines = self.log("log.csv").read_text().splitlines()
        fields = lines[row + 1].split(",")
        fields[col] = text
        lines[row + 1] = ",".join(fields)
        self.write("log.csv", "\n".join(lines) + "\n")

    def fill_out(self) -> None:
        """An --out folder that already holds files (a refused run must leave them as they are)."""
        self.out.mkdir()
        (self.out / "result.json").write_text("{}")
        (self.out / "mine.txt").write_text("keep me")


Case = Callable[[Work], list[str]]
CASES: list = []


def case(command: str, name: str, *fragments: str, marks=()):
    """Register a case of tests/test_bad_inputs.py: ``fn(work) -> argv``; the error line must contain
    every fragment."""
    def register(fn: Case) -> Case:
        CASES.append(pytest.param(fn, fragments, id=f"{command}-{name}", marks=marks))
        return fn

    return register


def edit(command: str, name: str, old: str, new: str, *fragments: str) -> None:
    """Register a case that changes one piece of the good configuration of ``command``."""
    case(command, name, *fragments)(lambda w: w.run(command, old, new))


def assert_refused(code: int, out: str, err: str, fragments, folder: Path, out_dir: Path, before) -> str:
    """Exit 2, one line 'dynid: error: ...' with the fragments, no traceback, no stdout, --out untouched."""
    assert "Traceback" not in err + out, err
    assert code == 2, (code, err)
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("dynid: error: "), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert out == ""
    assert snapshot(out_dir) == before
    assert not [p for p in folder.iterdir() if "staging" in p.name]
    return lines[0]
