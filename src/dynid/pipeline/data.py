"""From log files to processed joint-space datasets, as the configuration says.

Steps (each recorded in the returned provenance, in order):

1. read the named columns, convert units to SI, cut the row or time window;
2. map motor-side positions and efforts to joint space through the transmission
   (``q = C^{-1} θ + q0``, ``τ = C^T K i``);
3. resample irregular timestamps onto a uniform grid (``processing.resample``);
4. zero-phase Butterworth low-pass of positions (and efforts) with the cut-off in Hz;
5. velocities and accelerations by central differences (or measured ones);
6. trim the filter transients at both ends, then keep one sample in ``decimate``
   (``decimate_method = "samples"``), or leave the data at full rate for the parallel
   decimation of regressor and efforts done while the problem is built
   (``decimate_method = "parallel"``, Gautier; see :mod:`dynid.pipeline.identification`).
"""

from __future__ import annotations

import dataclasses

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import EFFORT_UNITS, POSITION_UNITS, TIME_UNITS, DataConfig, ProcessingConfig, RobotConfig
from dynid.dataset import Dataset
from dynid.errors import ConfigError, IdentifiabilityError, InputError
from dynid.io.bags import BagReader
from dynid.io.readers import TableReader
from dynid.model.mechanism import Mechanism
from dynid.model.system import System, as_system, with_actuator_extras, with_motor_terms
from dynid.model.transmission import Coupling, Transmission
from dynid.signals import central_difference, lowpass, padlen_for, resample_uniform
from dynid.pipeline.estimator_config import configured_estimator, ml_covariances, physical_options  # noqa: F401  (re-exported)

__all__ = ["build_system", "build_robot", "to_actuator_space", "check_units", "read_log", "check_held_out", "to_joint_space", "preprocess", "check_joint_motion", "velocity_mask", "reversal_keep", "velocity_noise_std"]

_TORQUE_UNITS = ("N*m", "Nm", "N.m", "mN*m")
_FORCE_UNITS = ("N",)
_ANGLE_UNITS = ("rad", "deg")
_LENGTH_UNITS = ("m", "mm")


def build_system(cfg: RobotConfig) -> System:
    """The robot of ``[robot]`` as a :class:`~dynid.model.system.System`: the model (serial or
    closed-loop), the actuator extras (a mechanism gains the extras named in the file as joint
    terms on its actuated joints) and the drive train of its actuators (gear ratios, couplings,
    drive gains, encoder offsets), for serial and parallel robots alike."""
    from dynid.model.loading import load_model

    model = load_model(cfg.model, extras=cfg.extras, actuated=cfg.actuated, independent=cfg.independent,
                       rotor_inertia=cfg.rotor_inertia)
    if isinstance(model, Mechanism) and cfg.extras_given:
        model = with_actuator_extras(model, cfg.extras)
    system = as_system(model)
    if not cfg.has_transmission:
        return system
    n = system.n_actuators
    for key, val in (("gear_ratios", cfg.gear_ratios), ("drive_gains", cfg.drive_gains), ("position_offset", cfg.position_offset)):
        if val is not None and len(val) != n:
            raise ConfigError(f"robot.{key}: {len(val)} entries for a robot with {n} "
                              f"{'joints' if system.kind == 'serial' else 'actuators'} ({', '.join(system.actuator_names)})")
    transmission = Transmission.from_ratios(
        cfg.gear_ratios if cfg.gear_ratios is not None else np.ones(n),
        [Coupling(c.motor, c.joints, c.weights) for c in cfg.couplings],
        drive_gains=cfg.drive_gains if cfg.drive_gains is not None else 1.0,
        position_offset=cfg.position_offset if cfg.position_offset is not None else 0.0,
    )
    if isinstance(model, Mechanism):
        model = with_motor_terms(model, transmission, cfg.extras)
    return as_system(model, transmission)


def build_robot(cfg: RobotConfig):
    """The model of :func:`build_system` (a :class:`RobotModel` with its transmission, or a
    :class:`~dynid.model.mechanism.Mechanism`)."""
    return build_system(cfg).model


def _units(sig, n: int, label: str) -> tuple[str | None, ...]:
    """The unit of each of the ``n`` channels of a signal (None: SI)."""
    if isinstance(sig.unit, tuple):
        if len(sig.unit) != n:
            raise ConfigError(f"{label}.unit: {len(sig.unit)} units for {n} channels")
        return sig.unit
    return (sig.unit,) * n


def check_units(spec: DataConfig, kinds: Sequence[str], names: Sequence[str], label: str) -> None:
    """Refuse units that do not fit the joints the columns measure: ``kinds`` holds
    ``"revolute"`` or ``"prismatic"`` per channel (the joints of a serial robot, the actuated
    joints of a mechanism). Joint-side positions (and velocities, accelerations) of a revolute
    joint are angles, of a prismatic one lengths; joint-side torques act on revolute joints,
    forces on prismatic ones. Motor-side signals are those of a rotary motor: angles, and torques
    or currents."""
    mixed = len(set(kinds)) > 1

    def refuse(what: str, unit: str, j: int, want: tuple[str, ...], side: str) -> None:
        quantity = {"rad": "an angle", "deg": "an angle", "m": "a length", "mm": "a length", "N": "a force"}.get(unit, "a torque")
        one_for_all = isinstance(getattr(spec, what).unit, str)
        hint = (f" (joints of both kinds take one unit per column: {label}.{what}.unit = [...])"
                if mixed and one_for_all and side == "joint" else "")
        raise ConfigError(f"{label}.{what}.unit = {unit!r} is {quantity}, but {side} {names[j]!r} is "
                          f"{kinds[j] if side == 'joint' else 'a rotary motor'}: use "
                          f"{' or '.join(repr(u) for u in want)}{hint}")

    n = len(kinds)
    signals = [(w, getattr(spec, w)) for w in ("position", "velocity", "acceleration")]
    signals += [("effort", spec.effort)] if spec.effort.kind == "torque" else []
    for what, sig in signals:
        if sig is None or sig.unit is None:
            continue
        side = "joint" if sig.side == "joint" else "the motor of joint"
        for j, (kind, unit) in enumerate(zip(kinds, _units(sig, n, f"{label}.{what}"))):
            if what == "effort":
                want = _FORCE_UNITS if kind == "prismatic" and sig.side == "joint" else _TORQUE_UNITS
            else:
                want = _LENGTH_UNITS if kind == "prismatic" and sig.side == "joint" else _ANGLE_UNITS
            if unit is not None and unit not in want:
                refuse(what, unit, j, want, side)


def _scale(table: dict[str, float], sig, n: int, label: str) -> FloatArray | float:
    """The factor to SI of each channel (no unit: the signal is in SI units already)."""
    if sig.unit is None:
        return 1.0
    return np.array([1.0 if u is None else table[u] for u in _units(sig, n, label)])


def _constant_efforts(ds: Dataset, columns: Sequence[str], path: Path, label: str) -> None:
    """Refuse effort channels that hold one value in every sample: they carry no information
    (a disconnected sensor, a column of zeros)."""
    tau = ds.tau
    const = [j for j in range(tau.shape[1]) if np.all(tau[:, j] == tau[0, j])]
    if not const:
        return
    n = ds.n_samples
    if len(const) == tau.shape[1] and not np.any(tau):
        raise InputError(f"{label}.effort: every column of {path.name} ({', '.join(columns)}) is 0 in all {n} samples: "
                         "the log holds no efforts")
    detail = ", ".join(f"{columns[j]!r} is {tau[0, j]:g}" for j in const)
    raise InputError(f"{label}.effort: {path.name}: {detail} in all {n} samples; a constant channel carries no "
                     "information (a disconnected sensor?)")


def log_meta(spec: DataConfig, files: dict, readers: dict) -> dict:
    """A log's provenance (the dataset's ``meta``): which sides and kind its signals are, the files
    of its columns (``files``: signal -> path) with their SHA-256 (``readers``: path -> reader), and
    the window read. The streamed path (:mod:`dynid.pipeline.streaming`) records the same."""
    return {
        "position_side": spec.position.side,
        "effort_kind": spec.effort.kind,
        "effort_side": spec.effort.side if spec.effort.kind == "torque" else "motor",
        **({"drive_gains": list(spec.effort.drive_gains)} if spec.effort.drive_gains else {}),
        "source": {k: str(v) for k, v in files.items()},
        "sha256": {str(p): readers[p].sha256() for p in dict.fromkeys(files.values())},
        "window": {"rows": list(spec.rows)} if spec.rows else ({"time": list(spec.time_window)} if spec.time_window else "all"),
    }


def read_log(
    spec: DataConfig, n_channels: int, names: tuple[str, ...], label: str, readers: dict[Path, TableReader] | None = None
) -> Dataset:
    """Read the columns named in ``spec`` into a raw :class:`Dataset` (SI units, window cut).

    ``readers`` caches open files across calls (training and validation windows of one
    log are read and hashed once).
    """
    readers = {} if readers is None else readers

    def reader(path: Path) -> TableReader:
        if path not in readers:
            readers[path] = BagReader(path) if spec.bag else TableReader(path, header=spec.header)
        return readers[path]

    def columns(sig, what: str, scale: float) -> tuple[FloatArray, Path]:
        path = sig.file or spec.file
        arr = bag_signals[what] if spec.bag else reader(path).columns(sig.columns)
        if arr.shape[1] != n_channels:
            raise InputError(f"{label}.{what}: {arr.shape[1]} columns for a robot with {n_channels} joints")
        return arr * scale, path

    bag_signals: dict[str, FloatArray] = {}
    if spec.bag:
        t, bag_signals, topics = _read_bag(spec, reader(spec.file), label)
    q, q_file = columns(spec.position, "position", _scale(POSITION_UNITS, spec.position, n_channels, f"{label}.position"))
    tau, tau_file = columns(spec.effort, "effort",
                            _scale(EFFORT_UNITS[spec.effort.kind], spec.effort, n_channels, f"{label}.effort"))
    extra: dict[str, FloatArray] = {}
    files = {"position": q_file, "effort": tau_file}
    for what, sig in (("velocity", spec.velocity), ("acceleration", spec.acceleration)):
        if sig is not None:
            extra[what], files[what] = columns(sig, what, _scale(POSITION_UNITS, sig, n_channels, f"{label}.{what}"))
    if spec.bag:
        files["time"] = spec.file
    elif spec.time is not None:
        tpath = spec.time.file or spec.file
        t = reader(tpath).columns([spec.time.column])[:, 0] * TIME_UNITS[spec.time.unit]
        files["time"] = tpath
    else:
        t = np.arange(q.shape[0]) / spec.sample_rate_hz
    lengths = {"time": t.shape[0], "position": q.shape[0], "effort": tau.shape[0], **{k: v.shape[0] for k, v in extra.items()}}
    if len(set(lengths.values())) > 1:
        detail = ", ".join(f"{k} ({files.get(k, 'sample_rate_hz')}) {v}" for k, v in lengths.items())
        raise InputError(f"{label}: mismatched lengths: {detail}")
    sl = slice(None)
    if spec.rows is not None:
        start, stop = spec.rows
        if stop > q.shape[0]:
            raise InputError(f"{label}.rows: stop {stop} is beyond the {q.shape[0]} rows of the log")
        sl = slice(start, stop)
    elif spec.time_window is not None:
        idx = np.flatnonzero((t >= spec.time_window[0]) & (t < spec.time_window[1]))
        if idx.size < 2:
            raise InputError(f"{label}.time_window {list(spec.time_window)} s selects {idx.size} samples")
        sl = slice(int(idx[0]), int(idx[-1]) + 1)
    meta = log_meta(spec, files, readers)
    if spec.bag:
        meta["ros_topics"] = topics
        meta["time_source"] = spec.time.column
    try:
        ds = Dataset(
            t=t[sl],
            q=q[sl],
            tau=tau[sl],
            dq=extra["velocity"][sl] if "velocity" in extra else None,
            ddq=extra["acceleration"][sl] if "acceleration" in extra else None,
            names=names,
            meta=meta,
        )
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None
    _constant_efforts(ds, spec.effort.columns if len(spec.effort.columns) == n_channels else
                      tuple(f"{spec.effort.columns[0]}[{j}]" for j in range(n_channels)), tau_file, label)
    return ds


def _read_bag(spec: DataConfig, bag: BagReader, label: str) -> tuple[FloatArray, dict[str, FloatArray], dict[str, str]]:
    """The signals of a ROS bag log on one time base: the messages of the position topic, their time
    (header stamps or receive times, ``spec.time.column``) in s from the first message. A signal on
    another topic whose messages have the same stamps is taken message for message; otherwise it is
    interpolated linearly onto the position times, and the rows outside its time span are left out
    (both recorded in the provenance). Times must increase strictly on every topic."""
    source = spec.time.column
    signals = {w: s for w, s in (("position", spec.position), ("effort", spec.effort), ("velocity", spec.velocity))
               if s is not None}
    topics = {w: s.topic or spec.topic for w, s in signals.items()}
    for w, topic in topics.items():
        if topic is None:
            raise ConfigError(f"{label}.{w}.topic: no topic (set {label}.topic or {label}.{w}.topic)")
    stamps = {}
    for topic in dict.fromkeys(topics.values()):
        ns = bag.stamps(topic, source)
        back = np.flatnonzero(np.diff(ns) <= 0)
        if back.size:
            k = int(back[0])
            what = "header stamps" if source == "header" else "receive times"
            raise InputError(f"{label}: {bag.path.name}: topic {topic!r}: the {what} do not increase at message {k + 2} "
                             f"({ns[k + 1] * 1e-9:.9f} s after {ns[k] * 1e-9:.9f} s)"
                             + (f"; {label}.time = 'receive' uses the bag's receive times" if source == "header" else ""))
        stamps[topic] = ns
    base_ns = stamps[topics["position"]]
    t0 = base_ns[0]
    t = (base_ns - t0) * 1e-9
    keep = np.ones(t.size, dtype=bool)
    out: dict[str, FloatArray] = {}
    how: dict[str, str] = {}
    for w, sig in signals.items():
        topic = topics[w]
        values = bag.joints(topic, w, sig.columns)
        ns = stamps[topic]
        if ns.shape == base_ns.shape and np.array_equal(ns, base_ns):
            out[w], how[w] = values, topic
            continue
        ts = (ns - t0) * 1e-9
        keep &= (t >= ts[0]) & (t <= ts[-1])
        out[w] = np.column_stack([np.interp(t, ts, values[:, j]) for j in range(values.shape[1])])
        how[w] = f"{topic} (interpolated linearly onto the {topics['position']} times)"
    if not keep.all():
        if keep.sum() < 2:
            raise InputError(f"{label}: {bag.path.name}: the topics {sorted(set(topics.values()))} do not overlap in time")
        first, last = np.flatnonzero(keep)[[0, -1]]
        sl = slice(int(first), int(last) + 1)
        t = t[sl]
        out = {w: v[sl] for w, v in out.items()}
    return t, out, how


def check_held_out(train: Dataset, held_out: Dataset) -> None:
    """Refuse a validation log that is the training log under another name.

    The configuration already refuses one file read by both with overlapping windows; this
    catches a copy: when the validation files have the same content (SHA-256) as the training
    files and the two windows share any instant, the "held-out" samples are training samples.
    """
    a, b = train.meta.get("sha256", {}), held_out.meta.get("sha256", {})
    if not a or sorted(a.values()) != sorted(b.values()) or set(a) == set(b):
        return  # other content, or the same files (whose windows the configuration checked)
    t_a, t_b = np.asarray(train.t), np.asarray(held_out.t)
    if max(t_a[0], t_b[0]) <= min(t_a[-1], t_b[-1]):
        copy = ", ".join(f"{Path(v).name} = {Path(t).name}" for v, t in zip(sorted(b), sorted(a)))
        raise InputError(f"validation: the validation log has the same content (SHA-256) as the training log ({copy}) "
                         f"and its window [{t_b[0]:.6g}, {t_b[-1]:.6g}] s overlaps the training window "
                         f"[{t_a[0]:.6g}, {t_a[-1]:.6g}] s: that is not held-out data; validate on another log or "
                         "on a window that training does not use")


def to_actuator_space(ds: Dataset, system: System, label: str) -> tuple[Dataset, list[str]]:
    """Map motor-side quantities to the actuators (the joints of a serial robot, the actuated
    joints of a mechanism) through the drive train: ``q_a = C^{-1}θ + q_0``, ``τ_a = C^T τ_m``,
    ``τ_a = C^T K i``. Returns the dataset and notes."""
    tr = system.transmission
    notes: list[str] = []
    q, dq, ddq, tau = ds.q, ds.dq, ds.ddq, ds.tau
    if ds.meta["position_side"] == "motor":
        if tr is None:
            raise ConfigError(f"{label}.position.side = 'motor' needs robot.gear_ratios")
        q = tr.joint_positions(q)
        dq = tr.joint_rates(dq) if dq is not None else None
        ddq = tr.joint_rates(ddq) if ddq is not None else None
    elif tr is not None:
        q = q + tr.position_offset
    if ds.meta["effort_kind"] == "current":
        own = ds.meta.get("drive_gains")  # this log's effort.drive_gains, in place of robot.drive_gains
        if own is not None:
            base = tr if tr is not None else Transmission.identity(system.n_actuators)
            if len(own) not in (1, base.drive_gains.size):
                raise ConfigError(f"{label}.effort.drive_gains: {len(own)} gains for {base.drive_gains.size} motors")
            tr_eff = dataclasses.replace(base, drive_gains=np.broadcast_to(np.asarray(own, float), base.drive_gains.shape).copy())
            notes.append(f"{label}: drive gains of this log (effort.drive_gains) {list(own)}")
        elif tr is None:
            tr_eff = Transmission.identity(system.n_actuators)
            notes.append("efforts are motor currents with unit drive gains: parameters absorb the unknown gains")
        else:
            tr_eff = tr
            if np.all(tr.drive_gains == 1.0):
                notes.append("drive gains are 1: identified parameters absorb the current-to-torque gains")
        tau = tr_eff.joint_torques_from_currents(tau)
    elif ds.meta["effort_side"] == "motor":
        if tr is None:
            raise ConfigError(f"{label}.effort.side = 'motor' needs robot.gear_ratios")
        tau = tr.joint_torques(tau)
    out = ds.replace(q=q, dq=dq, ddq=ddq, tau=tau, names=system.actuator_names,
                     meta={"position_side": "joint", "effort_kind": "torque", "effort_side": "joint"})
    return out, notes


def to_joint_space(ds: Dataset, robot, label: str) -> tuple[Dataset, list[str]]:
    """:func:`to_actuator_space` of a robot model (a serial robot's actuators are its joints)."""
    return to_actuator_space(ds, as_system(robot), label)


def preprocess(ds: Dataset, cfg: ProcessingConfig, label: str, *, filter_positions: bool = True,
               unknowns: Callable[[], tuple[int, int]] | None = None) -> tuple[Dataset, list[dict[str, Any]]]:
    """Resample, filter, differentiate, trim and decimate (see module docstring).

    ``unknowns``: called only when the log is too short for the trimming, it returns the number
    of base parameters and of equations per sample, for the message.

    ``filter_positions = False`` (``[processing.periodic]`` only): the positions are averaged
    over the periods but not filtered (velocities and accelerations zero), for a caller that
    filters them itself at several cut-offs (maximum likelihood, paper 004 Eq. 24)."""
    steps: list[dict[str, Any]] = []
    t, q, tau, dq_m, ddq_m = ds.t, ds.q, ds.tau, ds.dq, ds.ddq
    uniform = ds.is_uniform()
    if cfg.resample == "off" and not uniform:
        dt = np.diff(t)
        raise InputError(
            f"{label}: timestamps are irregular (period {dt.min():.4g}..{dt.max():.4g} s); "
            "set processing.resample = 'auto' or a rate in Hz"
        )
    if (cfg.resample == "auto" and not uniform) or isinstance(cfg.resample, float):
        fs_new = float(cfg.resample) if isinstance(cfg.resample, float) else ds.fs
        t_new, q = resample_uniform(t, q, fs_new, kind="cubic")
        _, tau = resample_uniform(t, tau, fs_new, kind="linear")
        dq_m = resample_uniform(t, dq_m, fs_new, kind="cubic")[1] if dq_m is not None else None
        ddq_m = resample_uniform(t, ddq_m, fs_new, kind="linear")[1] if ddq_m is not None else None
        steps.append({"step": "resample", "fs_hz": fs_new, "from_uniform": uniform, "positions": "cubic spline", "efforts": "linear"})
        t = t_new
    fs = 1.0 / float(np.median(np.diff(t)))
    if cfg.periodic is not None:
        return _preprocess_periodic(ds, t, q, tau, fs, cfg.periodic, steps, label, filter_positions)
    if not filter_positions:
        raise ConfigError("positions left unfiltered for a cut-off search need [processing.periodic]")
    lp = cfg.lowpass
    kalman = None
    if cfg.derivatives == "kalman":  # the smoother replaces the positions' low-pass (dynid.signals.kalman)
        from dynid.signals.kalman import smooth

        noise = cfg.position_noise_std
        if noise is not None and len(noise) not in (1, q.shape[1]):
            raise ConfigError(f"processing.position_noise_std has {len(noise)} values for {q.shape[1]} coordinates")
        kalman = smooth(q, 1.0 / fs, None if noise is None else np.array(noise))
    if lp is not None:
        if not lp.cutoff_hz < fs / 2:
            raise ConfigError(f"processing.lowpass.cutoff_hz = {lp.cutoff_hz} Hz is not below fs/2 = {fs / 2:g} Hz")
        if kalman is None:
            q = lowpass(q, lp.cutoff_hz, fs, lp.order)
        if dq_m is not None:
            dq_m = lowpass(dq_m, lp.cutoff_hz, fs, lp.order)
        if ddq_m is not None:
            ddq_m = lowpass(ddq_m, lp.cutoff_hz, fs, lp.order)
        if lp.filter_effort:
            tau = lowpass(tau, lp.cutoff_hz, fs, lp.order)
        steps.append({"step": "lowpass", "type": "zero-phase Butterworth (sosfiltfilt)", "cutoff_hz": lp.cutoff_hz, "order": lp.order, "fs_hz": fs, "efforts_filtered": lp.filter_effort})
    if kalman is not None:
        q, dq, ddq = kalman.q, kalman.dq, kalman.ddq
        steps.append({"step": "derivatives", "method": "Kalman (RTS) smoother of the positions, white noise in the "
                      "4th derivative (dynid.signals.kalman)", "noise_ratio": kalman.ratio.tolist(),
                      "position_noise_std": kalman.noise_std.tolist(),
                      "noise": "given" if cfg.position_noise_std is not None else "maximum likelihood from the log",
                      "std_position": kalman.std[:, 0].tolist(), "std_velocity": kalman.std[:, 1].tolist(),
                      "std_acceleration": kalman.std[:, 2].tolist(),
                      "positions_lowpassed": False})
    elif cfg.derivatives == "central":
        dq = central_difference(q, t)
        ddq = central_difference(dq, t)
        steps.append({"step": "derivatives", "method": "central differences of filtered positions"})
    else:
        if dq_m is None:
            raise ConfigError(f"processing.derivatives = 'measured' needs {label}.velocity columns")
        dq = dq_m
        ddq = ddq_m if ddq_m is not None else central_difference(dq_m, t)
        steps.append({"step": "derivatives", "method": "measured velocity" + (" and acceleration" if ddq_m is not None else ", central-difference acceleration")})
    n_trim = cfg.trim_samples
    if n_trim is None:
        n_trim = padlen_for(lp.order, lp.cutoff_hz, fs) if lp is not None else 2
        if kalman is not None:  # the smoother's start transient (below 1e-6 of its size)
            n_trim = max(n_trim if lp is not None else 2, kalman.settle)
    if 2 * n_trim >= t.shape[0] - 2:
        n, left = t.shape[0], t.shape[0] - 2 * n_trim
        msg = (f"{label}: {n} samples; after trimming {n_trim} filter-transient samples at each end "
               f"{left if left > 0 else 'none'} remain")
        if unknowns is not None:
            n_base, per = unknowns()
            after = n_base // per + 1
            msg += (f"; the {n_base} base parameters need at least {after + 2 * n_trim} samples ({after} after "
                    f"trimming, {per} equations each)")
        else:
            msg += f"; at least {2 * n_trim + 3} samples are needed"
        raise InputError(msg)
    keep = slice(n_trim, t.shape[0] - n_trim)
    steps.append({"step": "trim", "samples_each_end": int(n_trim)})
    k = cfg.decimate
    if k > 1 and cfg.decimate_method == "parallel":
        if lp is not None and lp.filter_effort:
            raise ConfigError(
                "processing.decimate_method = 'parallel' filters efforts and regressor columns together; "
                "set processing.lowpass.filter_effort = false (efforts would otherwise be filtered twice)"
            )
        steps.append({"step": "decimate", "method": "parallel (Gautier): regressor columns and efforts low-passed "
                      "together (zero-phase Butterworth order 8 at 0.8 x new Nyquist), one sample in factor kept",
                      "factor": k, "fs_hz": fs / k})
    elif k > 1:
        if lp is None or lp.cutoff_hz >= 0.5 * fs / k:
            raise ConfigError(
                f"processing.decimate = {k} needs processing.lowpass.cutoff_hz below the new Nyquist "
                f"frequency {0.5 * fs / k:g} Hz (anti-aliasing)"
            )
        keep = slice(n_trim, t.shape[0] - n_trim, k)
        steps.append({"step": "decimate", "method": "samples: one sample in factor kept after the low-pass", "factor": k, "fs_hz": fs / k})
    out = Dataset(
        t=t[keep], q=q[keep], tau=tau[keep], dq=dq[keep], ddq=ddq[keep], names=ds.names,
        meta={**ds.meta, "processing": steps},
    )
    return out, steps


def _preprocess_periodic(ds: Dataset, t, q, tau, fs: float, pc, steps: list, label: str, filter_positions: bool = True):
    """Whole periods -> period average (with the noise covariances) -> exact DFT filtering and
    differentiation (paper 004 §3.2-3.3; :mod:`dynid.signals.periodic`)."""
    from dynid.signals.periodic import fourier_filter, period_average

    n_per = int(round(pc.period_s * fs))
    if abs(n_per - pc.period_s * fs) > 1e-6 * n_per:
        raise ConfigError(f"processing.periodic.period_s = {pc.period_s} s is not a whole number of samples at {fs:g} Hz")
    n_m = t.shape[0] // n_per
    if n_m < 1:
        raise InputError(f"{label}: {t.shape[0]} samples are less than one period ({n_per} samples)")
    used = n_m * n_per
    record: dict[str, Any] = {"step": "periodic", "period_s": pc.period_s, "samples_per_period": n_per,
                              "periods": n_m, "samples_dropped_at_end": int(t.shape[0] - used), "cutoff_hz": pc.cutoff_hz}
    q, tau, t = q[:used], tau[:used], t[:used]
    if pc.average and n_m >= 2:
        q, cov_q = period_average(q, n_per)
        tau, cov_tau = period_average(tau, n_per)
        t = t[:n_per]
        record.update(averaged=True, noise_covariance_position=cov_q.tolist(), noise_covariance_effort=cov_tau.tolist(),
                      note="covariances of one sample's noise; the averaged period carries them divided by the number of periods")
    else:
        record.update(averaged=False)
    if not filter_positions:
        dq = ddq = np.zeros_like(q)
        record["positions"] = "averaged only; filtered at each candidate cut-off of the maximum-likelihood search"
    elif pc.domain == "pose":  # positions stay as averaged: the pose is filtered after forward kinematics
        dq = ddq = np.zeros_like(q)
        record["positions"] = "averaged only; the platform pose is filtered after forward kinematics (paper 004 §3.3)"
    else:
        q, dq, ddq = fourier_filter(q, fs, pc.cutoff_hz)
    if pc.filter_effort:
        tau = fourier_filter(tau, fs, pc.cutoff_hz)[0]
    record["method"] = "DFT of whole periods, rectangular window at the cut-off, x jw and -w^2, inverse DFT"
    record["efforts_filtered"] = pc.filter_effort
    steps.append(record)
    out = Dataset(t=t, q=q, tau=tau, dq=dq, ddq=ddq, names=ds.names, meta={**ds.meta, "processing": steps})
    return out, steps


def check_joint_motion(ds: Dataset, system: System, min_range: float, label: str) -> None:
    """Refuse data in which an actuator never moves: its parameters would be unidentifiable."""
    rng = np.ptp(ds.q, axis=0)
    still = [j for j in range(system.n_actuators) if rng[j] < min_range]
    if not still:
        return
    names = system.still_parameters(still)
    kinds = system.actuator_kinds()
    joints = ", ".join(f"{system.actuator_names[j]} (range {rng[j]:.3g} {'m' if kinds[j] == 'prismatic' else 'rad'})"
                       for j in still)
    raise IdentifiabilityError(
        f"{label}: joint never moves: {joints}; unidentifiable parameters include {', '.join(names) or 'its inertial terms'}",
        tuple(names),
    )


def velocity_mask(dq: np.ndarray, min_velocity: tuple[float, ...] | None) -> np.ndarray | None:
    """Rows of each joint equation to keep: ``|dq_j| >= min_velocity_j`` (None: all rows)."""
    if min_velocity is None:
        return None
    n = dq.shape[1]
    if len(min_velocity) not in (1, n):
        raise ConfigError(f"processing.min_velocity: {len(min_velocity)} entries for {n} joints")
    thr = np.broadcast_to(np.asarray(min_velocity, float), (n,))
    return np.abs(dq) >= thr


def reversal_keep(dq: np.ndarray, t: np.ndarray, guard_s: float,
                  slow: Sequence[float] | None = None) -> np.ndarray:
    """Rows of each joint equation farther than ``guard_s`` seconds from every velocity reversal
    and every slow sample of that joint (``processing.reversal_guard``), shape of ``dq``.

    A reversal is a sign change of the processed velocity between two consecutive samples, placed
    midway between them; a slow sample is one with ``|dq_j| < slow_j`` (``processing.min_velocity``,
    when set: a joint that stops or sticks without changing sign has the same step). Why: where a joint with Coulomb friction reverses, the true acceleration
    steps (the friction force flips, the controller answers); the zero-phase low-pass spreads that
    step over its settling time on both sides (:func:`dynid.signals.zero_phase_settling_time`), so
    within that distance the processed acceleration and the ``sign`` column of the regressor do
    not describe the measured effort. ``min_velocity`` alone only removes the slow centre of that
    window. On the hexapod twin of bench/README §8, leaving the window out brings the coverage of
    the 95 % intervals from 71 % (no selection) and 87 % (``min_velocity = 0.01``) to the nominal
    level (figures there).
    """
    dq = np.asarray(dq, float)
    t = np.asarray(t, float)
    keep = np.ones(dq.shape, dtype=bool)
    if guard_s <= 0 or dq.shape[0] < 2:
        return keep
    pos = dq >= 0.0
    fast = velocity_mask(dq, None if slow is None else tuple(slow))
    for j in range(dq.shape[1]):
        flips = np.nonzero(pos[1:, j] != pos[:-1, j])[0]
        times = 0.5 * (t[flips] + t[flips + 1])
        if fast is not None:
            times = np.union1d(times, t[~fast[:, j]])
        if times.size == 0:
            continue
        k = np.searchsorted(times, t)
        before = np.abs(t - times[np.clip(k - 1, 0, times.size - 1)])
        after = np.abs(times[np.clip(k, 0, times.size - 1)] - t)
        keep[:, j] = np.minimum(before, after) > guard_s
    return keep


def _white_noise_std(x: FloatArray, ref_hz: float, fs: float, order: int, n_trim: int) -> FloatArray:
    r"""Per column, the std of white noise in ``x`` read from what a zero-phase low-pass at ``ref_hz``
    removes: :math:`\hat\sigma = 1.4826\,\mathrm{MAD}(r) / \lVert \delta - h \rVert_2` with
    :math:`r = x - h * x` over the samples ``n_trim`` clear of the ends and :math:`h` the low-pass's
    impulse response.

    Assumptions: the signal has no content above ``ref_hz`` (everything the low-pass removes is
    noise) and the noise is white, Gaussian and independent of the signal. Then :math:`r` is the noise
    through the high-pass :math:`\delta - h`, whose variance is :math:`\sigma^2\lVert\delta-h\rVert_2^2`
    (about :math:`1 - 2 f_c / f_s`: the share of the band above the cut-off), which the division
    removes, and 1.4826 MAD is consistent for the std of a Gaussian. Bias: signal above
    ``ref_hz`` (a fast motion, the filter's transition band) reads as noise, upward; a coloured
    noise with less power above the cut-off than below reads low. Sampling spread: the MAD's
    asymptotic relative std for Gaussian data is :math:`\sqrt{1.3605/n} = 1.166/\sqrt n`
    (efficiency 37 % of the sample std's :math:`1/\sqrt{2n}`), :math:`n` the samples kept (nearly
    independent: the high-pass leaves white noise nearly white)."""
    r = (x - lowpass(x, ref_hz, fs, order))[n_trim: x.shape[0] - n_trim]
    n_h = padlen_for(order, ref_hz, fs)
    delta = np.zeros(2 * n_h + 1)
    delta[n_h] = 1.0
    hp_gain = float(np.linalg.norm(delta - lowpass(delta, ref_hz, fs, order)))
    return 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0) / hp_gain


def velocity_noise_std(ds: Dataset, cfg: ProcessingConfig, label: str = "data",
                       cutoff_hz: float | None = None) -> FloatArray:
    r"""Per coordinate, the std [rad/s or m/s] of the noise that ``cfg``'s processing leaves in the
    velocities of ``ds`` (the unprocessed log in actuator space): the width of the Coulomb terms'
    smooth sign for ``identification.coulomb_smoothing = "auto"``
    (:func:`~dynid.model.serial_dynamics.smooth_sign`).

    One rule for both kinds of velocity: the white noise of the signal the velocities come from,
    :math:`\sigma_s`, is read from what a low-pass removes from it (:func:`_white_noise_std`: the
    robust std, 1.4826 x MAD, of the residual, corrected for the share of the noise the low-pass
    keeps), at ``processing.lowpass``'s cut-off (without one, at a tenth of the sampling rate); it
    goes through the processing's linear chain :math:`h` to the velocity,
    :math:`\sigma_{\dot q} = \lVert h \rVert_2\,\sigma_s` (white noise through a linear filter).

    - ``processing.derivatives = "central"``: :math:`s` is the position, :math:`h` the configured
      zero-phase low-pass followed by central differences.
    - ``processing.derivatives = "measured"``: :math:`s` is the measured velocity itself (the log's
      velocity columns), :math:`h` the configured low-pass (the processing filters measured
      velocities with it), or the identity without one (:math:`\sigma_{\dot q} = \sigma_s`).
    - ``processing.derivatives = "kalman"``: the smoother's steady-state velocity std
      (:func:`dynid.signals.kalman.smooth`).

    ``cutoff_hz``: the gain of the same low-pass at another cut-off (maximum likelihood's candidate
    cut-offs, :func:`dynid.pipeline.identification._maximum_likelihood_time`); :math:`\sigma_s` is
    still read at the configured one. ``[processing.periodic]`` is refused: its noise is the period
    averaging's (give the widths)."""
    if cfg.periodic is not None:
        raise ConfigError("identification.coulomb_smoothing = 'auto' reads the velocity noise of a processed time "
                          "series; with [processing.periodic] give the widths per actuator instead")
    if cfg.derivatives == "kalman":  # the smoother's own steady-state velocity std
        from dynid.signals.kalman import smooth

        t = np.asarray(ds.t, dtype=float)
        noise = cfg.position_noise_std
        return smooth(np.asarray(ds.q, dtype=float), float(np.median(np.diff(t))),
                      None if noise is None else np.array(noise)).std[:, 1]
    measured = cfg.derivatives == "measured"
    if measured and ds.dq is None:
        raise ConfigError(f"identification.coulomb_smoothing = 'auto' with processing.derivatives = 'measured' reads "
                          f"the noise of the measured velocities: {label} has no velocity columns")
    t = np.asarray(ds.t, dtype=float)
    fs = 1.0 / float(np.median(np.diff(t)))
    lp = cfg.lowpass
    ref_hz = lp.cutoff_hz if lp is not None else 0.1 * fs
    order = lp.order if lp is not None else 4
    n_trim = padlen_for(order, ref_hz, fs)
    s = np.asarray(ds.dq if measured else ds.q, dtype=float)
    if s.shape[0] <= 2 * n_trim + 10:
        raise InputError(f"{label}: {s.shape[0]} samples are too few to estimate the velocity noise "
                         "(identification.coulomb_smoothing = 'auto'); give the widths per actuator")
    sigma_s = _white_noise_std(s, ref_hz, fs, order, n_trim)
    if cutoff_hz is not None and lp is None:
        raise ConfigError("velocity_noise_std: a candidate cut-off needs processing.lowpass")
    h_hz = ref_hz if cutoff_hz is None else float(cutoff_hz)
    n_h = padlen_for(order, min(ref_hz, h_hz), fs)
    delta = np.zeros(2 * n_h + 1)
    delta[n_h] = 1.0
    h = lowpass(delta, h_hz, fs, lp.order) if lp is not None else delta
    if not measured:
        h = central_difference(h, 1.0 / fs)
    return sigma_s * float(np.linalg.norm(h))

