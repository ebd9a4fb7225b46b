"""Exceptions of dynid.

Every error a user can cause (bad file, bad column, bad config key, unidentifiable
parameter, ...) is a :class:`DynidError` whose ``str()`` is one line naming the
problem. The command line prints that line and exits with status 2; library users
catch the specific subclass.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "DynidError",
    "InputError",
    "ConfigError",
    "ModelError",
    "IdentifiabilityError",
    "MissingExtraError",
    "DynidWarning",
    "ModelWarning",
    "decode_text",
    "existing_file",
    "read_file_bytes",
    "read_file_text",
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


class DynidWarning(UserWarning):
    """Base class of dynid's warnings: something accepted that the user should know about, in one
    line (the command line prints it as ``dynid: warning: ...`` on stderr)."""


class ModelWarning(DynidWarning):
    """A robot description accepted with a defect its user cannot fix (a vendor's file), e.g. a
    link whose inertial data no rigid body can have."""


def require(module: str, extra: str):
    """Import an optional module or raise :class:`MissingExtraError` naming the extra."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingExtraError(
            f"{module} is not installed: pip install 'dynid[{extra}]'"
        ) from exc


# ---------------------------------------------------------------------- user files
def existing_file(path: str | Path, what: str) -> Path:
    """``path`` when it names an existing regular file, else an :class:`InputError` that says
    what is there instead (nothing, a folder, a device) and names ``what`` (``"config file"``)."""
    p = Path(path)
    try:
        if p.is_file():
            return p
        if p.is_dir():
            raise InputError(f"{what} {p} is a folder, not a file")
        if p.exists():
            raise InputError(f"{what} {p} is not a regular file")
    except OSError as exc:  # e.g. a name too long for the file system
        raise InputError(f"{what} {p}: {exc.strerror or exc}") from None
    blocker = next((a for a in p.parents if a.exists() and not a.is_dir()), None)
    if blocker is not None:
        raise InputError(f"{what} not found: {p} ({blocker} is a file, not a folder)")
    raise InputError(f"{what} not found: {p}")


def read_file_bytes(path: str | Path, what: str) -> bytes:
    """The content of a user's file, or a one-line :class:`InputError` (missing, a folder,
    unreadable: permission, I/O error)."""
    p = existing_file(path, what)
    try:
        return p.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {what} {p}: {exc.strerror or exc}") from None


def decode_text(data: bytes, path: str | Path, what: str, error: type[DynidError] = InputError) -> str:
    """``data`` (the content of ``path``) as UTF-8 text, a leading byte-order mark dropped, or a
    one-line ``error`` (binary, not UTF-8)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {Path(path)} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"
                    + ("; it looks binary" if b"\0" in data[:4096] else "")) from None
    if "\0" in text:
        raise error(f"{what} {Path(path)} is not a text file (it contains NUL bytes)")
    return text.removeprefix("\ufeff")


def read_file_text(path: str | Path, what: str) -> str:
    """The UTF-8 text of a user's file (see :func:`read_file_bytes` and :func:`decode_text`)."""
    return decode_text(read_file_bytes(path, what), path, what)
