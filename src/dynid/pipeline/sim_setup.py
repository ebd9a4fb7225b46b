"""The set-up of a ``dynid simulate`` run (issue 38): one :class:`SimulationSetup` built from the
configuration by :func:`simulation_setup`, the true robot (perturbation, payload, ground-truth
friction), the commanded trajectory (:mod:`dynid.pipeline.sim_trajectory`), the sensors and the
control loop, handed to :mod:`dynid.pipeline.simulate`, which steps and records it."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from dynid.config.simulate import SimulateConfig
from dynid.errors import ConfigError, ModelError
from dynid.model.loading import load_model
from dynid.model.mechanism import Mechanism
from dynid.pipeline.control_model import controller_parameters
from dynid.pipeline.sim_trajectory import _check_reference_limits, _trajectory
from dynid.simulation.closed_loop import ActuatorReference, AugmentedPD, ConstrainedSimulator, DecentralizedPID
from dynid.simulation.control import ComputedTorque, FeedforwardPID, JointPID, SerialPlant, model_inverse
from dynid.simulation.sensors import Sensors

__all__ = ["SimulationSetup", "load_simulated_robot", "simulation_setup"]


@dataclasses.dataclass(frozen=True, eq=False)
class SimulationSetup:
    """Everything one virtual experiment is set up with, built once from the configuration by
    :func:`simulation_setup` and then handed, unchanged, to the stepping
    (:func:`~dynid.pipeline.simulate._simulate`) and the recording (:func:`~dynid.pipeline.simulate._record`):

    * the robot as simulated (``robot``: in task space for ``trajectory.coordinates = "task"``) and
      as loaded (``as_loaded``: what ``dynid identify`` builds), whether it is a mechanism, whether it
      is a variant built in code, whether the run is a replay on given plant parameters;
    * its nominal and true standard parameters, the payload (body name, pinocchio joint index,
      ``pinocchio.Inertia``; None without) and the ground-truth friction model of
      ``[robot.friction]`` (None without);
    * the commanded trajectory, the names of its coordinates, the duration and the control period;
    * the controller, the reference it follows, the plant it drives (a serial robot's
      :class:`~dynid.simulation.control.SerialPlant` or a mechanism's
      :class:`~dynid.simulation.closed_loop.ConstrainedSimulator`) and the record of the model the
      controller uses;
    * the sensors (noise settings, decimation to the log rate, their seed) and the log rate;
    * the seeds of the run's random draws (``seeds``): ``perturbation`` (the truth) and
      ``trajectory`` (a random Fourier reference), each drawn here from a generator of its own, and
      ``sensors`` (the measurement noise, drawn when the sensors measure:
      :func:`~dynid.pipeline.simulate.measure_signals`, which may replace it). The same seeds give the same run bit for bit.
    """

    cfg: SimulateConfig
    robot: Any
    as_loaded: Any
    mech: bool
    variant: bool
    replay: bool
    nominal: np.ndarray
    true: np.ndarray
    payload: tuple | None
    friction: Any
    trajectory: Any
    coord_names: list[str]
    duration: float
    dt: float
    controller: Any
    reference: Callable
    plant: Any
    model_used: dict
    sensors: Sensors
    log_rate: float
    seeds: dict[str, int | None]


def _seeds(cfg: SimulateConfig) -> dict[str, int | None]:
    """The seeds of a run's random draws (:attr:`SimulationSetup.seeds`); ``trajectory`` None: the
    trajectory draws nothing."""
    return {"perturbation": cfg.robot.perturbation_seed, "trajectory": cfg.trajectory.values.get("seed"),
            "sensors": cfg.sensors.seed}


def simulation_setup(cfg: SimulateConfig, variant=None, plant_params: np.ndarray | None = None,
                     coulomb_band: float | None = None) -> SimulationSetup:
    """The :class:`SimulationSetup` of ``cfg`` (``variant``, ``plant_params``, ``coulomb_band``: those
    of :func:`~dynid.pipeline.simulate.run_simulation`); every check of the configuration against the robot is made here,
    before any stepping."""
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
    seeds = _seeds(cfg)
    nominal = robot.nominal_parameters()
    true = _true_parameters(robot, nominal, cfg, np.random.default_rng(seeds["perturbation"]))
    payload = _payload(cfg, robot)
    c = cfg.control
    model_params, model_used = controller_parameters(c.model, cfg.base_dir, as_loaded, nominal, true)
    rng = None if seeds["trajectory"] is None else np.random.default_rng(seeds["trajectory"])
    traj, coord_names = _trajectory(cfg, robot, rng)
    duration = cfg.duration if cfg.duration is not None else float(getattr(traj, "duration", None) or traj.period)
    dt = 1.0 / c.rate_hz
    n_u = len(coord_names)
    if not mech:
        _check_reference_limits(traj, duration, dt, robot, coord_names)
    n_act = robot.n_actuators if mech else robot.dof
    if c.kind == "computed_torque":
        gains = {"kp": _gains(c.kp, n_u, "kp"), "kd": _gains(c.kd, n_u, "kd")}
    else:  # a PID per joint (serial) or per actuator (mechanism: decentralized, paper 002 Section 5.4)
        what = "actuators (one PID per actuator)" if mech else "independent coordinates"
        gains = {k: _gains(v, n_act, k, what) for v, k in ((c.kp, "kp"), (c.kd, "kd"), (c.ki, "ki"))}
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
        decimation=int(round(ratio)), time_jitter_std=s.time_jitter_std, seed=seeds["sensors"],
    )
    sensors.check(n_act)  # refuse a bad covariance now, not after the simulation
    loop = _mechanism_loop if mech else _serial_loop
    controller, reference, plant, friction = loop(cfg, robot, traj, model_params, gains, true, payload, plant_params,
                                                  coulomb_band)
    return SimulationSetup(cfg=cfg, robot=robot, as_loaded=as_loaded, mech=mech, variant=variant is not None,
                           replay=plant_params is not None, nominal=nominal, true=true, payload=payload,
                           friction=friction, trajectory=traj, coord_names=coord_names, duration=duration, dt=dt,
                           controller=controller, reference=reference, plant=plant, model_used=model_used,
                           sensors=sensors, log_rate=log_rate, seeds=seeds)


def _mechanism_loop(cfg: SimulateConfig, robot: Mechanism, traj, model_params: np.ndarray, gains: dict, true: np.ndarray,
                    payload, plant_params: np.ndarray | None, coulomb_band: float | None):
    """A mechanism's (controller, reference, plant, ground-truth friction model)."""
    c = cfg.control
    distribution = c.distribution if robot.redundant else None
    reference = traj.sample
    if c.kind == "computed_torque":
        ctrl = AugmentedPD(robot, model_params, gains["kp"], gains["kd"], distribution)
    else:
        reference = ActuatorReference(robot, traj.sample, model_params if c.kind == "feedforward_pid" else None,
                                      distribution)
        ctrl = DecentralizedPID(robot, JointPID(kp=gains["kp"], kd=gains["kd"], ki=gains["ki"]))
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
    return ctrl, reference, ConstrainedSimulator(robot, plant, friction=override, coulomb_band=band), fmodel


def _serial_loop(cfg: SimulateConfig, robot, traj, model_params: np.ndarray, gains: dict, true: np.ndarray, payload,
                 plant_params: np.ndarray | None, coulomb_band: float | None):
    """A serial robot's (controller, reference, plant, ground-truth friction model); ``coulomb_band`` is
    a mechanism's only."""
    c = cfg.control
    fmodel = None
    if plant_params is not None:
        plant = SerialPlant(robot, np.asarray(plant_params, dtype=float))
    else:
        fmodel = _friction_model(cfg.robot.friction, robot.dof)
        plant = SerialPlant(robot, true, friction=fmodel, payload=None if payload is None else payload[2],
                            payload_joint=None if payload is None else payload[1])
    inverse = model_inverse(robot, model_params)
    if c.kind == "computed_torque":
        ctrl = ComputedTorque(inverse, gains["kp"], gains["kd"])
    else:
        pid = JointPID(kp=gains["kp"], kd=gains["kd"], ki=gains["ki"])
        ctrl = pid if c.kind == "pid" else FeedforwardPID(inverse, pid)
    return ctrl, traj.sample, plant, fmodel


def load_simulated_robot(cfg: SimulateConfig):
    """The model of ``[robot]``: ``model`` with its chart (``actuated``, ``independent``) and its
    rotor inertias (``rotor_inertia``)."""
    r = cfg.robot
    return load_model(r.model, actuated=r.actuated, independent=r.independent, rotor_inertia=r.rotor_inertia)


def _true_parameters(robot, nominal: np.ndarray, cfg: SimulateConfig, rng: np.random.Generator) -> np.ndarray:
    """The twin's truth: ``perturbation`` away from the nominal model, body by body in mass, centre
    of mass and principal second moments, so that a physically consistent nominal model gives a
    physically consistent truth (:func:`dynid.model.base_parameters.perturb_bodies`). ``rng``: the
    generator of ``perturbation_seed``."""
    if cfg.robot.perturbation == 0:
        return nominal.copy()
    from dynid.model.base_parameters import perturb_bodies

    return perturb_bodies(nominal, robot.body_blocks(), cfg.robot.perturbation, rng)


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
