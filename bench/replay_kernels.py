"""Benchmark (issue 37, item 3, third pass): one model replay of IV/DIDIM, the Python loop against the
compiled one (:mod:`dynid.pipeline._sim_kernels`), paired, and where the compiled loop's time goes.

Method
------
* The replay of ``bench/control_loop_time.py``: the hexapod twin (``builtin:hexapod``, 10 %
  perturbed truth, 3-harmonic task-space excitation at 0.5 Hz, 3 periods: 3001 control periods of
  2 ms), the nominal model as the plant, 500 Hz computed torque (Kp 2500, Kd 100), 2 RK4 substeps,
  the regularized Coulomb law (band 0.005 m/s), the projection's shortcut.
* Paired rounds: each round runs the Python loop
  (:func:`dynid.simulation.closed_loop.simulate_mechanism_control`, ``exact_projection=False``)
  and the compiled loop (:func:`dynid.pipeline._sim_kernels.compiled_replay`) on fresh set-ups,
  in an order alternated from round to round; wall time of the loop alone (the set-up and the
  sensors' recording excluded), one BLAS thread. Reported: each loop's median, its time per control
  period, and the median of the round ratios (compiled / Python). The kernels are compiled (or
  loaded from numba's cache) before the first round.
* Per piece: one more compiled replay with every kernel and pinocchio call timed by a wrapper
  (the wrappers add about 0.1 us per call): microseconds per control period and per call.
* The largest difference of the two loops' motions, against the integrator's own error (the
  Python loop at 4 substeps against 2).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/replay_kernels.py [--rounds 5]``.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import median, print_machine  # noqa: E402

from dynid.config.simulate import parse_simulate_config  # noqa: E402
from dynid.pipeline import _sim_kernels as K  # noqa: E402
from dynid.pipeline.sim_setup import simulation_setup  # noqa: E402
from dynid.simulation.closed_loop import simulate_mechanism_control  # noqa: E402

DOC = {
    "robot": {"model": "builtin:hexapod", "perturbation": 0.1, "perturbation_seed": 4},
    "trajectory": {"coordinates": "task", "kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.05,
                   "max_velocity": 0.1, "max_acceleration": 1.0, "periods": 3, "seed": 4},
    "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "substeps": 2},
}
BAND = 0.005


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print_machine()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    cfg = parse_simulate_config(DOC, Path(tempfile.mkdtemp()))
    plant = simulation_setup(cfg).robot.nominal_parameters()

    def python(substeps: int = 2, exact: bool = False):
        s = simulation_setup(cfg, plant_params=plant, coulomb_band=BAND)
        t0 = time.perf_counter()
        m = simulate_mechanism_control(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                       substeps=substeps, exact_projection=exact)
        return time.perf_counter() - t0, m

    def compiled():
        s = simulation_setup(cfg, plant_params=plant, coulomb_band=BAND)
        t0 = time.perf_counter()
        m = K.compiled_replay(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt, substeps=2)
        return time.perf_counter() - t0, m

    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        _, mc = compiled()
        print(f"first compiled replay (compilation or cache load included): {time.perf_counter() - t0:.2f} s")
        tp, tc, ratio = [], [], []
        for r in range(args.rounds):
            order = (python, compiled) if r % 2 == 0 else (compiled, python)
            got = {f.__name__: f()[0] for f in order}
            tp.append(got["python"])
            tc.append(got["compiled"])
            ratio.append(got["compiled"] / got["python"])
        n = mc.t.size
        print(f"\nreplay of {n} control periods, {args.rounds} paired rounds:")
        print(f"  Python loop   median {median(tp):.3f} s = {median(tp) / n * 1e6:.0f} us/period  "
              f"(rounds {', '.join(f'{x:.3f}' for x in tp)})")
        print(f"  compiled loop median {median(tc):.3f} s = {median(tc) / n * 1e6:.0f} us/period  "
              f"(rounds {', '.join(f'{x:.3f}' for x in tc)})")
        print(f"  compiled / Python, round by round: {', '.join(f'{x:.3f}' for x in ratio)}; median {median(ratio):.3f}")

        # per piece, the compiled loop instrumented
        spent, calls = collections.defaultdict(float), collections.defaultdict(int)
        saved = []

        def wrap(mod, name):
            f = getattr(mod, name)
            saved.append((mod, name, f))

            def timed(*a, **kw):
                t = time.perf_counter()
                out = f(*a, **kw)
                spent[name] += time.perf_counter() - t
                calls[name] += 1
                return out

            setattr(mod, name, timed)

        for name in ("_geometry", "_accelerations", "_forces", "_rk4_stage", "_closure_check"):
            wrap(K, name)
        for name in ("constraintDynamics", "rnea", "computeJointJacobiansTimeVariation", "computeJointJacobians"):
            wrap(pin, name)
        kin_call = K._Kinematics.__call__

        def kin(self, q):
            t = time.perf_counter()
            out = kin_call(self, q)
            spent["placements (computeJointJacobians included)"] += time.perf_counter() - t
            calls["placements (computeJointJacobians included)"] += 1
            return out

        K._Kinematics.__call__ = kin
        total, _ = compiled()
        K._Kinematics.__call__ = kin_call
        for mod, name, f in saved:
            setattr(mod, name, f)
        print(f"\ncompiled loop instrumented: {total / n * 1e6:.0f} us/period")
        for name in sorted(spent, key=lambda x: -spent[x]):
            print(f"  {name:46s} {spent[name] / n * 1e6:6.1f} us/period  {calls[name] / n:4.1f} calls  "
                  f"{spent[name] / calls[name] * 1e6:6.2f} us/call")
        known = sum(v for k, v in spent.items() if k != "computeJointJacobians")
        print(f"  {'rest (the loop in Python, checks, mech.project)':46s} {(total - known) / n * 1e6:6.1f} us/period")

        _, mp = python()
        _, fine = python(4, True)
        print("\ncompiled against the Python loop (largest difference; the integrator's error: Python loop at 2 "
              "against 4 substeps):")
        for name in ("q", "dq", "ddq", "tau_a"):
            a, b, c = (np.asarray(getattr(m, name)) for m in (mc, mp, fine))
            print(f"  {name:6s} {np.abs(a - b).max():.3g}  integrator {np.abs(b - c).max():.3g}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
