"""Streamed identification: a long log read, processed and compressed chunk by chunk.

The in-memory path (:func:`dynid.pipeline.data.read_log`, :func:`~dynid.pipeline.data.preprocess`)
holds the whole window of the log, and its filtered positions, velocities, accelerations and
efforts: about 0.7 KB per sample of a 6-joint arm. The streamed path computes the same numbers
without ever holding an ``(N, n)`` array of the log:

1. the time column of the window is read whole (1-D, 8 bytes a sample: the sampling rate is the
   median of its steps, as in memory, and a ``time_window`` is resolved on it);
2. the other columns are read in blocks (:class:`dynid.io.readers.RowStream`), converted to SI and
   mapped to actuator space block by block;
3. for each block of processed rows ``[a, b)`` the raw rows ``[a - L - 2, b + L + 2)`` are low-passed
   by the same zero-phase Butterworth filter (``sosfiltfilt``, the same odd padding of the same
   length at the true ends of the window), differentiated by the same central differences
   (``np.gradient``), trimmed and decimated at the same global indices; the rows go to
   :class:`~dynid.estimation.problem.ProblemBuilder` exactly as :func:`_chunks` gives them in memory;
4. the validation log is scored the same way, its error sums accumulated per channel
   (:class:`ErrorSums`); the motion overlap (:func:`dynid.estimation.validation.motion_overlap`)
   takes the same evenly spaced rows and the training states' standard deviation merged chunk by
   chunk (Chan, Golub & LeVeque 1979, the pairwise update of mean and sum of squares).

Overlap bound. A chunk filtered on its own differs from the whole-signal filtering only through
the filter state at the chunk's cut ends: the forward pass starts from the odd-extension state of
the chunk instead of the true past, the backward pass from the chunk's end. Both mismatches are
free responses of the recursion, sums of the pole modes ``p_i^j`` (a Butterworth filter's poles are
simple), so ``j`` samples from a cut they are below ``C rho^j`` with ``rho = max |p_i|`` and ``C``
the state mismatch (of the order of the signal's range, times the state gain of the sections).
:func:`overlap_for` takes the smallest ``L`` with ``rho^L <= 1e-19``: with ``C`` up to 1e3 the
mismatch is below 1e-16 of the signal's range, i.e. at rounding level (about 900 samples for order
4 at 20 Hz and 1 kHz). The central differences need two more samples (velocity, then
acceleration). The tests check streamed against in-memory to 1e-9 relative.

When the path runs (:func:`plan`): ``[identification] streaming = "auto"`` (default) streams a
training window of at least :data:`AUTO_ROWS` rows when everything the run needs can be computed
chunk by chunk; ``"on"`` streams or refuses with the reason (:class:`~dynid.errors.ConfigError`);
``"off"`` keeps the in-memory path. Left in memory (the same method, only the memory differs):
ROS bags, closed-loop mechanisms, ``[processing.periodic]``,
parallel decimation, ``reversal_guard`` and ``coulomb_smoothing = "auto"`` (whole-log quantities),
resampling of irregular timestamps, methods that are not one compressed least-squares problem
(``ml``, ``iv``, ``didim``, ``cloe``, ``friction_model = "stribeck"``, ``hierarchical``) and ``[learning]``.
``result.json`` (``data_path``) and ``summary.txt`` say which path ran.

Plots (``[output] plots = true``) stream too: the figures' series are thinned chunk by chunk to the
panels' pixel columns and the processing figure's spectra are Welch-averaged
(:mod:`dynid.pipeline.stream_plots`), so a plotted run holds no more than an unplotted one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import EFFORT_UNITS, POSITION_UNITS, TIME_UNITS, Config, DataConfig, ProcessingConfig
from dynid.dataset import Dataset
from dynid.errors import ConfigError, InputError
from dynid.io.readers import RowStream, TableReader

__all__ = ["AUTO_ROWS", "LogStream", "ErrorSums", "StateSample", "overlap_for", "plan", "open_stream", "motion_overlap_streamed"]

AUTO_ROWS = 200_000
"""``streaming = "auto"``: training windows at least this long are streamed (shorter ones are held
in memory, where the outcome keeps its datasets for plots and studies)."""

FILTER_ROWS = 65536
"""Rows filtered at once (at least 4 overlaps): the re-filtered share ``2 L / FILTER_ROWS`` stays small."""
READ_ROWS = 65536
"""Rows read from the file at once."""

_RHO_TARGET = 1e-19


def overlap_for(sos: FloatArray) -> int:
    """Samples of overlap after which a chunk's zero-phase filtering equals the whole signal's to
    rounding: the smallest ``L`` with ``rho^L <= 1e-19``, ``rho`` the largest pole modulus of the
    second-order sections ``sos`` (see the module docstring)."""
    rho = max(float(np.max(np.abs(np.roots(s[3:])))) for s in np.atleast_2d(sos))
    if not rho < 1.0:
        raise ConfigError(f"processing.lowpass: the filter is not stable (pole modulus {rho:.6g})")
    return int(math.ceil(math.log(_RHO_TARGET) / math.log(rho)))


def _why_not(cfg: Config, system) -> str | None:
    """Why this configuration needs the in-memory path (None: it can be streamed)."""
    icfg, pcfg = cfg.identification, cfg.processing
    checks = [
        (system.kind != "serial", "closed-loop mechanisms are processed in memory"),
        (cfg.data.bag or cfg.validation.bag, "ROS bags are read in memory"),
        (pcfg.periodic is not None, "[processing.periodic] averages whole periods"),
        (pcfg.derivatives == "kalman", "the Kalman smoother's noise is estimated from the whole log"),
        (pcfg.decimate > 1 and pcfg.decimate_method == "parallel", "parallel decimation"),
        (pcfg.reversal_guard is not None, "processing.reversal_guard needs the whole log's reversals"),
        (isinstance(pcfg.resample, float), "processing.resample to a given rate"),
        (icfg.method in ("ml", "iv", "didim", "cloe", "ekf", "ukf"), f"method {icfg.method!r} is not one compressed least-squares problem"),
        (icfg.friction_model == "stribeck", "friction_model = 'stribeck' (nonlinear fit on sampled rows)"),
        (icfg.hierarchical, "hierarchical identification"),
        (icfg.coulomb_smoothing != "none", "coulomb_smoothing reads the whole log's velocity noise"),
        (cfg.learning is not None, "[learning] trains on the whole residual"),
    ]
    return next((why for bad, why in checks if bad), None)


@dataclasses.dataclass
class LogStream:
    """One window of a log ([data] or [validation]), read block by block (see module docstring)."""

    spec: DataConfig
    label: str
    names: tuple[str, ...]
    n_channels: int
    groups: list[tuple[RowStream, list[tuple[str, slice]]]]  # per file: its stream, (signal, columns)
    scales: dict[str, Any]
    start: int  # first file row of the window
    t: FloatArray  # window times [s]
    meta: dict[str, Any]
    effort_columns: tuple[str, ...]
    tau_file: Path
    # a part of the window on a cluster worker (dynid.pipeline.cluster_qr): ``t`` holds the window rows
    # [t0, t0 + len(t)), the window's length and sampling rate are the driver's
    t0: int = 0
    n_rows: int | None = None
    fs_hz: float | None = None

    @property
    def n(self) -> int:
        return int(self.t.shape[0]) if self.n_rows is None else self.n_rows

    @property
    def fs(self) -> float:
        return float(1.0 / np.median(np.diff(self.t))) if self.fs_hz is None else self.fs_hz

    def as_dataset_stub(self) -> SimpleNamespace:
        """What :func:`~dynid.pipeline.data.check_held_out` reads (times and provenance)."""
        return SimpleNamespace(t=self.t, meta=self.meta)

    # .................................................................. raw blocks
    def raw_blocks(self, system, block: int, constant: dict | None = None, first: int = 0,
                   last: int | None = None) -> Iterator[tuple[int, dict[str, FloatArray], list[str]]]:
        """(first window row, actuator-space signals ``t q tau [dq ddq]``, notes) block by block, of the
        window rows ``[first, last)`` (default: all). ``constant``: filled with the per-channel 'every
        value equal' flags of the efforts."""
        from dynid.pipeline.data import to_actuator_space

        last = self.n if last is None else last
        while (last - first) % block == 1 and block < last - first:  # no one-row tail: a Dataset needs two samples
            block += 1
        iters = [g.blocks(self.start + first, self.start + last, block) for g, _ in self.groups]
        a = first
        while a < last:
            arrays: dict[str, FloatArray] = {}
            k = None
            for it, (_, cols) in zip(iters, self.groups):
                try:
                    x = next(it)
                except StopIteration:
                    raise InputError(f"{self.label}: a column of the log ends at row {self.start + a}") from None
                k = x.shape[0] if k is None else k
                if x.shape[0] != k:
                    raise InputError(f"{self.label}: mismatched lengths among the log's files")
                for what, sl in cols:
                    arrays[what] = x[:, sl] * self.scales[what]
            b = a + k
            arrays["t"] = self.t[a - self.t0:b - self.t0]
            for what, label in (("q", "positions"), ("tau", "efforts"), ("dq", "velocities"), ("ddq", "accelerations")):
                if what in arrays:
                    bad = ~np.isfinite(arrays[what])
                    if bad.any():
                        first = tuple(np.argwhere(bad)[0])
                        kind = "NaN" if np.isnan(arrays[what][first]) else "inf"
                        raise InputError(f"{self.label}: {label} contains {kind} values (first at sample {a + int(first[0])})")
            if constant is not None:
                tau = arrays["tau"]
                if "first" not in constant:
                    constant.update(first=tau[0].copy(), same=np.ones(tau.shape[1], bool), zero=True)
                constant["same"] &= np.all(tau == constant["first"], axis=0)
                constant["zero"] = constant["zero"] and not np.any(tau)
            ds = Dataset(t=arrays["t"], q=arrays["q"], tau=arrays["tau"], dq=arrays.get("dq"), ddq=arrays.get("ddq"),
                         names=self.names, meta={k2: self.meta[k2] for k2 in ("position_side", "effort_kind", "effort_side", "drive_gains")
                               if k2 in self.meta})
            out, notes = to_actuator_space(ds, system, self.label)
            yield a, {"t": out.t, "q": out.q, "tau": out.tau, **({"dq": out.dq} if out.dq is not None else {}),
                      **({"ddq": out.ddq} if out.ddq is not None else {})}, notes
            a = b

    def check_constant(self, constant: dict) -> None:
        """:func:`dynid.pipeline.data._constant_efforts` on the flags of :meth:`raw_blocks`."""
        same = np.flatnonzero(constant["same"])
        if same.size == 0:
            return
        path, n, cols = self.tau_file, self.n, self.effort_columns
        if same.size == constant["same"].size and constant["zero"]:
            raise InputError(f"{self.label}.effort: every column of {path.name} ({', '.join(cols)}) is 0 in all {n} samples: "
                             "the log holds no efforts")
        detail = ", ".join(f"{cols[j]!r} is {constant['first'][j]:g}" for j in same)
        raise InputError(f"{self.label}.effort: {path.name}: {detail} in all {n} samples; a constant channel carries no "
                         "information (a disconnected sensor?)")

    # .................................................................. processing
    def processing(self, pcfg: ProcessingConfig, decimate: int | None = None) -> dict[str, Any]:
        """The processing of :func:`~dynid.pipeline.data.preprocess` for this window: filter, overlap,
        trim, decimation factor, processed row count and the provenance steps (the same records)."""
        from dynid.signals import butter_sos, padlen_for

        fs, n = self.fs, self.n
        lp = pcfg.lowpass
        k = pcfg.decimate if decimate is None else decimate
        steps: list[dict[str, Any]] = []
        sos = None
        if lp is not None:
            sos = butter_sos(lp.order, lp.cutoff_hz, fs)
            steps.append({"step": "lowpass", "type": "zero-phase Butterworth (sosfiltfilt)", "cutoff_hz": lp.cutoff_hz,
                          "order": lp.order, "fs_hz": fs, "efforts_filtered": lp.filter_effort})
        if pcfg.derivatives == "central":
            steps.append({"step": "derivatives", "method": "central differences of filtered positions"})
        else:
            steps.append({"step": "derivatives", "method": "measured velocity" + (
                " and acceleration" if self.spec.acceleration is not None else ", central-difference acceleration")})
        n_trim = pcfg.trim_samples
        if n_trim is None:
            n_trim = padlen_for(lp.order, lp.cutoff_hz, fs) if lp is not None else 2
        steps.append({"step": "trim", "samples_each_end": int(n_trim)})
        if k > 1:
            steps.append({"step": "decimate", "method": "samples: one sample in factor kept after the low-pass", "factor": k,
                          "fs_hz": fs / k})
        overlap = (overlap_for(sos) if sos is not None else 0) + 2
        rows = range(n_trim, n - n_trim, k)
        return {"sos": sos, "overlap": overlap, "n_trim": int(n_trim), "k": k, "rows": rows, "steps": steps,
                "padlen": None if sos is None else min(3 * (2 * sos.shape[0] + 1), n - 1)}

    def filter_rows(self, pcfg: ProcessingConfig, out_rows: int, decimate: int | None = None) -> int:
        """Processed rows filtered at once by :meth:`processed` (a whole multiple of ``out_rows``, long
        against the overlap: the re-filtered share ``2 L / block`` stays small whatever chunk_size is)."""
        p = self.processing(pcfg, decimate)
        return out_rows * max(1, -(-max(4 * p["overlap"], FILTER_ROWS) // (out_rows * p["k"])))

    def processed(self, system, pcfg: ProcessingConfig, out_rows: int, *, decimate: int | None = None,
                  read_rows: int | None = None, constant: dict | None = None,
                  notes: list | None = None, raw_tap=None,
                  span: tuple[int, int, int, int] | None = None) -> Iterator[tuple[int, dict[str, FloatArray]]]:
        """(first processed row, ``t q dq ddq tau``) of blocks of ``out_rows`` processed rows, equal
        to the rows of :func:`~dynid.pipeline.data.preprocess` of the whole window to rounding
        (module docstring). ``raw_tap(a, arrays)``: called on every raw actuator-space block of the
        window, in order (the processing figure, :class:`dynid.pipeline.stream_plots.ProcessingPlot`).
        ``span = (f_lo, f_hi, raw_lo, raw_hi)``: only the processed rows ``[f_lo, f_hi)``, filtered as one
        block, from the raw window rows ``[raw_lo, raw_hi)``, which must cover their overlap (a chunk on a
        cluster worker: :func:`dynid.pipeline.cluster_qr.chunk_spans` cuts at this path's filter blocks)."""
        from dynid.signals import central_difference

        p = self.processing(pcfg, decimate)
        sos, L, k, rows, padlen = p["sos"], p["overlap"], p["k"], p["rows"], p["padlen"]
        f_lo, f_hi, raw_lo, raw_hi = (0, len(rows), 0, self.n) if span is None else span
        lp = pcfg.lowpass
        raw = self.raw_blocks(system, read_rows or READ_ROWS, constant, raw_lo, raw_hi)
        if raw_tap is not None:
            raw = _tapped(raw, raw_tap)
        buf: dict[str, FloatArray] = {}
        buf_lo = buf_hi = raw_lo

        def window(lo: int, hi: int) -> dict[str, FloatArray]:
            nonlocal buf, buf_lo, buf_hi
            while buf_hi < hi:
                a, arrays, nt = next(raw)
                if notes is not None and not notes:
                    notes.extend(nt or ["-"])
                buf = arrays if not buf else {w: np.concatenate([buf[w], arrays[w]]) for w in buf}
                buf_hi = a + arrays["t"].shape[0]
            if lo > buf_lo:  # rows before lo are never needed again
                buf = {w: v[lo - buf_lo:] for w, v in buf.items()}
                buf_lo = lo
            return {w: v[lo - buf_lo: hi - buf_lo] for w, v in buf.items()}

        def filt(x: FloatArray) -> FloatArray:  # the call of dynid.signals.lowpass_sos, padlen of the whole window
            from scipy import signal

            return signal.sosfiltfilt(sos, x, axis=0, padtype="odd", padlen=padlen)

        n = self.n
        # filter blocks of whole multiples of out_rows (filter_rows), yielded out_rows at a time
        per = self.filter_rows(pcfg, out_rows, decimate) if span is None else max(1, f_hi - f_lo)
        for f0 in range(f_lo, f_hi, per):
            sel = rows[f0: min(f0 + per, f_hi)]
            a, b = sel[0], sel[-1] + 1
            lo, hi = max(0, a - L), min(n, b + L)
            if lo < raw_lo or hi > raw_hi:
                raise ValueError(f"processed rows [{f0}, {f0 + len(sel)}) need the raw rows [{lo}, {hi}), "
                                 f"outside the span's [{raw_lo}, {raw_hi})")
            w = window(lo, hi)
            t, q, tau = w["t"], w["q"], w["tau"]
            dq_m, ddq_m = w.get("dq"), w.get("ddq")
            if sos is not None:
                q = filt(q)
                dq_m = filt(dq_m) if dq_m is not None else None
                ddq_m = filt(ddq_m) if ddq_m is not None else None
                if lp.filter_effort:
                    tau = filt(tau)
            if pcfg.derivatives == "central":
                dq = central_difference(q, t)
                ddq = central_difference(dq, t)
            else:
                if dq_m is None:
                    raise ConfigError(f"processing.derivatives = 'measured' needs {self.label}.velocity columns")
                dq = dq_m
                ddq = ddq_m if ddq_m is not None else central_difference(dq_m, t)
            keep = slice(a - lo, b - lo, k)
            out = {"t": t[keep], "q": q[keep], "dq": dq[keep], "ddq": ddq[keep], "tau": tau[keep]}
            for j in range(0, out["t"].shape[0], out_rows):
                yield f0 + j, {w: v[j: j + out_rows] for w, v in out.items()}
        for _ in raw:  # the rows after the last kept one: the constant-effort flags cover the whole window
            pass


def _tapped(blocks, tap):
    for a, arrays, notes in blocks:
        tap(a, arrays)
        yield a, arrays, notes


def _scale(table, sig, n, label):
    from dynid.pipeline.data import _scale as scale

    return scale(table, sig, n, label)


def open_stream(spec: DataConfig, n_channels: int, names: tuple[str, ...], label: str,
                readers: dict, min_rows: int = 0) -> LogStream | str:
    """The :class:`LogStream` of ``spec``'s window, or why it cannot be streamed (then the in-memory
    path reads it, with its own messages for whatever is wrong in the file). ``min_rows``: a window
    of rows (or the whole file) shorter than this is refused before the time column is read."""
    if spec.bag:
        return "ROS bags are read in memory"
    if spec.rows is not None and spec.rows[1] - spec.rows[0] < min_rows:  # before any file is opened
        return f"window of {spec.rows[1] - spec.rows[0]} rows < {min_rows} (identification.streaming = 'auto')"

    def reader(path: Path):
        if path not in readers:
            readers[path] = TableReader(path, header=spec.header)
        return readers[path]

    signals = {"q": spec.position, "tau": spec.effort}
    if spec.velocity is not None:
        signals["dq"] = spec.velocity
    if spec.acceleration is not None:
        signals["ddq"] = spec.acceleration
    by_file: dict[Path, list[tuple[str, list[str]]]] = {}
    for what, sig in signals.items():
        by_file.setdefault(sig.file or spec.file, []).append((what, list(sig.columns)))
    groups = []
    for path, sigs in by_file.items():
        r = reader(path)
        if not isinstance(r, TableReader):
            return "the log is given as arrays in memory"
        cols = [c for _, c in sigs for c in c]
        stream = RowStream(r, cols)
        why = stream.unstreamable()
        if why is not None:
            return f"{path.name}: {why}"
        if stream.kind == "npz":  # a key may be a 2-D array: its width from the header
            keys = stream._npz_headers()
            widths = [1 if col is not None or len(keys[key][1]) == 1 else keys[key][1][1] for key, col in stream._npz_plan()]
        else:
            widths = [1] * len(cols)
        pos = np.concatenate([[0], np.cumsum(widths)]).astype(int)
        where, i = [], 0
        for what, c in sigs:
            where.append((what, slice(int(pos[i]), int(pos[i + len(c)]))))
            i += len(c)
        if any(sl.stop - sl.start != n_channels for _, sl in where):
            return "column counts differ from the joints"  # the in-memory reader says which
        groups.append((stream, where))
    lengths = {stream.n_rows() for stream, _ in groups}
    if spec.time is not None:
        tpath = spec.time.file or spec.file
        tr = reader(tpath)
        if not isinstance(tr, TableReader):
            return "the log is given as arrays in memory"
        ts = RowStream(tr, [spec.time.column])
        why = ts.unstreamable()
        if why is not None:
            return f"{tpath.name}: {why}"
        lengths.add(ts.n_rows())
    if len(lengths) > 1:
        return "mismatched lengths"  # the in-memory reader names them
    n_file = lengths.pop()
    start, stop = 0, n_file
    if spec.rows is not None:
        start, stop = spec.rows
        if stop > n_file:
            return "rows beyond the log"
    if spec.time_window is None and stop - start < min_rows:
        return f"window of {stop - start} rows < {min_rows} (identification.streaming = 'auto')"
    if spec.time is not None:
        t_all = None
        if spec.time_window is not None:  # the window is found on the whole time column
            t_all = np.concatenate(list(ts.blocks(0, None, 1 << 20)))[:, 0] * TIME_UNITS[spec.time.unit]
            idx = np.flatnonzero((t_all >= spec.time_window[0]) & (t_all < spec.time_window[1]))
            if idx.size < 2:
                return "time window too short"
            start, stop = int(idx[0]), int(idx[-1]) + 1
            t = t_all[start:stop]
            del t_all
        else:
            t = np.concatenate(list(ts.blocks(start, stop, 1 << 20)))[:, 0] * TIME_UNITS[spec.time.unit]
    else:
        t_all = np.arange(n_file) / spec.sample_rate_hz
        if spec.time_window is not None:
            idx = np.flatnonzero((t_all >= spec.time_window[0]) & (t_all < spec.time_window[1]))
            if idx.size < 2:
                return "time window too short"
            start, stop = int(idx[0]), int(idx[-1]) + 1
        t = t_all[start:stop].copy()
        del t_all
    t = np.ascontiguousarray(t, dtype=float)
    if t.shape[0] < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        return "time column not finite and increasing"  # the in-memory path reports where
    dt = np.diff(t)
    med = np.median(dt)
    if not np.all(np.abs(dt - med) <= 1e-3 * med):
        return "irregular timestamps (resampled in memory)"
    del dt
    files = {"position": spec.position.file or spec.file, "effort": spec.effort.file or spec.file}
    for what, sig in (("velocity", spec.velocity), ("acceleration", spec.acceleration)):
        if sig is not None:
            files[what] = sig.file or spec.file
    if spec.time is not None:
        files["time"] = spec.time.file or spec.file
    from dynid.pipeline.data import log_meta

    meta = log_meta(spec, files, readers)
    scales = {"q": _scale(POSITION_UNITS, spec.position, n_channels, f"{label}.position"),
              "tau": _scale(EFFORT_UNITS[spec.effort.kind], spec.effort, n_channels, f"{label}.effort")}
    if spec.velocity is not None:
        scales["dq"] = _scale(POSITION_UNITS, spec.velocity, n_channels, f"{label}.velocity")
    if spec.acceleration is not None:
        scales["ddq"] = _scale(POSITION_UNITS, spec.acceleration, n_channels, f"{label}.acceleration")
    effort_columns = (spec.effort.columns if len(spec.effort.columns) == n_channels else
                      tuple(f"{spec.effort.columns[0]}[{j}]" for j in range(n_channels)))
    return LogStream(spec, label, names, n_channels, groups, scales, start, t, meta, tuple(effort_columns),
                     files["effort"])


def plan(cfg: Config, system, readers: dict) -> tuple[tuple[LogStream, LogStream] | None, dict[str, Any]]:
    """Decide the path (module docstring): the two streams (None: in memory) and the record of
    ``result.json``'s ``data_path`` (``identification.cluster`` then checks it:
    :func:`dynid.pipeline.cluster_qr.check`)."""
    mode = cfg.identification.streaming
    if mode == "off":
        return None, {"mode": "in-memory", "reason": "identification.streaming = 'off'"}
    why = _why_not(cfg, system)
    streams = None
    if why is None:
        names, n = system.actuator_names, system.n_actuators
        tr = open_stream(cfg.data, n, names, "data", readers, AUTO_ROWS if mode == "auto" else 0)
        va = open_stream(cfg.validation, n, names, "validation", readers) if not isinstance(tr, str) else None
        if isinstance(tr, str) or isinstance(va, str):
            why = f"{'data' if isinstance(tr, str) else 'validation'}: {tr if isinstance(tr, str) else va}"
            if isinstance(tr, str) and tr.startswith("window of"):
                why = f"training {tr}"
        else:
            short = next((s.label for s in (tr, va) if not _long_enough(s, cfg.processing)), None)
            if short is not None:
                why = f"{short}: too short to stream"
            elif mode == "auto" and tr.n < AUTO_ROWS:
                why = f"training window of {tr.n} rows < {AUTO_ROWS} (identification.streaming = 'auto')"
            else:
                streams = (tr, va)
    if streams is None:
        if mode == "on":
            raise ConfigError(f"identification.streaming = 'on': this run cannot be streamed ({why}); "
                              "use 'auto' or 'off'")
        return None, {"mode": "in-memory", "reason": why}
    return streams, {"mode": "streamed", "reason": f"identification.streaming = {mode!r}",
                     "description": "read, filtered, differentiated and compressed chunk by chunk "
                                    "(dynid.pipeline.streaming); only the time column held whole"}


def _long_enough(s: LogStream, pcfg: ProcessingConfig) -> bool:
    """Room for the trimming and the filter's padding (else the in-memory path, with its message for a
    log that is too short)."""
    if pcfg.decimate > 1 and (pcfg.lowpass is None or pcfg.lowpass.cutoff_hz >= 0.5 * s.fs / pcfg.decimate):
        return False  # the in-memory path refuses it with its message
    if pcfg.lowpass is not None and not pcfg.lowpass.cutoff_hz < s.fs / 2:
        return False
    if pcfg.derivatives == "measured" and s.spec.velocity is None:
        return False
    p = s.processing(pcfg)  # blocks are clipped at the window's ends: a short window is one block, as in memory
    return s.n >= 64 and 2 * p["n_trim"] < s.n - 2 and len(p["rows"]) >= 3


class ErrorSums:
    """Per-channel error sums of a prediction over chunks: the numbers of
    :meth:`~dynid.estimation.validation.ValidationMetrics.of` without holding the arrays (mean and
    centred sum of squares merged pairwise: Chan, Golub & LeVeque 1979)."""

    def __init__(self, n_channels: int) -> None:
        c = n_channels
        self.n = np.zeros(c)
        self.rows = 0
        self.err2 = np.zeros(c)
        self.y2 = np.zeros(c)
        self.mean = np.zeros(c)
        self.m2 = np.zeros(c)
        self.max_err = np.zeros(c)

    def add(self, measured: FloatArray, predicted: FloatArray, kept: np.ndarray | None = None) -> None:
        w = np.ones(measured.shape, bool) if kept is None else np.broadcast_to(kept, measured.shape)
        self.rows += measured.shape[0]
        nb = w.sum(axis=0).astype(float)
        err = np.where(w, measured - predicted, 0.0)
        self.err2 += np.sum(err ** 2, axis=0)
        self.y2 += np.sum(np.where(w, measured, 0.0) ** 2, axis=0)
        self.max_err = np.maximum(self.max_err, np.max(np.abs(err), axis=0, initial=0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            mb = np.where(nb > 0, np.sum(np.where(w, measured, 0.0), axis=0) / np.where(nb > 0, nb, 1.0), 0.0)
        m2b = np.sum(np.where(w, measured - mb, 0.0) ** 2, axis=0)
        tot = self.n + nb
        delta = mb - self.mean
        safe = np.where(tot > 0, tot, 1.0)
        self.mean = np.where(tot > 0, self.mean + delta * nb / safe, 0.0)
        self.m2 = self.m2 + m2b + delta ** 2 * self.n * nb / safe
        self.n = tot

    def metrics(self, names, source, counts: bool = False):
        from dynid.estimation.validation import ValidationMetrics

        c = len(names)
        with np.errstate(divide="ignore", invalid="ignore"):
            rmse = np.sqrt(self.err2 / self.n)
            rms = np.sqrt(self.y2 / self.n)
            r2 = 1.0 - self.err2 / self.m2
        return ValidationMetrics(
            channel_names=tuple(names), n_samples=int(self.rows), rmse=rmse, rms_measured=rms,
            max_abs_error=np.where(self.n > 0, self.max_err, np.nan), r2=r2, t=np.empty(0),
            measured=np.empty((0, c)), predicted=np.empty((0, c)),
            source=dict(source) if isinstance(source, dict) else {"source": str(source)},
            counts=self.n.astype(int) if counts else None)


class StateSample:
    """The rows of ``(q, dq, ddq)`` that :func:`dynid.stats.nearest_distances` would take from the
    whole processed log (evenly spaced, at most ``m``), and, with ``std``, the standard deviation
    of every row's states merged chunk by chunk."""

    def __init__(self, n_rows: int, m: int, std: bool) -> None:
        from dynid.stats import _even

        self.idx = _even(n_rows, m)
        self.rows: list[FloatArray] = []
        self.std = std
        self.n, self.mean, self.m2 = 0, None, None

    def add(self, j0: int, p: dict[str, FloatArray]) -> None:
        x = np.hstack([p["q"], p["dq"], p["ddq"]])
        lo, hi = np.searchsorted(self.idx, [j0, j0 + x.shape[0]])
        if hi > lo:
            self.rows.append(x[self.idx[lo:hi] - j0])
        if self.std:
            nb = x.shape[0]
            mb = x.mean(axis=0)
            m2b = np.sum((x - mb) ** 2, axis=0)
            if self.mean is None:
                self.n, self.mean, self.m2 = nb, mb, m2b
            else:
                tot = self.n + nb
                delta = mb - self.mean
                self.mean = self.mean + delta * nb / tot
                self.m2 = self.m2 + m2b + delta ** 2 * self.n * nb / tot
                self.n = tot

    def matrix(self) -> FloatArray:
        return np.concatenate(self.rows)

    def scale(self) -> FloatArray:
        return np.sqrt(self.m2 / self.n)


def motion_overlap_streamed(train: StateSample, held: StateSample) -> dict[str, Any]:
    """:func:`dynid.estimation.validation.motion_overlap` from the sampled rows."""
    from dynid.estimation.validation import overlap_record
    from dynid.stats import nearest_distances_thinned

    return overlap_record(nearest_distances_thinned(train.matrix(), held.matrix(), train.scale()))

