"""The configuration of ``dynid identify``: a strict, typed schema read from TOML.

Unknown keys, wrong types and out-of-range values are :class:`~dynid.errors.ConfigError`
with the dotted key in the message. Relative paths are relative to the config file.
The complete schema with one example is documented in docs/guide/configuration.md.

Each section has its module: ``[robot]`` (:mod:`dynid.config.robot`), ``[data]`` and ``[validation]``
(:mod:`dynid.config.data`), ``[processing]`` (:mod:`dynid.config.processing`), ``[identification]``
(:mod:`dynid.config.identification`); here the whole :class:`Config`, re-exporting their names.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config._schema import (  # noqa: F401 - re-exported to the other schemas
    _bool,
    _int,
    _list,
    _num,
    _num_or_list,
    _path,
    _reject_unknown,
    _str,
    _table,
    parse_scheduler,
    parse_workers,
    read_toml,
)
from dynid.config.data import (  # noqa: F401 - re-exported: the names other modules import from dynid.config
    _BAG_ONLY,
    _DATA_KEYS,
    EFFORT_UNITS,
    POSITION_UNITS,
    TIME_UNITS,
    DataConfig,
    SignalConfig,
    TimeConfig,
    _check_held_out_windows,
    _column,
    _inherit,
    _parse_bag_data,
    _parse_bag_time,
    _parse_data,
    _parse_signal,
    _reads_bag,
    _tables_or_array,
    _validation_pair,
    _validation_spec,
    _windows,
    is_bag,
)
from dynid.config.identification import (  # noqa: F401 - re-exported
    _BODY_KEYS,
    _COVARIANCE_KEYS,
    _COVARIANCE_KINDS,
    _FORCE_MODELS,
    _LOOP_KEYS,
    _METHODS,
    _PHYSICAL_KEYS,
    _STRUCTURES,
    HIERARCHICAL_FAMILIES,
    IDENTIFICATION_KEYS,
    CovarianceConfig,
    IdentificationConfig,
    _chain_groups,
    _parse_bodies,
    _parse_cluster,
    _parse_covariance,
    _parse_identification,
)
from dynid.config.processing import (  # noqa: F401 - re-exported
    PROCESSING_KEYS,
    LowpassConfig,
    PeriodicConfig,
    ProcessingConfig,
    _noise_std,
    _parse_processing,
)
from dynid.config.robot import (  # noqa: F401 - re-exported
    _ALL_EXTRAS,
    _EXTRAS,
    ROBOT_KEYS,
    CouplingConfig,
    RobotConfig,
    _parse_robot,
    joint_name_list,
    rotor_inertia_list,
)
from dynid.errors import ConfigError

__all__ = [
    "Config",
    "RobotConfig",
    "CouplingConfig",
    "SignalConfig",
    "TimeConfig",
    "DataConfig",
    "LowpassConfig",
    "PeriodicConfig",
    "ProcessingConfig",
    "IdentificationConfig",
    "CovarianceConfig",
    "OutputConfig",
    "load_config",
    "parse_config",
    "POSITION_UNITS",
    "TIME_UNITS",
    "EFFORT_UNITS",
    "ROBOT_KEYS",
    "PROCESSING_KEYS",
    "IDENTIFICATION_KEYS",
]


@dataclasses.dataclass(frozen=True)
class OutputConfig:
    plots: bool = True  # validation.png, processing.png and report.html (false: none of them)


@dataclasses.dataclass(frozen=True)
class Config:
    robot: RobotConfig  # the model and its drive train
    data: DataConfig  # the training log ([[data]]: several experiments)
    validation: DataConfig  # the held-out log, never used for training; keys not given are taken from [data]
    processing: ProcessingConfig = ProcessingConfig()  # filtering, derivatives, decimation and row selection
    identification: IdentificationConfig = IdentificationConfig()  # the method and its options
    output: OutputConfig = OutputConfig()  # the figures
    source: Path | None = None
    # the residual friction network (dynid.learning.LearningConfig, config/learning.py; None without [learning])
    learning: Any = None
    raw: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    # [[data]] / [[validation]] (arrays of tables): every experiment, ``data`` / ``validation`` their first;
    # empty with a single [data] / [validation] table (dynid.pipeline.experiments)
    experiments: tuple[DataConfig, ...] = ()
    validations: tuple[DataConfig, ...] = ()
    # [payload] of dynid identify: the joint arm + payload mode (dynid.config.payload.PayloadConfig; None: no payload)
    payload: Any = None

    @property
    def training_logs(self) -> tuple[DataConfig, ...]:
        """Every training experiment: the [[data]] entries, or the single [data]."""
        return self.experiments or (self.data,)

    @property
    def validation_logs(self) -> tuple[DataConfig, ...]:
        """Every held-out log: the [[validation]] entries, or the single [validation]."""
        return self.validations or (self.validation,)



# ---------------------------------------------------------------------- parsing
def parse_config(doc: Mapping[str, Any], base_dir: Path, source: Path | None = None) -> Config:
    """Validate a parsed TOML document into a :class:`Config`."""
    doc = _table(dict(doc), "config", {"robot", "data", "validation", "processing", "identification", "output", "learning",
                                       "data_root", "payload"}, {"robot", "data", "validation"})
    data_base = data_root(doc, base_dir)
    data_list, val_list = _tables_or_array(doc["data"], "data"), _tables_or_array(doc["validation"], "validation")
    many = isinstance(doc["data"], list) or isinstance(doc["validation"], list)
    method = doc.get("identification", {}).get("method") if isinstance(doc.get("identification"), dict) else None
    if len(data_list) > 1 and method in ("iv", "didim", "cloe", "ml", "gm"):  # before the methods' own checks
        raise ConfigError(f"data: {len(data_list)} [[data]] experiments, but identification.method = {method!r} (only "
                          "'ols' and 'wls' stack experiments' factors; iv/didim/cloe run the control loop over one log, ml "
                          "cuts one log's filter, gm needs one log's cross-channel factor); give one [data] table")
    payloads = []
    for i, t in enumerate(data_list):
        where = f"data[{i}]" if isinstance(doc["data"], list) else "data"
        payloads.append(_bool(t.pop("payload"), f"{where}.payload") if "payload" in t else None)
    experiments = tuple(dataclasses.replace(_parse_data(t, f"data[{i}]", data_base), payload=pl)
                        for i, (t, pl) in enumerate(zip(data_list, payloads))) if many else ()
    val_payloads = []
    for i, t in enumerate(val_list):
        where = f"validation[{i}]" if isinstance(doc["validation"], list) else "validation"
        val_payloads.append(_bool(t.pop("payload"), f"{where}.payload") if "payload" in t else None)
    validations = tuple(dataclasses.replace(_validation_spec(data_list[0], v, data_base, f"validation[{i}]"), payload=pl)
                        for i, (v, pl) in enumerate(zip(val_list, val_payloads))) if many else ()
    payload = _joint_payload(doc, payloads, val_payloads, method)
    if many:
        for i, v in enumerate(validations):
            for j, d in enumerate(experiments):
                _check_held_out_windows(d, v, f"data[{j}]", f"validation[{i}]")
    data, validation = _validation_pair(data_list[0], val_list[0], data_base)
    if payloads[0] is not None:
        data = dataclasses.replace(data, payload=payloads[0])
    if val_payloads[0] is not None:
        validation = dataclasses.replace(validation, payload=val_payloads[0])
    out_t = _table(doc.get("output", {}), "output", {"plots"})
    processing = _parse_processing(doc.get("processing", {}))
    for label, spec in (("data", data), ("validation", validation), *((f"data[{i}]", d) for i, d in enumerate(experiments)),
                        *((f"validation[{i}]", d) for i, d in enumerate(validations))):
        given = [k for k in ("velocity", "acceleration") if getattr(spec, k) is not None]
        if given and processing.derivatives != "measured":
            raise ConfigError(f"{label}.{given[0]} columns are given but processing.derivatives = "
                              f"{processing.derivatives!r} differentiates the positions and would ignore them: "
                              "set processing.derivatives = 'measured' or drop them")
    return Config(
        robot=_parse_robot(doc["robot"], base_dir),
        data=data,
        validation=validation,
        processing=processing,
        identification=_parse_identification(doc.get("identification", {}), base_dir),
        output=OutputConfig(plots=_bool(out_t.get("plots", True), "output.plots")),
        source=source,
        raw=doc,
        learning=_learning(doc.get("learning")),
        experiments=experiments,
        validations=validations,
        payload=payload,
    )


def _joint_payload(doc: Mapping[str, Any], payloads: list, val_payloads: list, method: Any):
    """``[payload]`` of ``dynid identify`` (the joint mode, :mod:`dynid.pipeline.joint_payload`) and its refusals."""
    loaded = [i for i, v in enumerate(payloads) if v]
    if "payload" not in doc:
        marked = [f"data[{i}]" for i in loaded] + [f"validation[{i}]" for i, v in enumerate(val_payloads) if v]
        if marked:
            raise ConfigError(f"{marked[0]}.payload = true but there is no [payload] table (body, optional mass, "
                              "origin): give it to identify the payload jointly with the arm")
        return None
    from dynid.config._payload import parse_joint_payload

    if isinstance(doc["payload"], dict) and "arm" in doc["payload"]:
        raise ConfigError("payload.arm: dynid identify identifies the arm itself (jointly); 'arm' is read by "
                          "dynid payload (the given-arm mode)")
    spec = parse_joint_payload(doc["payload"])
    if not isinstance(doc["data"], list):
        raise ConfigError("payload: the joint mode needs [[data]] experiments, some with payload = true and some "
                          "without; a single [data] table cannot tell the payload from its body")
    if not loaded:
        raise ConfigError("payload: a [payload] table but no [[data]] experiment has payload = true (mark the "
                          "experiments recorded with the payload mounted)")
    if len(loaded) == len(payloads):
        raise ConfigError("payload: every [[data]] experiment has payload = true; the arm and the payload cannot be "
                          "told apart (their mount body's columns coincide): add an experiment without it")
    if method not in (None, "ols", "wls"):
        raise ConfigError(f"payload: identification.method = {method!r}; the joint arm + payload fit supports "
                          "'ols' and 'wls' (the payload block physically consistent with payload.physical)")
    return spec



def data_root(doc: Mapping[str, Any], base_dir: Path) -> Path:
    """``data_root``: the folder the logs' relative paths start from (``${VAR}`` expanded; itself relative
    to the config file); without it, the config file's folder."""
    if "data_root" not in doc:
        return base_dir
    root = _path(doc["data_root"], "data_root", base_dir)
    if not root.is_dir():
        raise ConfigError(f"data_root: {root} is {'not a folder' if root.exists() else 'not found'}")
    return root


def _learning(t: Any):
    from dynid.config.learning import parse_learning  # its own module (and dynid.learning's defaults)

    return parse_learning(t)


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML configuration file."""
    path = Path(path)
    doc = read_toml(path)
    return parse_config(doc, path.resolve().parent, source=path.resolve())
