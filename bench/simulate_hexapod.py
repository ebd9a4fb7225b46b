"""Virtual experiment speed: 10 s of the hexapod under 1 kHz digital control, on one core,
next to 10 s of the serial 6R arm under the same kind of control in the same run.

Target (project issue 4, item 9, as a ratio since issue 20): the hexapod run takes at most 23 times
the serial run of its round (the project's 30 s, converted where it was set; see ``TARGET_RATIO``).

Method
------
* One core: BLAS limited to 1 thread (threadpoolctl); pinocchio is single-threaded.
* Hexapod ``builtin:hexapod`` with its nominal parameters; a 3-harmonic Fourier motion of the
  six slider positions (0.5 Hz, about ±2 cm, fixed seed) tracked by computed torque in the
  slider coordinates (:class:`dynid.simulation.closed_loop.AugmentedPD` with the true model,
  Kp = 2500, Kv = 100) at 1 kHz with zero-order hold; 2 RK4 substeps of pinocchio's
  constrained forward dynamics per period; the state projected back on the loop closures
  after every period.
* Serial reference: ``builtin:generic6r`` under computed torque
  (:class:`dynid.simulation.control.ComputedTorque`), 1 kHz, 2 RK4 substeps of ABA.
* ``--repeats`` runs of each (default 2), alternating; reported: median wall time, time per
  control period, and the hexapod/serial ratio. Exit status 1 when the median paired ratio
  is above the target (not with ``--quick``, which simulates 1 s).

Run: ``.venv/bin/python bench/simulate_hexapod.py`` (``--quick`` for a smoke run).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from _util import median, print_machine, table

from dynid.model import load_robot
from dynid.model.robots import build_mechanism
from dynid.simulation.closed_loop import AugmentedPD, ConstrainedSimulator, simulate_mechanism_control
from dynid.simulation.control import ComputedTorque, SerialPlant, model_inverse, simulate_control
from dynid.trajectories import FourierTrajectory

# the project's 30 s for 10 s of the hexapod, set where 10 s of the serial 6R under the same kind of
# control took 1.30 s (bench/README section 4): 23 times the serial run, paired round by round
TARGET_RATIO = 23.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds (default 10)")
    ap.add_argument("--repeats", type=int, default=2, help="runs of each (default 2)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 1 s, 1 run; the target is not enforced")
    args = ap.parse_args(argv)
    if args.quick:
        args.duration, args.repeats = 1.0, 1
    print_machine()
    rng = np.random.default_rng(2026)
    mech = build_mechanism("hexapod")
    pi = mech.nominal_parameters()
    u0 = mech.coordinates(mech.q_ref)[0]
    ref = FourierTrajectory.random(6, 3, 0.5, rng, u0 - 0.02, u0 + 0.02, max_velocity=0.1, max_acceleration=1.0)
    robot = load_robot("builtin:generic6r")
    rpi = robot.nominal_parameters()
    lo, hi = robot.position_limits()
    sref = FourierTrajectory.random(6, 3, 0.5, rng, lo, hi, max_velocity=1.0, max_acceleration=3.0, fill=0.5)
    dt = 1e-3

    def hexa() -> float:
        sim = ConstrainedSimulator(mech, pi)
        ctrl = AugmentedPD(mech, pi, np.full(6, 2500.0), np.full(6, 100.0))
        m = simulate_mechanism_control(sim, ctrl, ref.sample, duration=args.duration, dt=dt, substeps=2)
        return float(np.abs(mech.constraint_residual(m.q[:: max(1, len(m.t) // 50)])).max())

    def serial() -> float:
        plant = SerialPlant(robot, rpi)
        ctrl = ComputedTorque(model_inverse(robot, rpi), np.full(6, 400.0), np.full(6, 40.0))
        m = simulate_control(plant, ctrl, sref.sample, duration=args.duration, dt=dt, substeps=2)
        return float(np.abs(m.q - m.q_ref).max())

    times: dict[str, list[float]] = {"serial 6R": [], "hexapod": []}
    with threadpool_limits(1):
        for r in range(args.repeats):
            for name, fn in (("serial 6R", serial), ("hexapod", hexa)):
                t0 = time.perf_counter()
                check = fn()
                times[name].append(time.perf_counter() - t0)
                print(f"  run {r + 1}/{args.repeats}: {name} {times[name][-1]:.1f} s"
                      + (f" (constraint error {check:.1e})" if name == "hexapod" else f" (tracking error {check:.1e} rad)"),
                      flush=True)
    periods = int(round(args.duration / dt))
    rows = [(k, f"{median(v):.2f}", f"{median(v) / periods * 1e3:.3f}") for k, v in times.items()]
    print()
    print(table(["variant", f"median s for {args.duration:g} s simulated", "ms per control period"], rows))
    h = median(times["hexapod"])
    ratio = median([a / b for a, b in zip(times["hexapod"], times["serial 6R"])])
    print(f"\nhexapod / serial 6R (paired): {ratio:.1f}")
    ok = ratio <= TARGET_RATIO
    print(f"hexapod, {args.duration:g} s at 1 kHz on one core: {h:.1f} s, {ratio:.1f} x the serial 6R run of its round "
          f"(target <= {TARGET_RATIO:g} x): {'PASS' if ok else 'FAIL'}")
    return 0 if ok or args.quick else 1


if __name__ == "__main__":
    sys.exit(main())
