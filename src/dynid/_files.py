"""Byte-reproducible files: equal content gives equal bytes.

``numpy.savez`` stamps every member of the zip archive with the current time, so two runs
that compute the same arrays write different files. :func:`save_npz` writes the same NPZ
format (a zip of ``.npy`` members, read by ``numpy.load``) with a fixed time stamp.
Wall-clock timings, the one thing that differs between equal runs, go to ``timing.json``
(:data:`TIMING_FILE`), the only output file documented as not reproducible.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["save_npz", "write_timing", "TIMING_FILE"]

TIMING_FILE = "timing.json"
_EPOCH = (1980, 1, 1, 0, 0, 0)  # the earliest time a zip member can carry


def save_npz(path: str | Path, arrays: Mapping[str, Any]) -> Path:
    """Write ``arrays`` as an uncompressed NPZ whose bytes depend on the arrays alone."""
    path = Path(path)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as z:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            z.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH), buf.getvalue())
    return path


def write_timing(folder: str | Path, timing: Mapping[str, Any]) -> Path:
    """``timing.json`` in ``folder``: wall-clock seconds of the run (not reproducible)."""
    path = Path(folder) / TIMING_FILE
    path.write_text(json.dumps(_plain(timing), indent=2) + "\n")
    return path


def _plain(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, np.integer):
        return int(x)
    return x
