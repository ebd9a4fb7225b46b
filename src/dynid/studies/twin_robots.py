"""Two robots of dynid's own geometry for the independent-engine twins (issue 34, item 6), written
as MJCF files that both dynid (pinocchio's MJCF reader, :mod:`dynid.model.mechanism_files`) and
MuJoCo load, and the prior of each: the same file with every moving body's inertial data off by
a seeded 15 % (:func:`prior_mjcf`).

* :func:`stewart_mjcf`: a 6-UPS Stewart platform. Per leg a universal joint at the base (hinges
  ``u<i>x``, ``u<i>y`` through a ring body), an actuated slide ``leg<i>`` along the leg (cylinder
  below, rod above) and a ball joint at the platform end: leg 1 carries the platform by a
  ``<joint type="ball">`` (dynid reads it as three hinges), legs 2-6 reach it through
  ``<connect>`` closures (a ball joint as a point coincidence). 21 tree joints, 15 closure rows,
  6 degrees of freedom, 6 actuators.
* :func:`planar_mjcf`: a redundantly actuated planar 3-RR robot in the vertical x-z plane
  (gravity does work): three legs (actuated base hinge ``a<i>``, passive elbow ``b<i>``) whose
  distal ends meet at the end-effector point P, carried by leg 1; legs 2 and 3 reach P through
  ``<connect>`` closures (their out-of-plane rows are redundant). 6 tree joints, 2 degrees of
  freedom, 3 actuators; the independent coordinates ``a1 a2`` are written in
  ``<custom><text name="dynid:independent">`` so that ``dynid init`` needs no flag.

Both files are written at the home pose (``qpos0``: every joint at 0, the ball at the identity)
with world-aligned body frames; links are uniform cylinders (inertia about the COM from their
axis, radius and length); joint terms: MuJoCo ``armature`` (rotor inertia), ``damping``
(viscous) and ``frictionloss`` (dry friction) on the actuated joints, a small ``damping`` on the
passive hinges, none on the ball (dynid's viscous term on a ball is per chart angle rate, MuJoCo's
per angular velocity component: equal only at the reference). Loop closures are made stiff in
MuJoCo (``solref``/``solimp`` below) so that its soft constraints approach the rigid ones dynid
models; the simulation step is 0.25 ms (four steps per 1 kHz control period, RK4).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynid._typing import FloatArray

__all__ = ["PRIOR_FRACTION", "PRIOR_SEED", "STEWART", "PLANAR", "stewart_mjcf", "planar_mjcf", "prior_mjcf",
           "inertial_data", "parts", "write_twins"]

PRIOR_FRACTION = 0.15
"""How far the prior is off: 15 % (issue 34 item 6)."""
PRIOR_SEED = 34
"""Seed of the prior's signs (:func:`prior_mjcf`)."""

TIMESTEP = 0.00025
"""MuJoCo's integration step [s]: four steps per 1 kHz control period."""
EQ_SOLREF = "0.0005 1"
"""Closure constraints: time constant 0.5 ms (MuJoCo's floor is two steps), critical damping."""
EQ_SOLIMP = "0.9999 0.9999 0.001"
"""Closure impedance 0.9999: the constraint removes 99.99 % of a violating acceleration per step
(MuJoCo's default 0.9-0.95 leaves the loops visibly soft)."""
FRICTION_SOLREF = "0.0005 1"
"""Dry friction (``frictionloss``) as stiff as the closures: close to dynid's ``fc * sign(v)``."""

STEWART = {
    "base_radius": 0.45, "platform_radius": 0.25, "height": 0.60,
    "base_angles_deg": (15.0, 105.0, 135.0, 225.0, 255.0, 345.0),
    "platform_angles_deg": (35.0, 85.0, 155.0, 205.0, 275.0, 325.0),
    "ring": {"mass": 0.15, "inertia": 2e-4},
    "cylinder": {"mass": 1.2, "radius": 0.035, "fraction": 0.5},  # lower half of the home leg length
    "rod": {"mass": 0.5, "radius": 0.015, "fraction": 0.5},  # upper half
    "platform": {"mass": 4.0, "com": (0.012, -0.008, 0.025),
                 "inertia": (0.085, 0.090, 0.160, 0.004, -0.003, 0.002)},  # ixx iyy izz ixy ixz iyz about the COM
    "slide": {"armature": 0.25, "damping": 6.0, "frictionloss": 1.0, "range": 0.15},
    "hinge_damping": 0.02,
}
"""The Stewart platform's geometry [m, deg] and inertial data [kg, kg m^2]; slide terms in kg,
N s/m, N; hinge damping in N m s/rad."""

PLANAR = {
    "bases": ((-0.30, 0.0), (0.30, 0.0), (0.0, 0.55)),  # (x, z) of the actuated hinges
    "point": (0.0, 0.175),  # P at home
    "elbow_side": (1.0, 1.0, 1.0),  # which of the two elbow positions each leg takes
    "proximal": {"length": 0.25, "mass": 0.6, "radius": 0.015},
    "distal": {"length": 0.30, "mass": 0.4, "radius": 0.012},
    "end_effector": 0.5,  # kg, a point mass at P on leg 1's distal link
    "actuated": {"armature": 0.004, "damping": 0.03, "frictionloss": 0.05, "range": 2.5},
    "passive_damping": 0.003,
}
"""The redundant planar robot's geometry [m] and inertial data [kg]; actuated hinge terms in
kg m^2, N m s/rad, N m."""


def _f(x: float) -> str:
    return f"{float(x):.12g}"


def _v(x: Sequence[float]) -> str:
    return " ".join(_f(v) for v in x)


def _rod_inertia(mass: float, radius: float, length: float, axis: FloatArray) -> FloatArray:
    """Inertia about the COM of a uniform solid cylinder along unit ``axis`` (3x3)."""
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    axial, perp = mass * radius**2 / 2.0, mass * (3.0 * radius**2 + length**2) / 12.0
    return perp * (np.eye(3) - np.outer(u, u)) + axial * np.outer(u, u)


def _full(I: FloatArray) -> str:
    """MJCF ``fullinertia`` (ixx iyy izz ixy ixz iyz)."""
    return _v((I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))


def _inertial(body: ET.Element, mass: float, com: Sequence[float], I: FloatArray) -> None:
    ET.SubElement(body, "inertial", pos=_v(com), mass=_f(mass), fullinertia=_full(I))


def _header(model: str, comment: str) -> ET.Element:
    root = ET.Element("mujoco", model=model)
    root.append(ET.Comment(comment))
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", timestep=_f(TIMESTEP), integrator="RK4", gravity="0 0 -9.81")
    return root


def _text(root: ET.Element) -> str:
    ET.indent(root, "  ")
    return ET.tostring(root, encoding="unicode") + "\n"


def stewart_points() -> tuple[FloatArray, FloatArray]:
    """Base joint centres B (6, 3) and platform ball centres P at home (6, 3), world frame [m]."""
    g = STEWART
    tb, tp = np.radians(g["base_angles_deg"]), np.radians(g["platform_angles_deg"])
    B = np.column_stack([g["base_radius"] * np.cos(tb), g["base_radius"] * np.sin(tb), np.zeros(6)])
    P = np.column_stack([g["platform_radius"] * np.cos(tp), g["platform_radius"] * np.sin(tp), np.full(6, g["height"])])
    return B, P


def _quat(R: FloatArray) -> FloatArray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (MJCF ``quat``)."""
    w = np.sqrt(max(1.0 + np.trace(R), 0.0)) / 2.0
    if w > 1e-6:
        return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    k = int(np.argmax(np.diag(R)))
    i, j = (k + 1) % 3, (k + 2) % 3
    q = np.empty(4)
    q[1 + k] = np.sqrt(max(1.0 + R[k, k] - R[i, i] - R[j, j], 0.0)) / 2.0
    q[0] = (R[j, i] - R[i, j]) / (4 * q[1 + k])
    q[1 + i] = (R[i, k] + R[k, i]) / (4 * q[1 + k])
    q[1 + j] = (R[j, k] + R[k, j]) / (4 * q[1 + k])
    return q


def stewart_leg_frames() -> FloatArray:
    """Per leg the rotation (6, 3, 3) from its own frame to the world's at home: z along the leg
    (base to platform), x horizontal (z_world x leg, normalized), y = z x x. In these frames the six
    legs are the same part: joint axes, placements and inertial data equal, leg by leg."""
    B, P = stewart_points()
    out = np.empty((6, 3, 3))
    for i in range(6):
        z = (P[i] - B[i]) / np.linalg.norm(P[i] - B[i])
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        out[i] = np.column_stack([x, np.cross(z, x), z])
    return out


def stewart_mjcf() -> str:
    """The MJCF text of the 6-UPS Stewart platform (module docstring; :data:`STEWART`).

    Each leg's bodies live in the leg's own frame (:func:`stewart_leg_frames`): universal joint
    ``u<i>x`` then ``u<i>y`` about the frame's x and y, slide ``leg<i>`` along its z, the cylinder
    and the rod uniform, axisymmetric about z; the six legs are identical parts, which a tool that
    looks for identical chains can find. The platform body is world-aligned."""
    g = STEWART
    B, P = stewart_points()
    R = stewart_leg_frames()
    C = np.array([0.0, 0.0, g["height"]])
    root = _header("twin_stewart", " dynid's MuJoCo twin: a 6-UPS Stewart platform (src/dynid/studies/twin_robots.py "
                   "writes this file; examples/mujoco_twins/README.md). ")
    world = ET.SubElement(root, "worldbody")
    base = ET.SubElement(world, "body", name="base")
    ET.SubElement(base, "inertial", pos="0 0 0", mass="5", diaginertia="0.2 0.2 0.4")
    sl = g["slide"]
    rods = []
    z = np.array([0.0, 0.0, 1.0])
    for i in range(6):
        n = i + 1
        L = float(np.linalg.norm(P[i] - B[i]))
        ring = ET.SubElement(base, "body", name=f"ring{n}", pos=_v(B[i]), quat=_v(_quat(R[i])))
        ET.SubElement(ring, "joint", name=f"u{n}x", type="hinge", axis="1 0 0", damping=_f(g["hinge_damping"]))
        ET.SubElement(ring, "inertial", pos="0 0 0", mass=_f(g["ring"]["mass"]),
                      diaginertia=_v([g["ring"]["inertia"]] * 3))
        cyl = ET.SubElement(ring, "body", name=f"cylinder{n}")
        ET.SubElement(cyl, "joint", name=f"u{n}y", type="hinge", axis="0 1 0", damping=_f(g["hinge_damping"]))
        c = g["cylinder"]
        lc = c["fraction"] * L
        _inertial(cyl, c["mass"], 0.5 * lc * z, _rod_inertia(c["mass"], c["radius"], lc, z))
        rod = ET.SubElement(cyl, "body", name=f"rod{n}")
        ET.SubElement(rod, "joint", name=f"leg{n}", type="slide", axis="0 0 1", range=_v((-sl["range"], sl["range"])),
                      armature=_f(sl["armature"]), damping=_f(sl["damping"]), frictionloss=_f(sl["frictionloss"]),
                      solreffriction=FRICTION_SOLREF)
        r = g["rod"]
        lr = r["fraction"] * L
        _inertial(rod, r["mass"], (L - 0.5 * lr) * z, _rod_inertia(r["mass"], r["radius"], lr, z))
        rods.append(rod)
    p = g["platform"]
    plat = ET.SubElement(rods[0], "body", name="platform", pos=_v(R[0].T @ (C - B[0])), quat=_v(_quat(R[0].T)))
    ET.SubElement(plat, "joint", name="ball1", type="ball", pos=_v(P[0] - C))
    ixx, iyy, izz, ixy, ixz, iyz = p["inertia"]
    _inertial(plat, p["mass"], p["com"], np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    eq = ET.SubElement(root, "equality")
    for i in range(1, 6):
        ET.SubElement(eq, "connect", name=f"ball{i + 1}", body1="platform", body2=f"rod{i + 1}", anchor=_v(P[i] - C),
                      solref=EQ_SOLREF, solimp=EQ_SOLIMP)
    act = ET.SubElement(root, "actuator")
    for i in range(6):
        ET.SubElement(act, "motor", name=f"m{i + 1}", joint=f"leg{i + 1}")
    return _text(root)


def planar_elbows(point: Sequence[float]) -> FloatArray:
    """Elbow positions (3, 2) (x, z) [m] of the planar robot with its end-effector at ``point``
    (each leg on its :data:`PLANAR` ``elbow_side``)."""
    g = PLANAR
    l1, l2 = g["proximal"]["length"], g["distal"]["length"]
    P = np.asarray(point, float)
    out = np.empty((3, 2))
    for i, (A, side) in enumerate(zip(np.array(g["bases"]), g["elbow_side"])):
        d = P - A
        r = float(np.linalg.norm(d))
        a = (l1**2 - l2**2 + r**2) / (2.0 * r)
        h = np.sqrt(max(l1**2 - a**2, 0.0))
        e = d / r
        out[i] = A + a * e + side * h * np.array([-e[1], e[0]])
    return out


def _xz(v: Sequence[float]) -> FloatArray:
    return np.array([v[0], 0.0, v[1]])


def planar_mjcf() -> str:
    """The MJCF text of the redundantly actuated planar 3-RR robot (module docstring; :data:`PLANAR`)."""
    g = PLANAR
    A = np.array(g["bases"])
    P = np.array(g["point"])
    E = planar_elbows(P)
    root = _header("twin_planar", " dynid's MuJoCo twin: a redundantly actuated planar 3-RR robot, 3 motors for 2 "
                   "degrees of freedom (src/dynid/studies/twin_robots.py writes this file; examples/mujoco_twins/README.md). ")
    custom = ET.SubElement(root, "custom")
    ET.SubElement(custom, "text", name="dynid:independent", data="a1 a2")
    world = ET.SubElement(root, "worldbody")
    base = ET.SubElement(world, "body", name="base")
    ET.SubElement(base, "inertial", pos="0 0 0", mass="5", diaginertia="0.1 0.1 0.1")
    ac, pr, di = g["actuated"], g["proximal"], g["distal"]
    dist1 = None
    for i in range(3):
        n = i + 1
        prox = ET.SubElement(base, "body", name=f"proximal{n}", pos=_v(_xz(A[i])))
        ET.SubElement(prox, "joint", name=f"a{n}", type="hinge", axis="0 1 0", range=_v((-ac["range"], ac["range"])),
                      armature=_f(ac["armature"]), damping=_f(ac["damping"]), frictionloss=_f(ac["frictionloss"]),
                      solreffriction=FRICTION_SOLREF)
        u = _xz(E[i] - A[i])
        _inertial(prox, pr["mass"], 0.5 * u, _rod_inertia(pr["mass"], pr["radius"], pr["length"], u))
        dist = ET.SubElement(prox, "body", name=f"distal{n}", pos=_v(u))
        ET.SubElement(dist, "joint", name=f"b{n}", type="hinge", axis="0 1 0", damping=_f(g["passive_damping"]))
        w = _xz(P - E[i])
        I = _rod_inertia(di["mass"], di["radius"], di["length"], w)
        if n == 1:  # the end-effector point mass at P
            m, me = di["mass"], g["end_effector"]
            c = (m * 0.5 * w + me * w) / (m + me)
            for mass, pos in ((m, 0.5 * w), (me, w)):  # parallel axes: the rod's COM and the point mass
                r = pos - c
                I = I + mass * (np.dot(r, r) * np.eye(3) - np.outer(r, r))
            _inertial(dist, m + me, c, I)
            dist1 = w
        else:
            _inertial(dist, di["mass"], 0.5 * w, I)
    eq = ET.SubElement(root, "equality")
    for n in (2, 3):
        ET.SubElement(eq, "connect", name=f"P{n}", body1="distal1", body2=f"distal{n}", anchor=_v(dist1),
                      solref=EQ_SOLREF, solimp=EQ_SOLIMP)
    act = ET.SubElement(root, "actuator")
    for n in (1, 2, 3):
        ET.SubElement(act, "motor", name=f"m{n}", joint=f"a{n}")
    return _text(root)


# ---------------------------------------------------------------------------- the prior
def _moving_inertials(root: ET.Element) -> list[tuple[str, ET.Element]]:
    """(body name, <inertial>) of every body with a joint and a positive mass, in file order."""
    out = []
    for body in root.iter("body"):
        inertial = body.find("inertial")
        if body.find("joint") is None or inertial is None or float(inertial.get("mass", "0")) <= 0:
            continue
        out.append((body.get("name", "?"), inertial))
    return out


def _inertia_matrix(el: ET.Element) -> FloatArray:
    if el.get("fullinertia") is not None:
        xx, yy, zz, xy, xz, yz = (float(v) for v in el.get("fullinertia").split())
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return np.diag([float(v) for v in el.get("diaginertia").split()])


def inertial_data(text: str) -> dict[str, tuple[float, FloatArray, FloatArray]]:
    """Per moving body: (mass [kg], COM in the body frame [m] (3,), inertia about the COM [kg m^2]
    (3, 3)) of an MJCF text whose ``<inertial>`` elements have no orientation."""
    root = ET.fromstring(text)
    return {name: (float(el.get("mass")), np.array([float(v) for v in el.get("pos", "0 0 0").split()]),
                   _inertia_matrix(el)) for name, el in _moving_inertials(root)}


def parts(text: str) -> list[int]:
    """Per moving body (file order) the index of its part: bodies with the same inertial data in
    their own frames (mass, COM, inertia equal to 1e-9 relative) are copies of one part, numbered
    in order of first appearance."""
    data = list(inertial_data(text).values())
    out: list[int] = []
    firsts: list[int] = []
    for m, c, I in data:
        for k, f in enumerate(firsts):
            m0, c0, I0 = data[f]
            scale = max(abs(m0), np.abs(c0).max(), np.abs(I0).max())
            if max(abs(m - m0), np.abs(c - c0).max(), np.abs(I - I0).max()) <= 1e-9 * scale:
                out.append(k)
                break
        else:
            out.append(len(firsts))
            firsts.append(len(out) - 1)
    return out


def prior_signs(n_parts: int, seed: int = PRIOR_SEED) -> FloatArray:
    """The prior's signs (n_parts, 7): per part (:func:`parts`), the signs of the mass, the three
    principal second moments and the three COM shifts (NumPy's default generator seeded with
    ``seed``)."""
    return np.random.default_rng(seed).choice([-1.0, 1.0], size=(n_parts, 7))


def prior_mjcf(text: str, fraction: float = PRIOR_FRACTION, seed: int = PRIOR_SEED) -> str:
    """The prior of a robot: its MJCF ``text`` with every moving body's inertial data off by ``fraction``.

    Per moving body (a body with a joint and a positive mass), with the signs ``s`` of
    :func:`prior_signs` for its part (:func:`parts`: the six legs of the Stewart platform are one
    part, each copy as far off as the others, as a CAD model's error is in the part):

    * mass :math:`m' = m (1 + f s_0)`;
    * second moments of the mass distribution about the COM,
      :math:`\\Sigma = \\tfrac12\\mathrm{tr}(I)\\mathbf 1 - I`: principal axes kept, each principal
      value :math:`\\sigma_k' = \\sigma_k (1 + f s_k)`, and the inertia about the COM
      :math:`I' = \\mathrm{tr}(\\Sigma')\\mathbf 1 - \\Sigma'` (positive second moments: a physical
      body, the triangle inequality holds);
    * COM :math:`c'_j = c_j + f\\,k\\,s_{3+j}` per body axis, :math:`k = \\sqrt{\\mathrm{tr}\\,\\Sigma / m}`
      the radius of gyration (a multiplicative change would leave a COM at 0 where it is).

    The rest of the file (geometry, joint terms, closures) is unchanged: a CAD model whose mass
    data are 15 % off, as :func:`dynid.model.base_parameters.perturb_bodies` does with
    Gaussian factors for ``dynid simulate``'s ``perturbation``, here with fixed magnitudes.
    """
    root = ET.fromstring(text)
    bodies = _moving_inertials(root)
    part = parts(text)
    signs = prior_signs(max(part) + 1, seed)[part]
    for (_, el), s in zip(bodies, signs):
        m = float(el.get("mass"))
        c = np.array([float(v) for v in el.get("pos", "0 0 0").split()])
        I = _inertia_matrix(el)
        S = 0.5 * np.trace(I) * np.eye(3) - I
        lam, V = np.linalg.eigh(S)
        S2 = (V * (lam * (1.0 + fraction * s[1:4]))) @ V.T
        I2 = np.trace(S2) * np.eye(3) - S2
        k = np.sqrt(max(np.trace(S), 0.0) / m)
        for key in ("diaginertia", "fullinertia"):
            el.attrib.pop(key, None)
        el.set("mass", _f(m * (1.0 + fraction * s[0])))
        el.set("pos", _v(c + fraction * k * s[4:7]))
        el.set("fullinertia", _full(I2))
    model = root.get("model", "robot")
    root.set("model", f"{model}_prior")
    root.insert(0, ET.Comment(f" PRIOR of {model}: every moving body's mass, principal second moments and COM off by "
                              f"{100 * fraction:g} % (dynid.studies.twin_robots.prior_mjcf, seed {seed}); the rest is "
                              "the robot's file "))
    return _text(root)


def write_twins(folder: str | Path) -> dict[str, Path]:
    """Write ``stewart.xml``, ``stewart_prior.xml``, ``planar.xml``, ``planar_prior.xml`` into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, text in (("stewart", stewart_mjcf()), ("planar", planar_mjcf())):
        for suffix, t in (("", text), ("_prior", prior_mjcf(text))):
            path = folder / f"{name}{suffix}.xml"
            path.write_text(t)
            out[name + suffix] = path
    return out
