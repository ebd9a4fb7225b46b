"""Load closed-loop mechanisms: ``builtin:<name>``, MJCF with ``<equality>`` loop closures, or
URDF with a closure YAML (:func:`load_mechanism`).

The file readers :func:`load_mechanism_mjcf` and :func:`load_mechanism_urdf` (and
:data:`ACTUATOR_TAGS`) live in :mod:`dynid.model.mechanism_files`, which documents the file
formats, and are re-exported here. This module sits above :mod:`dynid.model.robots` (the
built-in mechanisms, one of which is an MJCF file read by :mod:`dynid.model.mechanism_files`).
"""

from __future__ import annotations

from pathlib import Path

from dynid.errors import ModelError
from dynid.model.mechanism import Mechanism
from dynid.model.mechanism_files import ACTUATOR_TAGS, load_mechanism_mjcf, load_mechanism_urdf
from dynid.model.robots import build_mechanism

__all__ = ["ACTUATOR_TAGS", "load_mechanism", "load_mechanism_mjcf", "load_mechanism_urdf"]


def load_mechanism(spec: str | Path, **kw) -> Mechanism:
    """Load a mechanism: ``builtin:<name>``, ``.xml``/``.mjcf`` (MJCF) or ``.urdf`` (+ YAML).

    Keyword arguments go to :func:`load_mechanism_mjcf` or :func:`load_mechanism_urdf`.
    """
    text = str(spec)
    if text.startswith("builtin:"):
        return build_mechanism(text.split(":", 1)[1])
    path = Path(spec)
    suffix = path.suffix.lower()
    if suffix in (".xml", ".mjcf"):
        return load_mechanism_mjcf(path, **kw)
    if suffix == ".urdf":
        return load_mechanism_urdf(path, **kw)
    raise ModelError(f"{path}: unknown mechanism file type {suffix!r} (use .xml/.mjcf, or .urdf with a closure YAML)")
