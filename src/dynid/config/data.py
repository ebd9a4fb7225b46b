"""``[data]`` and ``[validation]`` of the identify configuration: the logs' files, columns, units
and windows (CSV and ROS bags), ``[[data]]`` / ``[[validation]]`` arrays, and the held-out log's
keys inherited from the training table."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config._schema import _bool, _int, _list, _num, _num_or_list, _path, _reject_unknown, _str, _table
from dynid.errors import ConfigError

POSITION_UNITS = {"rad": 1.0, "deg": 0.017453292519943295, "m": 1.0, "mm": 1e-3}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
EFFORT_UNITS = {
    "torque": {"N*m": 1.0, "Nm": 1.0, "N.m": 1.0, "mN*m": 1e-3, "N": 1.0},
    "current": {"A": 1.0, "mA": 1e-3},
}


@dataclasses.dataclass(frozen=True)
class SignalConfig:
    """A group of columns: ``{ columns = [...], unit = ..., side = ..., kind = ..., file = ... }``."""

    # the columns, one per joint or actuator (header = false: indices; NPZ: a 2-D key or "key[3]"; ROS bags: joint names)
    columns: tuple[str, ...]
    unit: str | tuple[str, ...] | None  # one for all columns, one per column, None: SI (rad or m; N*m or N; A)
    side: str = "joint"  # "joint" or "motor": the side of the drive train the signal is measured on
    kind: str = "torque"  # effort only: "torque" (N*m or N) or "current" (A, turned into torques by the drive gains)
    file: Path | None = None  # this signal's own file (default: the table's file)
    topic: str | None = None  # ROS bags: the JointState topic of this signal (None: [data] topic)
    # effort kind = "current": this log's current-to-torque gains per motor, in place of robot.drive_gains
    # (a log recorded with other current sensors or another calibration; [[data]] experiments differ)
    drive_gains: tuple[float, ...] | None = None


@dataclasses.dataclass(frozen=True)
class TimeConfig:
    column: str  # the time column (header = false: its index); ROS bags: "header" (header.stamp) or "receive"
    unit: str = "s"  # of the time column: "s", "ms", "us" or "ns"
    file: Path | None = None  # the time column's own file (default: the table's file)


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """``[data]`` (training log) or ``[validation]`` (held-out log)."""

    position: SignalConfig  # the positions: { columns = [...], unit = ..., side = ... } (joint or motor side)
    effort: SignalConfig  # the efforts: torques or forces, or motor currents (kind = "current")
    file: Path | None = None  # the log (.csv, .npz, .parquet or a ROS bag): the default file of every signal
    time: TimeConfig | None = None  # the time column: { column = "t", unit = "s" } (ROS bags: "header" or "receive")
    sample_rate_hz: float | None = None  # Hz: the log's constant sampling rate, when there is no time column
    velocity: SignalConfig | None = None  # optional measured velocities (as position's side, unit); derivatives = "measured"
    acceleration: SignalConfig | None = None  # optional measured accelerations (derivatives = "measured"; not from ROS bags)
    rows: tuple[int, int] | None = None  # a window [start, stop) of the log's rows (a ROS bag: of its position messages)
    time_window: tuple[float, float] | None = None  # a window [t0, t1) of the log's time in s (instead of rows)
    header: bool = True  # CSV: False reads a headerless file whose columns are named by index (0, 1, ...)
    topic: str | None = None  # ROS bags: the JointState topic of every signal without its own topic
    bag: bool = False  # file is a ROS bag (dynid.io.bags): columns are joint names, time the messages' stamps
    payload: bool | None = None  # [[data]] payload = true|false: the experiment carries the payload (None: not said)

    def files(self) -> tuple[Path, ...]:
        """Every file this spec reads."""
        out = []
        for s in (self.time, self.position, self.effort, self.velocity, self.acceleration):
            if s is not None:
                f = s.file or self.file
                if f is not None and f not in out:
                    out.append(f)
        return tuple(out)



def _column(v: Any, where: str, header: bool) -> str:
    """A column name; without a header row (``header = false``) a column index 0, 1, ... (kept as its text)."""
    if header:
        return _str(v, where)
    if isinstance(v, str):
        raise ConfigError(f"{where}: the file has no header row (header = false): name columns by index "
                          f"(0 is the first column), got {v!r}")
    return str(_int(v, where, 0))


def _parse_signal(t: Any, where: str, base: Path, what: str, header: bool = True, bag: bool = False) -> SignalConfig:
    allowed = {"columns", "unit", "side", "file", "topic"} | ({"kind", "drive_gains"} if what == "effort" else set())
    t = _table(t, where, allowed, {"columns"})
    if bag and "file" in t:
        raise ConfigError(f"{where}.file: every signal of a ROS bag log comes from the bag of {where.split('.')[0]}.file; "
                          f"give a signal its own topic with {where}.topic")
    if "topic" in t and not bag:
        raise ConfigError(f"{where}.topic is for ROS bags (file = a .bag, a ROS 2 bag folder, .db3 or .mcap)")
    cols = t["columns"]
    column = lambda v, w: _column(v, w, header)  # noqa: E731
    columns = (column(cols, f"{where}.columns"),) if not isinstance(cols, list) else _list(cols, f"{where}.columns", column)
    if not columns:
        raise ConfigError(f"{where}.columns: empty")
    twice = sorted({c for c in columns if columns.count(c) > 1})
    if twice:
        raise ConfigError(f"{where}.columns: {', '.join(repr(c) for c in twice)} named more than once "
                          "(one column per joint or actuator)")
    side = _str(t.get("side", "joint"), f"{where}.side", ("joint", "motor"))
    # a unit, one per column, or none (SI: rad or m, N*m or N, A); checked against the joints
    # once the model is known (dynid.pipeline.data.check_units)
    if what == "effort":
        kind = _str(t.get("kind", "torque"), f"{where}.kind", ("torque", "current"))
        units = tuple(EFFORT_UNITS[kind])
    else:
        kind = "torque"
        units = tuple(POSITION_UNITS)
    unit = None
    if "unit" in t:
        u = t["unit"]
        unit = _list(u, f"{where}.unit", lambda v, w: _str(v, w, units)) if isinstance(u, list) else _str(u, f"{where}.unit", units)
        if isinstance(unit, tuple) and len(unit) != len(columns) and len(columns) > 1:
            raise ConfigError(f"{where}.unit: {len(unit)} units for {len(columns)} columns")
    file = _path(t["file"], f"{where}.file", base) if "file" in t else None
    if file is not None and is_bag(file):
        raise ConfigError(f"{where}.file: {file.name} is a ROS bag; a bag is the file of the whole log ({where.split('.')[0]}.file)")
    topic = _str(t["topic"], f"{where}.topic") if "topic" in t else None
    gains = None
    if "drive_gains" in t:
        if kind != "current":
            raise ConfigError(f"{where}.drive_gains convert motor currents: they need {where}.kind = 'current'")
        g = _num_or_list(t["drive_gains"], f"{where}.drive_gains")
        gains = g if isinstance(g, tuple) else (g,)
        if any(v == 0 or not math.isfinite(v) for v in gains):
            raise ConfigError(f"{where}.drive_gains: every gain must be finite and non-zero, got {list(gains)}")
        if len(gains) not in (1, len(columns)):
            raise ConfigError(f"{where}.drive_gains: {len(gains)} gains for {len(columns)} columns")
    return SignalConfig(columns=columns, unit=unit, side=side, kind=kind, file=file, topic=topic, drive_gains=gains)


_DATA_KEYS = {"file", "time", "sample_rate_hz", "position", "effort", "velocity", "acceleration", "rows", "time_window",
              "header", "topic"}
_BAG_ONLY = ("topic",)


def _reads_bag(file: Path, t: Mapping[str, Any]) -> bool:
    """Whether a [data] table whose file is ``file`` reads a ROS bag: a .bag, .db3, .mcap, a ROS 2 bag folder, or
    a path without a suffix given a topic (a folder that is not a bag, or is not there: the bag reader says so)."""
    return is_bag(file) or ("topic" in t and file.suffix == "")


def is_bag(path: Path) -> bool:
    """A ROS bag (:func:`dynid.io.bags.is_bag`: .bag, .db3, .mcap, or a folder with metadata.yaml)."""
    return path.suffix.lower() in (".bag", ".db3", ".mcap") or (path / "metadata.yaml").is_file()


def _parse_bag_time(t: Mapping[str, Any], where: str) -> TimeConfig:
    """``time`` of a ROS bag log: ``"header"`` (default) or ``"receive"``."""
    if "sample_rate_hz" in t:
        raise ConfigError(f"{where}.sample_rate_hz: a ROS bag's messages carry their own time; use {where}.time = "
                          "'header' (the messages' header stamps, default) or 'receive' (the bag's receive time)")
    v = t.get("time", "header")
    if not isinstance(v, str):
        raise ConfigError(f"{where}.time of a ROS bag log is 'header' (the messages' header stamps, default) or "
                          f"'receive' (the bag's receive time), got {v!r}")
    return TimeConfig(column=_str(v, f"{where}.time", ("header", "receive")))


def _parse_data(t: Any, where: str, base: Path) -> DataConfig:
    t = _table(t, where, _DATA_KEYS, {"position", "effort"})
    file = _path(t["file"], f"{where}.file", base) if "file" in t else None
    bag = file is not None and _reads_bag(file, t)
    if bag:
        if "header" in t:
            raise ConfigError(f"{where}.header is for CSV files; {file.name} is a ROS bag")
        if "topic" not in t and not all(isinstance(t.get(k), dict) and "topic" in t[k]
                                        for k in ("position", "effort", "velocity", "acceleration") if k in t):
            raise ConfigError(f"{where}.topic: name the sensor_msgs/JointState topic of the bag {file.name} "
                              f"(or a topic per signal)")
        if "acceleration" in t:
            raise ConfigError(f"{where}.acceleration: a JointState message has no accelerations (position, velocity, effort)")
        return _parse_bag_data(t, where, base, file)
    given = [k for k in _BAG_ONLY if k in t]
    if given:
        raise ConfigError(f"{where}.{given[0]} is for ROS bags (file = a .bag, a ROS 2 bag folder, .db3 or .mcap)")
    header = _bool(t.get("header", True), f"{where}.header")
    time = None
    if "time" in t:
        if isinstance(t["time"], str):
            raise ConfigError(f"{where}.time: expected a table, got str ({t['time']!r}); a table's time is a column, "
                              f"{where}.time = {{ column = ... }} (time = 'header' or 'receive' is for ROS bags)")
        tt = _table(t["time"], f"{where}.time", {"column", "unit", "file"}, {"column"})
        time = TimeConfig(
            column=_column(tt["column"], f"{where}.time.column", header),
            unit=_str(tt.get("unit", "s"), f"{where}.time.unit", tuple(TIME_UNITS)),
            file=_path(tt["file"], f"{where}.time.file", base) if "file" in tt else None,
        )
    fs = _num(t["sample_rate_hz"], f"{where}.sample_rate_hz", positive=True) if "sample_rate_hz" in t else None
    if (time is None) == (fs is None):
        raise ConfigError(f"{where}: give exactly one of 'time' (a time column) or 'sample_rate_hz'")
    rows, window = _windows(t, where)
    spec = DataConfig(
        file=file,
        time=time,
        sample_rate_hz=fs,
        position=_parse_signal(t["position"], f"{where}.position", base, "position", header),
        effort=_parse_signal(t["effort"], f"{where}.effort", base, "effort", header),
        velocity=_parse_signal(t["velocity"], f"{where}.velocity", base, "velocity", header) if "velocity" in t else None,
        acceleration=_parse_signal(t["acceleration"], f"{where}.acceleration", base, "acceleration", header)
        if "acceleration" in t
        else None,
        rows=rows,
        time_window=window,
        header=header,
    )
    for s, label in ((spec.position, "position"), (spec.effort, "effort"), (spec.velocity, "velocity"),
                     (spec.acceleration, "acceleration"), (spec.time, "time")):
        if s is not None and s.file is None and spec.file is None:
            raise ConfigError(f"{where}.{label}: no file (set {where}.file or {where}.{label}.file)")
    return spec


def _parse_bag_data(t: Mapping[str, Any], where: str, base: Path, file: Path) -> DataConfig:
    """``[data]`` reading a ROS bag: columns are joint names of sensor_msgs/JointState messages."""
    rows, window = _windows(t, where)
    signal = lambda key: _parse_signal(t[key], f"{where}.{key}", base, key, bag=True) if key in t else None  # noqa: E731
    return DataConfig(
        file=file,
        time=_parse_bag_time(t, where),
        position=signal("position"),
        effort=signal("effort"),
        velocity=signal("velocity"),
        rows=rows,
        time_window=window,
        topic=_str(t["topic"], f"{where}.topic") if "topic" in t else None,
        bag=True,
    )


def _windows(t: Mapping[str, Any], where: str) -> tuple[tuple[int, int] | None, tuple[float, float] | None]:
    """``rows`` and ``time_window`` (at most one)."""
    rows = None
    if "rows" in t:
        rows = _list(t["rows"], f"{where}.rows", lambda v, w: _int(v, w, 0), 2)
        if rows[1] <= rows[0]:
            raise ConfigError(f"{where}.rows: stop {rows[1]} must exceed start {rows[0]}")
    window = None
    if "time_window" in t:
        window = _list(t["time_window"], f"{where}.time_window", _num, 2)
        if window[1] <= window[0]:
            raise ConfigError(f"{where}.time_window: end must exceed start")
    if rows is not None and window is not None:
        raise ConfigError(f"{where}: give 'rows' or 'time_window', not both")
    return rows, window



def _tables_or_array(v: Any, where: str) -> list[dict[str, Any]]:
    """``[where]`` (one table) or ``[[where]]`` (a non-empty array of tables), as a list of copies."""
    if isinstance(v, list):
        if not v:
            raise ConfigError(f"{where}: an empty array; give at least one [[{where}]] table")
        for i, t in enumerate(v):
            if not isinstance(t, dict):
                raise ConfigError(f"{where}[{i}]: expected a table, got {type(t).__name__}")
        return [dict(t) for t in v]
    if not isinstance(v, dict):
        raise ConfigError(f"{where}: expected a table, got {type(v).__name__}")
    return [dict(v)]


def _validation_spec(data_t: Mapping[str, Any], val_t: Mapping[str, Any], data_base: Path, where: str) -> DataConfig:
    """A held-out log's spec: its keys over the (first) training table's, as for a single [validation]."""
    return _parse_data(_inherit(dict(data_t), dict(val_t), data_base, where), where, data_base)


def _check_held_out_windows(data: DataConfig, validation: DataConfig, dl: str, vl: str) -> None:
    """A held-out log reading a training file holds out other samples."""
    if set(validation.files()) != set(data.files()):
        return
    if validation.rows is None and validation.time_window is None:
        raise ConfigError(f"{vl}: uses the training file of {dl} without 'rows' or 'time_window'; hold out samples")
    if data.rows is None and data.time_window is None:
        raise ConfigError(f"{dl}: training uses the whole file that {vl} also reads; set rows or time_window")
    if (data.rows is None) != (validation.rows is None):
        raise ConfigError(f"{dl} and {vl} windows must both be 'rows' or both 'time_window'")
    a, b = (data.rows, validation.rows) if data.rows is not None else (data.time_window, validation.time_window)
    if a[0] < b[1] and b[0] < a[1]:
        raise ConfigError(f"{vl} window {list(b)} overlaps the training window {list(a)} of {dl}")


def _inherit(data_t: dict[str, Any], val_t: dict[str, Any], data_base: Path, where: str = "validation") -> dict[str, Any]:
    _reject_unknown(val_t, where, _DATA_KEYS)
    inherited = {k: v for k, v in data_t.items() if k not in ("rows", "time_window")}
    # A time source given in [validation] replaces the inherited one (time column or rate).
    if "sample_rate_hz" in val_t:
        inherited.pop("time", None)
    if "time" in val_t:
        inherited.pop("sample_rate_hz", None)
    # [validation] file = ... replaces the files of inherited signals, so that no signal
    # is silently read from a training file named in [data].<signal>.file.
    if "file" in val_t:
        for key in ("time", "position", "effort", "velocity", "acceleration"):
            if key in inherited and key not in val_t and isinstance(inherited[key], dict):
                inherited[key] = {k: v for k, v in inherited[key].items() if k != "file"}
        # a validation log of the other kind (a bag for a CSV, a CSV for a bag) inherits no keys of that kind
        if isinstance(val_t["file"], str) and isinstance(data_t.get("file"), str):
            val_bag = _reads_bag(_path(val_t["file"], "validation.file", data_base), {**data_t, **val_t})
            if val_bag != _reads_bag(_path(data_t["file"], "data.file", data_base), data_t):
                for key in ("topic", "header", "time", "sample_rate_hz"):
                    inherited.pop(key, None)
                for key in ("position", "effort", "velocity"):
                    if isinstance(inherited.get(key), dict):
                        inherited[key] = {k: v for k, v in inherited[key].items() if k != "topic"}
    return {**inherited, **val_t}


def _validation_pair(data_t: dict[str, Any], val_t: dict[str, Any], data_base: Path) -> tuple[DataConfig, DataConfig]:
    """The single [data] / [validation] pair (with [[...]] arrays: their first entries)."""
    data_t = _table(data_t, "data", _DATA_KEYS)
    merged = _inherit(data_t, val_t, data_base)
    data = _parse_data(data_t, "data", data_base)
    validation = _parse_data(merged, "validation", data_base)
    if set(validation.files()) == set(data.files()):
        if validation.rows is None and validation.time_window is None:
            raise ConfigError("validation: uses the training file without 'rows' or 'time_window'; hold out samples")
        if data.rows is None and data.time_window is None:
            raise ConfigError("data: training uses the whole file that validation also reads; set data.rows or data.time_window")
        if (data.rows is None) != (validation.rows is None):
            raise ConfigError("data and validation windows must both be 'rows' or both 'time_window'")
        a, b = (data.rows, validation.rows) if data.rows is not None else (data.time_window, validation.time_window)
        if a[0] < b[1] and b[0] < a[1]:
            raise ConfigError(f"validation window {list(b)} overlaps the training window {list(a)}")
    return data, validation
