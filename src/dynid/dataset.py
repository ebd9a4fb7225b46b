"""The in-memory data value of an identification experiment.

A :class:`Dataset` holds time-aligned samples of one experiment: time ``t`` (s),
positions ``q``, efforts ``tau`` and, once computed or when measured, velocities
``dq`` and accelerations ``ddq``. Time is axis 0; every array is
``(n_samples, n_channels)``. Arrays are read-only: operations return new values.

``meta`` records what the numbers mean (``position_side``: "joint" or "motor";
``effort_kind``: "torque" or "current"; ``effort_side``) and where they came from
(``source``), so that later steps can refuse data in the wrong space instead of
silently misusing it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["Dataset"]


def _frozen_array(name: str, x: Any, ndim: int) -> FloatArray:
    arr = np.array(x, dtype=np.float64)  # always a private copy
    if arr.ndim == 1 and ndim == 2:
        arr = arr[:, None]
    if arr.ndim != ndim:
        raise InputError(f"{name} must be {ndim}-D (n_samples{', n_channels' if ndim == 2 else ''}), got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(np.argwhere(bad)[0])
        row = int(first[0])
        kind = "NaN" if np.isnan(arr[first]) else "inf"
        raise InputError(f"{name} contains {kind} values ({int(bad.sum())} entries, first at sample {row})")
    arr.setflags(write=False)
    return arr


@dataclasses.dataclass(frozen=True, eq=False)
class Dataset:
    """Samples of one experiment, time on axis 0.

    Parameters
    ----------
    t : array, shape (n,)
        Sample times [s], strictly increasing.
    q : array, shape (n, n_q)
        Positions [rad or m] (joint or motor side, see ``meta['position_side']``).
    tau : array, shape (n, n_tau)
        Efforts [N·m, N or A] (see ``meta['effort_kind']``).
    dq, ddq : array, shape (n, n_q), optional
        Velocities and accelerations, measured or computed.
    names : tuple of str
        Channel names of ``q`` (joint or motor names).
    meta : mapping
        Semantics and provenance; stored read-only.
    """

    t: FloatArray
    q: FloatArray
    tau: FloatArray
    dq: FloatArray | None = None
    ddq: FloatArray | None = None
    names: tuple[str, ...] = ()
    meta: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _frozen_array("time", self.t, 1)
        q = _frozen_array("positions", self.q, 2)
        tau = _frozen_array("efforts", self.tau, 2)
        n = t.shape[0]
        for label, arr in (("positions", q), ("efforts", tau)):
            if arr.shape[0] != n:
                raise InputError(f"mismatched lengths: time has {n} samples, {label} has {arr.shape[0]}")
        if n < 2:
            raise InputError(f"a dataset needs at least 2 samples, got {n}")
        dt = np.diff(t)
        if np.any(dt <= 0):
            i = int(np.argmax(dt <= 0))
            raise InputError(
                f"time is not strictly increasing at sample {i + 1} (t={float(t[i + 1])!r} after t={float(t[i])!r})"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "tau", tau)
        for field, label in (("dq", "velocities"), ("ddq", "accelerations")):
            val = getattr(self, field)
            if val is not None:
                arr = _frozen_array(label, val, 2)
                if arr.shape != q.shape:
                    raise InputError(f"mismatched shapes: {label} {arr.shape} vs positions {q.shape}")
                object.__setattr__(self, field, arr)
        names = tuple(self.names) if self.names else tuple(f"q{i + 1}" for i in range(q.shape[1]))
        if len(names) != q.shape[1]:
            raise InputError(f"{len(names)} channel names for {q.shape[1]} position channels")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))

    # ------------------------------------------------------------------ properties
    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Time span [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def fs(self) -> float:
        """Sampling rate [Hz] from the median sampling period."""
        return float(1.0 / np.median(np.diff(self.t)))

    def is_uniform(self, rtol: float = 1e-3) -> bool:
        """True when every sampling period is within ``rtol`` of the median one."""
        dt = np.diff(self.t)
        med = np.median(dt)
        return bool(np.all(np.abs(dt - med) <= rtol * med))

    # ------------------------------------------------------------------ operations
    def replace(self, **changes: Any) -> Dataset:
        """A new dataset with some fields replaced (``meta`` entries are merged)."""
        if "meta" in changes:
            changes["meta"] = {**self.meta, **changes["meta"]}
        return dataclasses.replace(self, **changes)

    def rows(self, start: int, stop: int) -> Dataset:
        """Samples ``start <= i < stop`` (Python slice semantics, negative allowed)."""
        n = self.n_samples
        s, e, _ = slice(start, stop).indices(n)
        if e - s < 2:
            raise InputError(f"row window [{start}, {stop}) selects {max(e - s, 0)} of {n} samples")
        sl = slice(s, e)
        return self._take(sl, f"rows[{s}:{e}]")

    def time_window(self, t0: float, t1: float) -> Dataset:
        """Samples with ``t0 <= t < t1`` [s]."""
        idx = np.flatnonzero((self.t >= t0) & (self.t < t1))
        if idx.size < 2:
            raise InputError(
                f"time window [{t0}, {t1}) s selects {idx.size} samples; data span [{self.t[0]}, {self.t[-1]}] s"
            )
        return self._take(slice(int(idx[0]), int(idx[-1]) + 1), f"time[{t0}:{t1}]")

    def select(self, indices: np.ndarray, label: str) -> Dataset:
        """The samples at ``indices`` (increasing integers), recorded as ``label`` in the history."""
        idx = np.asarray(indices, dtype=int)
        if idx.ndim != 1 or idx.size < 2 or np.any(np.diff(idx) <= 0) or idx[0] < 0 or idx[-1] >= self.n_samples:
            raise InputError(f"{label}: need at least 2 increasing sample indices within the {self.n_samples} samples")
        return self._take(idx, label)

    def _take(self, sl: slice | np.ndarray, label: str) -> Dataset:
        def pick(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else a[sl]

        history = tuple(self.meta.get("history", ())) + (label,)
        return dataclasses.replace(
            self,
            t=self.t[sl],
            q=self.q[sl],
            tau=self.tau[sl],
            dq=pick(self.dq),
            ddq=pick(self.ddq),
            meta={**self.meta, "history": history},
        )
