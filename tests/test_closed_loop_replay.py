"""The replay of a closed-loop experiment after the per-period projection's shortcut (issue 37,
item 3): :func:`dynid.simulation.closed_loop.simulate_mechanism_control` leaves a state that is
already on the loop closures within the tolerances (positions 1e-12, velocity residual
1e-12 / dt) instead of projecting its velocities every period (``exact_projection = False``:
the replays of IV and DIDIM with the regularized Coulomb law). The motion must stay on the
closures within those tolerances and equal the every-period projection's to far below the
integrator's own error."""

from __future__ import annotations

import numpy as np
import pytest

from dynid.config.simulate import parse_simulate_config
from dynid.pipeline.sim_setup import simulation_setup
from dynid.pipeline.simulate import run_simulation
from dynid.simulation.closed_loop import _PROJECTION_TOL, simulate_mechanism_control

# the set-up of bench/control_loop_time.py (hexapod twin, 500 Hz computed torque with the nominal
# model), shortened to 0.6 s: the replay IV and DIDIM run at every iteration
_DOC = {
    "robot": {"model": "builtin:hexapod", "perturbation": 0.1, "perturbation_seed": 4},
    "trajectory": {"coordinates": "task", "kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.05,
                   "max_velocity": 0.1, "max_acceleration": 1.0, "periods": 1, "seed": 4},
    "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "substeps": 2},
    "simulation": {"duration": 0.6},
}


@pytest.fixture(scope="module")
def replays(tmp_path_factory):
    cfg = parse_simulate_config(_DOC, tmp_path_factory.mktemp("replay"))
    truth = simulation_setup(cfg)
    # a replay as DIDIM makes it: the plant with other parameters (the nominal model here) and the
    # regularized Coulomb law (band 5 % of 0.1 m/s)
    plant = truth.robot.nominal_parameters()

    def run(substeps: int, exact: bool):
        s = simulation_setup(cfg, plant_params=plant, coulomb_band=0.005)
        return s, simulate_mechanism_control(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                             substeps=substeps, exact_projection=exact)

    setup, fast = run(2, False)
    replay = run_simulation(cfg, plant=plant, coulomb_band=0.005).motion  # the route IV and DIDIM take
    return setup, fast, run(2, True)[1], run(4, True)[1], replay


def test_a_smooth_replay_takes_the_shortcut(replays):
    _, fast, exact, _, replay = replays
    # the same operations as the shortcut's run (bit for bit), not those of the every-period projection
    np.testing.assert_array_equal(replay.dq, fast.dq)
    assert np.abs(replay.dq - exact.dq).max() > 0


def test_replay_stays_on_the_closures_within_the_tolerances(replays):
    setup, fast, _, _, _ = replays
    mech, dt = setup.robot, setup.dt
    # every logged state was either projected (positions to 1e-12, velocities to rounding) or left
    # because it already met the tolerances: positions within 1e-12, J_c dq within 1e-12 / dt. The
    # residuals are recomputed here by another route (the full constraint functions): a margin of 2
    # for their rounding (|q| ~ 1 m, 24 joints: ~1e-14)
    resid = np.abs(mech.constraint_residual(fast.q)).max()
    assert resid <= 2 * _PROJECTION_TOL
    vres = max(np.abs(mech.constraint_jacobian(q) @ v).max() for q, v in zip(fast.q[1:], fast.dq[1:]))
    assert vres <= 2 * _PROJECTION_TOL / dt


def test_replay_equals_the_every_period_projection_within_the_integrator_error(replays):
    _, fast, exact, fine, _ = replays
    for name in ("q", "dq", "ddq", "tau_a"):
        a, b, c = (np.asarray(getattr(m, name)) for m in (fast, exact, fine))
        # the integrator's own error on this run: RK4 at 2 substeps against 4 (Richardson: the
        # difference is 15/16 of the coarser run's error). The shortcut moves a state by at most the
        # tolerances above per period (1e-12 m; 5e-10 m/s, which the loop's gains turn into
        # accelerations of Kd 5e-10 = 5e-8 m/s^2), far below RK4's local error at h = 1 ms on a loop
        # of bandwidth sqrt(Kp) = 50 rad/s ((50 h)^5 / 120 ~ 3e-9 of the state per step, 2.6e-9 m on
        # 1 m). Hence a bound of 1 % of the integrator's error (measured: below 1e-5 of it)
        integrator = np.abs(b - c).max()
        assert integrator > 0
        assert np.abs(a - b).max() <= 1e-2 * integrator, name
