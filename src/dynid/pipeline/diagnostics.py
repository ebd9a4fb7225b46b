"""Alarms for the mistakes a newcomer makes with a log: ``dynid identify`` still fits *something*
to a log in the wrong units, with a flipped sign or two columns swapped, and a linear fit of
inverse dynamics happily absorbs a sign or a scale into its parameters. These checks compare the
log with what the robot description says it can be, and with what its nominal model predicts:

* :func:`limit_alarms`: positions beyond the description's joint limits (a log in degrees read as
  radians: up to 57x its range; millimetres read as metres: 1000x), efforts beyond its effort
  limits (a unit, a motor-side torque without its gear ratio);
* :func:`nominal_alarms`: the nominal model's prediction on the held-out rows anti-correlated with
  a measured effort (a flipped sign), correlated better with another joint's effort than with
  its own (two columns swapped), or a fit worse than predicting zero (relative RMSE > 100 %) or
  than the mean (R^2 < 0);
* :func:`friction_alarms`: every estimated viscous and Coulomb coefficient negative (friction
  dissipates: negative coefficients all at once are a flipped effort sign);
* :func:`actuator_limits`: the position and effort limits of each actuator from the description;
  an absent or infinite limit is no check.

Each alarm is an :class:`Alarm`: what was seen, with the numbers, and the likely cause. They are
computed by :mod:`dynid.pipeline.identification` and written to the console, summary.txt and
result.json (``"warnings"``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from dynid._typing import FloatArray

__all__ = ["Alarm", "actuator_limits", "limit_alarms", "nominal_alarms", "friction_alarms",
           "POSITION_MARGIN", "EFFORT_MARGIN", "SIGN_CORRELATION", "SWAP_FACTOR"]

POSITION_MARGIN = 0.1
"""A position is beyond its limits when it passes them by more than this fraction of the joint's
range: encoder noise, filtering overshoot and a limit rounded in the description stay within a
few percent, while a unit mistake is far beyond (degrees read as radians: 57.3x the values, so
any motion wider than 1/57 of the range leaves it; millimetres read as metres: 1000x)."""

EFFORT_MARGIN = 0.1
"""An effort is beyond its limit when its magnitude exceeds the description's effort limit (URDF
``<limit effort>``, MJCF ``actuatorfrcrange``: the most the drive exerts) by more than this
fraction: room for sensor noise on a drive that saturates and for a limit rounded in the file; a
unit mistake (mN·m read as N·m: 1000x) or motor-side torques without the gear ratio are far
beyond."""

SIGN_CORRELATION = -0.5
"""A channel's effort sign is taken as flipped when the nominal prediction's correlation with the
measured effort is at or below this value: the prediction then explains at least a quarter of the
measured variance (r^2 >= 0.25), with the wrong sign. An imprecise nominal model still correlates
positively (the gravity and inertia terms dominate); a weak channel whose prediction is mostly
noise stays near 0."""

SWAP_FACTOR = 0.5
"""Two effort columns i and j are taken as swapped when the nominal prediction of i fits the
measured effort of j, and that of j the effort of i, with relative RMSEs each below 100 % (better
than predicting zero) and together below this fraction of the two channels' own relative RMSEs
(each own one the better of the prediction and its negative, so that a flipped sign is not taken
for a swap). The errors, not correlations: coupled joints (two pitch joints carrying the same
distal mass) have efforts correlated at 0.8 or more, so a swap barely changes the correlations;
it changes the magnitudes. A nominal model 20 % off fits its own channels within a few tens of
percent; a permutation that halves the error is no such imprecision."""


@dataclasses.dataclass(frozen=True)
class Alarm:
    """One warning: ``kind`` (``"position_limits"``, ``"effort_limits"``, ``"effort_sign"``,
    ``"swapped_columns"``, ``"nominal_fit"``, ``"friction_sign"``), ``seen`` (what the data show,
    with numbers) and ``cause`` (the likely cause, and what to change)."""

    kind: str
    seen: str
    cause: str

    def __str__(self) -> str:
        return f"WARNING: {self.seen}; likely cause: {self.cause}"

    def to_dict(self) -> dict[str, str]:
        return {"kind": self.kind, "seen": self.seen, "likely_cause": self.cause}


def actuator_limits(system: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Lower and upper position limits and effort limit of each actuator, from the robot
    description (pinocchio's ``lowerPositionLimit``, ``upperPositionLimit``, ``effortLimit``:
    URDF ``<limit>``, MJCF ``range`` and ``actuatorfrcrange``), shape (n_a,) each.

    An absent limit is ``±inf`` (no check): pinocchio writes an absent limit as ±DBL_MAX (taken
    as infinite above 1e30); a zero effort limit (URDF's default when ``effort`` is omitted) and an
    empty or inverted position range are absent too."""
    model = system.model
    pm = model.pin_model
    if system.kind == "serial":  # the actuators are the joints (after the transmission)
        vidx = list(range(pm.nv))
    else:
        vidx = list(model.actuated)
    lo, hi, eff = (np.full(len(vidx), -np.inf), np.full(len(vidx), np.inf), np.full(len(vidx), np.inf))
    for a, v in enumerate(vidx):
        j = next((j for j in range(1, pm.njoints) if pm.joints[j].idx_v == v), None)
        if j is None or pm.joints[j].nq != 1 or pm.joints[j].nv != 1:
            continue
        iq = pm.joints[j].idx_q
        l, h = float(pm.lowerPositionLimit[iq]), float(pm.upperPositionLimit[iq])
        if np.isfinite(l) and np.isfinite(h) and abs(l) < 1e30 and abs(h) < 1e30 and h > l:
            lo[a], hi[a] = l, h
        e = float(pm.effortLimit[v])
        if np.isfinite(e) and 0 < e < 1e30:
            eff[a] = e
    return lo, hi, eff


def limit_alarms(q: FloatArray, tau: FloatArray | None, names: Sequence[str], kinds: Sequence[str],
                 system: Any, label: str) -> list[Alarm]:
    """Positions ``q`` (n, n_a) beyond the actuators' limits by more than :data:`POSITION_MARGIN`
    of their range, and efforts ``tau`` (n, n_a; None: not in torque units, no check) beyond their
    effort limits by more than :data:`EFFORT_MARGIN`. ``kinds``: ``"revolute"``/``"prismatic"``
    per actuator (which unit mistake fits); ``label``: the log (``"data"``, ``"validation"``)."""
    lo, hi, eff = actuator_limits(system)
    out: list[Alarm] = []
    q = np.asarray(q, dtype=float)
    span = hi - lo
    qmin, qmax = np.nanmin(q, axis=0), np.nanmax(q, axis=0)
    with np.errstate(invalid="ignore"):
        beyond = np.isfinite(span) & ((qmax > hi + POSITION_MARGIN * span) | (qmin < lo - POSITION_MARGIN * span))
    if beyond.any():
        idx = np.flatnonzero(beyond)
        seen = ", ".join(f"{names[a]} {qmin[a]:.4g} to {qmax[a]:.4g} (limits {lo[a]:.4g} to {hi[a]:.4g}, "
                         f"{max(qmax[a] - hi[a], lo[a] - qmin[a]) / span[a]:.3g}x its range beyond)" for a in idx)
        scale = {"revolute": (np.pi / 180.0, "degrees", "radians", "deg"),
                 "prismatic": (1e-3, "millimetres", "metres", "mm")}
        fits = []
        for kind, (f, was, read, unit) in scale.items():
            sel = [a for a in idx if kinds[a] == kind]
            if sel and all(lo[a] - POSITION_MARGIN * span[a] <= f * qmin[a] and f * qmax[a] <= hi[a] + POSITION_MARGIN
                           * span[a] for a in sel):
                fits.append(f"the log is in {was}, read as {read}: scaled by {f:.4g} every "
                            f"position of {', '.join(names[a] for a in sel)} lies within its limits (set "
                            f"{label}.position.unit = \"{unit}\")")
        other = ("a wrong column, or an encoder offset (robot.position_offset / the zero of the joint) - or limits in "
                 "the description that are not the robot's")
        worst = float(np.max(np.maximum(qmax - hi, lo - qmin)[idx] / span[idx]))
        if fits and worst < 1.0:  # less than a range beyond: a unit fits, but so may an offset
            cause = "; ".join(fits) + f"; or, as the excess is less than a joint's range, {other}"
        else:
            cause = "; ".join(fits) if fits else f"the position unit ({label}.position.unit), {other}"
        out.append(Alarm("position_limits", f"{label}: positions far beyond the robot description's joint limits: {seen}",
                         cause))
    if tau is not None:
        tmax = np.nanmax(np.abs(np.asarray(tau, dtype=float)), axis=0)
        over = np.flatnonzero(np.isfinite(eff) & (tmax > (1.0 + EFFORT_MARGIN) * eff))
        if over.size:
            seen = ", ".join(f"{names[a]} up to {tmax[a]:.4g} ({tmax[a] / eff[a]:.3g}x its limit {eff[a]:.4g})" for a in over)
            out.append(Alarm(
                "effort_limits", f"{label}: efforts beyond the robot description's effort limits: {seen}",
                f"the effort unit ({label}.effort.unit: mN*m read as N*m is 1000x), motor-side torques or currents "
                f"read as joint torques ({label}.effort.side / kind, robot.gear_ratios), or a wrong column"))
    return out


def _corr(a: FloatArray, b: FloatArray) -> FloatArray:
    """Correlation coefficient of every column of ``a`` with every column of ``b`` (NaN for a
    constant column)."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (a.T @ b) / np.outer(np.sqrt((a * a).sum(axis=0)), np.sqrt((b * b).sum(axis=0)))


def nominal_alarms(nominal: Any, label: str = "held-out") -> list[Alarm]:
    """Alarms from the nominal model's prediction against the measured efforts (``nominal``: its
    :class:`~dynid.estimation.validation.ValidationMetrics` on the held-out rows, whose arrays
    ``measured`` and ``predicted`` (n, channels) are used when kept).

    The nominal model is the robot description's own parameters: imprecise, but it knows the
    sign and the order of the joints. Swapped columns are looked for first (:data:`SWAP_FACTOR`; a
    swap also spoils the own channels' fit), then a flipped sign on the remaining channels
    (:data:`SIGN_CORRELATION`), then a
    fit worse than zero (relative RMSE > 100 %) or than the mean (R^2 < 0) on any channel."""
    names = list(nominal.channel_names)
    out: list[Alarm] = []
    meas, pred = np.asarray(nominal.measured, dtype=float), np.asarray(nominal.predicted, dtype=float)
    swapped: set[int] = set()
    if meas.ndim == 2 and meas.shape[0] > 2 and meas.shape == pred.shape:
        kept = nominal.kept
        rows = np.all(kept, axis=1) if kept is not None else np.ones(meas.shape[0], dtype=bool)
        p, m = pred[rows], meas[rows]
        C = _corr(p, m)  # C[i, j]: prediction of i against the measurement of j
        with np.errstate(divide="ignore", invalid="ignore"):
            # R[i, j]: relative RMSE of prediction i against measurement j, mean((m_j - p_i)^2) expanded
            # (no (n, channels, channels) array)
            mm, pp, pm = np.mean(m**2, axis=0), np.mean(p**2, axis=0), (p.T @ m) / m.shape[0]
            R = np.sqrt(np.maximum(mm[None, :] - 2 * pm + pp[:, None], 0.0) / mm[None, :])
            own = np.minimum(np.diag(R), np.sqrt(np.maximum(mm + 2 * np.diag(pm) + pp, 0.0) / mm))  # either sign
        n = len(names)
        pairs = []
        for i in range(n):
            for j in range(i + 1, n):
                if max(R[i, j], R[j, i]) < 1.0 and R[i, j] + R[j, i] < SWAP_FACTOR * (own[i] + own[j]):
                    pairs.append((R[i, j] + R[j, i] - own[i] - own[j], i, j))
        for _, i, j in sorted(pairs):
            if i in swapped or j in swapped:
                continue
            swapped |= {i, j}
            out.append(Alarm(
                "swapped_columns",
                f"the nominal model's prediction of {names[i]} fits the measured effort of {names[j]} (relative RMSE "
                f"{100 * R[i, j]:.3g} %) far better than its own ({100 * R[i, i]:.3g} %), and that of {names[j]} "
                f"fits {names[i]}'s ({100 * R[j, i]:.3g} %, own {100 * R[j, j]:.3g} %)",
                f"the effort columns of {names[i]} and {names[j]} are swapped (check the order of data.effort.columns, "
                "and of data.position.columns, against the robot's joints)"))
        flipped = [k for k in range(n) if k not in swapped and C[k, k] <= SIGN_CORRELATION]
        if flipped:
            out.append(Alarm(
                "effort_sign",
                "the nominal model's prediction is anti-correlated with the measured effort of "
                + ", ".join(f"{names[k]} (r = {C[k, k]:.2f})" for k in flipped),
                "the effort sign of " + ", ".join(names[k] for k in flipped) + " is flipped (the drive's or the "
                "sensor's positive direction is opposite to the joint axis of the description: negate the column, "
                "or the joint's axis in the description)"))
    rel, r2 = np.asarray(nominal.rel_rmse_pct, dtype=float), np.asarray(nominal.r2, dtype=float)
    with np.errstate(invalid="ignore"):
        bad = [k for k in range(len(names)) if rel[k] > 100.0 or r2[k] < 0.0]
    if bad:
        explained = bool(out)
        out.append(Alarm(
            "nominal_fit",
            f"the nominal model (the robot description's parameters) predicts the {label} efforts worse than zero "
            "(relative RMSE > 100 %) or than their mean (R^2 < 0) on "
            + ", ".join(f"{names[k]} (relative RMSE {rel[k]:.3g} %, R^2 {r2[k]:.3g})" for k in bad),
            ("see the warnings above; " if explained else "")
            + "the effort or position units, a flipped effort sign, the column order, or a description whose "
              "parameters are far from this robot (then the identified model is the one to trust, but check these "
              "first: a linear fit absorbs a scale or a sign into its parameters and still fits well)"))
    return out


def friction_alarms(result: Any, system: Any) -> list[Alarm]:
    """Every estimated viscous and Coulomb friction coefficient of the actuators negative (at least
    two of them, each its own base parameter). Friction dissipates energy: one negative estimate
    can be noise on a small coefficient, all of them at once is a flipped effort sign."""
    pairs, _ = system.friction_pairs()
    where = {n: k for k, n in enumerate(result.names)}
    found = [(n, float(result.params[where[n]])) for _, fc, fv, _ in pairs for n in (fv, fc) if n in where]
    if len(found) < 2 or not all(v < 0 for _, v in found):
        return []
    return [Alarm("friction_sign",
                  "every estimated friction coefficient is negative: " + ", ".join(f"{n} = {v:.4g}" for n, v in found),
                  "the effort sign is flipped on every joint (the log's efforts are the reaction, or the drive's "
                  "convention is opposite to the description's axes: negate data.effort's columns)")]
