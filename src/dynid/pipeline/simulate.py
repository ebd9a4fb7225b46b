"""``dynid simulate``: a virtual experiment from a config, with the ground truth attached.

The true robot (the model's nominal parameters, optionally perturbed, optionally carrying a
payload) follows a commanded trajectory under digital control (zero-order hold; serial
robots: pinocchio ABA; closed-loop mechanisms: pinocchio constraint dynamics with projection
on the loop closures): computed torque, or a PID per joint / per actuator with or without the
feedforward of a model (nominal, true or identified: paper 002, Section 5.4; paper 004,
Fig. 6); sensors turn the true signals into a log (see :mod:`dynid.simulation.sensors`).
Outputs, written together or not at all:

* ``log.csv`` or ``log.npz``: ``t`` [s], ``q_<actuator>`` [rad or m], ``tau_<actuator>``
  [N·m or N] (or ``i_<actuator>`` [A] with torque constants), and the commanded independent
  coordinates ``ref_<coordinate>`` at the logged instants (a constant-velocity experiment adds
  its labels ``cv_joint``, ``cv_speed``, ``cv_direction``, ``cv_repetition``,
  :mod:`dynid.trajectories.constant_velocity`);
* ``truth.json``: the true and nominal standard parameters of the robot (names and values),
  the true base parameters with their grouping expressions, the payload (body, mass, centre
  of mass, inertia) separately; with a payload, ``true_parameters_with_payload`` (the payload's
  inertia added to its body's block) and base ``true_values`` *with* the payload, what an
  identification of the log estimates (``true_values_without_payload``: the robot alone); with ``[robot.friction]`` the linear friction terms that model
  replaces in the plant are recorded as 0 and listed in ``replaced_by_ground_truth_friction``
  (the plant's friction is ``ground_truth_friction`` alone);
* ``metadata.json``: ``warnings`` (:mod:`dynid.simulation.loop_checks`: an unstable loop, a large
  tracking error, efforts beyond the description's limits), what every column means, units, seeds,
  control and sensor settings, the
  model the controller used (``control.model_used``: nominal, true, or the identification
  result's path relative to the configuration's folder), tracking metrics in the independent
  coordinates (per-axis RMS, P-RSME of Shang 2009, Eq. 23) and, for the PIDs of a mechanism,
  of the actuator positions (``tracking_actuators``, paper 002 Fig. 10), the largest
  loop-closure error, the versions;
* ``config.toml``: the configuration used;
* ``timing.json``: the wall-clock time of the simulation.

The same configuration (seeds included) gives bit-identical files, ``timing.json`` aside.

A run is set up once from the configuration (:class:`~dynid.pipeline.sim_setup.SimulationSetup`,
:mod:`dynid.pipeline.sim_setup`), then stepped (:func:`_simulate`) and recorded (:func:`_record`) here.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from dynid import __version__
from dynid._files import TIMING_FILE, save_npz, write_timing
from dynid.config.simulate import SimulateConfig
from dynid.dataset import Dataset
from dynid.errors import ConfigError, InputError
from dynid.io.output import staged_output
from dynid.model.closed_loop import mechanism_base_parameters
from dynid.model.mechanism import Mechanism
from dynid.model.base_parameters import robot_base_parameters
from dynid.simulation.closed_loop import simulate_mechanism_control
from dynid.simulation.control import simulate_control
from dynid.trajectories import ConstantVelocityExperiment, zyx_angular_velocity
from dynid.simulation.sensors import Measurements, Sensors
from dynid.stats import tracking_errors
from dynid.pipeline.sim_trajectory import _check_reference_limits, _coordinate_box, _trajectory  # noqa: F401  (tests)
from dynid.pipeline.sim_setup import (  # noqa: F401  (re-exported: _mechanism_friction for the tests)
    SimulationSetup, _mechanism_friction, _replaced_friction, _with_payload, load_simulated_robot, simulation_setup)

__all__ = ["SimulationOutcome", "SimulationSetup", "TrueSignals", "actuator_states", "load_simulated_robot", "measure_signals",
           "run_simulation", "simulation_setup", "write_simulation", "SIMULATION_FILES"]

SIMULATION_FILES = ("log.csv", "log.npz", "truth.json", "metadata.json", "config.toml")
Progress = Callable[[str, int, int], None]


@dataclasses.dataclass(frozen=True, eq=False)
class SimulationOutcome:
    """A finished virtual experiment: the logged :class:`~dynid.dataset.Dataset` (its ``meta``
    holds the truth and the settings), the columns as written, and the JSON documents."""

    dataset: Dataset
    columns: dict[str, np.ndarray]
    truth: dict
    metadata: dict
    config: SimulateConfig
    motion: object = None  # the true motion at the control instants (q, dq, ddq of all joints)
    signals: TrueSignals | None = None  # what the sensors saw (measure again with another seed)
    elapsed_s: float = float("nan")  # wall-clock time of the simulation (timing.json)

    def summary_text(self) -> str:
        m = self.metadata
        lines = [
            f"robot            : {m['robot']} ({m['kind']}, {m['n_actuators']} actuators"
            + (f"; {m['robot_source']})" if m.get("robot_source") else ")"),
            f"trajectory       : {m['trajectory']['kind']}, {m['duration_s']:.3f} s simulated",
            f"control          : {m['control']['kind']} at {m['control']['rate_hz']:g} Hz with the {_model_label(m['control'])} model",
            f"log              : {m['n_samples']} samples at {m['log_rate_hz']:g} Hz, efforts as {m['effort_kind']}",
            f"tracking         : P-RSME {m['tracking']['p_rsme']:.3e}, max |error| {max(m['tracking']['max_abs_per_axis']):.3e}",
        ]
        if m.get("constraint_error_max") is not None:
            lines.append(f"loop closures    : largest constraint error {m['constraint_error_max']:.1e}")
        return "\n".join(lines)


def _model_label(control: dict) -> str:
    used = control.get("model_used") or {}
    return f"identified ({used['result']})" if used.get("kind") == "identified" else str(control["model"])


@dataclasses.dataclass(frozen=True, eq=False)
class TrueSignals:
    """The true signals the sensors turn into the log: actuator positions ``q`` and efforts
    ``effort`` (n, n_a) at the control instants ``t`` (n,), the commanded coordinates as
    ``ref_*`` columns (n,) at the same instants, and the sensors of the configuration.

    The controller never sees the sensors, so the same motion measured with another seed is
    another run of the same experiment (what ``dynid montecarlo`` repeats)."""

    t: np.ndarray
    q: np.ndarray
    effort: np.ndarray
    actuators: tuple[str, ...]
    references: dict[str, np.ndarray]
    sensors: Sensors


def measure_signals(signals: TrueSignals, seed: int | None = None) -> tuple[Measurements, dict[str, np.ndarray]]:
    """One draw of the sensors: the measurements and the log's columns (``t``, ``q_<actuator>``,
    ``tau_<actuator>`` or ``i_<actuator>``, ``ref_*``). ``seed`` replaces the sensors' seed."""
    sensors = signals.sensors if seed is None else dataclasses.replace(signals.sensors, seed=int(seed))
    meas = sensors.measure(signals.t, signals.q, signals.effort)
    effort_prefix = "i" if meas.effort_kind == "current" else "tau"
    columns: dict[str, np.ndarray] = {"t": meas.t}
    for k, name in enumerate(signals.actuators):
        columns[f"q_{name}"] = meas.q[:, k]
    for k, name in enumerate(signals.actuators):
        columns[f"{effort_prefix}_{name}"] = meas.effort[:, k]
    for name, values in signals.references.items():
        columns[name] = values[meas.index]
    return meas, columns


def run_simulation(cfg: SimulateConfig, progress: Progress | None = None, *, robot=None,
                   plant: np.ndarray | None = None, coulomb_band: float | None = None) -> SimulationOutcome:
    """Run the virtual experiment of ``cfg`` (nothing is written).

    ``robot``: the model to simulate in place of loading ``cfg.robot.model``, for a variant built
    in code (e.g. a study's twin whose nominal joint terms differ, :func:`dataclasses.replace` of a
    :class:`~dynid.model.mechanism.Mechanism`); it must have the loaded model's parameters, in the
    same order, and truth.json records the variant's true values (``model`` says ``"variant of ..."``).

    ``plant``: standard parameters of the simulated robot (the layout of ``cfg.robot.model``)
    instead of the configured truth, its friction and its payload; the controller stays
    exactly as configured (its model included). This is the experiment replayed on a model,
    e.g. an identified one (IDIM-IV and DIDIM, :mod:`dynid.pipeline.control_loop`); the
    outcome's truth still describes the configured robot, without its base parameters
    (``truth["base_parameters"]`` is None: their computation, a regressor on random
    configurations, cost a mechanism's replay about 5 % of its time, and a replay is not written).

    ``coulomb_band``: with ``plant``, the plant's Coulomb friction through the regularized law of
    :class:`~dynid.simulation.closed_loop.ConstrainedSimulator` (a parallel robot's replay only).
    Such a replay runs its control loop with the per-period NumPy work compiled
    (:mod:`dynid.pipeline._sim_kernels`, numba; the same motion to rounding, about half the time of
    a period on the hexapod twin) where the plant and controller allow it (joint coordinates,
    no redundant actuation), otherwise
    :func:`~dynid.simulation.closed_loop.simulate_mechanism_control`.
    """
    t0 = time.perf_counter()
    outcome = _run_simulation(cfg, progress, robot, plant, coulomb_band)
    return dataclasses.replace(outcome, elapsed_s=time.perf_counter() - t0)


def _run_simulation(cfg: SimulateConfig, progress: Progress | None, variant=None,
                    plant_params: np.ndarray | None = None, coulomb_band: float | None = None) -> SimulationOutcome:
    setup = simulation_setup(cfg, variant, plant_params, coulomb_band)
    return _record(setup, *_simulate(setup))


def _simulate(setup: SimulationSetup):
    """Step the set-up loop: (motion, actuator positions, actuator efforts, independent coordinates,
    actuator names, largest loop-closure error or None, tracking errors of the drives or None)."""
    robot, c = setup.robot, setup.cfg.control
    if setup.mech:
        # a replay with the regularized Coulomb law (IV, DIDIM): the projection's shortcut (simulate_mechanism_control)
        exact = not (setup.replay and setup.plant.coulomb_band is not None)
        motion = None
        if not exact:  # the same loop with its per-period NumPy work compiled (numba, loaded here only)
            from dynid.pipeline import _sim_kernels

            if _sim_kernels.supports(setup.plant, setup.controller):
                motion = _sim_kernels.compiled_replay(setup.plant, setup.controller, setup.reference,
                                                      duration=setup.duration, dt=setup.dt, substeps=c.substeps)
        if motion is None:
            motion = simulate_mechanism_control(setup.plant, setup.controller, setup.reference, duration=setup.duration,
                                                dt=setup.dt, substeps=c.substeps, exact_projection=exact)
        q_act = motion.q[:, list(robot.actuated)]
        track_actuators = None
        if c.kind != "computed_torque":  # the drives' own errors (paper 002, Fig. 10; paper 004, Fig. 6)
            track_actuators = tracking_errors(setup.reference(motion.t)[3], q_act)
        constraint = float(np.abs(robot.constraint_residual(motion.q[:: max(1, motion.t.size // 200)])).max())
        return motion, q_act, motion.tau_a, robot.coordinates(motion.q), robot.actuated_names, constraint, track_actuators
    motion = simulate_control(setup.plant, setup.controller, setup.reference, duration=setup.duration, dt=setup.dt,
                              substeps=c.substeps)
    return motion, motion.q, motion.tau, motion.q, list(robot.joint_names), None, None


def _record(setup: SimulationSetup, motion, q_act: np.ndarray, tau: np.ndarray, u: np.ndarray, act_names: list[str],
            constraint: float | None, track_actuators: dict | None) -> SimulationOutcome:
    """The outcome of a stepped set-up: the references, the sensors' measurement, truth.json and
    metadata.json, the logged Dataset."""
    cfg, robot, mech, traj, coord_names = setup.cfg, setup.robot, setup.mech, setup.trajectory, setup.coord_names
    c, s, payload, true = cfg.control, cfg.sensors, setup.payload, setup.true
    u_ref = traj.sample(motion.t)[0]
    warnings = _loop_warnings(robot, mech, c, motion.t, u_ref, u, coord_names, tau, act_names, replay=setup.replay)
    references = {f"ref_{name}": u_ref[:, k] for k, name in enumerate(coord_names)}
    if {"RZ", "RY", "RX"} <= set(coord_names):  # commanded angular velocity, paper 004 Eq. 16
        sel = [coord_names.index(n) for n in ("RZ", "RY", "RX")]
        _, du_ref, ddu_ref = traj.sample(motion.t)
        omega, _ = zyx_angular_velocity(u_ref[:, sel], du_ref[:, sel], ddu_ref[:, sel])
        for k, axis in enumerate("xyz"):
            references[f"ref_w{axis}"] = omega[:, k]
    if isinstance(traj, ConstantVelocityExperiment):  # which joint, speed and window each sample belongs to
        references.update(traj.labels(motion.t))
    signals = TrueSignals(t=motion.t, q=q_act, effort=tau, actuators=tuple(act_names), references=references,
                          sensors=setup.sensors)
    meas, columns = measure_signals(signals)
    effort_prefix = "i" if meas.effort_kind == "current" else "tau"
    base = None
    if not setup.replay:  # a replay's truth goes without them (run_simulation)
        base = mechanism_base_parameters(robot) if mech else robot_base_parameters(robot)
    replaced = _replaced_friction(robot, mech) if cfg.robot.friction is not None and not setup.replay else []
    recorded = np.array(true, dtype=float)
    recorded[[list(robot.parameter_names).index(n) for n in replaced]] = 0.0
    loaded = recorded if payload is None else _with_payload(robot, recorded, payload[1], payload[2])
    truth = {
        "model": cfg.robot.model if not setup.variant else f"variant of {cfg.robot.model}",
        "parameter_names": list(robot.parameter_names),
        "true_parameters": recorded.tolist(),
        **({"replaced_by_ground_truth_friction": replaced} if replaced else {}),
        "nominal_parameters": setup.nominal.tolist(),
        "perturbation": cfg.robot.perturbation,
        "ground_truth_friction": (dict(cfg.robot.friction) if cfg.robot.friction is not None else
                                  "the joint terms of true_parameters"),
        "payload": ({"body": payload[0], **{k: v for k, v in cfg.robot.payload.items() if k != "body"}}
                    if payload is not None else None),
        **({"true_parameters_with_payload": loaded.tolist()} if payload is not None else {}),
        "base_parameters": None if base is None else {
            "names": list(base.names),
            # what an identification of the log estimates: the robot with its payload
            "true_values": base.from_standard(loaded).tolist(),
            **({"true_values_without_payload": base.from_standard(recorded).tolist(),
                "payload_included": True} if payload is not None else {}),
            "expressions": list(base.expressions()),
        },
    }
    track = tracking_errors(u_ref, u)
    metadata = {
        "dynid_version": __version__,
        "robot": robot.name,
        "robot_source": getattr(robot, "source", "") or str(cfg.robot.model),
        "kind": "closed-loop" if mech else "serial",
        "n_actuators": len(act_names),
        "actuators": act_names,
        "independent_coordinates": coord_names,
        "trajectory": {"kind": cfg.trajectory.kind, **{k: (list(v) if isinstance(v, tuple) else v)
                                                       for k, v in cfg.trajectory.values.items()}},
        "duration_s": float(motion.t[-1]),
        "control": {**dataclasses.asdict(c), "distribution": (c.distribution if mech and robot.redundant else None),
                    "model_used": setup.model_used},
        "log_rate_hz": setup.log_rate,
        "n_samples": int(meas.t.size),
        "effort_kind": meas.effort_kind,
        "columns": {
            "t": "time [s] (with the configured jitter)",
            "q_*": "actuator positions [rad or m], quantized and noisy",
            f"{effort_prefix}_*": "actuator efforts " + ("[A] (torque / torque constant)" if meas.effort_kind == "current" else "[N*m or N]"),
            "ref_*": "commanded independent coordinates at the nominal sample instants",
            **({"cv_joint": "constant-velocity experiment: the moving joint (1-based; 0 during moves and rests)",
                "cv_speed": "its speed level [rad/s or m/s]",
                "cv_direction": "+1 in the forward constant-velocity window, -1 in the backward one, 0 elsewhere",
                "cv_repetition": "the repetition of the cycle (from 1)"}
               if isinstance(traj, ConstantVelocityExperiment) else {}),
            "ref_w*": "commanded angular velocity of the platform [rad/s], world axes (paper 004, Eq. 16), when the "
                      "coordinates include the z-y-x angles",
        },
        "sensors": {k: (np.asarray(v).tolist() if v is not None else None) for k, v in dataclasses.asdict(s).items()},
        "tracking": _jsonable_metrics(track),
        "tracking_actuators": None if track_actuators is None else _jsonable_metrics(track_actuators),
        "constraint_error_max": constraint,
        "warnings": warnings,
    }
    dataset = Dataset(
        t=meas.t, q=meas.q, tau=meas.effort, names=tuple(act_names),
        meta={"position_side": "joint", "effort_kind": meas.effort_kind, "effort_side": "joint",
              "source": "simulation", "truth": truth, "simulation": metadata},
    )
    return SimulationOutcome(dataset=dataset, columns=columns, truth=truth, metadata=metadata, config=cfg, motion=motion,
                             signals=signals)


def _loop_warnings(robot, mech: bool, c, t: np.ndarray, u_ref: np.ndarray, u: np.ndarray, coord_names: list[str],
                   tau: np.ndarray, act_names: list[str], replay: bool = False) -> list[dict]:
    """:func:`dynid.simulation.loop_checks.loop_warnings` of a run; a run whose state or efforts
    left the finite numbers is refused (its log would be NaN from there on: nothing to write): a
    ConfigError (the configured gains), or for a replay on given plant parameters an InputError
    (the parameters: DIDIM and IDIM-IV then halve their step, :mod:`dynid.pipeline.control_loop`)."""
    from dynid.model.closures import JointCoordinates
    from dynid.model.robot import joint_kinds
    from dynid.simulation.loop_checks import declared_limits, loop_warnings, unstable_state

    bad = unstable_state(t, u, tau)
    if bad is not None and replay:
        raise InputError(f"the replayed experiment is unstable: the state or the efforts are no longer finite from "
                         f"t = {t[bad]:.4g} s")
    if bad is not None:
        raise ConfigError(f"control: the loop is unstable: the state or the efforts are no longer finite from t = "
                          f"{t[bad]:.4g} s ({c.kind} at {c.rate_hz:g} Hz, kp {_short(c.kp)}, kd {_short(c.kd)}); lower the "
                          "gains or raise control.rate_hz (docs/guide/simulation.md gives the gains' units)")
    act = list(robot.actuated) if mech else list(range(robot.dof))
    kinds = joint_kinds(robot.pin_model)
    ind = robot.independent if mech else None
    coord_kinds = ([kinds[j] for j in ind.joints] if isinstance(ind, JointCoordinates) else ["prismatic"] * len(coord_names)
                   ) if mech else list(kinds)
    position_unit = {"prismatic": "m"}
    effort_unit = {"prismatic": "N"}
    return loop_warnings(t, u_ref, u, coord_names, [position_unit.get(k, "rad") for k in coord_kinds], tau,
                         declared_limits(np.asarray(robot.pin_model.effortLimit)[act]), act_names,
                         [effort_unit.get(kinds[j], "N*m") for j in act])


def _short(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float)) else "[" + ", ".join(f"{v:g}" for v in value) + "]"


def actuator_states(outcome: SimulationOutcome) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The true actuator states of a simulation at the control instants: ``t`` (n,), positions,
    velocities, accelerations (n, n_a) (accelerations at the start of each hold, under the held
    forces)."""
    motion = outcome.motion
    robot = load_simulated_robot(outcome.config)
    act = list(robot.actuated) if isinstance(robot, Mechanism) else slice(None)
    return motion.t, motion.q[:, act], motion.dq[:, act], motion.ddq[:, act]


def _jsonable_metrics(track: dict) -> dict:
    return {k: (np.asarray(v).tolist() if not isinstance(v, float) else v) for k, v in track.items()}


def write_simulation(outcome: SimulationOutcome, out_dir: str | Path) -> list[str]:
    """Write the files of the module docstring into ``out_dir`` (all or nothing)."""
    cfg = outcome.config
    names = []
    with staged_output(out_dir) as stage:
        if cfg.output_format == "csv":
            header = ",".join(outcome.columns)
            table = np.column_stack(list(outcome.columns.values()))
            np.savetxt(stage / "log.csv", table, delimiter=",", header=header, comments="", fmt="%.17g")
            names.append("log.csv")
        else:
            save_npz(stage / "log.npz", outcome.columns)
            names.append("log.npz")
        (stage / "truth.json").write_text(json.dumps(outcome.truth, indent=2) + "\n")
        (stage / "metadata.json").write_text(json.dumps(outcome.metadata, indent=2, default=str) + "\n")
        write_timing(stage, {"simulation_s": outcome.elapsed_s})
        names += ["truth.json", "metadata.json", TIMING_FILE]
        if cfg.source is not None:
            (stage / "config.toml").write_text(Path(cfg.source).read_text())
            names.append("config.toml")
    return names
