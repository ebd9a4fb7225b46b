"""Friction points from bidirectional constant-velocity runs (paper 003, Sec. 3.1 and 4.4).

In a window where joint :math:`i` moves at constant velocity and the others rest, the inertial
torque vanishes, gravity depends on the position only and the Coriolis and centrifugal torque
is even in the velocity, :math:`C(q, \\dot q)\\dot q = C(q, -\\dot q)(-\\dot q)`; friction is odd.
So at equal positions the forward (:math:`+v`) and backward (:math:`-v`) torques give

.. math:: F_f(v) = \\tfrac12\\,[\\tau(q, v, 0) - \\tau(q, -v, 0)]

(paper 003, the equation after Eq. 16). :func:`extract_friction_points` pairs the two windows of
each joint, speed and repetition at matched positions: the backward torques, sorted by position,
are interpolated linearly onto the positions of the forward samples, over the stroke both windows
cover (after ``skip`` seconds at the start of each window, where the controller settles). The
point is the mean of :math:`F_f` over those samples, at the speed measured in the windows (the
mean of the forward and backward slopes of a straight line fitted to :math:`q(t)`); its
uncertainty is the spread (sample standard deviation) of :math:`F_f` divided by
:math:`\\sqrt{n}`: the standard error of the mean for independent samples (the interpolation
averages neighbouring backward samples, which makes this about 10 % small for white noise;
correlated noise or a position-dependent ripple make it smaller still, which is why the fits
scale their covariance by the reduced chi-square).

**Steady state** (paper 003, Sec. 3.1 and 4.4: "only data sampled during steady constant
velocity motion phases are retained"). After a reversal the drive's loop takes a while to hold
the new speed: its integral swings by about :math:`2F`, and at low speeds, where the friction
curve is steep (Eq. 15's arctan, a Stribeck dip), the speed rings about the command for seconds.
A mean over that transient is the friction at a wandering speed, not :math:`F_f(v)`. With
``settle`` on each window keeps, after the fixed ``skip`` (a floor), only the
samples after its *measured* speed has settled: the window is cut into blocks of
``settle_block`` seconds, each block's speed is the slope of a straight line fitted to its
positions and its noise level the slope's standard error from the scatter about that line; the
last third of the blocks is the reference (mean speed :math:`\\bar v_L`, noise level
:math:`s_L`, the root mean square of their standard errors). The window is steady from the
first block after which every block's speed stays within

.. math:: |v_b - \\bar v_L| \\le \\max(k\\, s_L,\\ \\epsilon\\, |\\bar v_L|)

(``settle_k`` = :math:`k`, default 3; ``settle_tol`` = :math:`\\epsilon`, default 0.02, the
2 % by which ``dynid friction`` already calls a point's measured speed off the command). A
window whose speed leaves that band within its last third never settles (the loop hunts: a
limit cycle at the lowest speeds); its pair is left out with a note, as is a pair whose settled
parts share fewer than ``min_samples`` positions (the windows are too short for the loop to
settle: lengthen them). Only the speed is tested, not the torque: at a steady speed the torque
is :math:`\\pm F_f(v) + G(q)` (the friction's own memory settles in milliseconds), and the
gravity's drift along the stroke would make a torque test see a transient where there is none.
The time each window lost (``skip`` plus the settling) is reported per point (``dropped_fwd``,
``dropped_bwd``). A window of fewer than 6 blocks cannot be tested; it is used from ``skip`` on,
with a note. ``settle`` is off by default (``dynid friction``'s configs and tests from before the
rule keep their points: in windows of 1-1.5 s the rule leaves the slowest pairs out, and too few
points remain for the held-out comparison); off, the rule still runs and a note names each
window whose speed is still settling after ``skip`` (its point is likely biased).

The friction's even part (an offset :math:`B`, any asymmetry :math:`f(v) + f(-v)`) cancels in
the difference with gravity: these runs cannot tell it from :math:`G(q)`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["FrictionPoints", "extract_friction_points", "settled_start"]


@dataclasses.dataclass(frozen=True, eq=False)
class FrictionPoints:
    """Extracted friction points, one per joint, speed level and repetition (arrays of shape (m,)).

    ``joint``: joint index (0-based); ``speed_cmd``: the commanded speed level; ``speed``: the
    measured one [rad/s or m/s]; ``force``: :math:`F_f` [N·m or N]; ``spread``: standard deviation
    of :math:`F_f` over the paired samples; ``n``: their number; ``sigma``: ``spread / sqrt(n)``;
    ``repetition`` (from 1); ``stroke``: the matched stroke [rad or m]; ``dropped_fwd``,
    ``dropped_bwd``: the seconds left out at the start of the forward and backward windows (``skip``
    plus the settling, module docstring). ``notes``: windows left out or not tested.
    """

    joint: np.ndarray
    speed_cmd: np.ndarray
    speed: np.ndarray
    force: np.ndarray
    spread: np.ndarray
    n: np.ndarray
    sigma: np.ndarray
    repetition: np.ndarray
    stroke: np.ndarray
    dropped_fwd: np.ndarray
    dropped_bwd: np.ndarray
    notes: tuple[str, ...] = ()

    def select(self, mask: np.ndarray) -> FrictionPoints:
        fields = {f.name: getattr(self, f.name)[mask] for f in dataclasses.fields(self) if f.name != "notes"}
        return FrictionPoints(**fields, notes=self.notes)

    def __len__(self) -> int:
        return int(self.force.size)


def _slope(t: FloatArray, q: FloatArray) -> float:
    tc = t - t.mean()
    return float(tc @ (q - q.mean()) / (tc @ tc))


SETTLE_MIN_BLOCKS = 6


def settled_start(t: FloatArray, q: FloatArray, *, block: float = 0.1, k: float = 3.0,
                  tol: float = 0.02) -> tuple[int | None, dict]:
    """Index of the first steady sample of one constant-velocity window (module docstring).

    ``t``, ``q``: the window's times and the moving joint's positions (after ``skip``). Returns
    ``(index, info)``: ``index`` None when the window never settles, 0 when nothing is dropped
    or the window is too short to test (``info["tested"]`` False); ``info`` holds the reference
    speed ``v_ref``, the band ``band`` and the block length ``block_samples``.
    """
    dt = float(np.median(np.diff(t))) if t.size > 1 else block
    nb = max(3, int(round(block / dt)))
    nblocks = t.size // nb
    if nblocks < SETTLE_MIN_BLOCKS:
        return 0, {"tested": False, "block_samples": nb, "blocks": nblocks}
    v = np.empty(nblocks)
    se = np.empty(nblocks)
    for b in range(nblocks):
        tb, qb = t[b * nb:(b + 1) * nb], q[b * nb:(b + 1) * nb]
        tc = tb - tb.mean()
        sxx = float(tc @ tc)
        v[b] = float(tc @ (qb - qb.mean())) / sxx
        r = qb - qb.mean() - v[b] * tc
        se[b] = np.sqrt(float(r @ r) / (nb - 2) / sxx)
    ref = slice(nblocks - nblocks // 3, nblocks)
    v_ref = float(v[ref].mean())
    noise = float(np.sqrt(np.mean(se[ref] ** 2)))
    band = max(k * noise, tol * abs(v_ref))
    out = np.abs(v - v_ref) > band
    info = {"tested": True, "v_ref": v_ref, "band": band, "noise": noise, "block_samples": nb, "blocks": nblocks}
    if out[ref].any():
        info["worst"] = float(np.abs(v[ref] - v_ref).max())
        return None, info
    first = int(np.flatnonzero(out)[-1]) + 1 if out.any() else 0
    return first * nb, info


def extract_friction_points(t: FloatArray, q: FloatArray, tau: FloatArray, joint: FloatArray, speed: FloatArray,
                            direction: FloatArray, repetition: FloatArray, *, skip: float = 0.3, min_samples: int = 10,
                            names: tuple[str, ...] | None = None, settle: bool = False, settle_block: float = 0.1,
                            settle_k: float = 3.0, settle_tol: float = 0.02) -> FrictionPoints:
    """Pair forward and backward windows at matched positions (see the module docstring).

    Parameters
    ----------
    t : array (n,) [s]; q, tau : arrays (n, n_joints) [rad or m; N·m or N]
    joint, speed, direction, repetition : arrays (n,)
        The label columns of a constant-velocity log (1-based joint, 0 outside the windows;
        speed level; +1 / -1 / 0; repetition), as :mod:`dynid.trajectories.constant_velocity` writes them.
    skip : float
        Seconds left out at the start of each window (with ``settle``, a floor).
    min_samples : int
        Fewest paired samples for a point; a window pair with fewer is left out and noted.
    names : tuple of str, optional
        Joint names for the notes.
    settle : bool
        Keep only each window's steady part (module docstring, paper 003 Sec. 3.1); False (the
        default): every sample after ``skip``, with a note for each window still settling.
    settle_block, settle_k, settle_tol : float
        The block length [s], the noise multiple :math:`k` and the relative band :math:`\\epsilon`
        of the steady-state rule (module docstring).
    """
    t = np.asarray(t, dtype=float)
    q, tau = np.atleast_2d(np.asarray(q, dtype=float)), np.atleast_2d(np.asarray(tau, dtype=float))
    joint, speed, direction, repetition = (np.asarray(x, dtype=float) for x in (joint, speed, direction, repetition))
    n, nj = q.shape
    if tau.shape != (n, nj) or any(x.shape != (n,) for x in (t, joint, speed, direction, repetition)):
        raise InputError(f"constant-velocity log: mismatched shapes (t {t.shape}, q {q.shape}, tau {tau.shape})")
    names = names or tuple(f"joint {k + 1}" for k in range(nj))
    moving = direction != 0
    bad = moving & ((joint < 1) | (joint > nj) | (joint != np.round(joint)) | (speed <= 0))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"constant-velocity log: row {k} is in a window (cv_direction {direction[k]:g}) with "
                         f"cv_joint {joint[k]:g} and cv_speed {speed[k]:g}; expected a joint 1..{nj} and a speed > 0")
    keys = sorted({(int(j), float(v), int(r)) for j, v, r in zip(joint[moving], speed[moving], repetition[moving])})
    rows: list[tuple] = []
    notes: list[str] = []
    for j, v, r in keys:
        sel = (joint == j) & (speed == v) & (repetition == r)
        fwd, bwd = np.flatnonzero(sel & (direction > 0)), np.flatnonzero(sel & (direction < 0))
        what = f"{names[j - 1]} at {v:g} (repetition {r})"
        if fwd.size == 0 or bwd.size == 0:
            notes.append(f"{what}: only the {'forward' if fwd.size else 'backward'} window; left out")
            continue
        t_fwd0, t_bwd0 = t[fwd[0]], t[bwd[0]]
        fwd = fwd[t[fwd] >= t_fwd0 + skip]
        bwd = bwd[t[bwd] >= t_bwd0 + skip]
        if fwd.size < 2 or bwd.size < 2:
            notes.append(f"{what}: the windows are shorter than skip = {skip:g} s; left out")
            continue
        if settle:
            starts = []
            for idx, label in ((fwd, "forward"), (bwd, "backward")):
                i0, info = settled_start(t[idx], q[idx, j - 1], block=settle_block, k=settle_k, tol=settle_tol)
                if i0 is None:
                    notes.append(f"{what}: the {label} window never settles (its speed, {info['v_ref']:.3g} in the last "
                                 f"third, still strays {info['worst']:.2g} from it there, beyond the band "
                                 f"{info['band']:.2g}: the loop hunts); left out")
                elif not info["tested"]:
                    notes.append(f"{what}: the {label} window after skip has {info['blocks']} blocks of "
                                 f"{settle_block:g} s (fewer than {SETTLE_MIN_BLOCKS}): its settling is not tested")
                starts.append(i0)
            if starts[0] is None or starts[1] is None:
                continue
            fwd, bwd = fwd[starts[0]:], bwd[starts[1]:]
        else:
            late = []
            for idx, label in ((fwd, "forward"), (bwd, "backward")):
                i0, info = settled_start(t[idx], q[idx, j - 1], block=settle_block, k=settle_k, tol=settle_tol)
                if i0 is None:
                    late.append(f"the {label} window never settles")
                elif i0 > 0:
                    late.append(f"the {label} window's speed settles {t[idx[i0]] - t[idx[0]]:.2g} s after skip")
            if late:
                notes.append(f"{what}: {' and '.join(late)}: the point is likely biased (settle = true keeps only "
                             "the steady part)")
        qf, qb = q[fwd, j - 1], q[bwd, j - 1]
        vf, vb = _slope(t[fwd], qf), _slope(t[bwd], qb)
        if not (vf > 0 > vb):
            notes.append(f"{what}: the positions do not move forward then backward (slopes {vf:.3g}, {vb:.3g}); left out")
            continue
        lo, hi = max(qf.min(), qb.min()), min(qf.max(), qb.max())
        order = np.argsort(qb, kind="stable")
        inside = (qf >= lo) & (qf <= hi)
        if inside.sum() < min_samples:
            extra = (f" after settling (the forward window steady from {t[fwd[0]] - t_fwd0:.2f} s, the backward from "
                     f"{t[bwd[0]] - t_bwd0:.2f} s: lengthen the windows)" if settle else "")
            notes.append(f"{what}: {int(inside.sum())} paired samples (fewer than {min_samples}){extra}; left out")
            continue
        tb = np.interp(qf[inside], qb[order], tau[bwd, j - 1][order])
        ff = 0.5 * (tau[fwd, j - 1][inside] - tb)
        spread = float(ff.std(ddof=1))
        rows.append((j - 1, v, 0.5 * (vf - vb), float(ff.mean()), spread, int(ff.size), spread / np.sqrt(ff.size), r,
                     float(hi - lo), float(t[fwd[0]] - t_fwd0), float(t[bwd[0]] - t_bwd0)))
    if not rows:
        detail = f" ({notes[0]})" if notes else ""
        raise InputError(f"constant-velocity log: no pair of forward and backward windows gives a friction point{detail}")
    cols = list(zip(*rows))
    return FrictionPoints(joint=np.array(cols[0], dtype=int), speed_cmd=np.array(cols[1]), speed=np.array(cols[2]),
                          force=np.array(cols[3]), spread=np.array(cols[4]), n=np.array(cols[5], dtype=int),
                          sigma=np.array(cols[6]), repetition=np.array(cols[7], dtype=int), stroke=np.array(cols[8]),
                          dropped_fwd=np.array(cols[9]), dropped_bwd=np.array(cols[10]), notes=tuple(notes))
