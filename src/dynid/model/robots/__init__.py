"""Built-in robots, addressed as ``builtin:<name>``.

Each entry is a small builder module (or a DH TOML file in this folder) documented with
its geometry, parameter values and sources.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources

from dynid.model.robot import JOINT_EXTRAS, RobotModel

__all__ = ["BUILTINS", "MECHANISMS", "build_builtin", "build_mechanism"]


def _generic6r(extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.model.dh import read_dh_toml

    with resources.as_file(resources.files(__package__) / "generic6r.toml") as path:
        model, nominal, name = read_dh_toml(path)
    return RobotModel(model, name=name, extras=extras, nominal_extras=nominal, source="builtin:generic6r")


def _cobot6r(extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.model.dh import read_dh_toml

    with resources.as_file(resources.files(__package__) / "cobot6r.toml") as path:
        model, nominal, name = read_dh_toml(path)
    return RobotModel(model, name=name, extras=extras, nominal_extras=nominal, source="builtin:cobot6r")


def _puma560(extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.model.robots import puma560

    return puma560.build(extras)


BUILTINS: dict[str, Callable[..., RobotModel]] = {
    "puma560": _puma560,
    "generic6r": _generic6r,
    "cobot6r": _cobot6r,
}

MECHANISMS: dict[str, str] = {
    "shang2dof": "planar 2-DOF manipulator with 3 actuators (Shang et al. 2009, paper 001)",
    "rps3": "3-RPS parallel manipulator (paper 000)",
    "hexapod": "6-UPS Stewart-Gough platform modelled as PaLiDA (papers 002, 004)",
    "fivebar": "planar five-bar linkage from an MJCF file (a template for MJCF mechanisms)",
}
"""Built-in closed-loop mechanisms (:class:`~dynid.model.mechanism.Mechanism`)."""


def build_mechanism(name: str):
    """A built-in closed-loop mechanism by name."""
    from importlib import import_module

    from dynid.errors import ModelError

    if name not in MECHANISMS:
        raise ModelError(f"unknown built-in mechanism {name!r}; available: {', '.join(sorted(MECHANISMS))}")
    if name == "fivebar":
        from dynid.model.mechanism_files import load_mechanism_mjcf

        with resources.as_file(resources.files(__package__) / "fivebar.xml") as path:
            mech = load_mechanism_mjcf(path)
        import dataclasses

        return dataclasses.replace(mech, source="builtin:fivebar") if mech.source != "builtin:fivebar" else mech
    return import_module(f"dynid.model.robots.{name}").build()


def build_builtin(name: str, extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.errors import ModelError

    try:
        builder = BUILTINS[name]
    except KeyError:
        if name in MECHANISMS:
            raise ModelError(f"builtin:{name} is a closed-loop mechanism, not a serial robot") from None
        available = ", ".join(sorted([*BUILTINS, *MECHANISMS]))
        raise ModelError(f"unknown built-in robot {name!r}; available: {available}") from None
    return builder(extras)
