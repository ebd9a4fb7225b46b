"""Readers of tabular logs: CSV (and TSV), NPZ, Parquet.

A log is read through an explicit column mapping: the caller names the columns (CSV,
Parquet) or keys (NPZ) it wants, and gets a float array ``(n_samples, n_columns)``.
Missing files, missing columns and non-numeric cells are :class:`~dynid.errors.InputError`
with a one-line message naming them (and listing what the file has).

For NPZ files a single name may refer to a 2-D array (``"positions"`` of shape
``(n, 7)``); several names refer to 1-D arrays stacked as columns; ``"key[3]"`` picks
column 3 of a 2-D array.
"""

from __future__ import annotations

import hashlib
import re
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError, MissingExtraError

__all__ = ["TableReader", "file_sha256"]

_INDEXED = re.compile(r"^(?P<key>.+)\[(?P<col>\d+)\]$")


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file (for provenance)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class TableReader:
    """Lazy reader of one log file; columns are loaded on first use and cached.

    Parameters
    ----------
    path : path
        ``.csv``/``.tsv``/``.txt`` (header row required), ``.npz`` or ``.parquet``.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"data file not found: {self.path}")
        suffix = self.path.suffix.lower()
        if suffix in (".csv", ".tsv", ".txt"):
            self.kind = "csv"
        elif suffix == ".npz":
            self.kind = "npz"
        elif suffix == ".parquet":
            self.kind = "parquet"
        else:
            raise InputError(f"{self.path}: unknown data file type {suffix!r} (use .csv, .npz or .parquet)")
        self._frame = None
        self._npz: dict[str, np.ndarray] | None = None
        self._sha256: str | None = None

    # ------------------------------------------------------------------ loading
    def _load_frame(self):
        if self._frame is None:
            import pandas as pd

            try:
                if self.kind == "csv":
                    sep = "\t" if self.path.suffix.lower() == ".tsv" else ","
                    self._frame = pd.read_csv(self.path, sep=sep)
                else:
                    try:
                        self._frame = pd.read_parquet(self.path)
                    except ImportError as exc:
                        raise MissingExtraError(f"reading Parquet needs pyarrow: pip install pyarrow ({exc})") from None
            except (ValueError, OSError, pd.errors.ParserError) as exc:
                raise InputError(f"{self.path}: cannot read ({str(exc).splitlines()[0]})") from None
            if self._frame.shape[0] == 0:
                raise InputError(f"{self.path}: no data rows")
        return self._frame

    def _load_npz(self) -> dict[str, np.ndarray]:
        if self._npz is None:
            if not zipfile.is_zipfile(self.path):
                raise InputError(f"{self.path}: not an NPZ file (not a zip archive of arrays)")
            try:
                with np.load(self.path, allow_pickle=False) as z:
                    self._npz = {k: z[k] for k in z.files}
            except (ValueError, OSError) as exc:
                raise InputError(f"{self.path}: cannot read NPZ ({str(exc).splitlines()[0]})") from None
        return self._npz

    @property
    def available(self) -> list[str]:
        """Column names (CSV/Parquet) or keys (NPZ) in the file."""
        if self.kind == "npz":
            return sorted(self._load_npz())
        return [str(c) for c in self._load_frame().columns]

    # ------------------------------------------------------------------ access
    def columns(self, names: Sequence[str] | str) -> FloatArray:
        """Float array (n_samples, k) of the named columns, in the given order."""
        names = [names] if isinstance(names, str) else list(names)
        if not names:
            raise InputError(f"{self.path}: empty column list")
        if self.kind == "npz":
            return self._npz_columns(names)
        frame = self._load_frame()
        missing = [n for n in names if n not in frame.columns]
        if missing:
            raise InputError(
                f"{self.path.name}: missing columns {missing}; the file has {self.available[:20]}"
            )
        import pandas as pd

        sub = frame[names]
        values = sub.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
        bad = np.isnan(values) & ~sub.isna().to_numpy()
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise InputError(f"{self.path.name}: non-numeric value {sub.iat[r, c]!r} in column {names[c]!r} (row {r + 1})")
        return values

    def _npz_columns(self, names: list[str]) -> FloatArray:
        z = self._load_npz()
        cols: list[np.ndarray] = []
        for n in names:
            m = _INDEXED.match(n)
            key, col = (m.group("key"), int(m.group("col"))) if m and n not in z else (n, None)
            if key not in z:
                raise InputError(f"{self.path.name}: missing key {n!r}; the file has {sorted(z)}")
            arr = np.asarray(z[key])
            if not np.issubdtype(arr.dtype, np.number):
                raise InputError(f"{self.path.name}: key {key!r} is not numeric (dtype {arr.dtype})")
            arr = arr.astype(float)
            if col is not None:
                if arr.ndim != 2 or col >= arr.shape[1]:
                    raise InputError(f"{self.path.name}: {n!r} selects column {col} of an array of shape {arr.shape}")
                cols.append(arr[:, col : col + 1])
            elif arr.ndim == 1:
                cols.append(arr[:, None])
            elif arr.ndim == 2:
                cols.append(arr)
            else:
                raise InputError(f"{self.path.name}: key {key!r} has {arr.ndim} dimensions; expected 1 or 2")
        lengths = {c.shape[0] for c in cols}
        if len(lengths) > 1:
            raise InputError(f"{self.path.name}: mismatched lengths among {names}: {sorted(lengths)}")
        return np.hstack(cols)

    def sha256(self) -> str:
        """SHA-256 of the file (computed once per reader)."""
        if self._sha256 is None:
            self._sha256 = file_sha256(self.path)
        return self._sha256
