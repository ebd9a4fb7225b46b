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

The friction's even part (an offset :math:`B`, any asymmetry :math:`f(v) + f(-v)`) cancels in
the difference with gravity: these runs cannot tell it from :math:`G(q)`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["FrictionPoints", "extract_friction_points"]


@dataclasses.dataclass(frozen=True, eq=False)
class FrictionPoints:
    """Extracted friction points, one per joint, speed level and repetition (arrays of shape (m,)).

    ``joint``: joint index (0-based); ``speed_cmd``: the commanded speed level; ``speed``: the
    measured one [rad/s or m/s]; ``force``: :math:`F_f` [N·m or N]; ``spread``: standard deviation
    of :math:`F_f` over the paired samples; ``n``: their number; ``sigma``: ``spread / sqrt(n)``;
    ``repetition`` (from 1); ``stroke``: the matched stroke [rad or m]. ``notes``: windows left out.
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
    notes: tuple[str, ...] = ()

    def select(self, mask: np.ndarray) -> FrictionPoints:
        fields = {f.name: getattr(self, f.name)[mask] for f in dataclasses.fields(self) if f.name != "notes"}
        return FrictionPoints(**fields, notes=self.notes)

    def __len__(self) -> int:
        return int(self.force.size)


def _slope(t: FloatArray, q: FloatArray) -> float:
    tc = t - t.mean()
    return float(tc @ (q - q.mean()) / (tc @ tc))


def extract_friction_points(t: FloatArray, q: FloatArray, tau: FloatArray, joint: FloatArray, speed: FloatArray,
                            direction: FloatArray, repetition: FloatArray, *, skip: float = 0.3, min_samples: int = 10,
                            names: tuple[str, ...] | None = None) -> FrictionPoints:
    """Pair forward and backward windows at matched positions (see the module docstring).

    Parameters
    ----------
    t : array (n,) [s]; q, tau : arrays (n, n_joints) [rad or m; N·m or N]
    joint, speed, direction, repetition : arrays (n,)
        The label columns of a constant-velocity log (1-based joint, 0 outside the windows;
        speed level; +1 / -1 / 0; repetition), as :mod:`dynid.trajectories.constant_velocity` writes them.
    skip : float
        Seconds left out at the start of each window.
    min_samples : int
        Fewest paired samples for a point; a window pair with fewer is left out and noted.
    names : tuple of str, optional
        Joint names for the notes.
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
        fwd = fwd[t[fwd] >= t[fwd[0]] + skip]
        bwd = bwd[t[bwd] >= t[bwd[0]] + skip]
        if fwd.size < 2 or bwd.size < 2:
            notes.append(f"{what}: the windows are shorter than skip = {skip:g} s; left out")
            continue
        qf, qb = q[fwd, j - 1], q[bwd, j - 1]
        vf, vb = _slope(t[fwd], qf), _slope(t[bwd], qb)
        if not (vf > 0 > vb):
            notes.append(f"{what}: the positions do not move forward then backward (slopes {vf:.3g}, {vb:.3g}); left out")
            continue
        lo, hi = max(qf.min(), qb.min()), min(qf.max(), qb.max())
        order = np.argsort(qb, kind="stable")
        inside = (qf >= lo) & (qf <= hi)
        if inside.sum() < min_samples:
            notes.append(f"{what}: {int(inside.sum())} paired samples (fewer than {min_samples}); left out")
            continue
        tb = np.interp(qf[inside], qb[order], tau[bwd, j - 1][order])
        ff = 0.5 * (tau[fwd, j - 1][inside] - tb)
        spread = float(ff.std(ddof=1))
        rows.append((j - 1, v, 0.5 * (vf - vb), float(ff.mean()), spread, int(ff.size), spread / np.sqrt(ff.size), r,
                     float(hi - lo)))
    if not rows:
        detail = f" ({notes[0]})" if notes else ""
        raise InputError(f"constant-velocity log: no pair of forward and backward windows gives a friction point{detail}")
    cols = list(zip(*rows))
    return FrictionPoints(joint=np.array(cols[0], dtype=int), speed_cmd=np.array(cols[1]), speed=np.array(cols[2]),
                          force=np.array(cols[3]), spread=np.array(cols[4]), n=np.array(cols[5], dtype=int),
                          sigma=np.array(cols[6]), repetition=np.array(cols[7], dtype=int), stroke=np.array(cols[8]),
                          notes=tuple(notes))
