"""Helpers for the real-data tests: the example configs with their ../shared/data paths pointed
at wherever the shared data are (DYNID_SHARED_DATA), and tables printed even under -q."""

from __future__ import annotations

import tomllib

from conftest import REPO, SHARED_DATA

from dynid.config import Config, parse_config

_DEFAULT_ROOT = "../../../shared/data/"


def example_text(name: str) -> str:
    """TOML text of ``examples/<name>/identify.toml`` with absolute shared-data paths."""
    text = (REPO / "examples" / name / "identify.toml").read_text()
    return text.replace(_DEFAULT_ROOT, f"{SHARED_DATA.as_posix()}/")


def example_config(name: str, **sections: dict) -> Config:
    """Parsed example config; keyword arguments update whole sections, e.g. ``output={"plots": False}``."""
    doc = tomllib.loads(example_text(name))
    for section, values in sections.items():
        doc.setdefault(section, {}).update(values)
    path = REPO / "examples" / name / "identify.toml"
    return parse_config(doc, path.parent, source=path)


def table(title: str, header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]

    def fmt(r):
        return "  ".join(str(c).rjust(w) if i else str(c).ljust(w) for i, (c, w) in enumerate(zip(r, widths)))

    return "\n".join([title, fmt(header), "-" * len(fmt(header))] + [fmt(r) for r in rows])


def show(capsys, text: str) -> None:
    """Print even under ``pytest -q`` (the figures are part of the acceptance)."""
    with capsys.disabled():
        print("\n" + text)
