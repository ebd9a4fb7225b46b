"""Exceptions of dynid.

Every error a user can cause (bad file, bad column, bad config key, unidentifiable
parameter, ...) is a :class:`DynidError` whose ``str()`` is one line naming the
problem. The command line prints that line and exits with status 2; library users
catch the specific subclass.
"""

from __future__ import annotations

__all__ = [
    "DynidError",
    "InputError",
    "ConfigError",
    "ModelError",
    "IdentifiabilityError",
    "MissingExtraError",
]


class DynidError(Exception):
    """Base class: a user-facing error with a one-line message."""

    def __str__(self) -> str:  # keep the message on one line, whatever was passed
        return " ".join(str(a) for a in self.args).replace("\n", " ").strip()


class InputError(DynidError, ValueError):
    """Bad data: a missing file or column, NaN/inf, non-monotonic time, wrong shapes."""


class ConfigError(DynidError, ValueError):
    """Bad configuration: unknown keys, wrong types, out-of-range values."""


class ModelError(DynidError, ValueError):
    """Bad robot description or an operation the model does not support."""


class IdentifiabilityError(DynidError):
    """The data do not determine some parameters (their regressor columns are dependent)."""

    def __init__(self, message: str, names: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.names = tuple(names)


class MissingExtraError(DynidError, ImportError):
    """An optional dependency is missing; the message names the extra to install."""


def require(module: str, extra: str):
    """Import an optional module or raise :class:`MissingExtraError` naming the extra."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingExtraError(
            f"{module} is not installed: pip install 'dynid[{extra}]'"
        ) from exc
