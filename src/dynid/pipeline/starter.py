"""``dynid init ROBOT LOG``: a commented starting configuration for ``dynid identify``.

The robot's actuators (the joints of a serial robot, the actuated joints of a parallel one; the
same :func:`~dynid.pipeline.data.build_system` as ``dynid identify``) are matched to the log's
columns by name (``q_<joint>``, ``<joint>_pos``, ``tau_<joint>``, ``<joint>_effort``,
``current_<joint>`` ...) or, failing that, by index (``q1 ... qn``, ``tau[0] ...``: said to be
guessed). The time column's unit is read from its name or guessed from the sampling rate it
gives; the rate sets the processing defaults. The log is read through
:class:`~dynid.io.readers.TableReader` only (its ``available`` names and ``columns``), so a
format that reader learns is a format ``init`` reads.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynid._typing import FloatArray
from dynid.config import TIME_UNITS, RobotConfig, parse_config
from dynid.errors import ConfigError, InputError
from dynid.io.readers import TableReader
from dynid.pipeline.processing_choice import (BAND_FACTOR, MIN_CUTOFF_HZ, NOISE_SIGMAS, STEP_RATIO, DerivedProcessing,  # noqa: F401
                                             cutoff_for, derive_processing, motion_bandwidth_hz, round2)

__all__ = ["StartingConfig", "starting_config", "write_starting_config"]

_SEP = r"[\s_./:\-\[\]()]+"
_ROLES = {
    "position": {"q", "pos", "position", "positions", "angle", "angles", "theta"},
    "velocity": {"dq", "qd", "qdot", "vel", "velocity", "velocities", "v", "speed"},
    "acceleration": {"ddq", "qdd", "acc", "accel", "acceleration"},
    "torque": {"tau", "torque", "torques", "effort", "efforts", "trq", "force", "forces", "f"},
    "current": {"current", "currents", "cur", "curr", "i", "amp", "amps"},
}
_TIME_WORDS = {"t", "time", "times", "timestamp", "timestamps", "stamp", "sec", "secs", "seconds", "s", "ms", "msec", "us",
               "usec", "ns", "nsec", "nsecs", "elapsed"}
_TIME_UNIT_WORDS = {"ms": "ms", "msec": "ms", "us": "us", "usec": "us", "ns": "ns", "nsec": "ns", "nsecs": "ns",
                    "s": "s", "sec": "s", "secs": "s", "seconds": "s"}
PLAUSIBLE_RATE_HZ = (10.0, 20000.0)
"""Sampling rates of robot logs: the time unit that puts the rate in this range is the guess."""


def _tokens(name: str) -> list[str]:
    return [t for t in re.split(_SEP, name.lower()) if t]


@dataclasses.dataclass(frozen=True)
class Match:
    column: str | None  # None: unmatched
    how: str  # "name", "index" (guessed) or "unmatched"


@dataclasses.dataclass(frozen=True)
class StartingConfig:
    """The text of the starting config and what was found (for the command's message and tests)."""

    text: str
    joints: tuple[str, ...]
    position: tuple[Match, ...]
    effort: tuple[Match, ...]
    effort_kind: str
    time_column: str | None
    time_unit: str
    sample_rate_hz: float
    cutoff_hz: float

    @property
    def unmatched(self) -> list[str]:
        return [f"{w} of {j}" for j, p, e in zip(self.joints, self.position, self.effort)
                for w, m in (("position", p), ("effort", e)) if m.column is None]


def _log_columns(reader: TableReader) -> dict[str, FloatArray]:
    """Every single column the reader can select by name: a CSV/Parquet column, an NPZ key of a
    1-D array, or ``key[i]`` for column ``i`` of an NPZ key's 2-D array (numeric ones only)."""
    out: dict[str, FloatArray] = {}
    for name in reader.available:
        try:
            arr = reader.columns([name])
        except InputError:  # a non-numeric column (labels, strings)
            continue
        if arr.shape[1] == 1:
            out[name] = arr[:, 0]
        else:
            out.update({f"{name}[{i}]": arr[:, i] for i in range(arr.shape[1])})
    if not out:
        raise InputError(f"{reader.path}: no numeric columns")
    return out


def _joint_in(col: str, joint: str) -> list[str] | None:
    """The tokens of ``col`` left when ``joint`` is removed from it as a whole (bounded by
    separators or the ends), or None when the joint's name is not in it."""
    c, j = col.lower(), joint.lower()
    for m in re.finditer(re.escape(j), c):
        a, b = m.start(), m.end()
        if (a == 0 or re.match(_SEP, c[a - 1])) and (b == len(c) or re.match(_SEP, c[b])):
            return _tokens(c[:a] + " " + c[b:])
    return None


def _by_name(columns: Sequence[str], joints: Sequence[str], role: str) -> list[str | None]:
    """Per joint the column that is the joint's name plus one word of ``role`` (``q_j1``,
    ``j1_pos``, ``j1.effort``); the joint's name alone counts as its position. The longest joint
    name wins (``joint_1`` does not take ``joint_10``'s columns: names are bounded)."""
    out: list[str | None] = []
    for joint in joints:
        found = []
        for col in columns:
            rest = _joint_in(col, joint)
            if rest is None:
                continue
            if (rest and len(rest) == 1 and rest[0] in _ROLES[role]) or (not rest and role == "position"):
                found.append(col)
        out.append(found[0] if len(found) == 1 else None)
    return out


def _by_index(columns: Sequence[str], n: int, role: str) -> list[str | None] | None:
    """``n`` columns ``<word><k>`` / ``<word>_<k>`` / ``<word>[k]`` of one ``role`` word with the
    indices 1..n or 0..n-1, in index order (a guess: the log's joint order is the model's)."""
    pat = re.compile(r"^(?P<word>[a-z]+?)[\s_.\-]*\[?(?P<k>\d+)\]?$")
    groups: dict[str, dict[int, str]] = {}
    for col in columns:
        m = pat.match(col.lower())
        if m and m.group("word") in _ROLES[role]:
            groups.setdefault(m.group("word"), {})[int(m.group("k"))] = col
    for word in sorted(groups, key=lambda w: (w not in ("q", "tau", "current"), w)):
        idx = groups[word]
        for first in (1, 0):
            if all(first + j in idx for j in range(n)) and len(idx) == n:
                return [idx[first + j] for j in range(n)]
    return None


def _match(columns: Sequence[str], joints: Sequence[str], role: str) -> tuple[Match, ...]:
    named = _by_name(columns, joints, role)
    if all(c is not None for c in named):
        return tuple(Match(c, "name") for c in named)
    guessed = _by_index([c for c in columns if c not in named], len(joints), role)
    return tuple(Match(c, "name") if c is not None else
                 (Match(guessed[j], "index") if guessed is not None else Match(None, "unmatched"))
                 for j, c in enumerate(named))


def _time_column(columns: dict[str, FloatArray]) -> str | None:
    cands = [c for c in columns if _tokens(c) and set(_tokens(c)) <= _TIME_WORDS]
    cands.sort(key=lambda c: (_tokens(c)[0] not in ("t", "time", "timestamp"), len(c)))
    return cands[0] if cands else None


def _time_unit(name: str, t: FloatArray) -> tuple[str, str, float]:
    """(unit, how it was found, sampling rate in Hz): the unit word in the name, else the unit
    (s, ms, us, ns in that order) that puts the median rate in :data:`PLAUSIBLE_RATE_HZ`."""
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise InputError(f"time column {name!r}: {float(t[bad[0]])} in data row {bad[0] + 1} (not a finite time)")
    dt = np.diff(t)
    if dt.size == 0:
        raise InputError(f"time column {name!r}: one sample; a log needs at least two")
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        raise InputError(f"time column {name!r} is not increasing (data row {k + 2}: {float(t[k + 1])!r} after {float(t[k])!r})")
    med = float(np.median(dt))
    words = [_TIME_UNIT_WORDS[w] for w in _tokens(name) if w in _TIME_UNIT_WORDS]
    if words:
        unit = words[-1]
        return unit, f"from the column's name ({name!r})", 1.0 / (med * TIME_UNITS[unit])
    for unit in ("s", "ms", "us", "ns"):
        fs = 1.0 / (med * TIME_UNITS[unit])
        if PLAUSIBLE_RATE_HZ[0] <= fs <= PLAUSIBLE_RATE_HZ[1]:
            return unit, (f"GUESSED: the name says no unit; {unit} makes the rate {fs:.4g} Hz, a robot log's "
                          f"({PLAUSIBLE_RATE_HZ[0]:g} Hz to {PLAUSIBLE_RATE_HZ[1] / 1000:g} kHz)"), fs
    return "s", f"GUESSED: seconds (no unit gives a rate in {PLAUSIBLE_RATE_HZ[0]:g}-{PLAUSIBLE_RATE_HZ[1]:g} Hz; check it)", 1.0 / med


def _s(x: str) -> str:
    return json.dumps(x)  # a TOML basic string


def _rel(path: Path, folder: Path) -> str:
    try:
        return os.path.relpath(path, folder)
    except ValueError:  # another drive (Windows)
        return str(path)


DRIVE_KEYS = ("gear_ratios", "couplings", "drive_gains", "position_offset", "rotor_inertia")
"""The keys of ``dynid init --drive FILE``'s ``[robot]`` table: the drive train a robot description
(URDF, MJCF) does not hold, as ``[robot]`` of the config spells them (docs/guide/configuration.md)."""


def read_drive(path: str | Path) -> dict:
    """The ``[robot]`` table of ``dynid init --drive FILE`` (:data:`DRIVE_KEYS` only), or a one-line error."""
    from dynid.config._schema import read_toml

    doc = read_toml(Path(path))
    if set(doc) != {"robot"} or not isinstance(doc["robot"], dict):
        raise ConfigError(f"--drive {path}: expected one [robot] table with the drive train ({', '.join(DRIVE_KEYS)}); "
                          f"found {', '.join(sorted(doc)) or 'nothing'}")
    unknown = [k for k in doc["robot"] if k not in DRIVE_KEYS]
    if unknown:
        k = unknown[0]
        near = nearest(k, DRIVE_KEYS)
        raise ConfigError(f"--drive {path}: [robot].{k} is not a drive-train key" + (f" (did you mean {near!r}?)" if near else "")
                          + f"; known: {', '.join(DRIVE_KEYS)}")
    return dict(doc["robot"])


def _toml_value(v) -> str:
    """A TOML literal of a drive-train value (numbers, lists, inline tables)."""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return _s(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise ConfigError(f"--drive: value {v!r} of an unsupported type")


def _osa_distance(a: str, b: str) -> int:
    """Edit distance with adjacent transpositions (optimal string alignment): a typo's distance."""
    d = [[i + j if i * j == 0 else 0 for j in range(len(b) + 1)] for i in range(len(a) + 1)]
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            c = int(a[i - 1] != b[j - 1])
            d[i][j] = min(d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + c)
            if i > 1 and j > 1 and a[i - 1] == b[j - 2] and a[i - 2] == b[j - 1]:
                d[i][j] = min(d[i][j], d[i - 2][j - 2] + 1)
    return d[-1][-1]


def nearest(name: str, names) -> str | None:
    """The name in ``names`` nearest ``name`` by edit distance (transpositions count once;
    case-insensitive), None when there is none."""
    names = sorted(set(names))
    return min(names, key=lambda n: (_osa_distance(name.lower(), n.lower()), n)) if names else None


def _sig2(x: float) -> float:
    return float(f"{x:.2g}") if x > 0 else 0.0

def _structure_lines(system) -> list[str]:
    """``[identification] structure`` of a parallel robot, with the identical chains of its description."""
    if system.kind == "serial":
        return []
    from dynid.pipeline.structure import candidate_chains

    chains, source = candidate_chains(system.model, None)
    if not chains:
        return ["structure = \"auto\"                             # no identical chains (none declared, none found in the "
                "description): every body its own parameters"]
    return ["structure = \"auto\"                             # identical chains tied unless the training log rejects it "
            "(F test and cross-validation); \"full\" or \"identical_chains\" force either",
            f"identical_chains = [{', '.join('[' + ', '.join('[' + ', '.join(_s(j) for j in c) + ']' for c in g) + ']' for g in chains)}]",
            f"# identical chains {source}"]


def starting_config(robot: str, log: str | Path, out: str | Path, *, actuated: Sequence[str] | None = None,
                    independent: Sequence[str] | None = None, sample_rate_hz: float | None = None,
                    validation: str | Path | None = None, effort_log: str | Path | None = None,
                    drive: str | Path | None = None) -> StartingConfig:
    """The starting config of ``dynid init`` (nothing is written; see :func:`write_starting_config`).

    Processing defaults: the zero-phase Butterworth low-pass at 10 times the motion's bandwidth
    (paper 001 Sec. 3: the cut-off above 10 times the position loop's bandwidth), at most a fifth
    of the sampling rate (0.4 of Nyquist), at least :data:`MIN_CUTOFF_HZ`; the efforts unfiltered (paper 004
    Sec. 3: filtering the actuator forces biases the estimates through the discontinuous friction,
    and their noise is additive to the output); WLS (paper 001 Eqs. 10-16); the last quarter of
    the log held out.

    ``effort_log``: the efforts in a second file with the same rows (a controller that writes
    positions and currents apart); ``drive``: a TOML file with one ``[robot]`` table holding the
    drive train the description lacks (:data:`DRIVE_KEYS`: gear ratios, couplings, drive gains,
    encoder offsets, rotor inertias), copied into the config; the positions are then taken as
    motor-side when they move further than a joint's limits allow, and the processing is derived
    from the joint-side signals (the pipeline's own mapping).
    """
    from dynid.pipeline.data import build_system

    out = Path(out)
    folder = out.resolve().parent
    model = robot if robot.startswith("builtin:") else str(Path(robot).expanduser().resolve())
    drive_table = read_drive(drive) if drive is not None else {}
    rcfg = RobotConfig(model=model, actuated=tuple(actuated) if actuated else None,
                       independent=tuple(independent) if independent else None)
    if drive_table:
        from dynid.config import _parse_robot

        try:
            parsed = _parse_robot({"model": model, **drive_table}, folder)
        except ConfigError as exc:
            raise ConfigError(f"--drive {drive}: {exc}") from None
        rcfg = dataclasses.replace(parsed, actuated=rcfg.actuated, independent=rcfg.independent, extras_given=False)
    system = build_system(rcfg)
    joints, kinds = tuple(system.actuator_names), tuple(system.actuator_kinds())
    reader = TableReader(log)
    columns = _log_columns(reader)
    names = list(columns)
    n_rows = next(iter(columns.values())).shape[0]

    tcol = _time_column(columns)
    if tcol is not None:
        tunit, thow, fs = _time_unit(tcol, columns[tcol])
        dt = np.diff(columns[tcol]) * TIME_UNITS[tunit]
        jitter = float(np.std(dt) / np.median(dt))
    elif sample_rate_hz is not None:
        tunit, thow, fs, jitter = "s", "", float(sample_rate_hz), 0.0
    else:
        raise InputError(f"{reader.path.name}: no time column (t, time, timestamp, time_ms, ...) among "
                         f"{names[:20]}; give the sampling rate: --rate HZ")
    if tcol is not None and sample_rate_hz is not None:
        raise InputError(f"--rate: {reader.path.name} has a time column {tcol!r}; --rate is for logs without one")
    position = _match([c for c in names if c != tcol], joints, "position")
    used = {m.column for m in position}
    rest = [c for c in names if c != tcol and c not in used]
    n_found = lambda ms: sum(m.column is not None for m in ms)  # noqa: E731
    ereader, kind_how = None, ""
    if effort_log is not None:
        ereader = TableReader(effort_log)
        ecolumns = _log_columns(ereader)
        n_e = next(iter(ecolumns.values())).shape[0]
        if n_e != n_rows:
            raise InputError(f"--effort-log {ereader.path}: {n_e} rows, the log {reader.path.name} has {n_rows} (the "
                             "two files must hold the same samples)")
        rest = [c for c in ecolumns if c != _time_column(ecolumns)]
    eff_columns = ecolumns if ereader is not None else columns
    torque, current = _match(rest, joints, "torque"), _match(rest, joints, "current")
    effort, kind = (torque, "torque") if n_found(torque) >= n_found(current) else (current, "current")
    if ereader is not None and n_found(effort) < len(joints):
        # a file of efforts only: the joint's name alone names its effort; its kind from the file's name
        effort = _match(rest, joints, "position")
        words = set(_tokens(ereader.path.stem))
        kind = "current" if words & _ROLES["current"] else "torque"
        kind_how = (f"the file's name {ereader.path.name!r} says current" if kind == "current" else
                    (f"the file's name {ereader.path.name!r} says torque" if words & _ROLES["torque"] else
                     f"GUESSED: neither the columns nor the file's name {ereader.path.name!r} say current"))

    q_cols = [columns[m.column] for m in position if m.column is not None]
    cap = fs / 5.0
    band, vband, cutoff = cutoff_for(np.column_stack(q_cols), fs) if q_cols else (0.0, 0.0, round2(min(MIN_CUTOFF_HZ, cap)))
    split = n_rows - n_rows // 4
    serial = system.kind == "serial"
    projected = not serial and bool(getattr(system, "redundant", False))
    derived = None
    complete = all(m.column is not None for m in position + effort)
    if complete and not drive_table:
        t_s = (columns[tcol] * TIME_UNITS[tunit]) if tcol is not None else np.arange(n_rows) / fs
        rows = slice(0, n_rows if validation is not None else split)
        derived = derive_processing(t_s[rows], np.column_stack([columns[m.column] for m in position])[rows],
                                    np.column_stack([eff_columns[m.column] for m in effort])[rows], cutoff,
                                    parallel=not serial, projected=projected)
    side, side_how = "joint", ""
    if drive_table.get("gear_ratios") and q_cols and len(q_cols) == len(joints):
        from dynid.pipeline.diagnostics import actuator_limits

        lo, hi, _ = actuator_limits(system)
        span = np.ptp(np.column_stack([columns[m.column] for m in position]), axis=0)
        beyond = [j for j in range(len(joints)) if np.isfinite(hi[j] - lo[j]) and span[j] > 1.5 * (hi[j] - lo[j])]
        side = "motor" if beyond else "joint"
        side_how = (f"motor-side: {', '.join(joints[j] for j in beyond)} move(s) over more than 1.5 x the joint's range "
                    "(encoders on the motors, before the gears)" if beyond else
                    "joint-side: every position stays within its joint's range (set side = \"motor\" for motor encoders)")
    if validation is not None and ereader is not None:
        raise InputError("--validation with --effort-log: a validation run in two files is not read by init; give "
                         "the validation run's [validation] by hand (docs/guide/configuration.md), or one file per run")
    vlog = None
    if validation is not None:
        vreader = TableReader(validation)
        vcols = set(vreader.available) | set(_log_columns(vreader))
        need = [c for c in [tcol] + [m.column for m in position + effort] if c is not None]
        missing = [c for c in need if c not in vcols]
        if missing:
            raise InputError(f"--validation {vreader.path}: no column(s) {', '.join(missing)} (the training log's names"
                             + "".join(f"; for {c!r} it has {nearest(c, vcols)!r}" for c in missing) + ")")
        vlog = vreader.path.resolve()

    def col_list(ms: tuple[Match, ...], role: str) -> str:
        return "[" + ", ".join(_s(m.column) if m.column is not None else _s(f"<UNMATCHED {role} of {j}>")
                               for m, j in zip(ms, joints)) + "]"

    def how(ms: tuple[Match, ...]) -> list[str]:
        out_ = []
        for j, m in zip(joints, ms):
            text = {"name": "matched by name", "index": "GUESSED by index (the log's order taken as the joints' order)",
                    "unmatched": "UNMATCHED: put the column's name in its place"}[m.how]
            out_.append(f"#   {j:<14} <- {m.column if m.column is not None else '?':<20} {text}")
        return out_

    units = {"revolute": "rad", "prismatic": "m"}
    degrees = [j for j, k, m in zip(joints, kinds, position)
               if k == "revolute" and m.column is not None and np.ptp(columns[m.column]) > 2 * math.tau and side == "joint"]
    lines = [
        f"# dynid identify config written by `dynid init {robot} {reader.path.name}`.",
        "# Check every line marked GUESSED or UNMATCHED, then run: dynid identify "
        f"{out.name} --out out/{out.stem}",
        "",
        "[robot]",
        f"model = {_s(robot if robot.startswith('builtin:') else _rel(Path(model), folder))}",
        f"# actuators (dynid info {robot}): " + ", ".join(f"{j} ({k})" for j, k in zip(joints, kinds)),
    ]
    rotor = False
    if system.kind == "serial":
        try:
            nom = np.asarray(system.model.nominal_parameters(), float)
            rotor = bool(np.any(nom[system.model.layout.extra_index["Ia"]] != 0))
        except (AttributeError, KeyError, IndexError):
            rotor = False
    if system.kind == "serial" and (kind == "current" or rotor):
        lines.append("extras = [\"Ia\", \"fv\", \"fc\", \"offset\"]      # rotor inertia ("
                     + ("motor currents drive it" if kind == "current" else "the description gives one") + "), viscous and "
                     "Coulomb friction, torque offset")
    elif system.kind == "serial":
        lines.append("extras = [\"fv\", \"fc\", \"offset\"]            # torques, and no rotor inertia in the description: "
                     "taken as link-side (joint torque sensors do not see the rotor); add \"Ia\" for a motor-side torque")
    else:
        lines.append("# extras = [\"Ia\", \"fv\", \"fc\", \"offset\"]    # parallel robots: named extras become joint terms "
                     "of the actuated joints (default: the description's)")
    if actuated:
        lines.append(f"actuated = [{', '.join(_s(a) for a in actuated)}]")
    if independent:
        lines.append(f"independent = [{', '.join(_s(a) for a in independent)}]")
    elif system.kind != "serial" and system.model.independent_choice:  # redundant actuation: the automatic chart
        chart = [system.model.pin_model.names[j + 1] for j in system.model.independent.joints]
        lines += [f"# independent = [{', '.join(_s(a) for a in chart)}]   # {system.model.independent_choice};",
                  "#   identify chooses again over the training log; uncomment (or name others) to fix them"]
    if drive_table:
        lines.append(f"# the drive train, from --drive {Path(drive).name}:")
        lines += [f"{k} = {_toml_value(drive_table[k])}" for k in DRIVE_KEYS if k in drive_table]
    else:
        lines.append("# gear_ratios = [...]; couplings; drive_gains; position_offset: for motor-side logs (docs/guide/configuration.md; "
                     "dynid init --drive)")
    lines += [
        "",
        ("[data]                                         # the training log" if vlog is not None else
         "[data]                                         # the training log: the first three quarters"),
        f"file = {_s(_rel(reader.path.resolve(), folder))}",
    ]
    if tcol is not None:
        lines += [f"time = {{ column = {_s(tcol)}, unit = {_s(tunit)} }}   # unit {thow}",
                  f"# sampling rate {fs:.6g} Hz (median interval; spread {100 * jitter:.2g} % of it"
                  + ("; irregular: resampled, processing.resample" if jitter > 0.01 else "") + ")"]
    else:
        lines += [f"sample_rate_hz = {fs!r}                 # from --rate (the log has no time column)"]
    lines += ([] if vlog is not None else [f"rows = [0, {split}]"]) + [
              (f"position = {{ columns = {col_list(position, 'position')}, side = \"motor\" }}   # rad at the motor"
               if side == "motor" else
               f"position = {{ columns = {col_list(position, 'position')} }}   # SI: "
               + ", ".join(sorted({units[k] for k in kinds})) + " (else unit = ...)")]
    if side_how:
        lines.append(f"# {side_how}")
    lines += ["# position columns:"] + how(position)
    if degrees:
        lines.append(f"# WARNING: {', '.join(degrees)} span more than two turns: degrees? then set unit = \"deg\"")
    efile = f"file = {_s(_rel(ereader.path.resolve(), folder))}, " if ereader is not None else ""
    if kind_how:
        lines.append(f"# effort kind: {kind_how}")
    if kind == "current":
        lines += [f"effort = {{ {efile}columns = {col_list(effort, 'effort')}, kind = \"current\", unit = \"A\" }}",
                  "# motor currents: without robot.drive_gains (N*m/A) identify estimates them from the prior (the",
                  "# nominal model's torques fitted to the currents, with intervals) and uses them when each is known to",
                  "# 10 %: parameters, comparison with the prior and model.urdf then in N*m; otherwise the parameters",
                  "# absorb the gains (said in the summary). A known-payload experiment measures the gains better."]
    else:
        lines += [f"effort = {{ {efile}columns = {col_list(effort, 'effort')} }}   # SI: "
                  + ", ".join(sorted({'revolute': 'N*m', 'prismatic': 'N'}[k] for k in set(kinds)))]
    lines += ["# effort columns:"] + how(effort)
    left = [c for c in names if c != tcol and c not in used and (ereader is not None or c not in {m.column for m in effort})]
    if left:
        lines.append(f"# columns not used: {', '.join(left[:30])}{' ...' if len(left) > 30 else ''}")
    if vlog is not None:
        val = ["[validation]                                   # held out, never used for training: another run",
               f"file = {_s(_rel(vlog, folder))}              # the same columns as [data]"]
    else:
        val = ["[validation]                                   # held out, never used for training: the last quarter",
               f"rows = [{split}, {n_rows}]                        # or --validation OTHER_LOG (a run with other motion "
               "is better than a tail of the same run)"]
    if drive_table and complete:
        # the processing is derived from the joint-side signals: the pipeline's own reading and mapping
        # through the drive train (gear ratios, couplings, offsets) of the config written so far
        import tomllib

        from dynid.pipeline.data import read_log, to_actuator_space

        part = parse_config(tomllib.loads("\n".join(lines + ["", *val])), folder)
        joint_side, _ = to_actuator_space(read_log(part.data, system.n_actuators, tuple(joints), "data", {}), system, "data")
        band, vband, cutoff = cutoff_for(np.asarray(joint_side.q), fs)
        derived = derive_processing(np.asarray(joint_side.t), np.asarray(joint_side.q), np.asarray(joint_side.tau), cutoff,
                                    parallel=not serial, projected=projected)
    lines += ["", *val, "", "[processing]",
              "resample = \"auto\"                              # irregular timestamps resampled at the median rate"]
    fe = derived.filter_effort if derived is not None else False
    parallel_decimation = serial and derived is not None and derived.decimate > 1
    if parallel_decimation:
        fe = False  # the parallel decimation filters the efforts, with the regressor (below)
    lines += [
        f"lowpass = {{ cutoff_hz = {cutoff!r}, order = 4, filter_effort = {str(fe).lower()} }}",
        f"# cut-off: {BAND_FACTOR:g} x the motion's bandwidth ({max(band, vband):.3g} Hz: 99 % of the velocity power below it, "
        f"{band:.3g} Hz",
        f"# of the position power), within [{MIN_CUTOFF_HZ:g} Hz, fs/5 = {cap:.4g} Hz] (0.4 x Nyquist {fs / 2:.4g} Hz); paper 001",
        "# Sec. 3 asks for more than 10 x the position loop's bandwidth, which the motion's velocities stand in for",
        "# (the regressor is made of velocities and accelerations): set it from the loop's if you know it.",
    ]
    if parallel_decimation:
        lines.append("# filter_effort = false: the efforts are filtered by the parallel decimation below, with the regressor; "
                     f"on their own they would be {str(derived.filter_effort).lower()}: "
                     + derived.reasons["filter_effort"].split(": ", 1)[1])
    elif derived is not None:
        lines.append(f"# filter_effort = {derived.reasons['filter_effort']}")
    lines.append("derivatives = \"central\"                        # velocities and accelerations of the filtered positions")
    if derived is not None:
        lines += [f"decimate = {derived.decimate}", f"# {derived.reasons['decimate']}"]
        if parallel_decimation:
            lines += ["decimate_method = \"parallel\"                 # regressor and efforts filtered together, then decimated",
                      "# (Gautier's parallel filtering, paper 001 Sec. 3): the same filter on both sides of the equation,",
                      "# so the efforts' noise goes while their Coulomb steps stay matched by the regressor's"]
        mv = [_sig2(x) for x in derived.min_velocity]
        if any(x > 0 for x in mv):
            lines += [f"min_velocity = [{', '.join(repr(x) for x in mv)}]   # " + ", ".join(sorted({units[k] for k in kinds})) + "/s",
                      f"# {derived.reasons['min_velocity']}"]
        else:
            lines.append("# min_velocity: not set (no position noise measurable: the log is noise-free or quantized coarsely)")
        if derived.reversal_guard:
            lines.append("reversal_guard = \"auto\"                       # the low-pass's settling time around each reversal")
        lines.append(f"# reversal_guard: {derived.reasons['reversal_guard']}")
    else:
        lines.append("# decimate, min_velocity, reversal_guard: not derived (a column is unmatched); docs/guide/configuration.md, [processing]")
    lines += ["", "[identification]",
              "method = \"wls\"                                 # weighted least squares, per-joint noise (paper 001 Eqs. 10-16)",
              *_structure_lines(system)]
    if serial:
        lines += ["coulomb_smoothing = \"auto\"                     # Coulomb terms as erf(v / (sqrt(2) w)), w the velocity noise",
                  "# the processing leaves: the expected friction of a noisy velocity, 0 at rest instead of +-fc at random"]
        lines.append("physical_consistency = true                    # a model a simulator can use (LMI, Wensing 2017); on the "
                     "real KUKA log the unconstrained fit does not generalize to another run (docs/guide/results.md)")
    lines += ["", "[output]", "plots = true", ""]
    text = "\n".join(lines)
    import tomllib

    parse_config(tomllib.loads(text), folder)  # what identify will read (a bug here, not the user's)
    return StartingConfig(text, joints, position, effort, kind, tcol, tunit, fs, cutoff)


def write_starting_config(robot: str, log: str | Path, out: str | Path, *, force: bool = False,
                          **kwargs) -> StartingConfig:
    """:func:`starting_config` written to ``out`` (refused when it exists, unless ``force``)."""
    out = Path(out)
    if out.is_dir():
        raise InputError(f"--out {out}: a folder; give the config file's name (e.g. {out / 'identify.toml'})")
    if out.exists() and not force:
        raise InputError(f"--out {out}: exists; --force replaces it")
    if not out.resolve().parent.is_dir():
        raise InputError(f"--out {out}: folder {out.resolve().parent} does not exist")
    cfg = starting_config(robot, log, out, **kwargs)
    try:
        out.write_text(cfg.text)
    except OSError as exc:
        raise InputError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    return cfg
