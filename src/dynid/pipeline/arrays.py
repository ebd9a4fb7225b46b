"""The array API: :func:`identify_arrays`, ``dynid identify`` on arrays held in memory.

No second code path: the arguments become the same configuration document a TOML file gives
(:func:`dynid.config.parse_config`, with its checks and messages), and the arrays reach
:func:`dynid.pipeline.identification.identify` through the reader interface a log file on disk
uses (:class:`ArrayTable`, in place of :class:`~dynid.io.readers.TableReader`). The result is
the :class:`~dynid.pipeline.identification.IdentifyOutcome` of ``dynid identify`` (estimates with
their covariance, held-out validation against the nominal model, ``_repr_html_`` for notebooks;
:func:`~dynid.pipeline.identification.write_outputs` writes its files).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import IDENTIFICATION_KEYS, PROCESSING_KEYS, ROBOT_KEYS, parse_config
from dynid.errors import DynidError, InputError
from dynid.pipeline.identification import identify
from dynid.pipeline.outcome import IdentifyOutcome
from dynid.pipeline.rows import Progress

__all__ = ["ArrayTable", "identify_arrays", "OPTION_SECTIONS"]

OPTION_SECTIONS: dict[str, str] = {
    **{k: "robot" for k in ROBOT_KEYS},
    **{k: "processing" for k in PROCESSING_KEYS},
    **{k: "identification" for k in IDENTIFICATION_KEYS},
}
"""Each keyword option of :func:`identify_arrays` and the configuration section it sets (the
keys of the three sections are distinct)."""

_TRAIN, _HELD_OUT = "<arrays:training>", "<arrays:held-out>"


class ArrayTable:
    """Named float columns held in memory, read like a log file (``columns``, ``available``,
    ``sha256``: the interface :func:`dynid.pipeline.data.read_log` uses)."""

    def __init__(self, path: Path, columns: Mapping[str, FloatArray]) -> None:
        self.path = path
        self.kind = "arrays"
        self._columns = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
        self._sha256: str | None = None

    @property
    def available(self) -> list[str]:
        return list(self._columns)

    def columns(self, names: Sequence[str] | str) -> FloatArray:
        names = [names] if isinstance(names, str) else list(names)
        missing = [n for n in names if n not in self._columns]
        if missing:
            from dynid.io.readers import missing_names

            raise InputError(f"{self.path.name}: missing columns {missing} ({missing_names(missing, self.available)}); "
                             f"the arrays are {self.available}")
        return np.column_stack([self._columns[n] for n in names])

    def sha256(self) -> str:
        """SHA-256 of the arrays' bytes in column order (the provenance a file's hash gives)."""
        if self._sha256 is None:
            h = hashlib.sha256()
            for name, col in self._columns.items():
                h.update(name.encode())
                h.update(np.ascontiguousarray(col, dtype="<f8").tobytes())
            self._sha256 = h.hexdigest()
        return self._sha256


def _as_arrays(t: Any, q: Any, effort: Any, label: str) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``t`` (n,), ``q`` and ``effort`` (n, k) (a 1-D array: one joint) as float arrays."""
    out = []
    for name, x, ndim in (("t", t, 1), ("q", q, 2), ("effort", effort, 2)):
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{label} {name}: not an array of numbers ({exc})") from None
        if ndim == 2 and a.ndim == 1:
            a = a[:, None]
        if a.ndim != ndim:
            raise InputError(f"{label} {name}: expected {'a 1-D array (n,)' if ndim == 1 else 'a 2-D array (n, joints)'}, "
                             f"got shape {a.shape}")
        out.append(a)
    if out[1].shape[1] != out[2].shape[1]:
        raise InputError(f"{label}: q has {out[1].shape[1]} columns, effort {out[2].shape[1]}; one per joint/actuator each")
    return out[0], out[1], out[2]


def _table(t: FloatArray, q: FloatArray, effort: FloatArray, path: Path) -> ArrayTable:
    cols: dict[str, FloatArray] = {"t": t}
    cols.update({f"q[{j}]": q[:, j] for j in range(q.shape[1])})
    cols.update({f"effort[{j}]": effort[:, j] for j in range(effort.shape[1])})
    return ArrayTable(path, cols)


def identify_arrays(robot: str, t: Any, q: Any, effort: Any, *, held_out: tuple[Any, Any, Any] | None = None,
                    holdout: float | None = None, method: str = "wls", processing: Mapping[str, Any] | None = None,
                    identification: Mapping[str, Any] | None = None, learning: Mapping[str, Any] | None = None,
                    progress: Progress | None = None, **options: Any) -> IdentifyOutcome:
    """Identify the base parameters of ``robot`` from arrays: ``dynid identify`` without files.

    Parameters
    ----------
    robot : str
        As ``[robot] model``: ``builtin:<name>``, or a ``.urdf`` (a parallel robot's closure YAML
        ``robot.yaml`` beside it), MJCF ``.xml`` or DH ``.toml`` path (relative to the current folder).
    t, q, effort : array_like
        Training log in SI units: times [s] (n,), actuator positions [rad or m] and forces [N*m or
        N] (n, actuators), in the order of ``dynid info ROBOT`` (the joints of a serial robot, the
        actuated joints of a parallel one).
    held_out : (t, q, effort), optional
        A held-out log (another run), for the validation. Without it, the last ``holdout``
        fraction of the rows (default 0.25) is held out: ``[data] rows`` and ``[validation] rows``
        of one log, as in a configuration file.
    method : str
        ``[identification] method`` (default ``"wls"``).
    processing, identification, learning : mapping, optional
        Sections of the configuration as dictionaries (the schema of docs/guide/configuration.md).
    **options
        Any key of ``[robot]`` (except ``model``), ``[processing]`` or ``[identification]`` as a
        keyword, e.g. ``lowpass={"cutoff_hz": 10.0}``, ``min_velocity=0.05``,
        ``friction_model="stribeck"``, ``physical_consistency=True``, ``extras=["Ia", "fv", "fc"]``.
        An unknown keyword, a key given twice, or a value the schema refuses is an
        :class:`~dynid.errors.InputError` (a :class:`~dynid.errors.ConfigError` for values)
        naming it.
    progress : callable, optional
        ``progress(task, done, total)`` as long work advances.

    Returns
    -------
    IdentifyOutcome
        What ``dynid identify`` computes: ``.result`` (estimates, covariance), ``.validation``,
        ``.nominal_validation`` and ``.prior`` (the nominal model on the same held-out rows),
        ``.summary_text()``, and an HTML table in a notebook.

    The provenance names the arrays ``<arrays:training>`` and ``<arrays:held-out>`` (beside the
    current folder) with the SHA-256 of their bytes; ``[output] plots`` is false (write the files
    with :func:`~dynid.pipeline.identification.write_outputs`: no plots).

    The estimators are those of the configuration (e.g. ``"wls"``: Gautier & Poignet's weighted
    least squares, paper 000 Eq. 21; see :mod:`dynid.estimation`).
    """
    if not isinstance(robot, str) or not robot.strip():
        raise InputError(f"robot: expected a model name or path (builtin:<name>, .urdf, .xml, DH .toml), got {robot!r}")
    unknown = sorted(k for k in options if k not in OPTION_SECTIONS)
    if unknown:
        raise InputError(f"identify_arrays: unknown keyword{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                         f"the options are the keys of [robot] {sorted(ROBOT_KEYS)}, [processing] "
                         f"{sorted(PROCESSING_KEYS)} and [identification] {sorted(IDENTIFICATION_KEYS)} (or the "
                         "sections as dictionaries: processing={...}, identification={...}, learning={...})")
    sections: dict[str, dict[str, Any]] = {"robot": {}, "processing": {}, "identification": {"method": method}}
    for name, given in (("processing", processing), ("identification", identification)):
        if given is None:
            continue
        if not isinstance(given, Mapping):
            raise InputError(f"{name}: expected a dictionary of [{name}] keys, got {type(given).__name__}")
        if name == "identification" and "method" in given:
            raise InputError("identification: give the method as method=..., not inside identification={...}")
        sections[name].update(given)
    for key, value in options.items():
        sec = OPTION_SECTIONS[key]
        if key in sections[sec]:
            raise InputError(f"identify_arrays: {key} given twice (as a keyword and in {sec}={{...}})")
        sections[sec][key] = value
    model = robot if robot.startswith("builtin:") else str(Path(robot).expanduser().resolve())

    t, q, effort = _as_arrays(t, q, effort, "training")
    k = q.shape[1]
    signals = {"time": {"column": "t"}, "position": {"columns": [f"q[{j}]" for j in range(k)]},
               "effort": {"columns": [f"effort[{j}]" for j in range(k)]}}
    base_dir = Path.cwd()
    tables = {}
    if held_out is not None:
        if holdout is not None:
            raise InputError("identify_arrays: give held_out=(t, q, effort) or holdout=FRACTION, not both")
        if not (isinstance(held_out, (tuple, list)) and len(held_out) == 3):
            raise InputError("held_out: expected a tuple (t, q, effort) of the held-out log")
        ht, hq, he = _as_arrays(*held_out, "held_out")
        data = {"file": _TRAIN, **signals}
        validation: dict[str, Any] = {"file": _HELD_OUT}
        tables[_HELD_OUT] = (ht, hq, he)
    else:
        frac = 0.25 if holdout is None else holdout
        if isinstance(frac, bool) or not isinstance(frac, (int, float)) or not 0 < frac < 1:
            raise InputError(f"holdout: expected a fraction of the rows between 0 and 1, got {holdout!r}")
        n = t.shape[0]
        split = n - int(round(frac * n))
        if not 0 < split < n:
            raise InputError(f"holdout {frac:g} of {n} rows leaves no training or no held-out row")
        data = {"file": _TRAIN, **signals, "rows": [0, split]}
        validation = {"rows": [split, n]}
    tables[_TRAIN] = (t, q, effort)
    doc = {"robot": {"model": model, **sections["robot"]}, "data": data, "validation": validation,
           "processing": sections["processing"], "identification": sections["identification"],
           "output": {"plots": False}}
    if learning is not None:
        doc["learning"] = dict(learning)
    try:
        cfg = parse_config(doc, base_dir)
    except DynidError:
        raise
    except (TypeError, ValueError, AttributeError) as exc:  # a value of a type TOML cannot hold
        raise InputError(f"identify_arrays: an option's value is not a TOML value ({exc})") from None
    readers = {base_dir / name: _table(*arrays, base_dir / name) for name, arrays in tables.items()}
    readers = {p.resolve(): r for p, r in readers.items()}
    return identify(cfg, progress if progress is not None else (lambda task, done, total: None), readers=readers)
