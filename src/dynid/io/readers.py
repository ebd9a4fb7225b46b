"""Readers of tabular logs: CSV (and TSV), NPZ, Parquet.

A log is read through an explicit column mapping: the caller names the columns (CSV,
Parquet) or keys (NPZ) it wants, and gets a float array ``(n_samples, n_columns)``.
Missing files, missing columns and non-numeric cells are :class:`~dynid.errors.InputError`
with a one-line message naming them, the file's path, the nearest names the file has
(:func:`missing_names`) and what the file has.

For NPZ files a single name may refer to a 2-D array (``"positions"`` of shape
``(n, 7)``); several names refer to 1-D arrays stacked as columns; ``"key[3]"`` picks
column 3 of a 2-D array.
"""

from __future__ import annotations

import csv
import difflib
import hashlib
import re
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError, MissingExtraError, existing_file

__all__ = ["RowStream", "TableReader", "file_sha256", "missing_names", "nearest_names"]

_INDEXED = re.compile(r"^(?P<key>.+)\[(?P<col>\d+)\]$")
_SEPARATORS = {",": "comma", ";": "semicolon", "\t": "tab", "|": "vertical bar"}
_HEAD_BYTES = 1 << 16


def nearest_names(name: str, available: Sequence[str], n: int = 2) -> list[str]:
    """The names of ``available`` closest to ``name`` (case-insensitive, :func:`difflib.get_close_matches`
    at a similarity ratio of 0.5, twice the characters in common over the total: ``'torque2'``
    finds ``'tau2'`` (0.55), ``'tau1'`` does not find ``'t'`` (0.4)), best first, at most ``n``."""
    lower: dict[str, str] = {}
    for a in available:
        lower.setdefault(str(a).lower(), str(a))
    return [lower[m] for m in difflib.get_close_matches(str(name).lower(), list(lower), n=n, cutoff=0.5)]


def missing_names(missing: Sequence[str], available: Sequence[str]) -> str:
    """``"nearest to 'torque2': 'tau2', 'q2'"`` for each missing name (``"no similar name"``
    when none comes close): the part of a missing-column message that says what was meant."""
    hints = []
    for m in missing:
        near = nearest_names(m, available)
        hints.append(f"nearest to {m!r}: {', '.join(repr(x) for x in near)}" if near else f"no name like {m!r}")
    return "; ".join(hints)


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
        ``.csv``/``.tsv``/``.txt``, ``.npz`` or ``.parquet``.
    header : bool
        CSV only: True (default), the first row names the columns; False, the file has no header row
        and its columns are named by index, ``"0"``, ``"1"``, ... (0 is the first column).
    """

    def __init__(self, path: str | Path, header: bool = True) -> None:
        self.path = existing_file(path, "data file")
        self.header = header
        suffix = self.path.suffix.lower()
        if suffix in (".csv", ".tsv", ".txt"):
            self.kind = "csv"
        elif suffix == ".npz":
            self.kind = "npz"
        elif suffix == ".parquet":
            self.kind = "parquet"
        else:
            raise InputError(f"{self.path}: unknown data file type {suffix!r} (use .csv, .npz or .parquet)")
        if not header and self.kind != "csv":
            raise InputError(f"{self.path}: header = false is for CSV files; a {self.kind} file names its columns")
        self._frame = None
        self._plain: tuple[dict[str, int], FloatArray] | bool | None = None
        self._header: list[str] = []
        self._npz: dict[str, np.ndarray] | None = None
        self._sha256: str | None = None

    # ------------------------------------------------------------------ loading
    def _head(self) -> bytes:
        """The first bytes of the file (refusing an unreadable or empty file)."""
        try:
            with open(self.path, "rb") as fh:
                head = fh.read(_HEAD_BYTES)
        except OSError as exc:
            raise InputError(f"cannot read data file {self.path}: {exc.strerror or exc}") from None
        if not head:
            raise InputError(f"data file {self.path} is empty")
        return head

    @property
    def _sep(self) -> str:
        return "\t" if self.path.suffix.lower() == ".tsv" else ","

    def _check_csv_header(self) -> None:
        """Refuse binary or non-UTF-8 files and headers that name a column twice (pandas would
        silently rename the second ``q1`` to ``q1.1``); keep the header for the messages."""
        head = self._head()
        if b"\0" in head:
            raise InputError(f"data file {self.path} is binary, not a CSV text file")
        line = head.split(b"\n", 1)[0].rstrip(b"\r")
        try:
            text = line.decode("utf-8")
        except UnicodeDecodeError as exc:
            if exc.start < len(line) - 3 or b"\n" in head:  # not a character cut at the end of the chunk
                raise InputError(f"data file {self.path} is not UTF-8 text (byte 0x{line[exc.start]:02x} at offset "
                                 f"{exc.start} of the header)") from None
            text = line[: exc.start].decode("utf-8")
        if not self.header:
            return
        self._header = next(csv.reader([text.removeprefix("\ufeff")], delimiter=self._sep), [])
        seen: dict[str, list[int]] = {}
        for i, name in enumerate(self._header):
            seen.setdefault(name, []).append(i + 1)
        twice = {n: pos for n, pos in seen.items() if len(pos) > 1}
        if twice:
            detail = "; ".join(f"{n!r} is columns {', '.join(map(str, pos))}" for n, pos in twice.items())
            raise InputError(f"{self.path}: the header names a column more than once ({detail}); column names must be unique")

    def _separator_hint(self) -> str:
        """When the header is one field holding another separator: say so."""
        if len(self._header) != 1:
            return ""
        field = self._header[0]
        other = next((c for c in _SEPARATORS if c != self._sep and c in field), None)
        if other is None:
            return ""
        wanted = "tab-separated (.tsv)" if self._sep == "\t" else "comma-separated CSV (.tsv for tab-separated)"
        return (f"its header is one field {field[:60]!r}: the file seems to be separated by {_SEPARATORS[other]}s "
                f"({other!r}), and dynid reads {wanted}")

    def _load_frame(self):
        if self._frame is None:
            import pandas as pd

            if self.kind == "csv":
                self._check_csv_header()
            else:
                self._head()
            try:
                if self.kind == "csv" and not self.header:
                    self._frame = pd.read_csv(self.path, sep=self._sep, header=None)
                    self._frame.columns = [str(c) for c in range(self._frame.shape[1])]
                elif self.kind == "csv":
                    self._frame = pd.read_csv(self.path, sep=self._sep)
                else:
                    try:
                        self._frame = pd.read_parquet(self.path)
                    except ImportError as exc:
                        raise MissingExtraError(f"reading Parquet needs pyarrow: pip install 'dynid[parquet]' ({exc})") from None
            except UnicodeDecodeError as exc:
                raise InputError(f"data file {self.path} is not UTF-8 text ({exc})") from None
            except pd.errors.EmptyDataError:
                raise InputError(f"data file {self.path} has no header row (it is blank)") from None
            except (ValueError, OSError, pd.errors.ParserError) as exc:
                raise InputError(f"{self.path}: cannot read ({str(exc).strip().splitlines()[0]})") from None
            if self._frame.shape[0] == 0:
                raise InputError(f"{self.path}: no data rows (the file has a header only)")
        return self._frame

    def _plain_csv(self) -> tuple[dict[str, int], FloatArray] | None:
        """A CSV file of numbers only, read by NumPy (column index of every name, values), or None
        where it is anything else (quoted or missing fields, NA markers, unnamed columns...): pandas
        then reads it (:meth:`_load_frame`) with its rules and messages. The numbers are the same
        (both parse decimal text to the nearest double); what differs is the memory: pandas and the
        pyarrow it loads weigh ~77 MB (issue 20, item 10), more than the rest of a TX40 run."""
        if self._plain is None:
            self._plain = False
            if self._frame is None:
                self._check_csv_header()
                names = self._header if self.header else None
                if names is None or (names and all(n.strip() for n in names)):
                    try:
                        with warnings.catch_warnings():  # a file without data rows: pandas says so
                            warnings.simplefilter("ignore")
                            values = np.loadtxt(self.path, dtype=float, delimiter=self._sep, comments=None, ndmin=2,
                                                skiprows=1 if self.header else 0, encoding="utf-8")
                    except (ValueError, UnicodeDecodeError):
                        values = None
                    if values is not None and values.shape[0] > 0 and (names is None or values.shape[1] == len(names)):
                        names = names if names is not None else [str(i) for i in range(values.shape[1])]
                        self._plain = ({n: i for i, n in enumerate(names)}, values)
        return self._plain or None

    def _load_npz(self) -> dict[str, np.ndarray]:
        if self._npz is None:
            if not self._head().startswith((b"PK\x03\x04", b"PK\x05\x06")):
                raise InputError(f"{self.path}: not an NPZ file (not a zip archive of arrays)")
            try:
                with np.load(self.path, allow_pickle=False) as z:
                    self._npz = {k: z[k] for k in z.files}
            except (ValueError, OSError, EOFError, KeyError, zipfile.BadZipFile) as exc:
                raise InputError(f"{self.path}: cannot read NPZ ({str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__})") from None
            if not self._npz:
                raise InputError(f"{self.path}: the NPZ archive holds no arrays")
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
        plain = self._plain_csv() if self.kind == "csv" else None
        if plain is not None and all(n in plain[0] for n in names):
            return plain[1][:, [plain[0][n] for n in names]]
        frame = self._load_frame()
        missing = [n for n in names if n not in frame.columns]
        if missing:
            if not self.header:
                raise InputError(f"{self.path}: missing columns {missing}; the file has {frame.shape[1]} columns "
                                 f"(0 to {frame.shape[1] - 1}; header = false names columns by index)")
            raise InputError(
                f"{self.path}: missing columns {missing} ({missing_names(missing, self.available)}); "
                + (self._separator_hint() or f"the file has {self.available[:20]}")
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
                raise InputError(f"{self.path}: missing key {n!r} ({missing_names([key], sorted(z))}); the file has "
                                 f"{sorted(z)}")
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


# ---------------------------------------------------------------------------------------------- streaming
class RowStream:
    """Rows of named columns of one log file read in order, block by block, never the whole file
    (the streamed identification, :mod:`dynid.pipeline.streaming`).

    * NPZ: each key's ``.npy`` member is opened inside the zip archive (stored or deflated) and read
      row by row after its header (``numpy.lib.format``); a stored member is read in place, a
      deflated one is decompressed incrementally. Fortran-ordered 2-D arrays are not streamable.
    * CSV: pandas ``read_csv(..., chunksize=)``, the same parser as the in-memory reader.
    * Parquet: pyarrow ``ParquetFile.iter_batches``.

    :meth:`unstreamable` says why a file cannot be streamed (None when it can): the caller then keeps
    the in-memory path, whose reader gives the usual error for a missing key or column.
    """

    def __init__(self, reader: TableReader, names: Sequence[str]) -> None:
        self.reader, self.path, self.kind = reader, reader.path, reader.kind
        self.names = list(names)
        self._n: int | None = None
        self._npz_keys: dict[str, tuple[zipfile.ZipInfo, tuple[int, ...], np.dtype, bool]] | None = None

    # .................................................................. inspection
    def _npz_headers(self) -> dict[str, tuple[zipfile.ZipInfo, tuple[int, ...], np.dtype, bool]]:
        if self._npz_keys is None:
            out = {}
            with zipfile.ZipFile(self.path) as zf:
                for info in zf.infolist():
                    if not info.filename.endswith(".npy"):
                        continue
                    with zf.open(info) as fh:
                        shape, fortran, dtype = _npy_header(fh)
                    out[info.filename[:-4]] = (info, shape, dtype, fortran)
            self._npz_keys = out
        return self._npz_keys

    def _npz_plan(self) -> list[tuple[str, int | None]]:
        keys = self._npz_headers()
        plan = []
        for n in self.names:
            m = _INDEXED.match(n)
            key, col = (m.group("key"), int(m.group("col"))) if m and n not in keys else (n, None)
            plan.append((key, col))
        return plan

    def unstreamable(self) -> str | None:
        """Why these columns of this file cannot be streamed (None: they can)."""
        try:
            if self.kind == "npz":
                if not self.reader._head().startswith((b"PK\x03\x04", b"PK\x05\x06")):
                    return "not a zip archive"
                keys = self._npz_headers()
                lengths = set()
                for key, col in self._npz_plan():
                    if key not in keys:
                        return f"no key {key!r}"
                    _, shape, dtype, fortran = keys[key]
                    if dtype.hasobject or not np.issubdtype(dtype, np.number) or len(shape) not in (1, 2):
                        return f"key {key!r} is not a 1-D or 2-D numeric array"
                    if fortran and len(shape) == 2 and shape[1] > 1:
                        return f"key {key!r} is stored in Fortran order (columns contiguous)"
                    if col is not None and (len(shape) != 2 or col >= shape[1]):
                        return f"no column {col} in key {key!r}"
                    lengths.add(shape[0])
                if len(lengths) != 1:
                    return "keys of different lengths"
                return None
            if self.kind == "csv":
                self.reader._check_csv_header()
                if self.reader.header:
                    missing = [n for n in self.names if n not in self.reader._header]
                    return f"missing columns {missing}" if missing else None
                width = len(next(csv.reader([self.reader._head().split(b"\n", 1)[0].decode("utf-8", "replace")],
                                            delimiter=self.reader._sep), []))
                bad = [n for n in self.names if not (n.isdigit() and int(n) < width)]
                return f"missing columns {bad}" if bad else None
            import pyarrow.parquet as pq  # noqa: F401  (parquet)

            schema = self._parquet().schema_arrow
            missing = [n for n in self.names if n not in schema.names]
            if missing:
                return f"missing columns {missing}"
            import pyarrow.types as pt

            odd = [n for n in self.names if not (pt.is_integer(schema.field(n).type) or pt.is_floating(schema.field(n).type))]
            return f"non-numeric columns {odd}" if odd else None
        except ImportError:
            return "pyarrow is not installed"
        except (InputError, OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            return f"unreadable ({exc})"

    def _parquet(self):
        import pyarrow.parquet as pq

        return pq.ParquetFile(self.path)

    def n_rows(self) -> int:
        """Rows of the file (NPZ, Parquet: from the headers; CSV: one pass over its first named column)."""
        if self._n is None:
            if self.kind == "npz":
                key = self._npz_plan()[0][0]
                self._n = int(self._npz_headers()[key][1][0])
            elif self.kind == "parquet":
                self._n = int(self._parquet().metadata.num_rows)
            else:
                self._n = sum(b.shape[0] for b in RowStream(self.reader, self.names[:1]).blocks(0, None, 1 << 18))
        return self._n

    # .................................................................. reading
    def blocks(self, start: int, stop: int | None, block: int):
        """Float arrays ``(k, len(names))`` of rows ``[start, stop)`` in order, ``k = block`` but for the
        last (``stop`` None: to the end of the file). Non-numeric CSV cells are an :class:`InputError`
        naming the row, as in :meth:`TableReader.columns`."""
        if self.kind == "npz":
            yield from self._npz_blocks(start, stop, block)
        elif self.kind == "csv":
            yield from _reblock(self._csv_blocks(start, stop, block), block)
        else:
            yield from _reblock(self._parquet_blocks(start, stop, block), block)

    def _npz_blocks(self, start: int, stop: int | None, block: int):
        keys = self._npz_headers()
        plan = self._npz_plan()
        n = self.n_rows()
        stop = n if stop is None else min(stop, n)
        wanted = list(dict.fromkeys(k for k, _ in plan))
        with zipfile.ZipFile(self.path) as zf:
            handles = {}
            try:
                for key in wanted:
                    info, shape, dtype, _ = keys[key]
                    fh = zf.open(info)
                    handles[key] = fh
                    _npy_header(fh)
                    row_bytes = dtype.itemsize * (shape[1] if len(shape) == 2 else 1)
                    fh.seek(start * row_bytes, 1)
                for a in range(start, stop, block):
                    k = min(block, stop - a)
                    cols = []
                    parts = {}
                    for key in wanted:
                        _, shape, dtype, _ = keys[key]
                        width = shape[1] if len(shape) == 2 else 1
                        raw = _read_exact(handles[key], k * width * dtype.itemsize, self.path)
                        parts[key] = np.frombuffer(raw, dtype=dtype).reshape(k, width).astype(float)
                    for key, col in plan:
                        cols.append(parts[key] if col is None else parts[key][:, col : col + 1])
                    yield np.hstack(cols)
            finally:
                for fh in handles.values():
                    fh.close()

    def _csv_blocks(self, start: int, stop: int | None, block: int):
        import pandas as pd

        r = self.reader
        if r.header:
            it = pd.read_csv(r.path, sep=r._sep, usecols=self.names, chunksize=block)
        else:
            it = pd.read_csv(r.path, sep=r._sep, header=None, usecols=[int(n) for n in self.names], chunksize=block)
        seen = 0
        try:
            for frame in it:
                if not r.header:
                    frame.columns = [str(c) for c in frame.columns]
                a, b = seen, seen + frame.shape[0]
                seen = b
                lo, hi = max(a, start), b if stop is None else min(b, stop)
                if hi > lo:
                    sub = frame.iloc[lo - a : hi - a][self.names]
                    values = sub.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
                    bad = np.isnan(values) & ~sub.isna().to_numpy()
                    if bad.any():
                        i, c = np.argwhere(bad)[0]
                        raise InputError(f"{r.path.name}: non-numeric value {sub.iat[i, c]!r} in column "
                                         f"{self.names[c]!r} (row {lo + i + 1})")
                    yield values
                if stop is not None and b >= stop:
                    return
        except (ValueError, pd.errors.ParserError) as exc:
            raise InputError(f"{r.path}: cannot read ({str(exc).strip().splitlines()[0]})") from None

    def _parquet_blocks(self, start: int, stop: int | None, block: int):
        pf = self._parquet()
        seen, groups = 0, []  # the row groups before ``start`` are skipped unread (their sizes are in the footer)
        for g in range(pf.metadata.num_row_groups):
            n = pf.metadata.row_group(g).num_rows
            if groups or seen + n > start:
                groups.append(g)
            else:
                seen += n
        if not groups:
            return
        for batch in pf.iter_batches(batch_size=block, columns=self.names, row_groups=groups):
            a, b = seen, seen + batch.num_rows
            seen = b
            lo, hi = max(a, start), b if stop is None else min(b, stop)
            if hi > lo:
                cols = [np.asarray(batch.column(n).to_numpy(zero_copy_only=False), dtype=float)[lo - a : hi - a]
                        for n in self.names]
                yield np.column_stack(cols)
            if stop is not None and b >= stop:
                return


def _npy_header(fh) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran_order, dtype) of the ``.npy`` stream ``fh``, left at the first data byte."""
    from numpy.lib import format as npf

    version = npf.read_magic(fh)
    if version == (1, 0):
        return npf.read_array_header_1_0(fh)
    if version == (2, 0):
        return npf.read_array_header_2_0(fh)
    return npf._read_array_header(fh, version)


def _read_exact(fh, n: int, path: Path) -> bytes:
    data = fh.read(n)
    if len(data) != n:
        raise InputError(f"{path.name}: the archive ends before the array does (truncated file)")
    return data


def _reblock(parts, block: int):
    """Re-cut a stream of row arrays into arrays of exactly ``block`` rows (the last shorter)."""
    pending: list[np.ndarray] = []
    have = 0
    for p in parts:
        pending.append(p)
        have += p.shape[0]
        while have >= block:
            cat = np.concatenate(pending) if len(pending) > 1 else pending[0]
            yield cat[:block]
            rest = cat[block:]
            pending, have = ([rest] if rest.shape[0] else []), rest.shape[0]
    if have:
        yield np.concatenate(pending) if len(pending) > 1 else pending[0]
