"""Checks of a finished closed-loop run: is it a usable virtual experiment?

A virtual experiment whose loop is unstable, whose robot does not follow the commanded motion,
or whose drives deliver forces the real ones cannot, still writes a log that ``dynid identify``
reads; these checks say so instead (``dynid simulate`` prints them and records them in
``metadata.json``'s ``warnings``). Pure numpy on the run's arrays, time on axis 0.

* :func:`unstable_state`: the first sample whose state or effort is not finite (the loop
  diverged: nothing usable is left to write);
* :func:`loop_warnings`: a tracking error growing through the run (an unstable loop whose state
  is still finite), a tracking error large against the commanded motion
  (:data:`TRACKING_FRACTION` of each coordinate's commanded range), and efforts beyond the
  actuators' declared limits (the description's ``effort`` limits; none declared, no check).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dynid._typing import FloatArray

__all__ = ["GROWTH_FACTOR", "TRACKING_FRACTION", "declared_limits", "loop_warnings", "unstable_state"]

TRACKING_FRACTION = 0.1
"""A tracking error above this fraction of a coordinate's commanded range (peak to peak) is
large: the robot then moves noticeably otherwise than commanded, so the excitation the log holds
is not the designed one (its predicted uncertainties do not apply) and the controller's reaction,
not the reference, shapes the efforts. A coordinate commanded to stay put (range 0, the idle joints
of a constant-velocity experiment) is measured against a tenth of the largest range."""

GROWTH_FACTOR = 10.0
"""An error whose peak over the last eighth of the run is this many times its peak over the
fourth eighth, growing through the last four eighths, and large (:data:`TRACKING_FRACTION`), is
a loop going unstable (a stable loop's error on a bounded reference stays bounded; an unstable
one grows geometrically until the state overflows)."""

_NO_LIMIT = np.finfo(float).max  # pinocchio's "no limit" (URDF/MJCF without one, built-ins)


def declared_limits(effort_limit: FloatArray) -> np.ndarray:
    """The effort limits a description declares, inf where it declares none (pinocchio's
    ``effortLimit`` holds the largest double, or inf, for those)."""
    lim = np.array(effort_limit, dtype=float)
    lim[~np.isfinite(lim) | (np.abs(lim) >= _NO_LIMIT) | (lim <= 0)] = np.inf
    return lim


def unstable_state(t: FloatArray, *arrays: FloatArray) -> int | None:
    """Index of the first sample at which any of ``arrays`` (each (n, k)) is not finite, or None."""
    bad = np.zeros(np.asarray(t).size, dtype=bool)
    for a in arrays:
        a = np.asarray(a, dtype=float)
        bad |= ~np.all(np.isfinite(a.reshape(a.shape[0], -1)), axis=1)
    return int(np.argmax(bad)) if bad.any() else None


def loop_warnings(t: FloatArray, reference: FloatArray, actual: FloatArray, coordinates: Sequence[str],
                  coordinate_units: Sequence[str], effort: FloatArray, effort_limit: FloatArray,
                  actuators: Sequence[str], effort_units: Sequence[str]) -> list[dict]:
    """The warnings of a finite run (see the module docstring).

    Parameters
    ----------
    t : (n,) [s]
    reference, actual : (n, n_u)
        Commanded and true independent coordinates [rad or m].
    coordinates, coordinate_units : names and units of the n_u coordinates
    effort : (n, n_a)
        The held actuator efforts [N*m or N].
    effort_limit : (n_a,)
        Declared limits (:func:`declared_limits`; inf: none).
    actuators, effort_units : names and units of the n_a actuators

    Returns
    -------
    list of dict
        Each ``{"kind": "unstable" | "tracking" | "effort_limit", "message": str, ...}`` with the
        figures of the message.
    """
    t = np.asarray(t, dtype=float)
    ref, act = np.asarray(reference, dtype=float), np.asarray(actual, dtype=float)
    tau = np.asarray(effort, dtype=float)
    out: list[dict] = []
    e = np.abs(ref - act)
    span = np.ptp(ref, axis=0)
    floor = 0.1 * span.max() if span.size else 0.0
    threshold = TRACKING_FRACTION * np.maximum(span, floor)
    if threshold.size and np.all(threshold > 0):
        rel = e / threshold  # 1: the error equals its threshold
        windows = np.array_split(np.arange(t.size), 8)
        if len(windows[-1]):
            peaks = np.array([rel[w].max() if len(w) else 0.0 for w in windows])
            growing = np.all(np.diff(peaks[-4:]) > 0)
            if peaks[-1] > 1 and peaks[-1] > GROWTH_FACTOR * max(peaks[3], 1e-300) and growing:
                k = int(np.argmax(rel[windows[-1]].max(axis=0)))
                a, b = (float(e[w, k].max()) for w in (windows[3], windows[-1]))
                out.append({"kind": "unstable", "coordinate": coordinates[k], "error_mid": a, "error_end": b,
                            "message": f"unstable loop: the tracking error of {coordinates[k]} grows from {a:.3g} to "
                                       f"{b:.3g} {coordinate_units[k]} over the second half of the run (peaks of "
                                       f"successive eighths growing, x{b / a if a > 0 else np.inf:.3g}); lower the "
                                       "gains or raise control.rate_hz"})
        for k in np.flatnonzero(e.max(axis=0) > threshold):
            i = int(np.argmax(e[:, k]))
            out.append({"kind": "tracking", "coordinate": coordinates[k], "max_error": float(e[i, k]),
                        "threshold": float(threshold[k]), "t": float(t[i]),
                        "message": f"large tracking error: {coordinates[k]} is {e[i, k]:.3g} {coordinate_units[k]} "
                                   f"off its reference at t = {t[i]:.3f} s, above {threshold[k]:.3g} "
                                   f"{coordinate_units[k]} ({TRACKING_FRACTION:.0%} of its commanded range: the log "
                                   "holds another motion than the commanded one, which identification uses, but not "
                                   "the designed excitation); retune the gains"})
    lim = np.asarray(effort_limit, dtype=float)
    peak = np.abs(tau).max(axis=0) if tau.size else np.zeros(lim.size)
    for k in np.flatnonzero(peak > lim):
        i = int(np.argmax(np.abs(tau[:, k])))
        out.append({"kind": "effort_limit", "actuator": actuators[k], "peak": float(peak[k]), "limit": float(lim[k]),
                    "t": float(t[i]),
                    "message": f"effort beyond the limit: {actuators[k]} reaches {peak[k]:.5g} {effort_units[k]} at "
                               f"t = {t[i]:.3f} s, {peak[k] / lim[k]:.3g} x its limit {lim[k]:.5g} {effort_units[k]} "
                               "(the description's effort limit; a real drive saturates there); lower the gains or "
                               "slow the trajectory"})
    return out
