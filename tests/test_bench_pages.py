"""The site's studies pages are bench/README.md cut by section at build time
(docs/_ext/dynid_bench_pages.py): nothing is lost, nothing copied twice, every image resolves."""

from __future__ import annotations

import importlib.util
import re

from conftest import REPO


def _module():
    spec = importlib.util.spec_from_file_location("dynid_bench_pages", REPO / "docs" / "_ext" / "dynid_bench_pages.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_line_of_bench_readme_lands_on_exactly_one_page(tmp_path):
    pages = _module().generate(REPO, tmp_path)
    text = (REPO / "bench" / "README.md").read_text(encoding="utf-8")
    body = [l for l in text.splitlines() if l.strip() and not re.match(r"#{1,6} ", l)]
    generated = [l for p in pages for l in p.read_text(encoding="utf-8").splitlines()]
    heading_free = [re.sub(r"\]\(\.\./\.\./\.\./bench/figures/", "](figures/", l) for l in generated
                    if l.strip() and not re.match(r"#{1,6} ", l)]
    # the same non-heading lines in the same order (headings move up a level, image paths are rebased)
    assert heading_free == body
    for page in pages:
        lines = page.read_text(encoding="utf-8").splitlines()
        assert lines[0].startswith("# ") and sum(l.startswith("# ") for l in lines) == 1, page.name
        # heading levels never jump by more than one (MyST warns, and the build treats warnings as errors)
        fenced, last = False, 1
        for l in lines:
            if l.startswith("```"):
                fenced = not fenced
            m = None if fenced else re.match(r"(#{1,6}) ", l)
            if m:
                assert len(m.group(1)) <= last + 1, (page.name, l)
                last = len(m.group(1))
        for img in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page.read_text(encoding="utf-8")):
            assert (REPO / "docs" / "studies" / "generated" / img).resolve().is_file(), img
