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
from dynid.errors import ConfigError, InputError, ModelError
from dynid.io.output import staged_output
from dynid.model.closed_loop import mechanism_base_parameters
from dynid.model.loading import load_model
from dynid.model.mechanism import JointCoordinates, Mechanism
from dynid.model.base_parameters import robot_base_parameters
from dynid.pipeline.control_model import controller_parameters
from dynid.simulation.closed_loop import (ActuatorReference, AugmentedPD, ConstrainedSimulator, DecentralizedPID,
                                          simulate_mechanism_control)
from dynid.simulation.control import ComputedTorque, FeedforwardPID, JointPID, SerialPlant, model_inverse, simulate_control
from dynid.trajectories import ConstantVelocityExperiment, zyx_angular_velocity
from dynid.simulation.sensors import Measurements, Sensors
from dynid.stats import tracking_errors
from dynid.pipeline.sim_trajectory import _check_reference_limits, _coordinate_box, _trajectory  # noqa: F401  (tests)

__all__ = ["SimulationOutcome", "TrueSignals", "actuator_states", "load_simulated_robot", "measure_signals", "run_simulation",
           "write_simulation", "SIMULATION_FILES"]

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


def load_simulated_robot(cfg: SimulateConfig):
    """The model of ``[robot]``: ``model`` with its chart (``actuated``, ``independent``) and its
    rotor inertias (``rotor_inertia``)."""
    r = cfg.robot
    return load_model(r.model, actuated=r.actuated, independent=r.independent, rotor_inertia=r.rotor_inertia)


def _true_parameters(robot, nominal: np.ndarray, cfg: SimulateConfig) -> np.ndarray:
    """The twin's truth: ``perturbation`` away from the nominal model, body by body in mass, centre
    of mass and principal second moments, so that a physically consistent nominal model gives a
    physically consistent truth (:func:`dynid.model.base_parameters.perturb_bodies`)."""
    if cfg.robot.perturbation == 0:
        return nominal.copy()
    from dynid.model.base_parameters import perturb_bodies

    return perturb_bodies(nominal, robot.body_blocks(), cfg.robot.perturbation,
                          np.random.default_rng(cfg.robot.perturbation_seed))


def _gains(value, n: int, where: str, what: str = "independent coordinates") -> np.ndarray:
    g = np.asarray(value, dtype=float)
    if g.ndim == 1 and g.size != n:
        raise ConfigError(f"control.{where} has {g.size} entries; the robot has {n} {what}")
    return np.broadcast_to(g, (n,)).copy()


def _payload(cfg: SimulateConfig, robot):
    """``[robot.payload]``: the name and pinocchio joint index of the body that carries it, and its
    ``pinocchio.Inertia`` in that joint's frame (None without a payload).

    Serial robots: any joint's body, default the last. Mechanisms: a body with parameters (not a
    massless virtual body), default the platform (the joint of the last task coordinate)."""
    pl = cfg.robot.payload
    if pl is None:
        return None
    import pinocchio as pin

    names = list(robot.pin_model.names)
    if isinstance(robot, Mechanism):
        carriers = [names[j] for j in robot.bodies]
        if "body" in pl:
            body = pl["body"]
        elif robot.task_coordinates:
            body = robot.task_coordinates[-1]
        else:
            raise ConfigError(f"robot.payload.body: {robot.name!r} declares no platform; name the body that carries the "
                              f"payload, one of {carriers}")
        if body not in names[1:]:
            raise ConfigError(f"robot.payload.body = {body!r} is no joint of {robot.name!r}; one of {carriers}")
        if names.index(body) not in robot.bodies:
            raise ConfigError(f"robot.payload.body = {body!r} is a massless (virtual) body of {robot.name!r}; "
                              f"a payload goes on one of {carriers}")
    else:
        body = pl.get("body", names[-1])
        if body not in names[1:]:
            raise ConfigError(f"robot.payload.body = {body!r} is no joint of {robot.name!r}; one of {names[1:]}")
    inertia = pin.Inertia(pl["mass"], np.asarray(pl["com"], float), np.diag(np.asarray(pl["inertia"], float)))
    return body, names.index(body), inertia


def _with_payload(robot, params: np.ndarray, joint: int, payload) -> np.ndarray:
    """The standard parameters of ``robot`` with the payload's dynamic parameters
    ``[m, m c, I about the joint origin]`` added to the block of body ``joint`` (pinocchio joint
    index): the true model of the simulator (a mechanism's plant; a serial plant adds the same
    inertia to its pinocchio body, :class:`~dynid.simulation.control.SerialPlant`), and truth.json's
    ``true_parameters_with_payload`` and base ``true_values``."""
    k = robot.bodies.index(joint) if isinstance(robot, Mechanism) else joint - 1
    out = np.array(params, dtype=float)
    out[10 * k : 10 * k + 10] += np.asarray(payload.toDynamicParameters(), dtype=float)
    return out


def _friction_model(spec: dict | None, n: int):
    """The ground-truth friction model of ``[robot.friction]`` for ``n`` joints, or None."""
    if spec is None:
        return None
    from dynid.model import friction as fr

    cls = {"coulomb_viscous": fr.CoulombViscous, "stribeck": fr.Stribeck, "power_law": fr.PowerLawViscous,
           "smooth_stribeck": fr.SmoothStribeck}[spec["model"]]
    kw, memory = {}, None
    for k, v in spec.items():
        if k == "model":
            continue
        a = np.asarray(v, dtype=float)
        if a.ndim == 1 and a.size != n:
            raise ConfigError(f"robot.friction.{k} has {a.size} entries; the friction acts on {n} joints")
        if k == "memory":
            memory = a
            continue
        kw[k] = a
    steady = cls(**kw)
    return steady if memory is None else fr.FrictionMemory(steady, memory)


def _replaced_friction(robot, mech: bool) -> list[str]:
    """The linear friction parameters that ``[robot.friction]`` replaces in the plant: every
    friction extra of a serial robot (``fv``, ``fc``, their asymmetric forms, ``offset``: the plant
    uses the configured model instead, :class:`~dynid.simulation.control.SerialPlant`), or every
    non-inertia joint term acting only on an actuated joint of a mechanism (the passive joints
    keep theirs, :func:`_mechanism_friction`). truth.json records them as 0 (the plant has no
    such term beyond the configured model) and lists them: the values the robot description or
    its perturbation gave them never reached the plant."""
    if mech:
        act = set(robot.actuated)
        return [t.name for t in robot.terms if t.kind != "inertia" and set(t.joints) <= act]
    lay = robot.layout
    names = list(robot.parameter_names)
    return [names[i] for e, idx in lay.extra_index.items() if e != "Ia" for i in idx]


def _mechanism_friction(mech: Mechanism, params: np.ndarray, model):
    """Generalized friction forces: the joint terms' friction on the passive joints and
    ``model`` on the actuated ones (rotor inertias stay in the simulator)."""
    from dynid.model.closed_loop import term_columns

    nb = mech.n_body_params
    theta = np.array(params[nb:], dtype=float)
    theta[[k for k, t in enumerate(mech.terms) if t.kind == "inertia"]] = 0.0
    act = list(mech.actuated)

    def forces(dq):
        f = term_columns(mech, dq[None], np.zeros((1, dq.size)))[0] @ theta
        f[act] = model.force(dq[act])[0]
        return f

    return forces


def _force_covariance(s, n_a: int) -> np.ndarray:
    if s.force_covariance is not None:
        cov = np.array(s.force_covariance, dtype=float)
        if cov.shape != (n_a, n_a):
            raise ConfigError(f"sensors.force_covariance must be {n_a} x {n_a}, got {cov.shape}")
        return cov
    std = np.asarray(s.force_noise_std, dtype=float)
    if std.ndim == 1 and std.size != n_a:
        raise ConfigError(f"sensors.force_noise_std has {std.size} entries for {n_a} actuators")
    std = np.broadcast_to(std, (n_a,))
    corr = (1 - s.force_correlation) * np.eye(n_a) + s.force_correlation * np.ones((n_a, n_a))
    return std[:, None] * corr * std[None, :]


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
    """
    t0 = time.perf_counter()
    outcome = _run_simulation(cfg, progress, robot, plant, coulomb_band)
    return dataclasses.replace(outcome, elapsed_s=time.perf_counter() - t0)


def _run_simulation(cfg: SimulateConfig, progress: Progress | None, variant=None,
                    plant_params: np.ndarray | None = None, coulomb_band: float | None = None) -> SimulationOutcome:
    robot = load_simulated_robot(cfg)
    if variant is not None:
        if list(variant.parameter_names) != list(robot.parameter_names):
            raise ModelError(f"the variant of {cfg.robot.model} has other parameters than the model itself")
        robot = variant
    mech = isinstance(robot, Mechanism)
    as_loaded = robot  # the robot dynid identify builds (its base parameters)
    if cfg.trajectory.values["coordinates"] == "task":
        if not mech:
            raise ConfigError("trajectory.coordinates = 'task' is for parallel robots (a serial robot moves in joint space here)")
        robot = robot.in_task_space()
    nominal = robot.nominal_parameters()
    true = _true_parameters(robot, nominal, cfg)
    payload = _payload(cfg, robot)
    c = cfg.control
    model_params, model_used = controller_parameters(c.model, cfg.base_dir, as_loaded, nominal, true)
    traj, coord_names = _trajectory(cfg, robot)
    duration = cfg.duration if cfg.duration is not None else float(getattr(traj, "duration", None) or traj.period)
    dt = 1.0 / c.rate_hz
    n_u = len(coord_names)
    if not mech:
        _check_reference_limits(traj, duration, dt, robot, coord_names)
    n_act = robot.n_actuators if mech else robot.dof
    if c.kind == "computed_torque":
        kp, kd = _gains(c.kp, n_u, "kp"), _gains(c.kd, n_u, "kd")
    else:  # a PID per joint (serial) or per actuator (mechanism: decentralized, paper 002 Section 5.4)
        what = "actuators (one PID per actuator)" if mech else "independent coordinates"
        kp, kd, ki = (_gains(v, n_act, k, what) for v, k in ((c.kp, "kp"), (c.kd, "kd"), (c.ki, "ki")))
    s = cfg.sensors
    log_rate = s.log_rate_hz or c.rate_hz
    ratio = c.rate_hz / log_rate
    if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
        raise ConfigError(f"sensors.log_rate_hz = {log_rate:g} must divide control.rate_hz = {c.rate_hz:g}")
    for key in ("encoder_resolution", "position_noise_std", "torque_constants"):
        value = getattr(s, key)
        if isinstance(value, tuple) and len(value) != n_act:
            raise ConfigError(f"sensors.{key} has {len(value)} entries for {n_act} actuators")
    sensors = Sensors(
        encoder_resolution=s.encoder_resolution, position_noise_std=s.position_noise_std,
        force_covariance=_force_covariance(s, n_act), torque_constants=s.torque_constants,
        decimation=int(round(ratio)), time_jitter_std=s.time_jitter_std, seed=s.seed,
    )
    sensors.check(n_act)  # refuse a bad covariance now, not after the simulation
    track_actuators = None
    if mech:
        distribution = c.distribution if robot.redundant else None
        reference = traj.sample
        if c.kind == "computed_torque":
            ctrl = AugmentedPD(robot, model_params, kp, kd, distribution)
        else:
            reference = ActuatorReference(robot, traj.sample, model_params if c.kind == "feedforward_pid" else None,
                                          distribution)
            ctrl = DecentralizedPID(robot, JointPID(kp=kp, kd=kd, ki=ki))
        if cfg.robot.friction is not None and "memory" in cfg.robot.friction:
            raise ConfigError("robot.friction.memory: friction with memory is simulated on serial robots only (the "
                              "constrained simulator has no friction state)")
        fmodel = _friction_model(cfg.robot.friction, robot.n_actuators)
        override = None
        if fmodel is not None and plant_params is None:
            override = _mechanism_friction(robot, true, fmodel)
        plant = true if payload is None else _with_payload(robot, true, payload[1], payload[2])
        if plant_params is not None:
            plant = np.asarray(plant_params, dtype=float)
        band = coulomb_band if plant_params is not None else None
        motion = simulate_mechanism_control(ConstrainedSimulator(robot, plant, friction=override, coulomb_band=band), ctrl,
                                            reference,
                                            duration=duration, dt=dt, substeps=c.substeps)
        q_act = motion.q[:, list(robot.actuated)]
        if c.kind != "computed_torque":  # the drives' own errors (paper 002, Fig. 10; paper 004, Fig. 6)
            track_actuators = tracking_errors(reference(motion.t)[3], q_act)
        tau = motion.tau_a
        u = robot.coordinates(motion.q)
        act_names = robot.actuated_names
        constraint = float(np.abs(robot.constraint_residual(motion.q[:: max(1, motion.t.size // 200)])).max())
    else:
        if plant_params is not None:
            plant = SerialPlant(robot, np.asarray(plant_params, dtype=float))
        else:
            plant = SerialPlant(robot, true, friction=_friction_model(cfg.robot.friction, robot.dof),
                                payload=None if payload is None else payload[2],
                                payload_joint=None if payload is None else payload[1])
        inverse = model_inverse(robot, model_params)
        if c.kind == "computed_torque":
            ctrl = ComputedTorque(inverse, kp, kd)
        else:
            pid = JointPID(kp=kp, kd=kd, ki=ki)
            ctrl = pid if c.kind == "pid" else FeedforwardPID(inverse, pid)
        motion = simulate_control(plant, ctrl, traj.sample, duration=duration, dt=dt, substeps=c.substeps)
        q_act, tau, u = motion.q, motion.tau, motion.q
        act_names = list(robot.joint_names)
        constraint = None
    u_ref = traj.sample(motion.t)[0]
    warnings = _loop_warnings(robot, mech, c, motion.t, u_ref, u, coord_names, tau, act_names, replay=plant_params is not None)
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
                          sensors=sensors)
    meas, columns = measure_signals(signals)
    effort_prefix = "i" if meas.effort_kind == "current" else "tau"
    base = None
    if plant_params is None:  # a replay's truth goes without them (run_simulation)
        base = mechanism_base_parameters(robot) if mech else robot_base_parameters(robot)
    replaced = _replaced_friction(robot, mech) if cfg.robot.friction is not None and plant_params is None else []
    recorded = np.array(true, dtype=float)
    recorded[[list(robot.parameter_names).index(n) for n in replaced]] = 0.0
    loaded = recorded if payload is None else _with_payload(robot, recorded, payload[1], payload[2])
    truth = {
        "model": cfg.robot.model if variant is None else f"variant of {cfg.robot.model}",
        "parameter_names": list(robot.parameter_names),
        "true_parameters": recorded.tolist(),
        **({"replaced_by_ground_truth_friction": replaced} if replaced else {}),
        "nominal_parameters": nominal.tolist(),
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
                    "model_used": model_used},
        "log_rate_hz": log_rate,
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
                          "gains or raise control.rate_hz (README 'Virtual experiments' gives the gains' units)")
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
