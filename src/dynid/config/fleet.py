"""The configuration of ``dynid fleet``: many robots x many logs, a strict, typed schema read from TOML.

Sections (unknown keys are errors naming the dotted key):

``[fleet]``
    ``logs``: the table of robots and their logs, a CSV file (header ``robot, model, file`` and
    optionally ``date``, ``validation``) or a TOML file of ``[[log]]`` tables, relative to this
    file (or give the ``[[log]]`` tables here instead); ``workers``: process workers of the local
    Dask cluster (default 2; ``0`` or ``"auto"``: all cores); ``scheduler``: the address of an
    existing Dask scheduler (``tcp://host:port``) instead of a local cluster; ``alpha``: the level
    of the intervals and of every test (outliers, drift, change point; default 0.05);
    ``retries``: how many times Dask reruns a job whose worker raised an unexpected error
    (default 1; a job whose worker died is rerun by the scheduler in any case).
``[models]``
    One entry per robot model: ``NAME = "identify.toml"``, a ``dynid identify`` configuration
    (relative to this file) whose ``[data]`` / ``[validation]`` tables are the template of every
    log of a robot of that model: each log's file replaces ``data.file`` and, unless the log
    names its own ``validation`` file, ``validation.file`` (then the template's
    ``[validation]`` window of the same file is held out).
``[[log]]``
    ``robot`` (an id), ``model`` (a name of ``[models]``), ``file`` (the log, relative to the
    table), optionally ``date`` (a TOML date or ``YYYY-MM-DD``; dated logs give the drift) and
    ``validation`` (a held-out log of its own).

A log's own faults (missing, unreadable, wrong columns, another robot's joints) are not
configuration errors: they fail that log alone and the fleet reports them
(:mod:`dynid.fleet.run`).
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config import Config, _int, _num, _path, _str, _table, parse_config, read_toml
from dynid.config._schema import usable_cores
from dynid.config.montecarlo import parse_scheduler, parse_workers
from dynid.errors import ConfigError, decode_text, read_file_bytes

__all__ = ["FleetConfig", "FleetLog", "load_fleet_config", "parse_fleet_config", "LOG_COLUMNS"]

LOG_COLUMNS = ("robot", "model", "file", "date", "validation")
"""The columns of the log table (the first three required)."""

_FLEET_KEYS = {"logs", "workers", "scheduler", "alpha", "retries"}
_REFUSED = {
    "learning": "a residual network is not a linear estimate with a covariance to pool",
}


@dataclasses.dataclass(frozen=True)
class FleetLog:
    """One row of the log table: ``index`` its place in the table (the order of every output)."""

    index: int
    robot: str
    model: str
    file: Path
    date: datetime.date | None = None
    validation: Path | None = None


@dataclasses.dataclass(frozen=True)
class FleetConfig:
    """``dynid fleet``: the models' identification templates, the log table and how to run."""

    models: Mapping[str, Mapping[str, Any]]  # model name -> its identify document (validated)
    model_files: Mapping[str, Path]
    logs: tuple[FleetLog, ...]
    workers: int = 2
    scheduler: str | None = None
    alpha: float = 0.05
    retries: int = 1
    base_dir: Path = Path(".")
    source: Path | None = None

    @property
    def n_workers(self) -> int:
        """Local process workers (``workers = 0``: the cores this process may use)."""
        return usable_cores(self.workers)

    @property
    def robots(self) -> tuple[str, ...]:
        """Robot ids in the order of their first log in the table."""
        return tuple(dict.fromkeys(log.robot for log in self.logs))

    def log_config(self, log: FleetLog) -> Config:
        """The ``dynid identify`` configuration of one log: its model's template with the log's file."""
        return _log_config(self.models[log.model], self.model_files[log.model], log.file, log.validation)


def _log_config(template: Mapping[str, Any], model_file: Path, file: Path, validation: Path | None) -> Config:
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in template.items()}
    doc["data"] = {**doc["data"], "file": str(file)}
    doc["validation"] = {**doc["validation"], "file": str(validation if validation is not None else file)}
    doc["output"] = {"plots": False}
    # every log of a robot identifies the same model (their estimates are pooled): the structure is "full"
    # unless named, never "auto", whose choice could differ from log to log
    ident = dict(doc.get("identification", {}))
    if "structure" not in ident and "identical_chains" not in ident:
        doc["identification"] = {**ident, "structure": "full"}
    return parse_config(doc, model_file.parent, source=model_file)


def _parse_model(name: str, value: Any, base_dir: Path) -> tuple[dict[str, Any], Path]:
    path = _path(value, f"models.{name}", base_dir)
    doc = read_toml(path)
    for key, why in _REFUSED.items():
        if key in doc:
            raise ConfigError(f"models.{name} ({path}): [{key}] is not available in dynid fleet: {why}")
    for key in ("data", "validation"):
        if key not in doc:
            raise ConfigError(f"models.{name} ({path}): no [{key}] table (the template of every log's {key})")
        if isinstance(doc[key], list):
            raise ConfigError(f"models.{name} ({path}): [[{key}]] arrays are not a template; give one [{key}] table "
                              "(each log of the fleet is one experiment)")
    ident = doc.get("identification", {})
    if isinstance(ident, dict):
        if ident.get("hierarchical") is True or ident.get("friction_model", "linear") != "linear":
            raise ConfigError(f"models.{name} ({path}): hierarchical or Stribeck friction is not available in dynid "
                              "fleet: its estimates are not linear base parameters with a covariance to pool")
        if ident.get("structure") == "auto":
            raise ConfigError(f"models.{name} ({path}): identification.structure = 'auto' could choose differently "
                              "from log to log; name 'full', 'identical_chains' or 'paper'")
    proc = doc.get("processing", {})
    if isinstance(proc, dict) and "periodic" in proc:
        raise ConfigError(f"models.{name} ({path}): processing.periodic is not available in dynid fleet (its held-out "
                          "rows are period averages, not the rows the fleet scores the pooled estimate on)")
    try:  # every key checked now, on a stand-in log (the real ones are read by the workers)
        _log_config(doc, path, path.parent / "log.csv", None)
    except ConfigError as exc:
        raise ConfigError(f"models.{name} ({path}): {exc}") from None
    return doc, path


def _date(value: Any, where: str) -> datetime.date | None:
    if value is None or value == "":
        return None
    if isinstance(value, datetime.datetime):
        return value.date()
    if isinstance(value, datetime.date):
        return value
    text = _str(value, where).strip()
    try:
        return datetime.date.fromisoformat(text)
    except ValueError:
        raise ConfigError(f"{where}: {text!r} is not a date (YYYY-MM-DD)") from None


def _read_csv_table(path: Path) -> list[dict[str, Any]]:
    text = decode_text(read_file_bytes(path, "log table"), path, "log table", ConfigError)
    reader = csv.DictReader(text.splitlines())
    header = [h.strip() for h in (reader.fieldnames or [])]
    unknown = sorted(set(header) - set(LOG_COLUMNS))
    if unknown:
        raise ConfigError(f"{path}: unknown column{'s' if len(unknown) > 1 else ''} {unknown}; the log table's columns "
                          f"are {list(LOG_COLUMNS)}")
    rows = []
    for row in reader:
        rows.append({k.strip(): v.strip() for k, v in row.items() if k is not None and v is not None and v.strip()})
    return rows


def _log_rows(fleet: Mapping[str, Any], doc: Mapping[str, Any], base_dir: Path) -> tuple[list[dict[str, Any]], Path, str]:
    if "logs" in fleet and "log" in doc:
        raise ConfigError("give the logs either as fleet.logs = \"table\" or as [[log]] tables, not both")
    if "log" in doc:
        if not isinstance(doc["log"], list):
            raise ConfigError("log: expected [[log]] tables (an array)")
        return list(doc["log"]), base_dir, "log"
    if "logs" not in fleet:
        raise ConfigError("fleet.logs: missing (a CSV or TOML table of robots and their logs), or give [[log]] tables")
    path = _path(fleet["logs"], "fleet.logs", base_dir)
    if path.suffix.lower() == ".toml":
        t = _table(read_toml(path), str(path), {"log"}, {"log"})
        if not isinstance(t["log"], list):
            raise ConfigError(f"{path}: expected [[log]] tables (an array)")
        return list(t["log"]), path.parent, f"{path.name}: log"
    return _read_csv_table(path), path.parent, path.name


def _parse_logs(rows: list[Any], base: Path, where: str, models: Mapping[str, Any]) -> tuple[FleetLog, ...]:
    if not rows:
        raise ConfigError(f"{where}: no logs")
    logs, seen, model_of = [], set(), {}
    for i, row in enumerate(rows):
        w = f"{where}[{i}]"
        t = _table(row, w, set(LOG_COLUMNS), {"robot", "model", "file"})
        robot, model = _str(t["robot"], f"{w}.robot").strip(), _str(t["model"], f"{w}.model").strip()
        if not robot:
            raise ConfigError(f"{w}.robot: empty robot id")
        if model not in models:
            raise ConfigError(f"{w}.model: {model!r} is not in [models] (known: {sorted(models)})")
        if model_of.setdefault(robot, model) != model:
            raise ConfigError(f"{w}: robot {robot!r} is a {model_of[robot]!r} in an earlier row, not a {model!r}")
        file = _path(t["file"], f"{w}.file", base)
        if (robot, file) in seen:
            raise ConfigError(f"{w}: robot {robot!r} lists {file} twice")
        seen.add((robot, file))
        val = _path(t["validation"], f"{w}.validation", base) if t.get("validation") else None
        logs.append(FleetLog(index=i, robot=robot, model=model, file=file, date=_date(t.get("date"), f"{w}.date"),
                             validation=val))
    return tuple(logs)


def parse_fleet_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> FleetConfig:
    """Validate a parsed TOML document (see module docstring)."""
    doc = _table(dict(doc), "config", {"fleet", "models", "log"}, {"models"})
    fleet = _table(doc.get("fleet", {}), "fleet", _FLEET_KEYS)
    models_t = _table(doc["models"], "models", set(doc["models"]) if isinstance(doc["models"], dict) else set())
    if not models_t:
        raise ConfigError("models: no model (give NAME = \"identify.toml\" per robot model)")
    models, files = {}, {}
    for name in models_t:
        models[name], files[name] = _parse_model(name, models_t[name], base_dir)
    rows, table_base, where = _log_rows(fleet, doc, base_dir)
    logs = _parse_logs(rows, table_base, where, models)
    alpha = _num(fleet.get("alpha", 0.05), "fleet.alpha")
    if not 0 < alpha < 1:
        raise ConfigError(f"fleet.alpha: must be in (0, 1), got {alpha}")
    return FleetConfig(
        models=models, model_files=files, logs=logs,
        workers=parse_workers(fleet.get("workers", 2), "fleet.workers"),
        scheduler=parse_scheduler(fleet["scheduler"], "fleet.scheduler") if "scheduler" in fleet else None,
        alpha=alpha, retries=_int(fleet.get("retries", 1), "fleet.retries", 0),
        base_dir=base_dir, source=source,
    )


def load_fleet_config(path: str | Path) -> FleetConfig:
    """Read and validate a ``dynid fleet`` TOML file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_fleet_config(doc, path.resolve().parent, source=path.resolve())
