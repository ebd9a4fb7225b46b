"""The replay of a closed-loop experiment after the per-period projection's shortcut (issue 37,
item 3): :func:`dynid.simulation.closed_loop.simulate_mechanism_control` leaves a state that is
already on the loop closures within the tolerances (positions 1e-12, velocity residual
1e-12 / dt) instead of projecting its velocities every period (``exact_projection = False``:
the replays of IV and DIDIM with the regularized Coulomb law). The motion must stay on the
closures within those tolerances and equal the every-period projection's to far below the
integrator's own error.

Third pass: the replay route runs the same loop with its per-period NumPy work in numba kernels
(:mod:`dynid.pipeline._sim_kernels`); its motion must equal the Python loop's to far below the
integrator's error as well, on the hexapod and on two other closed chains (the five-bar, the
3-RPS: rotor inertias in the controller and the plant), and a serial arm must not load numba."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from dynid.config.simulate import parse_simulate_config
from dynid.errors import ModelError
from dynid.pipeline import _sim_kernels
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
    s = simulation_setup(cfg, plant_params=plant, coulomb_band=0.005)
    assert _sim_kernels.supports(s.plant, s.controller)
    compiled = _sim_kernels.compiled_replay(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                            substeps=2)
    replay = run_simulation(cfg, plant=plant, coulomb_band=0.005).motion  # the route IV and DIDIM take
    return setup, fast, run(2, True)[1], run(4, True)[1], replay, compiled


def test_the_replay_route_runs_the_compiled_loop(replays):
    _, fast, exact, _, replay, compiled = replays
    # run_simulation's replay is the compiled loop's (bit for bit: the same operations), and that loop
    # took the shortcut: its states differ from the every-period projection's (the next test bounds by how much)
    for name in ("q", "dq", "ddq", "tau_a"):
        np.testing.assert_array_equal(getattr(replay, name), getattr(compiled, name))
    assert np.abs(compiled.dq - exact.dq).max() > 0


@pytest.mark.parametrize("which", [1, 5])  # the Python loop's replay, the compiled one
def test_replay_stays_on_the_closures_within_the_tolerances(replays, which):
    setup, fast = replays[0], replays[which]
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
    _, fast, exact, fine, _, _ = replays
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


def _integrator_bound(fast, fine, compiled):
    """Largest difference of the compiled replay from the Python loop's, per signal, against the
    integrator's own error on the same run (RK4 at 2 substeps against 4)."""
    out = {}
    for name in ("q", "dq", "ddq", "tau_a"):
        a, b, c = (np.asarray(getattr(m, name)) for m in (compiled, fast, fine))
        out[name] = (np.abs(a - b).max(), np.abs(b - c).max())
    return out


def test_compiled_replay_equals_the_python_loop_within_the_integrator_error(replays):
    _, fast, _, fine, _, compiled = replays
    # The kernels evaluate the Python loop's formulas with other sums (loops instead of BLAS, an
    # unblocked LU instead of LAPACK's): each period differs by rounding, a few ulps of the state
    # (|q| ~ 1 m: 1e-16 m) times the conditioning of the 18x18 closure block (at most its bound
    # 1e8, about 1e2 here), carried through the stable closed loop. The requirement is the
    # integrator's accuracy, as for the shortcut above: at most 1 % of RK4's own error on this run
    # (measured: about 1e-9 of it; 2e-12 N against 6e-3 N on the forces)
    for name, (diff, integrator) in _integrator_bound(fast, fine, compiled).items():
        assert integrator > 0
        assert diff <= 1e-2 * integrator, name


@pytest.mark.parametrize("robot", ["fivebar", "rps3"])
def test_compiled_replay_of_other_closed_chains(tmp_path, robot):
    # two other mechanisms in joint coordinates, with rotor inertias (the plant's armature, the
    # controller's inertia term), 0.3 s of a replay at 500 Hz; the bound of the test above
    doc = {"robot": {"model": f"builtin:{robot}", "perturbation": 0.1, "perturbation_seed": 4},
           "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.3, "periods": 1,
                          "seed": 4},
           "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "substeps": 2},
           "simulation": {"duration": 0.3}}
    cfg = parse_simulate_config(doc, tmp_path)
    plant = simulation_setup(cfg).robot.nominal_parameters()

    def run(substeps: int, compiled: bool = False):
        s = simulation_setup(cfg, plant_params=plant, coulomb_band=0.01)
        if compiled:
            assert _sim_kernels.supports(s.plant, s.controller)
            assert np.any(s.controller._forces.inertia) and np.any(s.plant.model.armature)
            return _sim_kernels.compiled_replay(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                                substeps=substeps)
        return simulate_mechanism_control(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                          substeps=substeps, exact_projection=False)

    for name, (diff, integrator) in _integrator_bound(run(2), run(4), run(2, True)).items():
        assert integrator > 0
        assert diff <= 1e-2 * integrator, name


def test_a_serial_arm_does_not_load_numba(tmp_path):
    # numba is for the closed-chain replay only: a serial arm's simulation (controller, integrator,
    # sensors) through the same run_simulation leaves it unloaded (a fresh interpreter's sys.modules)
    code = (
        "import sys, pathlib\n"
        "from dynid.config.simulate import parse_simulate_config\n"
        "from dynid.pipeline.simulate import run_simulation\n"
        "doc = {'robot': {'model': 'builtin:puma560'}, 'trajectory': {'kind': 'fourier', 'base_frequency_hz': 0.5,"
        " 'harmonics': 2, 'fill': 0.3, 'periods': 1, 'seed': 1}, 'control': {'rate_hz': 200},"
        " 'simulation': {'duration': 0.1}}\n"
        f"out = run_simulation(parse_simulate_config(doc, pathlib.Path({str(tmp_path)!r})))\n"
        "print(out.motion.q.shape[0], 'numba' in sys.modules)\n")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows, loaded = proc.stdout.split()[-2:]
    assert int(rows) > 1 and loaded == "False"


def test_a_diverging_compiled_replay_fails_as_the_python_loop(tmp_path):
    # bodies 1e6 times too light under the same controller: the motion diverges within 0.3 s; both
    # loops must stop with the projection's error (a DynidError: IV and DIDIM halve their step on it)
    doc = {"robot": {"model": "builtin:fivebar", "perturbation": 0.1, "perturbation_seed": 4},
           "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.3, "periods": 1,
                          "seed": 4},
           "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "substeps": 2},
           "simulation": {"duration": 0.3}}
    cfg = parse_simulate_config(doc, tmp_path)
    robot = simulation_setup(cfg).robot
    bad = robot.nominal_parameters()
    bad[: robot.n_body_params] *= 1e-6
    messages = []
    for compiled in (False, True):
        s = simulation_setup(cfg, plant_params=bad, coulomb_band=0.01)
        with pytest.raises(ModelError, match="not finite") as err:
            if compiled:
                _sim_kernels.compiled_replay(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                             substeps=2)
            else:
                simulate_mechanism_control(s.plant, s.controller, s.reference, duration=s.duration, dt=s.dt,
                                           substeps=2, exact_projection=False)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def test_didim_rows_from_the_replays_own_joint_positions(replays):
    """DIDIM's rows of a replay (dynid.pipeline.control_loop): the replay's joint positions, on the
    closures to the projection's tolerance, taken as they are (KnownJointPositions) and the compiled
    velocity map, velocities and accelerations (loop_kinematics.states) give the rows that the
    position check and the numpy route of actuator_states give from the same positions as starting
    points, to rounding: the same closure equations, solved through the dependent joints' 18 x 18
    block (backward-stable LU: relative error at most a few n * cond * eps; n = 24 joints)."""
    from dynid.model.loading import load_model
    from dynid.model.system import KnownJointPositions, as_system

    replay = replays[4]
    system = as_system(load_model("builtin:hexapod"))
    act = list(system.model.actuated)
    q, dq, ddq = replay.q[:, act], replay.dq[:, act], replay.ddq[:, act]
    tau = replay.tau_a
    old = system.rows(None)(q, dq, ddq, tau, 0, joint_q=replay.q)
    new = system.rows(None)(q, dq, ddq, tau, 0, joint_q=KnownJointPositions(replay.q))
    cond = float(np.max(system.model.states(replay.q, dq, ddq).cond))
    bound = 4 * 24 * cond * np.finfo(float).eps * np.max(np.abs(old.W))
    assert np.max(np.abs(new.W - old.W)) <= bound, (np.max(np.abs(new.W - old.W)), bound)
    np.testing.assert_array_equal(new.y, old.y)
    np.testing.assert_array_equal(new.inconsistency, np.zeros(q.shape[0]))
    # positions not on the actuator samples given: the rows solve them again (the position check)
    shifted = system.rows(None)(q + 1e-6, dq, ddq, tau, 0, joint_q=KnownJointPositions(replay.q))
    assert np.all(shifted.inconsistency < 1e-9) and not np.allclose(shifted.W, old.W, rtol=0, atol=bound)
