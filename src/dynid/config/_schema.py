"""Building blocks of the strict TOML schemas of :mod:`dynid.config`: typed readers of one value
that raise :class:`~dynid.errors.ConfigError` naming the dotted key, and the reader of a TOML file."""

from __future__ import annotations

import math
import os
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.errors import ConfigError, decode_text, read_file_bytes

__all__ = ["read_toml"]


def _table(value: Any, where: str, allowed: set[str], required: set[str] = frozenset()) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
    _reject_unknown(value, where, allowed)
    missing = sorted(required - set(value))
    if missing:
        raise ConfigError(f"{where}: missing required keys {missing}")
    return value


def _reject_unknown(value: Mapping[str, Any], where: str, allowed: set[str]) -> None:
    unknown = sorted(set(value) - allowed)
    if unknown:
        dotted = [k if where == "config" else f"{where}.{k}" for k in unknown]
        raise ConfigError(
            f"unknown key{'s' if len(dotted) > 1 else ''} {', '.join(dotted)}; allowed keys in "
            f"{'the top level' if where == 'config' else f'[{where}]'} are {sorted(allowed)}"
        )


def _str(value: Any, where: str, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"{where}: expected a string, got {value!r}")
    if choices is not None and value not in choices:
        raise ConfigError(f"{where}: must be one of {list(choices)}, got {value!r}")
    return value


def _num(value: Any, where: str, positive: bool = False, *, minimum: float | None = None) -> float:
    """A finite number (TOML's ``nan`` and ``inf`` are refused); ``positive``: > 0;
    ``minimum``: >= that value."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):  # TOML allows nan and inf
        raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    if positive and not value > 0:
        raise ConfigError(f"{where}: must be positive, got {value!r}")
    if minimum is not None and value < minimum:
        raise ConfigError(f"{where}: must be >= {minimum:g}, got {value!r}")
    return float(value)


def _int(value: Any, where: str, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise ConfigError(f"{where}: must be >= {minimum}, got {value}")
    return int(value)


def _bool(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{where}: expected true or false, got {value!r}")
    return value


def _list(value: Any, where: str, item, n: int | None = None) -> tuple:
    if not isinstance(value, list):
        raise ConfigError(f"{where}: expected a list, got {value!r}")
    if n is not None and len(value) != n:
        raise ConfigError(f"{where}: expected {n} entries, got {len(value)}")
    return tuple(item(v, f"{where}[{i}]") for i, v in enumerate(value))


def _num_or_list(value: Any, where: str, positive: bool = False, *, minimum: float | None = None):
    """A number, or a non-empty list of numbers (per joint / actuator / channel)."""
    if isinstance(value, list):
        if not value:
            raise ConfigError(f"{where}: empty list; give a number or one per joint/actuator")
        return _list(value, where, lambda v, w: _num(v, w, positive, minimum=minimum))
    return _num(value, where, positive, minimum=minimum)


_VAR = re.compile(r"\$\{([^}]*)\}")


def _expand(text: str, where: str) -> str:
    """``${NAME}`` replaced by the environment variable NAME; an unset (or empty) variable is an error
    naming it, never a path that silently points elsewhere."""

    def value(m: re.Match) -> str:
        name = m.group(1)
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise ConfigError(f"{where}: {m.group(0)!r} is not a variable name (letters, digits, _)")
        v = os.environ.get(name)
        if not v:
            raise ConfigError(f"{where}: environment variable {name} is {'empty' if v == '' else 'not set'} "
                              f"(in {text!r})")
        return v

    return _VAR.sub(value, text)


def _path(value: Any, where: str, base: Path) -> Path:
    """A path: ``${VAR}`` expanded, ``~`` expanded, relative to ``base``, canonical."""
    p = Path(_expand(_str(value, where), where)).expanduser()
    # canonical, so that one file named two ways is recognised as the same file
    return (p if p.is_absolute() else (base / p)).resolve()


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML document, or a one-line error naming the file (missing, a folder, unreadable,
    empty, not UTF-8 text, invalid TOML)."""
    text = decode_text(read_file_bytes(path, "config file"), path, "config file", ConfigError)
    if not text.strip():
        raise ConfigError(f"config file {path} is empty")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML ({exc})") from None


def usable_cores(workers: int) -> int:
    """Local process workers for a ``workers`` setting: itself when positive, else (``0``) the cores
    this process may use."""
    if workers > 0:
        return workers
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def parse_workers(value: Any, where: str) -> int:
    """``workers``: an integer >= 0 or ``"auto"`` (0: all cores)."""
    if value == "auto":
        return 0
    if isinstance(value, str):
        raise ConfigError(f"{where}: expected an integer >= 0 or \"auto\", got {value!r}")
    return _int(value, where, 0)


_SCHEDULER = re.compile(r"^(?:(?P<scheme>[A-Za-z][A-Za-z0-9+.-]*)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                        r"(?::(?P<port>\d{1,5}))?$")
_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")


def parse_scheduler(value: Any, where: str) -> str:
    """A Dask scheduler address: ``[tcp|tls|ucx|ws|wss://]host[:port]``."""
    text = _str(value, where)
    m = _SCHEDULER.match(text)
    if m is None or (m.group("scheme") or "tcp") not in _SCHEMES or (m.group("port") and not 0 < int(m.group("port")) < 65536):
        raise ConfigError(f"{where}: {text!r} is not a Dask scheduler address; expected "
                          f"[{'|'.join(_SCHEMES)}://]host[:port], e.g. tcp://127.0.0.1:8786")
    return text
