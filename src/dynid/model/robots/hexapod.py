"""``builtin:hexapod``: a 6-UPS Stewart–Gough platform modelled like the hexapod PaLiDA of
Abdellatif & Heimann (paper 002, Section 5.1, Fig. 4, Tables 1–2; paper 004, Section 6,
Tables I–II).

Structure (papers 002/004)
--------------------------
19 bodies: the platform E, 6 cardan rings, 6 stators, 6 sliders (electromagnetic linear
direct drives as struts). Per strut j (joints in this order): revolute ``a{j}`` (α_j, about
the base axis x_j, body: cardan ring) → revolute ``b{j}`` (β_j, about the ring axis y,
body: stator) → actuated prismatic ``P{j}`` along the strut (body: slider; ``P{j}`` is the
strut length |A_j B_j| and the slider frame sits at the platform joint B_j, like frame 3 of
Fig. 4). The strut direction is :math:`R_z(\\gamma_j) R_x(\\alpha_j) R_y(\\beta_j) e_z`
(PaLiDA's MDH angles of Fig. 4 differ by constant offsets). The platform is the chain
``PX, PY, PZ, RZ, RY, RX`` (x, y, z, ψ, θ, φ; R = Rz(ψ) Ry(θ) Rx(φ)) with five massless
intermediate bodies; each spherical joint is a ``"3d"`` closure between the slider frame
and B_j: 24 joints, 18 constraint rows, mobility 6; the strut lengths are the independent
coordinates. Gravity: pinocchio's default (0, 0, -9.81), base z up.

Dimensions (our choice: the papers give none)
---------------------------------------------
Base joints A_j at radius 0.40 m, z = 0, angles ±10° about 0°, 120°, 240°; platform joints
B_j at radius 0.09 m, angles ±10° about 60°, 180°, 300°, a height h = 0.1174 m above the
platform frame E (E is the tool point below the joints); strut j joins A_j to the nearest
joint B_j of the neighbouring platform pair (40° apart in angle). Stroke 0.80–1.30 m, |α|, |β| ≤ 60°; home pose
z = 0.85 m (struts ≈ 1.02 m).

Parameters
----------
Body values are our choice, made so that the grouped rigid-body parameters of paper 002,
Table 1 (= paper 004, Table I) take exactly the *a priori* (CAD) values of paper 002,
Table 2 / paper 004, Table II (p5 with the sign of paper 004, which the estimates share):
ring 1.1 kg (centre on the cardan), stator 4.0 kg with centre 0.155 m up the strut, slider
2.0 kg with centre 0.615 m below B, platform 4.19 kg with centre in the joint plane
(see :func:`table1_parameters`). Friction (14 terms, paper 002, Section 5.1): Coulomb of each
actuator ``fc_P{j}`` [N], viscous ``fv_P{j}`` [N·s/m], one Coulomb coefficient shared by the
six α joints ``fc_alpha`` and one by the six β joints ``fc_beta`` [N·m]; nominal values are
the Gauss–Markov estimates of paper 002, Table 2.

Base parameters: 88 by default, the papers' 10 with their assumptions
---------------------------------------------------------------------
:func:`dynid.model.closed_loop.mechanism_base_parameters` finds 88 rigid-body base
parameters (+ the 14 friction terms = 102): 13 per strut (ring: inertia about α grouped
with the axial stator and slider inertias, and the two first moments across α that gravity
reveals since α is horizontal; stator: 5 inertia combinations and the first moments along
the strut and across β; slider: its 3 first moments about B_j) and 10 for the platform
group (platform + the six slider masses at B_j, Steiner). Paper 002's 10 (Table 1) rest on
two modelling assumptions, both checked numerically on the regressor of this model:

* **identical struts** (one set p1–p5 for the six, "6 identical ... cardan rings ...
  stators ... sliders", Section 5.1): tying the six struts' parameters leaves 13 + 10 = 23;
* **symmetric bodies**: no products of inertia, first moments only along the strut and the
  platform's z axis, ring centred on the cardan: keeping only the 15 standard parameters
  of Table 1 (ring Ixx; stator and slider Ixx, Iyy, Izz, mz; slider m; platform m, mz,
  Ixx, Iyy, Izz) leaves exactly 10.

Both are available as structural reductions (:mod:`dynid.model.reduction`, ``[identification]
structure``): the module declares the six struts as identical chains (:data:`IDENTICAL_CHAINS`)
and the symmetric bodies' zeros (:data:`SYMMETRIC_ZERO`: products of inertia, first moments across
the strut, the ring centred on the cardan, the platform's first moments across z). With
``structure = "paper"`` the base parameters are exactly Table 1's p1..p10 (:data:`TABLE1_NAMES`;
the platform, which belongs to no strut, comes first in the reduced vector, so the natural-order
regrouping lumps the slider masses into it as the paper does) and their nominal values are
:data:`A_PRIORI`; with the 14 friction terms, paper 004's 24 rows of Table II.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model.mechanism import JointCoordinates, JointTerm, LoopClosure, Mechanism

__all__ = ["A_PRIORI", "FRICTION", "HOME", "IDENTICAL_CHAINS", "SYMMETRIC_ZERO", "TABLE1_NAMES", "build",
           "chain_from_transform", "inverse_kinematics", "table1_parameters"]

R_BASE, R_PLATFORM = 0.40, 0.09
"""Joint-circle radii of base and platform [m] (our choice)."""
GAMMA_A = np.deg2rad([-10.0, 10.0, 110.0, 130.0, 230.0, 250.0])
GAMMA_B = np.deg2rad([-50.0, 50.0, 70.0, 170.0, 190.0, 290.0])
"""Angular positions of A_j and B_j [rad]; strut j joins A_j and B_j."""
STROKE = (0.80, 1.30)
"""Strut-length limits [m]."""
ANGLE_LIMIT = np.pi / 3
"""Limit of the cardan angles α, β, ±[rad]."""
HOME = np.array([0.0, 0.0, 0.85, 0.0, 0.0, 0.0])
"""Home pose (x, y, z [m], ψ, θ, φ [rad])."""
PLATFORM_JOINTS = ("PX", "PY", "PZ", "RZ", "RY", "RX")

A_PRIORI = (0.0074, 0.9439, 0.9458, 0.6201, -1.2295, 0.2878, 0.2878, 0.1217, 1.9012, 16.1920)
"""p1..p10 a priori (CAD) values, paper 002 Table 2 / paper 004 Table II [kg m², kg m, kg]."""
FRICTION = {
    "fc_alpha": 0.5756,
    "fc_beta": 0.9195,
    "fc": (11.9772, 4.8071, 20.1528, 5.1518, 1.5857, 5.0057),
    "fv": (16.8771, 16.7406, 6.3408, 23.1662, 26.4675, 22.8053),
}
"""Gauss–Markov friction estimates of paper 002, Table 2 [N·m, N, N·s/m]."""

# our body values (see module docstring); strut axis = local z of stator and slider
_M_RING, _M_STATOR, _M_SLIDER = 1.1, 4.0, 2.0
_J_AXIAL = (0.0015, 0.0004)  # stator, slider axial inertia [kg m^2]; p3 - p2 = their sum
_T_STATOR = 0.0533  # stator transverse inertia at its centre of mass [kg m^2]


IDENTICAL_CHAINS = (tuple((f"a{j}", f"b{j}", f"P{j}") for j in range(1, 7)),)
"""The six struts (paper 002, Section 5.1: "6 identical ... cardan rings ... stators ... sliders")."""
SYMMETRIC_ZERO = tuple(
    [f"{p}_a{j}" for j in range(1, 7) for p in ("mx", "my", "mz", "Ixy", "Ixz", "Iyz")]
    + [f"{p}_{b}{j}" for b in ("b", "P") for j in range(1, 7) for p in ("mx", "my", "Ixy", "Ixz", "Iyz")]
    + [f"{p}_RX" for p in ("mx", "my", "Ixy", "Ixz", "Iyz")]
)
"""Parameters zero by the bodies' symmetry (structure ``"paper"``): products of inertia of every body,
first moments across the strut (ring: all three, centred on the cardan) and across the platform's z axis."""
TABLE1_NAMES = ("Ixx_a1..6", "Ixx_b1..6", "Iyy_b1..6", "mz_b1..6", "mz_P1..6", "Ixx_RX", "Iyy_RX", "Izz_RX", "mz_RX", "m_RX")
"""The base parameters p1..p10 of paper 002, Table 1 under ``identification.structure = "paper"``: the
independent parameter each groups (``Ixx_a1..6 + Izz_b1..6 + Izz_P1..6`` = p1, ``m_RX + 6 m_P1..6`` = p10, ...)."""


def _rz(g: float) -> FloatArray:
    return np.array([[np.cos(g), -np.sin(g), 0.0], [np.sin(g), np.cos(g), 0.0], [0.0, 0.0, 1.0]])


def _points(radius: float, angles: FloatArray, z: float) -> FloatArray:
    return np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(angles.shape, z)], -1)


def _height() -> float:
    """Joint plane above E [m]: every mass of the platform group at one height (p9/p10)."""
    return A_PRIORI[8] / A_PRIORI[9]


def _bodies() -> tuple[pin.Inertia, pin.Inertia, pin.Inertia, pin.Inertia]:
    """Ring, stator, slider, platform inertias reproducing :data:`A_PRIORI` exactly."""
    p1, p2, p3, p4, p5, p6, _, p8, p9, p10 = A_PRIORI
    ja2, ja3 = _J_AXIAL
    if abs((p3 - p2) - (ja2 + ja3)) > 1e-12:
        raise ModelError("inconsistent nominal strut inertias")  # pragma: no cover - constants
    i_ring = p1 - ja2 - ja3  # about α (and β); thin ring: about its normal 2x
    ring = pin.Inertia(_M_RING, np.zeros(3), np.diag([i_ring, i_ring, 2 * i_ring]))
    d2, c3 = p4 / _M_STATOR, p5 / _M_SLIDER
    t3 = p3 - (_T_STATOR + _M_STATOR * d2**2) - _M_SLIDER * c3**2  # slider transverse at its centre
    stator = pin.Inertia(_M_STATOR, np.array([0.0, 0.0, d2]), np.diag([_T_STATOR, _T_STATOR, ja2]))
    slider = pin.Inertia(_M_SLIDER, np.array([0.0, 0.0, c3]), np.diag([t3, t3, ja3]))
    h = _height()
    m_e = p10 - 6 * _M_SLIDER
    b = _points(R_PLATFORM, GAMMA_B, h)
    # inertia of E about its frame origin from p6 = p7 and p8, then at its centre of mass (0, 0, h)
    ixx = p6 - _M_SLIDER * np.sum(b[:, 1] ** 2 + b[:, 2] ** 2)
    izz = p8 - _M_SLIDER * np.sum(b[:, 0] ** 2 + b[:, 1] ** 2)
    i_com = np.diag([ixx - m_e * h**2, ixx - m_e * h**2, izz])
    if min(t3, i_com[0, 0], i_com[2, 2]) <= 0 or i_com[2, 2] > 2 * i_com[0, 0]:
        raise ModelError("inconsistent nominal body values")  # pragma: no cover - constants
    platform = pin.Inertia(m_e, np.array([0.0, 0.0, h]), i_com)
    return ring, stator, slider, platform


def build(extras: object = None) -> Mechanism:
    """The hexapod mechanism (``extras`` is accepted for the loader's signature and ignored:
    its 14 joint terms are those of papers 002/004)."""
    model = pin.Model()
    model.name = "hexapod"
    ring, stator, slider, platform = _bodies()
    A = _points(R_BASE, GAMMA_A, 0.0)
    lo, hi = [], []
    for j in range(6):
        ja = model.addJoint(0, pin.JointModelRX(), pin.SE3(_rz(GAMMA_A[j]), A[j]), f"a{j + 1}")
        model.appendBodyToJoint(ja, ring, pin.SE3.Identity())
        jb = model.addJoint(ja, pin.JointModelRY(), pin.SE3.Identity(), f"b{j + 1}")
        model.appendBodyToJoint(jb, stator, pin.SE3.Identity())
        jp = model.addJoint(jb, pin.JointModelPZ(), pin.SE3.Identity(), f"P{j + 1}")
        model.appendBodyToJoint(jp, slider, pin.SE3.Identity())
        lo += [-ANGLE_LIMIT, -ANGLE_LIMIT, STROKE[0]]
        hi += [ANGLE_LIMIT, ANGLE_LIMIT, STROKE[1]]
    parent, massless = 0, []
    joint_models = (pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ, pin.JointModelRZ, pin.JointModelRY, pin.JointModelRX)
    for name, jm in zip(PLATFORM_JOINTS, joint_models):
        parent = model.addJoint(parent, jm(), pin.SE3.Identity(), name)
        if name != "RX":
            model.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
            massless.append(parent)
    model.appendBodyToJoint(parent, platform, pin.SE3.Identity())
    lo += [-0.3, -0.3, 0.5, -np.pi / 3, -np.pi / 3, -np.pi / 3]
    hi += [0.3, 0.3, 1.3, np.pi / 3, np.pi / 3, np.pi / 3]
    model.lowerPositionLimit = np.array(lo)
    model.upperPositionLimit = np.array(hi)
    b = _points(R_PLATFORM, GAMMA_B, _height())
    closures = tuple(
        LoopClosure(f"S{j + 1}", 3 * j + 3, pin.SE3.Identity(), parent, pin.SE3(np.eye(3), b[j]), "3d") for j in range(6)
    )
    terms = [JointTerm("fc_alpha", "coulomb", tuple(3 * j for j in range(6))), JointTerm("fc_beta", "coulomb", tuple(3 * j + 1 for j in range(6)))]
    nominal = {"fc_alpha": FRICTION["fc_alpha"], "fc_beta": FRICTION["fc_beta"]}
    for kind, key in (("coulomb", "fc"), ("viscous", "fv")):
        for j in range(6):
            terms.append(JointTerm(f"{key}_P{j + 1}", kind, (3 * j + 2,)))
            nominal[f"{key}_P{j + 1}"] = FRICTION[key][j]
    actuated = tuple(3 * j + 2 for j in range(6))
    return Mechanism(
        model,
        closures,
        actuated=actuated,
        independent=JointCoordinates(actuated),
        terms=tuple(terms),
        massless=tuple(massless),
        nominal_terms=nominal,
        q_guess=inverse_kinematics(HOME[None])[0],
        name="hexapod",
        source="builtin:hexapod",
        task_coordinates=PLATFORM_JOINTS,
        task_ik=inverse_kinematics,
        identical_chains=IDENTICAL_CHAINS,
        symmetric_zero=SYMMETRIC_ZERO,
        notes=(
            "6-UPS hexapod modelled like PaLiDA (papers 002/004): 19 bodies, cardan ring + stator + slider per strut",
            "dimensions are our choice; body values reproduce the a priori p1..p10 of paper 002, Table 2",
            "14 friction terms: Coulomb + viscous per actuator, one Coulomb shared by all α and one by all β joints",
            "each strut its own parameters: 88 rigid-body base parameters (identification.structure = 'full'); the six "
            "struts tied: 23 ('identical_chains'; the default 'auto' ties them unless the training log rejects it); "
            "'paper' also fixes the symmetric bodies' zeros: the papers' 10 (Table 1)",
        ),
    )


def chain_from_transform(position: FloatArray, rotation: FloatArray) -> FloatArray:
    """Platform-chain values (x, y, z, ψ, θ, φ) of a pose given as position and rotation.

    Parameters
    ----------
    position : array, shape (n, 3) [m]
    rotation : array, shape (n, 3, 3)
        Rotation of the platform frame E; decomposed as Rz(ψ) Ry(θ) Rx(φ), |θ| < π/2.

    Returns
    -------
    array, shape (n, 6)
    """
    p = np.atleast_2d(np.asarray(position, dtype=float))
    R = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    if p.shape != (R.shape[0], 3):
        raise InputError(f"positions {p.shape} and rotations {R.shape} do not match")
    psi = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    th = np.arctan2(-R[:, 2, 0], np.hypot(R[:, 0, 0], R[:, 1, 0]))
    ph = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    return np.column_stack([p, psi, th, ph])


def _rotations(chain: FloatArray) -> FloatArray:
    """R = Rz(ψ) Ry(θ) Rx(φ) per row of ``chain`` (n, 6), shape (n, 3, 3)."""
    cs, ss, ct, st, cp, sp = (f(chain[:, k]) for k in (3, 4, 5) for f in (np.cos, np.sin))
    return np.stack(
        [
            np.stack([cs * ct, cs * st * sp - ss * cp, cs * st * cp + ss * sp], -1),
            np.stack([ss * ct, ss * st * sp + cs * cp, ss * st * cp - cs * sp], -1),
            np.stack([-st, ct * sp, ct * cp], -1),
        ],
        1,
    )


def inverse_kinematics(pose: FloatArray) -> FloatArray:
    """All 24 joint positions from the platform pose (closed form).

    With :math:`d_j = p + R\\,b_j - A_j` in the base frame of strut j
    (:math:`R_z(\\gamma_j)^T d_j = l_j [\\sin\\beta_j, -\\sin\\alpha_j\\cos\\beta_j, \\cos\\alpha_j\\cos\\beta_j]`):
    :math:`l_j = |d_j|`, :math:`\\alpha_j = \\mathrm{atan2}(-d_y, d_z)`,
    :math:`\\beta_j = \\mathrm{atan2}(d_x, \\sqrt{d_y^2 + d_z^2})`.

    Parameters
    ----------
    pose : array, shape (n, 6)
        x, y, z [m], ψ, θ, φ [rad]: the platform-chain values (see :func:`chain_from_transform`).

    Returns
    -------
    array, shape (n, 24)
        ``[a1, b1, P1, ..., a6, b6, P6, x, y, z, ψ, θ, φ]``.

    Raises
    ------
    ModelError
        When a strut length leaves the stroke or a cardan angle its limit.
    """
    pose = np.atleast_2d(np.asarray(pose, dtype=float))
    if pose.ndim != 2 or pose.shape[1] != 6:
        raise InputError(f"hexapod pose must have shape (n, 6) (x, y, z, ψ, θ, φ), got {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise InputError("hexapod pose contains NaN or infinite values")
    R = _rotations(pose)
    A = _points(R_BASE, GAMMA_A, 0.0)
    b = _points(R_PLATFORM, GAMMA_B, _height())
    out = np.empty((pose.shape[0], 24))
    out[:, 18:] = pose
    for j in range(6):
        d = (pose[:, :3] + R @ b[j] - A[j]) @ _rz(GAMMA_A[j])  # = (Rz^T d^T)^T
        length = np.linalg.norm(d, axis=1)
        alpha = np.arctan2(-d[:, 1], d[:, 2])
        beta = np.arctan2(d[:, 0], np.hypot(d[:, 1], d[:, 2]))
        for values, lo, hi, what, unit in (
            (length, *STROKE, f"strut {j + 1} length", "m"),
            (alpha, -ANGLE_LIMIT, ANGLE_LIMIT, f"cardan angle a{j + 1}", "rad"),
            (beta, -ANGLE_LIMIT, ANGLE_LIMIT, f"cardan angle b{j + 1}", "rad"),
        ):
            bad = (values < lo) | (values > hi)
            if np.any(bad):
                k = int(np.argmax(bad))
                raise ModelError(
                    f"hexapod pose {np.array2string(pose[k], precision=4)} is unreachable: "
                    f"{what} {values[k]:.4f} {unit} is outside [{lo:.4f}, {hi:.4f}] {unit}"
                )
        out[:, 3 * j : 3 * j + 3] = np.column_stack([alpha, beta, length])
    return out


def table1_parameters(params: FloatArray) -> FloatArray:
    """Paper 002's Table 1 combinations p1..p10 from standard parameters of :func:`build`.

    Strut combinations (p1–p5) are averaged over the six struts (identical in the papers);
    platform ones use each slider's own mass. Axes: α = ring x, β = stator y, strut = z.
    """
    params = np.asarray(params, dtype=float)
    blocks = params[: 19 * 10].reshape(19, 10)  # bodies: 6 x (ring, stator, slider), platform
    ring, stator, slider, plat = blocks[0:18:3], blocks[1:18:3], blocks[2:18:3], blocks[18]
    # columns: m mx my mz Ixx Ixy Iyy Ixz Iyz Izz
    p1 = ring[:, 4] + stator[:, 9] + slider[:, 9]
    p2 = stator[:, 4] + slider[:, 4] - stator[:, 9] - slider[:, 9]
    p3 = stator[:, 6] + slider[:, 6]
    b = _points(R_PLATFORM, GAMMA_B, _height())
    m3 = slider[:, 0]
    p6 = plat[4] + m3 @ (b[:, 1] ** 2 + b[:, 2] ** 2)
    p7 = plat[6] + m3 @ (b[:, 0] ** 2 + b[:, 2] ** 2)
    p8 = plat[9] + m3 @ (b[:, 0] ** 2 + b[:, 1] ** 2)
    p9 = plat[3] + m3 @ b[:, 2]
    p10 = plat[0] + m3.sum()
    return np.array([p1.mean(), p2.mean(), p3.mean(), stator[:, 3].mean(), slider[:, 3].mean(), p6, p7, p8, p9, p10])
