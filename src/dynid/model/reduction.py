"""Structural reduction of a mechanism's standard parameters: :math:`\\pi = T\\psi`.

Papers 002 (Section 5.1, Table 1) and 004 (Table I) identify the hexapod PaLiDA with 10
rigid-body parameters instead of the ~88 of its 19 bodies, under two modelling assumptions:

* **identical kinematic chains** ("6 identical ... cardan rings ... stators ... sliders",
  paper 002, Section 5.1): corresponding bodies of identical chains have the same inertial
  parameters, each **expressed in its own body frame** (joint frame, pinocchio's order
  ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``). One block :math:`\\psi_g` of 10
  parameters then stands for the bodies of group ``g``, :math:`\\pi_b = \\psi_g` for each
  of them;
* **symmetric bodies** (structure ``"paper"``): the parameters a robot's description declares
  zero by symmetry (products of inertia, first moments off the body's axis: for the hexapod
  the parameters outside paper 002's Table 1) are fixed at 0. Their columns of :math:`T` are
  zero; they stay in :math:`\\psi` so that every body keeps its 10-parameter block (physical
  consistency, :class:`~dynid.model.base_parameters.StandardMap` ``zero``).

Joint terms (friction, rotor inertia, offsets) are not tied: the papers identify the friction
of each actuator. The zeros are held by the SDP of physically consistent fits
(:mod:`dynid.estimation.physical`) and by the feasibility check; the Stribeck fit's log-Cholesky
body parametrization (:mod:`dynid.estimation.nonlinear`) does not hold them (its bodies are
consistent, the zeros free, as any parameter outside the base combinations). The reduced regressor is :math:`Y T` (:math:`Y\\pi = Y T\\psi`); its base
parameters are computed like any other (:func:`dynid.model.closed_loop.mechanism_base_parameters`,
on constraint-consistent samples). :meth:`ParameterReduction.reduce` maps a full standard vector
to :math:`\\psi` (the mean over tied bodies: :math:`T^+\\pi`, exact when :math:`\\pi` satisfies
the assumptions).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence

import numpy as np

from dynid._typing import FloatArray, IntArray
from dynid.errors import ConfigError, ModelError
from dynid.model.mechanism import Mechanism
from dynid.model.robot import BODY_PARAMS

__all__ = ["CHAIN_TOL", "STRUCTURES", "ParameterReduction", "chain_groups", "detect_identical_chains", "reduce_mechanism"]

STRUCTURES = ("full", "identical_chains", "paper")
"""``full``: every body its own parameters; ``identical_chains``: corresponding bodies of identical
chains share theirs; ``paper``: identical chains plus the description's symmetric-body zeros.
(``identification.structure = "auto"`` chooses between ``full`` and ``identical_chains`` from the
data: :mod:`dynid.pipeline.structure`.)"""

CHAIN_TOL = 1e-6
"""Relative tolerance within which two nominal bodies, joint axes and joint placements are called
identical. A description written with 6 significant digits (``%g``, the usual CAD/URDF/MJCF
export) rounds every value by up to 5e-7 relative: identical legs written that way must still
match; a difference of 1e-6 of a body's mass or inertia is far below what any identification
resolves (relative standard deviations of 1e-3 and more), so tying such bodies costs nothing."""


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterReduction:
    """The linear map :math:`\\pi = T\\psi` of a mechanism's standard parameters (module docstring).

    Attributes
    ----------
    structure : str
        ``"identical_chains"`` or ``"paper"``.
    chains : tuple of tuple of tuple of str
        Groups of identical chains, each chain the names of its joints in corresponding order.
    names : tuple of str
        Names of :math:`\\psi`: a tied body is named by its joints, e.g. ``Ixx_a1..6``.
    T : array, shape (p, p_psi)
        Embedding; columns of the parameters fixed at zero are zero.
    body_blocks : tuple of int arrays (10,)
        Indices in :math:`\\psi` of each body block.
    zero : int array
        Indices in :math:`\\psi` fixed at zero (structure ``"paper"``).
    n_body_params : int
        Body parameters in :math:`\\psi` (joint terms follow, in the mechanism's order).
    """

    structure: str
    chains: tuple[tuple[tuple[str, ...], ...], ...]
    names: tuple[str, ...]
    T: FloatArray
    body_blocks: tuple[IntArray, ...]
    zero: IntArray
    n_body_params: int

    def __post_init__(self) -> None:
        for f in ("T", "zero"):
            a = np.array(getattr(self, f))
            a.setflags(write=False)
            object.__setattr__(self, f, a)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def expand(self, psi: FloatArray) -> FloatArray:
        """The full standard vector :math:`T\\psi` (last axis)."""
        psi = np.asarray(psi, dtype=float)
        if psi.shape[-1] != self.n_params:
            raise ModelError(f"expected {self.n_params} reduced parameters, got {psi.shape[-1]}")
        return psi @ self.T.T

    def reduce(self, pi: FloatArray) -> FloatArray:
        """:math:`\\psi = T^+\\pi` (last axis): tied bodies averaged, zero-fixed parameters 0."""
        pi = np.asarray(pi, dtype=float)
        if pi.shape[-1] != self.T.shape[0]:
            raise ModelError(f"expected {self.T.shape[0]} standard parameters, got {pi.shape[-1]}")
        # T has orthogonal columns (each a sum of unit vectors on disjoint rows): T^+ = D^-1 T^T
        counts = np.sum(self.T, axis=0)
        return (pi @ self.T) / np.where(counts > 0, counts, 1.0)

    def describe(self) -> dict:
        return {"structure": self.structure, "identical_chains": [[list(c) for c in g] for g in self.chains],
                "n_params": self.n_params, "n_fixed_zero": int(self.zero.size)}


def _compact(joints: Sequence[str]) -> str:
    """``a1..6`` for ``a1, ..., a6`` (one prefix, consecutive numbers), else ``a1|x2``."""
    parts = [re.fullmatch(r"(.*?)(\d+)", j) for j in joints]
    if all(parts) and len({p.group(1) for p in parts}) == 1:  # type: ignore[union-attr]
        nums = [int(p.group(2)) for p in parts]  # type: ignore[union-attr]
        if nums == list(range(nums[0], nums[0] + len(nums))):
            return f"{joints[0]}..{nums[-1]}"
    return "|".join(joints)


def chain_groups(spec) -> tuple[tuple[tuple[str, ...], ...], ...]:
    """Groups of chains from ``identical_chains``: one group ``[["a1", "b1"], ["a2", "b2"]]`` or
    several ``[[["a1", "b1"], ["a2", "b2"]], [["c1"], ["c2"]]]``."""
    if not isinstance(spec, (list, tuple)) or not spec:
        raise ConfigError("identification.identical_chains must be a non-empty list of chains (lists of joint names)")
    depth3 = all(isinstance(c, (list, tuple)) and c and isinstance(c[0], (list, tuple)) for c in spec)
    groups = spec if depth3 else [spec]
    out = []
    for g in groups:
        if not isinstance(g, (list, tuple)) or len(g) < 2:
            raise ConfigError(f"identification.identical_chains: a group needs at least two chains, got {g!r}")
        chains = []
        for c in g:
            if not isinstance(c, (list, tuple)) or not c or not all(isinstance(j, str) for j in c):
                raise ConfigError(f"identification.identical_chains: a chain is a list of joint names, got {c!r}")
            chains.append(tuple(c))
        out.append(tuple(chains))
    return tuple(out)


def _motion_axis(m, j: int) -> FloatArray:
    """The 1-DOF joint's motion subspace (6,) in its own frame (linear, angular)."""
    jm = m.joints[j]
    jd = jm.createData()
    jm.calc(jd, np.zeros(jm.nq))
    return np.asarray(jd.S, dtype=float).ravel()


def _body_scales(pa: FloatArray, pb: FloatArray) -> FloatArray:
    """Per-parameter magnitude of two body blocks ``[m, mc(3), I(6)]``: the mass, the first moments'
    largest or sqrt(m * I_max) (kg m), the inertias' largest, so that a zero first moment rounded to
    1e-9 in one file is not called a difference."""
    m = max(abs(pa[0]), abs(pb[0]))
    inertia = max(np.abs(pa[4:]).max(), np.abs(pb[4:]).max())
    first = max(np.abs(pa[1:4]).max(), np.abs(pb[1:4]).max(), np.sqrt(m * inertia))
    return np.array([m, first, first, first, *[inertia] * 6])


def _mismatch(mech: Mechanism, a: int, b: int, first: bool, length: float, tol: float = CHAIN_TOL) -> str | None:
    """Why pinocchio joints ``a`` and ``b`` (corresponding joints of two chains) differ, or None:
    joint type and motion axis in the joint's own frame; unless ``first`` (the chain's own frame,
    free), the placement in the previous joint's frame (rotation to ``tol``, translation to
    ``tol * length``); the bodies (massless or not, inertial parameters in their own frames to
    ``tol`` of :func:`_body_scales`)."""
    m = mech.pin_model
    ka, kb = m.joints[a].shortname(), m.joints[b].shortname()
    if ka != kb or np.abs(_motion_axis(m, a) - _motion_axis(m, b)).max() > tol:
        return f"joint types or axes differ ({ka} against {kb})"
    if not first:
        Ma, Mb = m.jointPlacements[a], m.jointPlacements[b]
        if (np.abs(Ma.rotation - Mb.rotation).max() > tol
                or np.abs(Ma.translation - Mb.translation).max() > tol * max(length, 1e-300)):
            return "their placements in the previous joint's frame differ"
    ma, mb = a in mech.massless, b in mech.massless
    pa, pb = m.inertias[a].toDynamicParameters(), m.inertias[b].toDynamicParameters()
    if ma != mb or np.any(np.abs(pa - pb) > tol * np.maximum(_body_scales(pa, pb), 1e-300)):
        return "their bodies differ in the nominal model (own frames)"
    return None


def _chain_length(mech: Mechanism, chains: Sequence[Sequence[int]]) -> float:
    """Length scale [m] of a set of chains: their largest joint-to-joint translation."""
    m = mech.pin_model
    return max((float(np.linalg.norm(m.jointPlacements[j].translation)) for c in chains for j in c), default=1.0)


def _check_chains(mech: Mechanism, groups) -> list[list[list[int]]]:
    """pinocchio joint indices of every chain, checked (one-line ConfigError naming the cause)."""
    m = mech.pin_model
    names = list(m.names)
    seen: dict[str, int] = {}
    idx_groups = []
    for gi, group in enumerate(groups):
        n0 = len(group[0])
        idx_chains = []
        for chain in group:
            unknown = [j for j in chain if j not in names[1:]]
            if unknown:
                raise ConfigError(f"identification.identical_chains: {unknown} are not joints of {mech.name!r} "
                                  f"(joints: {', '.join(names[1:])})")
            if len(chain) != n0:
                raise ConfigError(f"identification.identical_chains: chain {list(chain)} has {len(chain)} joints, "
                                  f"chain {list(group[0])} has {n0}")
            for j in chain:
                if j in seen:
                    raise ConfigError(f"identification.identical_chains: joint {j!r} is in more than one chain")
                seen[j] = gi
            idx_chains.append([names.index(j) for j in chain])
        ref = idx_chains[0]
        length = _chain_length(mech, idx_chains)
        for chain, idx in zip(group[1:], idx_chains[1:]):
            for k, (a, b) in enumerate(zip(ref, idx)):
                # a named chain's joints need not follow each other in the tree: only the types and bodies are checked
                why = _mismatch(mech, a, b, True, length)
                if why is not None:
                    raise ConfigError(f"identification.identical_chains: joint {names[b]!r} does not match joint "
                                      f"{names[a]!r} of chain {list(group[0])}: {why}; chains {list(chain)} and "
                                      f"{list(group[0])} are not identical")
        idx_groups.append(idx_chains)
    return idx_groups


def detect_identical_chains(mech: Mechanism, tol: float = CHAIN_TOL) -> tuple[tuple[tuple[str, ...], ...], ...]:
    """Groups of identical kinematic chains found in the description.

    A chain is a path of the kinematic tree that starts at a child of a branching body (a body
    with two or more child joints: the base of a parallel robot) and follows single children
    until the tree branches or ends. Two sibling chains are identical over the length of the
    shorter when their corresponding joints have the same type and axis in their own frames,
    the same placements relative to the previous joint (the first joint's placement, which
    puts the chain on the base, is free: that is the chain's local frame) and the same bodies
    in their own frames, all within ``tol`` (:data:`CHAIN_TOL`, relative; :func:`_mismatch`).
    A longer chain (the leg that carries the platform) contributes its first joints. Groups
    without a body with mass are dropped (nothing to tie).

    Returns
    -------
    tuple of groups, each a tuple of chains (joint names in corresponding order), as
    :func:`chain_groups` returns them; empty when there is none.
    """
    m = mech.pin_model
    children: dict[int, list[int]] = {}
    for j in range(1, m.njoints):
        children.setdefault(int(m.parents[j]), []).append(j)
    groups_out = []
    for node in sorted(children):
        kids = children[node]
        if len(kids) < 2:
            continue
        paths = []
        for c in kids:
            path = [c]
            while len(children.get(path[-1], ())) == 1:
                path.append(children[path[-1]][0])
            paths.append(path)
        groups: list[list[list[int]]] = []  # each: chains (joint indices), the first the reference
        for path in paths:
            for g in groups:
                n = min(len(g[0]), len(path))
                length = _chain_length(mech, [g[0][:n], path[:n]])
                if all(_mismatch(mech, a, b, k == 0, length, tol) is None for k, (a, b) in enumerate(zip(g[0][:n], path[:n]))):
                    g.append(path)
                    break
            else:
                groups.append([path])
        for g in groups:
            n = min(len(c) for c in g)
            if len(g) >= 2 and any(j not in mech.massless for j in g[0][:n]):
                groups_out.append(tuple(tuple(m.names[j] for j in c[:n]) for c in g))
    return tuple(groups_out)


def reduce_mechanism(mech: Mechanism, structure: str, chains=None) -> ParameterReduction | None:
    """The reduction of ``mech`` for ``structure`` (None for ``"full"``).

    Parameters
    ----------
    mech : Mechanism
    structure : {"full", "identical_chains", "paper"}
    chains : groups of chains, optional
        As :func:`chain_groups` returns; default: the mechanism's own ``identical_chains``
        (declared by the built-ins from their symmetry), else those found in its description
        (:func:`detect_identical_chains`).

    Raises
    ------
    ConfigError
        Unknown structure or joints, chains of different lengths or joint types, bodies that
        are not identical in the nominal model, no identical chains (named, declared by the
        mechanism or found by :func:`detect_identical_chains`).
    """
    if structure not in STRUCTURES:
        raise ConfigError(f"identification.structure = {structure!r}; choose from {list(STRUCTURES)}")
    if structure == "full":
        if chains:
            raise ConfigError("identification.identical_chains needs identification.structure = "
                              "'identical_chains' or 'paper'")
        return None
    groups = chain_groups(chains) if chains else (tuple(mech.identical_chains) or detect_identical_chains(mech))
    if not groups:
        raise ConfigError(f"identification.structure = {structure!r}: {mech.name!r} declares no identical chains and none "
                          f"are found in its description (same joints and bodies to {CHAIN_TOL:g}); name them in "
                          "identification.identical_chains")
    if structure == "paper" and not mech.symmetric_zero:
        raise ConfigError(f"identification.structure = 'paper': {mech.name!r} declares no symmetric-body "
                          "simplification (only the built-in hexapod does); use 'identical_chains'")
    idx_groups = _check_chains(mech, groups)
    body_pos = {j: k for k, j in enumerate(mech.bodies)}
    rep: dict[int, tuple[int, str]] = {}  # body joint -> (representative body joint, label)
    for group, idx in zip(groups, idx_groups):
        for k in range(len(idx[0])):
            members = [c[k] for c in idx]
            if members[0] not in body_pos:
                continue  # massless bodies (checked identical): nothing to tie
            label = _compact([c[k] for c in group])
            for j in members:
                rep[j] = (members[0], label)
    p, nb = mech.n_standard_params, mech.n_body_params
    names, cols = [], {}  # cols: representative body joint -> psi block start
    T_cols: list[list[int]] = []  # per psi body block: the full body positions it stands for
    # bodies of no chain (the platform) first, then one block per group of tied bodies: the natural-order
    # regrouping of the base parameters then lumps the chain ends' masses into the platform (Steiner), as
    # papers 002/004 do (Table 1: p6-p10 are the platform's with the six slider masses)
    for j in sorted(mech.bodies, key=lambda j: (j in rep, body_pos[j])):
        r, label = rep.get(j, (j, mech.body_label(j)))
        if r in cols:
            T_cols[cols[r] // 10].append(body_pos[j])
            continue
        cols[r] = 10 * len(T_cols)
        T_cols.append([body_pos[j]])
        names += [f"{q}_{label}" for q in BODY_PARAMS]
    nb_psi = 10 * len(T_cols)
    n_terms = p - nb
    T = np.zeros((p, nb_psi + n_terms))
    for b, members in enumerate(T_cols):
        for k in members:
            T[10 * k : 10 * k + 10, 10 * b : 10 * b + 10] = np.eye(10)
    T[nb:, nb_psi:] = np.eye(n_terms)
    names += list(mech.parameter_names[nb:])
    zero = np.zeros(0, dtype=int)
    if structure == "paper":
        full_zero = {mech.parameter_names.index(n) for n in mech.symmetric_zero}
        z = []
        for c in range(nb_psi):
            rows = set(np.flatnonzero(T[:, c]).tolist())
            if rows <= full_zero:
                z.append(c)
            elif rows & full_zero:
                raise ConfigError(f"{mech.name!r}: the symmetric-body zeros of {names[c]!r} differ between tied bodies")
        zero = np.array(z, dtype=int)
        T[:, zero] = 0.0
    blocks = tuple(np.arange(10 * b, 10 * b + 10) for b in range(len(T_cols)))
    return ParameterReduction(structure=structure, chains=tuple(groups), names=tuple(names), T=T,
                              body_blocks=blocks, zero=zero, n_body_params=nb_psi)
