"""Built-in robots, addressed as ``builtin:<name>``.

Each entry is a small builder module (or a DH TOML file in this folder) documented with
its geometry, parameter values and sources.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources

from dynid.model.robot import JOINT_EXTRAS, RobotModel

__all__ = ["BUILTINS", "build_builtin"]


def _generic6r(extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.model.dh import read_dh_toml

    with resources.as_file(resources.files(__package__) / "generic6r.toml") as path:
        model, nominal, name = read_dh_toml(path)
    return RobotModel(model, name=name, extras=extras, nominal_extras=nominal, source="builtin:generic6r")


def _puma560(extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.model.robots import puma560

    return puma560.build(extras)


BUILTINS: dict[str, Callable[..., RobotModel]] = {
    "puma560": _puma560,
    "generic6r": _generic6r,
}


def build_builtin(name: str, extras: tuple[str, ...] = JOINT_EXTRAS) -> RobotModel:
    from dynid.errors import ModelError

    try:
        builder = BUILTINS[name]
    except KeyError:
        raise ModelError(f"unknown built-in robot {name!r}; available: {', '.join(sorted(BUILTINS))}") from None
    return builder(extras)
