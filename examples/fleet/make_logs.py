"""Simulated logs of a fleet of eight arm3 robots (docs/guide/fleets.md), four monthly runs each.

Every robot is the URDF's arm perturbed by 5 % (its own seed: robots differ a little, no payload)
with Coulomb + viscous joint friction. Robot r4 is an outlier: it was built with a heavier elbow
motor, its forearm weighs 1.4 kg more than the description's 1.4 kg (the description, arm3.urdf, is
the same for every robot; r4's truth is written to logs/r4_truth.urdf). Robot r5 wears: its
shoulder's viscous friction grows by 0.1 N*m*s/rad a month.
Each run is another excitation (Fourier seed) with its own torque noise. The table logs.csv lists every
log with its date, and one log that was never copied off r3 (logs/r3_2026-05-15.csv): dynid fleet
reports it and identifies the rest.

    python make_logs.py            # writes logs/*.csv and logs.csv
"""

from __future__ import annotations

import datetime
from pathlib import Path

from dynid.config.simulate import parse_simulate_config
from dynid.pipeline.simulate import run_simulation

HERE = Path(__file__).resolve().parent
ROBOTS = ("r1", "r2", "r3", "r4", "r5", "r6", "r7", "r8")
DATES = tuple(datetime.date(2026, m, 15) for m in (1, 2, 3, 4))
FC = [0.3, 0.3, 0.2]  # N*m
FV = [0.2, 0.2, 0.1]  # N*m*s/rad
WEAR = 0.1 / 30.0     # r5: shoulder viscous friction, N*m*s/rad per day


def friction(robot: str, day: float) -> dict:
    fc, fv = list(FC), list(FV)
    if robot == "r5":  # wear
        fv[1] = FV[1] + WEAR * day
    return {"model": "coulomb_viscous", "fc": fc, "fv": fv}


def description(robot: str) -> Path:
    """The true robot's description: the URDF, or for r4 the URDF with a forearm twice as heavy."""
    if robot != "r4":
        return HERE / "arm3.urdf"
    text = (HERE / "arm3.urdf").read_text()
    heavy = text.replace('<origin xyz="0.11 0.0 -0.005"/>\n      <mass value="1.4"/>',
                         '<origin xyz="0.11 0.0 -0.005"/>\n      <mass value="2.8"/>')
    assert heavy != text
    path = HERE / "logs" / "r4_truth.urdf"
    path.write_text(heavy)
    return path


def simulate(robot: str, k: int, day: float, out: Path) -> None:
    n = ROBOTS.index(robot) + 1
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": str(description(robot)), "rotor_inertia": [0.05, 0.04, 0.02], "perturbation": 0.05,
                  "perturbation_seed": n, "friction": friction(robot, day)},
        "trajectory": {"kind": "fourier", "base_frequency_hz": 0.2, "harmonics": 3, "fill": 0.5,
                       "max_velocity": 1.5, "max_acceleration": 6.0, "periods": 1, "seed": 10 * n + k},
        "control": {"rate_hz": 200, "kp": 400, "kd": 40, "model": "true"},
        "sensors": {"encoder_resolution": 1e-5, "force_noise_std": 0.05, "seed": 100 * n + k},
        "output": {"format": "csv"},
    }, HERE))
    cols = sim.columns
    names = [c for c in cols if c == "t" or c.startswith(("q_", "tau_"))]
    import numpy as np

    np.savetxt(out, np.column_stack([cols[c] for c in names]), delimiter=",", header=",".join(names), comments="",
               fmt="%.10g")


def main() -> None:
    (HERE / "logs").mkdir(exist_ok=True)
    rows = ["robot,model,file,date"]
    for robot in ROBOTS:
        for k, date in enumerate(DATES):
            name = f"logs/{robot}_{date.isoformat()}.csv"
            simulate(robot, k, float((date - DATES[0]).days), HERE / name)
            rows.append(f"{robot},arm3,{name},{date.isoformat()}")
    rows.append("r3,arm3,logs/r3_2026-05-15.csv,2026-05-15")  # never copied off the robot: reported, not fatal
    (HERE / "logs.csv").write_text("\n".join(rows) + "\n")
    print(f"wrote {len(ROBOTS) * len(DATES)} logs and logs.csv in {HERE}")


if __name__ == "__main__":
    main()
