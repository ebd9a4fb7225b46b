"""Drive gains estimated from the prior when a log gives currents without robot.drive_gains (issue 35: the pipeline
split by concern). Re-exported by :mod:`dynid.pipeline.identification`."""

from __future__ import annotations

from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.dataset import Dataset
from dynid.errors import ConfigError, InputError
from dynid.model.base_parameters import BaseParameters
from dynid.model.serial_dynamics import inverse_dynamics
from dynid.model.system import System
from dynid.pipeline.rows import _chunks


GAIN_REL_STD = 0.10
"""The largest relative standard error of an estimated drive gain that :func:`~dynid.pipeline.identification.identify` uses: a
motor whose torques the nominal model barely predicts (a wrist whose currents are mostly
friction) has a gain the prior does not decide; then no gain is used (unit gains, said so).
10 %: a CAD prior is itself typically 10-15 % off, so a gain known to 10 % adds no more to the
comparison with the prior than the prior's own error."""

GAIN_BLOCKS = 20
"""Contiguous blocks of the training rows over which :func:`estimate_drive_gains` repeats its
fit: the spread of the block estimates gives the interval (it sees the prior's systematic error
as it varies along the log, which the residuals' white-noise variance would not)."""


def estimate_drive_gains(system: System, base: BaseParameters, train: Dataset, force_model: str | None, *,
                         parallel_decimate: int = 1, chunk_size: int = 20000) -> dict[str, Any]:
    r"""The motors' current-to-torque gains :math:`K` from the prior (issue 34, item 8).

    With efforts logged as motor currents and no ``robot.drive_gains`` the parameters would absorb
    the gains. The nominal model's torques explain the currents up to them: per actuator equation
    :math:`j`,

    .. math:: \tau^{nom}_j = \sum_m C_{mj} k_m i_m - f_{v,j}\,\dot q_j - f_{c,j}\,\mathrm{sign}(\dot q_j) - c_j,

    with :math:`\tau^{nom} = W\beta_{nom}` the description's rigid-body torques (for a serial arm
    by pinocchio's recursive Newton-Euler on the nominal model, which equals the regressor's product
    to rounding at a third of its cost; a mechanism filters the base regressor's product), :math:`C` the
    coupling matrix (identity without couplings), and viscous, Coulomb friction and an offset
    per actuator as nuisance terms where the description has no friction for that joint (a
    description rarely has the friction the currents carry; where it has, its torques include it).
    One least-squares fit over all rows (``train`` processed with unit gains, so its efforts are
    :math:`C^T i`); the interval of each :math:`k_m` from the fits on :data:`GAIN_BLOCKS`
    contiguous blocks (standard error of the block mean). The prior's own error enters as bias:
    a description 10 % off in mass gives gains about 10 % off, which the identification then
    carries; a known-payload experiment removes it (docs/guide/payloads.md).
    """
    if not system.channels_are_actuators(force_model):
        raise ConfigError("drive gains from the prior: the equations are projected (redundant actuation); give "
                          "robot.drive_gains")
    tr = system.transmission
    n = system.n_actuators
    C = np.eye(n) if tr is None else np.asarray(tr.matrix, dtype=float)
    ys, ts, vs = [], [], []
    if system.kind == "serial":
        # a serial arm's nominal torques by pinocchio's RNEA (about a third of the regressor's cost,
        # equal to W beta_nom to rounding: Featherstone's recursion and the regressor of Atkeson et al.
        # are the same dynamics; serial_dynamics.inverse_dynamics), not through the regressor
        model, std_nominal = system.model, system.nominal_parameters()
        way: dict[str, Any] = {"torques": lambda q, dq, ddq: inverse_dynamics(model, std_nominal, q, dq, ddq)}
    else:  # a mechanism: the base regressor times the nominal base parameters, only that column filtered
        way = {"project": base.from_standard(system.nominal_parameters())[:, None]}
    for c in _chunks(system, base, train, force_model, parallel_decimate=parallel_decimate, chunk_size=chunk_size,
                     task="drive gains", **way):
        ys.append(c.y)
        ts.append(c.W[..., 0])
        vs.append(c.dq)
    u, tau, dq = np.concatenate(ys), np.concatenate(ts), np.concatenate(vs)
    cur = np.linalg.solve(C.T, u.T).T  # the currents (the efforts are C^T i at unit gains)
    rows = u.shape[0]
    # friction as a nuisance only where the description has none (where it has some, its torques
    # include it, and a free friction term would trade with the gain of a friction-dominated joint)
    free = np.ones(n, dtype=bool)
    try:
        idx = system.model.layout.extra_index
        std_nom = np.asarray(system.nominal_parameters(), float)
        for key in ("fv", "fc"):
            if key in idx:
                free &= std_nom[idx[key]] == 0
    except (AttributeError, KeyError, IndexError, TypeError):
        pass

    def fit(sl: slice) -> FloatArray:
        m = cur[sl].shape[0]
        A = np.zeros((m * n, n + 3 * n))
        for j in range(n):
            r = slice(j * m, (j + 1) * m)
            A[r, :n] = cur[sl] * C[:, j]
            if free[j]:
                A[r, n + j] = -dq[sl, j]
                A[r, 2 * n + j] = -np.sign(dq[sl, j])
            A[r, 3 * n + j] = -1.0
        b = tau[sl].T.reshape(-1)
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        x = np.linalg.lstsq(A / scale, b, rcond=None)[0] / scale
        return x[:n]

    k = fit(slice(0, rows))
    nb = min(GAIN_BLOCKS, rows // max(4 * n, 10))
    if nb >= 4:
        edges = np.linspace(0, rows, nb + 1).astype(int)
        kb = np.array([fit(slice(a, b)) for a, b in zip(edges[:-1], edges[1:])])
        std = kb.std(axis=0, ddof=1) / np.sqrt(nb)
    else:
        std = np.full(n, np.nan)
    if not np.all(np.isfinite(k)) or np.any(k <= 0):
        bad = [f"{nm} {x:.3g}" for nm, x in zip(system.actuator_names, k) if not (np.isfinite(x) and x > 0)]
        raise InputError(f"drive gains from the prior: {', '.join(bad)} (not positive): the currents do not follow the "
                         "nominal model's torques (a sign flipped, columns swapped, or a joint that does not move); "
                         "give robot.drive_gains")
    return {"value": k.tolist(), "std": std.tolist(), "blocks": int(nb), "rows": int(rows),
            "source": "prior: the nominal model's torques fitted to the currents (with friction and offset as "
                      "nuisance terms), interval from contiguous blocks"}
