"""Charts of a closed-loop mechanism: which of its joints serve as independent coordinates. The
best-conditioned subset of the actuated joints over a set of configurations (:func:`rank_charts`,
:func:`choose_independent`, over a log's samples or :func:`workspace_samples`), and the valid choices
named in an error (:func:`chart_hint`). Functions of a :class:`~dynid.model.mechanism.Mechanism`
``mech`` (its methods call them; this module does not import it, so that the two do not import
each other)."""

from __future__ import annotations

import dataclasses
import itertools
from typing import Any

import numpy as np
import pinocchio as pin
import scipy.linalg as sla

from dynid._typing import FloatArray
from dynid.errors import ModelError
from dynid.model.closures import JointCoordinates

__all__ = ["WORKSPACE_SAMPLES", "check_topology", "workspace_samples", "rank_charts", "choose_independent", "chart_hint"]


WORKSPACE_SAMPLES = 64
"""Configurations of the workspace over which a redundant mechanism's chart is chosen without a log."""


def workspace_samples(mech, q_ref: FloatArray, Jc: FloatArray, data: pin.Data, seed: int = 0) -> FloatArray:
    """Assembled configurations around ``q_ref``: steps along the tangent space of the loops
    (null space of ``Jc``) scaled to a quarter of each joint's range (0.3 rad, or 0.3 of the
    mechanism's length scale for a slide, where the description gives no limits), at random
    fractions of that size, then closed by :meth:`Mechanism._assemble <dynid.model.mechanism.Mechanism._assemble>`; those that cannot close or come
    near a ball joint's singularity are left out. ``q_ref`` first."""
    m = mech.pin_model
    rng = np.random.default_rng(seed)
    N = sla.null_space(Jc)
    lo, hi = mech.position_limits()
    length = max((float(np.linalg.norm(m.jointPlacements[j].translation)) for j in range(1, m.njoints)), default=1.0)
    slide = np.array([m.joints[j].shortname().startswith("JointModelP") for j in range(1, m.njoints)])
    size = np.where(np.isfinite(hi - lo), 0.25 * (hi - lo), np.where(slide, 0.3 * length, 0.3))
    out = [q_ref]
    for _ in range(WORKSPACE_SAMPLES - 1):
        d = N @ rng.standard_normal(N.shape[1])
        d *= rng.uniform() / max(np.max(np.abs(d) / size), 1e-300)
        try:
            qk = mech._assemble(q_ref + d, data)
            mech.check_ball_charts(qk)
        except ModelError:
            continue
        out.append(qk)
    return np.array(out)


def rank_charts(mech, q: FloatArray) -> list[tuple[tuple[int, ...], float]]:
    r"""Subsets of the actuated joints as independent coordinates, best first: each with the
    worst condition number over the configurations ``q`` (n, n_v) of its velocity map.

    With :math:`N(q)` an orthonormal basis of the loops' tangent space (null space of
    :math:`J_c`), the velocity map of the joints :math:`S` is :math:`G = N (S N)^{-1}`
    (:math:`\dot q = G \dot u`), whose condition number is that of :math:`S N`: infinite where
    the joints do not determine the motion. Mixed joint kinds compare rad with m (the
    condition number is not unit-free); the subsets are tried in actuator order, ties keep
    the first."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    data = mech.pin_model.createData()
    bases = [sla.null_space(mech._constraint_jacobian(qk, data)[mech.constraint_rows]) for qk in q]
    out = []
    for combo in itertools.combinations(mech.actuated, mech.mobility):
        worst = 0.0
        for N in bases:
            c = np.linalg.cond(N[list(combo)]) if N.shape[1] == len(combo) else np.inf
            worst = max(worst, c if np.isfinite(c) else np.inf)
        out.append((tuple(int(j) for j in combo), float(worst)))
    return sorted(out, key=lambda t: t[1])


def choice_text(mech, ranked: list[tuple[tuple[int, ...], float]], n: int, over: str) -> str:
    names = mech.pin_model.names
    label = lambda c: "(" + ", ".join(names[j + 1] for j in c) + ")"  # noqa: E731
    others = ", ".join(f"{label(c)} {w:.3g}" for c, w in ranked[1:4])
    return (f"chosen automatically among the actuated joints: the best-conditioned velocity map over {n} {over} "
            f"(worst-case condition number {ranked[0][1]:.3g}" + (f"; next {others}" if others else "") + ")")


def choose_independent(mech, q: FloatArray, over: str = "log samples") -> Any:
    """The same mechanism with the actuated joints whose velocity map is best conditioned over
    the configurations ``q`` (n, n_v) as independent coordinates (:func:`rank_charts`),
    recorded in ``independent_choice``; unchanged when those are already its coordinates
    (the record then says over what they were confirmed)."""
    ranked = rank_charts(mech, q)
    best, worst = ranked[0]
    if not np.isfinite(worst):
        raise ModelError(f"{mech.name!r}: no {mech.mobility} of the actuated joints {mech.actuated_names} determine "
                         f"the motion at every one of the {len(q)} {over}; give [robot] independent")
    return dataclasses.replace(mech, independent=JointCoordinates(best), q_guess=mech.q_ref,
                               independent_choice=choice_text(mech, ranked, len(q), over))


def chart_hint(mech, Jc: FloatArray, mob: int, limit: int = 4, budget: int = 5000) -> str:
    """``"; valid choices ...: [...], [...]"``: sets of ``mob`` joints whose positions are a
    chart at the reference configuration (rank of ``[J_c; S]`` = n_v, condition number below
    1e10), the actuated joints' subsets first, then any joints; at most ``budget`` sets tried."""
    nv = mech.pin_model.nv
    names = mech.pin_model.names
    found: list[list[str]] = []
    tried = 0
    pools = [list(mech.actuated), list(range(nv))]
    seen: set[tuple[int, ...]] = set()
    for pool in pools:
        for combo in itertools.combinations(pool, mob):
            if combo in seen:
                continue
            seen.add(combo)
            tried += 1
            if tried > budget or len(found) >= limit:
                break
            S = np.zeros((mob, nv))
            S[np.arange(mob), list(combo)] = 1.0
            c = np.linalg.cond(np.vstack([Jc, S]))
            if np.isfinite(c) and c <= 1e10:
                found.append([names[j + 1] for j in combo])
        if found:
            break
    if not found:
        return f"; no set of {mob} joint positions tried ({min(tried, budget)}) is a chart here"
    return (f"; give {mob} joints as the independent coordinates ([robot] independent = [...], dynid info --independent), e.g. "
            + ", ".join(str(f) for f in found))


def check_topology(mech, auto: bool = False) -> None:
    """Assemble the loops, find independent constraint rows and check the mobility; ``auto``
    (no independent coordinates given): a redundantly actuated mechanism gets the best
    conditioned subset of its actuated joints over a sample of its workspace
    (:func:`choose_independent`)."""
    m = mech.pin_model
    nv = m.nv
    data = m.createData()
    q0 = pin.neutral(m) if mech.q_guess is None else np.asarray(mech.q_guess, dtype=float)
    if q0.shape != (nv,):
        raise ModelError(f"q_guess must have shape ({nv},), got {q0.shape}")
    q = mech._assemble(q0, data)
    mech.check_ball_charts(q, f"reference configuration of {mech.name!r}")
    object.__setattr__(mech, "q_ref", q)
    object.__setattr__(mech, "constraint_rows", np.arange(sum(c.rows for c in mech.closures)))
    Jc = mech._constraint_jacobian(q, data)
    scale = max(np.abs(Jc).max(), 1e-300)
    _, r, piv = sla.qr(Jc.T / scale, mode="economic", pivoting=True)
    d = np.abs(np.diag(r)) if r.size else np.zeros(0)
    rank = int(np.count_nonzero(d > 1e-9 * (d[0] if d.size else 1.0)))
    rows = np.sort(piv[:rank])
    object.__setattr__(mech, "constraint_rows", rows)
    mob = nv - rank
    object.__setattr__(mech, "mobility", mob)
    if mob <= 0:
        raise ModelError(f"mechanism {mech.name!r} cannot move: the loop closures remove all {nv} degrees of freedom")
    if auto and len(mech.actuated) > mob:
        qs = workspace_samples(mech, q, Jc[rows], data)
        ranked = rank_charts(mech, qs)
        best, worst = ranked[0]
        if np.isfinite(worst) and worst <= 1e8:
            object.__setattr__(mech, "independent", JointCoordinates(best))
            object.__setattr__(mech, "independent_choice", choice_text(mech, ranked, len(qs), "workspace samples"))
    n_u = mech.independent.size
    if len(mech.actuated) < mob:
        raise ModelError(
            f"actuated joints {mech.actuated_names} are fewer than the mobility {mob}: the mechanism is under-actuated"
        )
    if n_u != mob:
        raise ModelError(
            f"mechanism {mech.name!r} has mobility {mob} (n_v {nv} - {rank} independent constraint rows) "
            f"but {n_u} independent coordinates were given{chart_hint(mech, Jc[rows], mob)}"
        )
    Sa = np.zeros((len(mech.actuated), nv))
    Sa[np.arange(len(mech.actuated)), list(mech.actuated)] = 1.0
    ra = np.linalg.matrix_rank(np.vstack([Jc[rows], Sa]), tol=1e-9 * max(1.0, np.abs(Jc).max()))
    if ra < nv:
        raise ModelError(
            f"actuated joints {mech.actuated_names} do not determine the motion: "
            f"{nv - ra} degree(s) of freedom stay free at the reference configuration (mobility {mob})"
        )
    A = np.vstack([Jc[rows], mech._coordinate_jacobian(q, data)])
    cond = np.linalg.cond(A)
    if not np.isfinite(cond) or cond > 1e10:
        given = (f" {[mech.pin_model.names[j + 1] for j in mech.independent.joints]}"
                 if isinstance(mech.independent, JointCoordinates) else "")
        raise ModelError(
            f"the independent coordinates{given} do not determine the motion at the reference configuration "
            f"(condition number of [J_c; J_u] = {cond:.3g}){chart_hint(mech, Jc[rows], mob)}"
        )
