"""Sphinx extension: the studies and benchmarks of ``bench/README.md`` as pages of the site.

``bench/README.md`` is the record of every study and benchmark (the papers' tables reproduced on
dynid's twins, speed and memory against baselines measured in the same run). It stays the one
place they are written; at build time this extension cuts it into one page per section under
``studies/generated/`` (ignored by git, rewritten on every build), so the site never holds a
hand-copied figure:

* every level-2 section (``## ...``) is a page, its headings raised by one level;
* a level-2 section that only gathers numbered level-3 sections (``## Results``) gives one page per
  level-3 section instead, raised by two levels; its own introduction becomes a page of its own;
* image links (``figures/x.png``) point at ``bench/figures`` from the generated page.

``studies/index.md`` lists the generated pages with a glob toctree, in the README's order.
"""

from __future__ import annotations

import re
from pathlib import Path

_HEADING = re.compile(r"^(#{1,6}) (.*)$")
_FENCE = re.compile(r"^(```|~~~)")


def _slug(text: str) -> str:
    s = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return s[:60].rstrip("-") or "section"


def _lines_with_headings(text: str):
    """(line, heading level or 0) for each line; headings inside code fences are not headings."""
    fenced = False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            yield line, 0
            continue
        m = None if fenced else _HEADING.match(line)
        yield line, (len(m.group(1)) if m else 0)


def _sections(lines, level: int):
    """Split (line, level) pairs at headings of ``level``: [(title or None, [pairs])]."""
    out: list[tuple[str | None, list]] = [(None, [])]
    for line, lv in lines:
        if lv == level:
            out.append((line[level + 1:].strip(), [(line, lv)]))
        else:
            out[-1][1].append((line, lv))
    return [s for s in out if s[0] is not None or any(l.strip() for l, _ in s[1])]


def _render(pairs, raise_by: int, title: str, figures: str) -> str:
    body = []
    for line, lv in pairs:
        if lv:
            line = "#" * max(1, lv - raise_by) + line[lv:]
        body.append(re.sub(r"\]\(figures/", f"]({figures}/", line))
    if not body or not body[0].startswith("# "):
        body.insert(0, f"# {title}\n")
    return "\n".join(body).rstrip() + "\n"


def generate(root: Path, out: Path) -> list[Path]:
    """Write the pages of ``root/bench/README.md`` into ``out``; return them in the README's order."""
    text = (root / "bench" / "README.md").read_text(encoding="utf-8")
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.md"):
        old.unlink()
    figures = Path("../../../bench/figures").as_posix()  # from docs/studies/generated/
    pairs = list(_lines_with_headings(text))
    pages: list[tuple[str, str]] = []
    for title, sec in _sections(pairs, 2):
        if title is None:  # the README's own title and introduction
            pages.append(("Benchmarks and studies: how they are run", _render(
                [(l, lv) for l, lv in sec if lv != 1], 0, "Benchmarks and studies: how they are run", figures)))
            continue
        subs = _sections(sec[1:], 3)
        numbered = [t for t, _ in subs if t is not None and re.match(r"\d+\. ", t)]
        if numbered and len(numbered) == len([t for t, _ in subs if t is not None]):
            intro = [p for t, p in subs if t is None]
            if intro and any(l.strip() for l, _ in intro[0]):
                pages.append((title, _render([sec[0]] + intro[0], 1, title, figures)))
            for t, p in subs:
                if t is not None:
                    pages.append((t, _render(p, 2, t, figures)))
        else:
            pages.append((title, _render(sec, 1, title, figures)))
    written = []
    for i, (title, content) in enumerate(pages, 1):
        path = out / f"{i:02d}-{_slug(title)}.md"
        path.write_text(content, encoding="utf-8")
        written.append(path)
    return written


def _on_builder_inited(app) -> None:
    docs = Path(app.srcdir)
    generate(docs.parent, docs / "studies" / "generated")


def setup(app):
    app.connect("builder-inited", _on_builder_inited)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
