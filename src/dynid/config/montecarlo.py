"""The configuration of ``dynid montecarlo``: a strict, typed schema read from TOML.

A Monte Carlo study repeats one virtual experiment and its identification many times with
known truth (paper 002 §5, the 100 repeated trials). Sections (unknown keys are errors naming
the dotted key):

``[simulate]`` (required)
    A whole ``dynid simulate`` configuration as sub-tables (``[simulate.robot]``,
    ``[simulate.trajectory]``, ``[simulate.control]``, ``[simulate.sensors]``, ...), or
    ``file = "path.toml"``: such a configuration in a file of its own (relative to this file).
``[identify]``
    The ``dynid identify`` configuration without the logs, which are the simulated ones:
    ``[identify.processing]`` and ``[identify.identification]`` as in ``dynid identify``;
    ``[identify.robot]`` (default: the simulated model, ``model`` may be left out);
    ``[identify.data]`` and ``[identify.validation]``: ``rows`` or ``time_window`` of the
    simulated log used for training and for the held-out check, given together (default:
    the first 80 % of the rows train, the last 20 % validate).
``[montecarlo]``
    ``trials`` (default 100); ``seed``: sensor-noise seed of trial 0 (default: the simulation's
    ``sensors.seed``; trial ``k`` uses ``seed + k``); ``workers``: local processes (default 1;
    ``0`` or ``"auto"``: all cores); ``resimulate`` (default false: the motion is simulated
    once and each trial redraws the sensor noise; true: each trial runs the whole simulation
    again with every seed of ``[simulate]`` offset by ``k``); ``alpha`` (default 0.05: 95 %
    intervals and ellipsoid); ``scheduler``: address of a Dask scheduler
    (``tcp://host:port``) to run the trials on instead of local processes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from dynid.config import Config, _bool, _int, _num, _str, _table, parse_config, read_toml
from dynid.config._schema import parse_scheduler, parse_workers, usable_cores  # noqa: F401  (re-exported)
from dynid.config.simulate import SimulateConfig, load_simulate_config, parse_simulate_config
from dynid.errors import ConfigError, InputError

__all__ = ["MonteCarloConfig", "load_montecarlo_config", "parse_montecarlo_config", "parse_scheduler", "parse_workers",
           "DEFAULT_TRAIN_SHARE"]

DEFAULT_TRAIN_SHARE = 0.8
"""Share of the simulated log's rows used for training when no window is given."""

_IDENTIFY_KEYS = {"robot", "data", "validation", "processing", "identification"}
_WINDOW_KEYS = {"rows", "time_window"}
_MONTECARLO_KEYS = {"trials", "seed", "workers", "resimulate", "alpha", "scheduler"}


@dataclasses.dataclass(frozen=True)
class MonteCarloConfig:
    """``dynid montecarlo``: the experiment, the identification template and the repetition."""

    simulate: SimulateConfig
    identify: Mapping[str, Any]  # the [identify] table (validated; the logs are filled in per trial)
    trials: int = 100
    seed: int = 0
    workers: int = 1  # 0: all cores
    resimulate: bool = False
    alpha: float = 0.05
    scheduler: str | None = None
    base_dir: Path = Path(".")
    source: Path | None = None
    raw: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def n_workers(self) -> int:
        """Local worker processes (``workers = 0``: the cores this process may use)."""
        return usable_cores(self.workers)

    def identify_config(self, log: Path, actuators: Sequence[str], effort_kind: str, n_samples: int) -> Config:
        """The ``dynid identify`` configuration of one trial whose log is ``log`` (the columns of
        ``dynid simulate``: ``t``, ``q_<actuator>``, ``tau_<actuator>`` or ``i_<actuator>``)."""
        r = self.simulate.robot
        chart = {k: list(v) for k, v in (("actuated", r.actuated), ("independent", r.independent)) if v is not None}
        return parse_config(_identify_document(self.identify, r.model, log, actuators, effort_kind, n_samples, chart),
                            self.base_dir, source=self.source)


def _identify_document(t: Mapping[str, Any], model: str, log: Path, actuators: Sequence[str], effort_kind: str,
                       n_samples: int, chart: Mapping[str, Any] | None = None) -> dict[str, Any]:
    prefix = "i" if effort_kind == "current" else "tau"
    data: dict[str, Any] = {
        "file": str(log),
        "time": {"column": "t", "unit": "s"},
        "position": {"columns": [f"q_{a}" for a in actuators]},
        "effort": {"columns": [f"{prefix}_{a}" for a in actuators], "kind": effort_kind},
    }
    if "data" in t:
        train, held_out = dict(t["data"]), dict(t["validation"])
    else:
        split = max(1, min(n_samples - 1, int(DEFAULT_TRAIN_SHARE * n_samples)))
        train, held_out = {"rows": [0, split]}, {"rows": [split, n_samples]}
    robot = {"model": model, **(chart or {}), **t.get("robot", {})}  # the simulated chart unless identify names its own
    doc: dict[str, Any] = {"robot": robot, "data": {**data, **train}, "validation": held_out, "output": {"plots": False}}
    for key in ("processing", "identification"):
        if key in t:
            doc[key] = t[key]
    # every trial identifies the same model (the trials' estimates are compared): the default structure is
    # "full" here, not "auto", whose choice could change from trial to trial
    ident = dict(doc.get("identification", {}))
    if "structure" not in ident and "identical_chains" not in ident:
        doc["identification"] = {**ident, "structure": "full"}
    return doc


def _parse_identify(t: Any, model: str, base_dir: Path) -> dict[str, Any]:
    t = _table(t, "identify", _IDENTIFY_KEYS)
    windows = [k for k in ("data", "validation") if k in t]
    for k in windows:
        _table(t[k], f"identify.{k}", _WINDOW_KEYS)
    if len(windows) == 1:
        missing = ({"data", "validation"} - set(windows)).pop()
        raise ConfigError(f"identify: [identify.{windows[0]}] needs [identify.{missing}] (the training and held-out windows "
                          "of the simulated log go together)")
    if "robot" in t:
        _table(t["robot"], "identify.robot", {"model", "extras", "gear_ratios", "couplings", "drive_gains", "position_offset"})
    # validate every key now, on a stand-in log (the real one is written per trial)
    try:
        cfg = parse_config(_identify_document(t, model, base_dir / "trial.npz", ["a"], "torque", 1000), base_dir)
    except ConfigError as exc:
        raise ConfigError(f"identify: {exc}") from None
    if cfg.identification.hierarchical:
        raise ConfigError("identify.identification.hierarchical = true is not available in dynid montecarlo: its trials "
                          "compare base parameters with the simulated truth and do not map friction curves")
    if cfg.identification.structure == "auto":
        raise ConfigError("identify.identification.structure = 'auto' is not available in dynid montecarlo: its choice could "
                          "differ between trials, whose estimates are compared; name 'full', 'identical_chains' or 'paper'")
    if cfg.identification.friction_model != "linear":
        raise ConfigError("identify.identification.friction_model = 'stribeck' is not available in dynid montecarlo: "
                          "its trials compare base parameters with the simulated truth and do not map Stribeck parameters yet")
    return dict(t)


def _parse_simulate(t: Any, base_dir: Path) -> SimulateConfig:
    if not isinstance(t, dict):
        raise ConfigError(f"simulate: expected a table, got {type(t).__name__}")
    if "file" in t:
        if set(t) != {"file"}:
            raise ConfigError(f"simulate: give either file = \"...\" or the configuration's tables, not both "
                              f"(found {sorted(set(t) - {'file'})})")
        p = Path(_str(t["file"], "simulate.file")).expanduser()
        path = p if p.is_absolute() else base_dir / p
        try:
            return load_simulate_config(path)
        except (ConfigError, InputError) as exc:
            raise type(exc)(f"simulate.file {path}: {exc}") from None
    try:
        return parse_simulate_config(t, base_dir)
    except ConfigError as exc:
        raise ConfigError(f"simulate: {exc}") from None


def parse_montecarlo_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> MonteCarloConfig:
    """Validate a parsed TOML document (see module docstring)."""
    doc = _table(dict(doc), "config", {"simulate", "identify", "montecarlo"}, {"simulate"})
    sim = _parse_simulate(doc["simulate"], base_dir)
    ident = _parse_identify(doc.get("identify", {}), sim.robot.model, base_dir)
    mc = _table(doc.get("montecarlo", {}), "montecarlo", _MONTECARLO_KEYS)
    alpha = _num(mc.get("alpha", 0.05), "montecarlo.alpha")
    if not 0 < alpha < 1:
        raise ConfigError(f"montecarlo.alpha: must be in (0, 1), got {alpha}")
    scheduler = parse_scheduler(mc["scheduler"], "montecarlo.scheduler") if "scheduler" in mc else None
    return MonteCarloConfig(
        simulate=sim,
        identify=ident,
        trials=_int(mc.get("trials", 100), "montecarlo.trials", 1),
        seed=_int(mc.get("seed", sim.sensors.seed), "montecarlo.seed", 0),
        workers=parse_workers(mc.get("workers", 1), "montecarlo.workers"),
        resimulate=_bool(mc.get("resimulate", False), "montecarlo.resimulate"),
        alpha=alpha,
        scheduler=scheduler,
        base_dir=base_dir,
        source=source,
        raw=doc,
    )


def load_montecarlo_config(path: str | Path) -> MonteCarloConfig:
    """Read and validate a ``dynid montecarlo`` TOML file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_montecarlo_config(doc, path.resolve().parent, source=path.resolve())
