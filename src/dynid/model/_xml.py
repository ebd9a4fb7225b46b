"""Low-level helpers of the robot-file readers (:mod:`dynid.model.loading` for serial robots,
:mod:`dynid.model.mechanism_files` for closed-loop mechanisms): XML parsing, the checks of
``<inertial>`` data, URDF ``<dynamics>`` extraction, and the capture of what the C++ parsers
write to stderr.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from dynid.errors import ModelError, ModelWarning, read_file_bytes
from dynid.model.robot import check_inertia, inertia_defect

__all__ = [
    "check_mjcf_inertials",
    "check_urdf_inertials",
    "native_stderr",
    "parse_failure",
    "parse_xml_file",
    "urdf_without_dynamics",
]


@contextlib.contextmanager
def native_stderr() -> Iterator[list[str]]:
    """Collect what C++ code (urdfdom, pinocchio's parsers) writes to file descriptor 2 instead
    of letting it reach the terminal; the yielded list gets its non-empty lines on exit."""
    lines: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no file descriptor 2: nothing to protect
        yield lines
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(x.strip() for x in tmp.read().decode("utf-8", "replace").splitlines() if x.strip())


def parse_failure(exc: BaseException, native: list[str]) -> str:
    """The first meaningful line of a parser failure: urdfdom's own message (``Error: ...``)
    when it wrote one, else the exception's."""
    for line in native:
        text = line.removeprefix("Error:").strip()
        if text and not text.startswith("at line "):
            return text
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _floats(text: str | None, n: int, where: str) -> np.ndarray:
    try:
        values = np.array([float(x) for x in (text or "").split()])
    except ValueError:
        raise ModelError(f"{where}: {text!r} is not {n} number{'s' if n > 1 else ''}") from None
    if values.size != n:
        raise ModelError(f"{where}: {text!r} is not {n} number{'s' if n > 1 else ''}")
    return values


def check_urdf_inertials(root: ET.Element, path: Path) -> list[str]:
    """Check the ``<inertial>`` of every URDF link: refuse a negative or non-finite mass and
    non-finite numbers (:class:`ModelError` naming the link); accept a link whose inertia no rigid
    body can have (not positive semi-definite, or breaking the triangle inequality beyond
    :func:`~dynid.model.robot.inertia_defect`'s tolerance, relative to the link's own inertia
    scale) with one :class:`~dynid.errors.ModelWarning` for that link, and return those links'
    names.

    Vendors ship such files (example-robot-data: dummy base links of 1e-6 kg with moments
    (0, 0, 3e-6) kg*m^2 on ANYmal, Go1, B1, HyQ; Tiago's antennas; PR2's sensor mounts; Allegro's
    distal finger links) and their users cannot fix them. The parameters are identified from data; where a
    physically consistent prior is needed (physically consistent estimation, the export's
    tie-break) the nearest consistent inertia of the link's body (the links pinocchio merges
    into one moving body, summed) is used instead
    (:func:`dynid.model.base_parameters.consistent_parameters`).
    """
    defective: list[str] = []
    for link in root.iter("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        name = link.get("name", "?")
        where = f"{path.name}: link {name!r}"
        mass_el, inertia_el = inertial.find("mass"), inertial.find("inertia")
        mass = _floats(mass_el.get("value") if mass_el is not None else "0", 1, f"{where} <mass value>")[0]
        I = np.zeros((3, 3))
        if inertia_el is not None:
            keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
            v = dict(zip(keys, (_floats(inertia_el.get(k, "0"), 1, f"{where} <inertia {k}>")[0] for k in keys)))
            I = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]], [v["ixz"], v["iyz"], v["izz"]]])
        origin = inertial.find("origin")
        com = _floats(origin.get("xyz", "0 0 0") if origin is not None else "0 0 0", 3, f"{where} <inertial origin xyz>")
        defect = inertia_defect(mass, I, where, com)
        if defect is not None:
            defective.append(name)
            warnings.warn(f"{where}: {defect}; accepted as the file gives it (where a physically consistent prior "
                          "is needed, the nearest consistent inertia of its body is used)", ModelWarning, stacklevel=2)
    return defective


def check_mjcf_inertials(root: ET.Element, path: Path) -> None:
    """Refuse an MJCF body whose ``<inertial>`` no rigid body can have (negative mass, inertia not
    positive semi-definite or breaking the triangle inequality; :func:`~dynid.model.robot.check_inertia`),
    naming it. Unlike a URDF link's, such a body is an error: MuJoCo's own compiler refuses it
    (unless told to balance it), so a file MuJoCo runs has none."""
    for body in root.iter("body"):
        inertial = body.find("inertial")
        if inertial is None:
            continue
        where = f"{path.name}: body {body.get('name', '?')!r}"
        mass = _floats(inertial.get("mass"), 1, f"{where} <inertial mass>")[0]
        if inertial.get("fullinertia") is not None:
            xx, yy, zz, xy, xz, yz = _floats(inertial.get("fullinertia"), 6, f"{where} <inertial fullinertia>")
            I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        else:
            I = np.diag(_floats(inertial.get("diaginertia", "0 0 0"), 3, f"{where} <inertial diaginertia>"))
        com = _floats(inertial.get("pos", "0 0 0"), 3, f"{where} <inertial pos>")
        check_inertia(mass, I, where, com=com)


def parse_xml_file(path: Path) -> ET.Element:
    """The root of an XML robot file (refusing a missing, unreadable or malformed one)."""
    data = read_file_bytes(path, "robot file")
    if not data.strip():
        raise ModelError(f"robot file {path} is empty")
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise ModelError(f"{path}: invalid XML ({exc})") from None


def urdf_without_dynamics(path: Path, check: bool = True) -> tuple[str, dict[str, tuple[float, float]]]:
    """URDF text with ``<dynamics>`` removed, and those values per joint name.

    dynid identifies friction itself; pinocchio 4 refuses URDFs with negative
    ``friction`` (as in identified models), so the tags are taken out before parsing
    and kept as nominal viscous (``damping``) and Coulomb (``friction``) values.
    ``check``: check the links' inertial data (:func:`check_urdf_inertials`: a warning per link
    whose inertia no rigid body can have). A ``<robot>`` without a name (urdfdom refuses it) is
    named after the file (its stem); one without links is refused (no moving joints).
    """
    root = parse_xml_file(path)
    if root.tag != "robot":
        raise ModelError(f"{path}: not a URDF file (its root element is <{root.tag}>, not <robot>)")
    if root.find("link") is None:  # e.g. example-robot-data's ur3.urdf, an empty xacro output
        raise ModelError(f"{path}: the model has no moving joints (the file has no <link>)")
    if not root.get("name", "").strip():  # urdfdom refuses it ("No name given for the robot")
        root.set("name", path.stem)
    if check:
        check_urdf_inertials(root, path)
    found: dict[str, tuple[float, float]] = {}
    for joint in root.iter("joint"):
        for dyn in joint.findall("dynamics"):
            try:
                found[joint.get("name", "")] = (float(dyn.get("damping", 0.0)), float(dyn.get("friction", 0.0)))
            except ValueError:
                raise ModelError(f"{path}: joint {joint.get('name')!r} has a non-numeric <dynamics>") from None
            joint.remove(dyn)
    return ET.tostring(root, encoding="unicode"), found
