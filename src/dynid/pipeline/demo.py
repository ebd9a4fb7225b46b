"""``dynid demo``: the main job on a built-in default, needing nothing outside the package.

A virtual experiment on ``builtin:puma560``: joint torques from its inverse dynamics
(rigid body, rotor inertia, viscous and Coulomb friction; Corke's values) along a
5-harmonic Fourier trajectory, plus white noise; the log is written as CSV with a
config file, identified with WLS exactly as ``dynid identify`` would, and validated
on a second, different trajectory. Because the truth is known, the demo also reports
how many true base parameters fall inside their 95 % intervals.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from dynid.config import load_config
from dynid.dataset import Dataset
from dynid.io.output import staged_output
from dynid.model.loading import load_robot
from dynid.pipeline.identify import IdentifyOutcome, Progress, _no_progress, identify, write_files
from dynid.simulation import FourierTrajectory, simulate_serial

__all__ = ["DemoOutcome", "run_demo", "DEMO_SEED"]

DEMO_SEED = 2026
_FS = 200.0
_TORQUE_NOISE = (1.0, 1.5, 0.6, 0.08, 0.08, 0.05)  # N*m, about 1-3 % of the torques
_POSITION_NOISE = 2e-5  # rad (encoder-like)

_CONFIG = """\
# dynid demo: identification of builtin:puma560 from simulated logs (see README "Configuration")
[robot]
model = "builtin:puma560"
extras = ["Ia", "fv", "fc", "offset"]

[data]
file = "data/train.csv"
time = {{ column = "t", unit = "s" }}
position = {{ columns = {q}, unit = "rad" }}
effort = {{ columns = {tau}, kind = "torque", unit = "N*m" }}

[validation]
file = "data/validation.csv"

[processing]
lowpass = {{ cutoff_hz = 5.0, order = 4, filter_effort = false }}
derivatives = "central"

[identification]
method = "wls"
"""


@dataclasses.dataclass(frozen=True, eq=False)
class DemoOutcome:
    outcome: IdentifyOutcome
    true_base: np.ndarray
    out_dir: Path

    @property
    def z_scores(self) -> np.ndarray:
        r = self.outcome.result
        return (r.params - self.true_base) / r.bse

    def truth_table(self) -> str:
        r = self.outcome.result
        ci = r.conf_int()
        inside = (ci[:, 0] <= self.true_base) & (self.true_base <= ci[:, 1])
        lines = [
            f"Ground truth check: {int(inside.sum())} of {inside.size} true base parameters lie inside their 95 % intervals "
            f"(expected about {0.95 * inside.size:.0f}); largest |z| = {np.max(np.abs(self.z_scores)):.2f}",
        ]
        return "\n".join(lines)


def _relocate(obj, old: str, new: str):
    """Replace the path prefix ``old`` by ``new`` in every string of a nested structure."""
    if isinstance(obj, str):
        return new + obj[len(old):] if obj.startswith(old) else obj
    if isinstance(obj, dict):
        return {(_relocate(k, old, new)): _relocate(v, old, new) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_relocate(v, old, new) for v in obj]
    return obj


def _write_csv(path: Path, ds: Dataset) -> None:
    n = ds.q.shape[1]
    header = ["t"] + [f"q{j + 1}" for j in range(n)] + [f"tau{j + 1}" for j in range(n)]
    table = np.column_stack([ds.t, ds.q, ds.tau])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.10g")


def run_demo(out_dir: str | Path, progress: Progress = _no_progress, seed: int = DEMO_SEED) -> DemoOutcome:
    """Simulate, identify, validate; write data, config and results into ``out_dir``."""
    robot = load_robot("builtin:puma560")
    truth = robot.nominal_parameters()
    rng = np.random.default_rng(seed)
    lo, hi = robot.position_limits()
    train_traj = FourierTrajectory.random(robot.dof, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    valid_traj = FourierTrajectory.random(robot.dof, 4, 0.125, rng, lo, hi, max_velocity=1.2, max_acceleration=3.0, fill=0.5)
    progress("simulate", 0, 2)
    train = simulate_serial(robot, truth, train_traj, fs=_FS, duration=30.0, torque_noise_std=_TORQUE_NOISE,
                            position_noise_std=_POSITION_NOISE, rng=rng)
    progress("simulate", 1, 2)
    valid = simulate_serial(robot, truth, valid_traj, fs=_FS, duration=16.0, torque_noise_std=_TORQUE_NOISE,
                            position_noise_std=_POSITION_NOISE, rng=rng)
    progress("simulate", 2, 2)
    out = Path(out_dir)
    with staged_output(out) as stage:
        _write_csv(stage / "data" / "train.csv", train)
        _write_csv(stage / "data" / "validation.csv", valid)
        n = robot.dof
        cfg_text = _CONFIG.format(q=json.dumps([f"q{j + 1}" for j in range(n)]), tau=json.dumps([f"tau{j + 1}" for j in range(n)]))
        (stage / "config.toml").write_text(cfg_text)
        outcome = identify(load_config(stage / "config.toml"), progress)
        # the inputs were read from the staging folder; the record must name their final place
        relocated = _relocate(dict(outcome.result.provenance), str(stage.resolve()), str(out.resolve()))
        outcome = dataclasses.replace(outcome, result=outcome.result.with_provenance(**relocated))
        true_base = outcome.base.from_standard(truth)
        demo = DemoOutcome(outcome, true_base, out)
        write_files(outcome, stage)
        (stage / "truth.json").write_text(json.dumps({
            "seed": seed,
            "true_standard_params": dict(zip(robot.parameter_names, truth.tolist())),
            "true_base_params": dict(zip(outcome.base.names, true_base.tolist())),
            "torque_noise_std": list(_TORQUE_NOISE),
            "position_noise_std": _POSITION_NOISE,
        }, indent=2))
        with open(stage / "summary.txt", "a") as fh:
            fh.write("\n" + demo.truth_table() + "\n")
    return demo
