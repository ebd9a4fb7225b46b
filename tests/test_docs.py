"""The README's configuration example is a valid configuration (the docs stay in step)."""

from __future__ import annotations

import re
import tomllib

from conftest import REPO

from dynid.config import parse_config


def test_readme_config_example_parses():
    text = (REPO / "README.md").read_text()
    section = text.split("## Configuration", 1)[1]
    block = re.search(r"```toml\n(.*?)```", section, re.S).group(1)
    cfg = parse_config(tomllib.loads(block), REPO / "examples" / "tx40")
    assert cfg.robot.couplings[0].joints == (5, 6)
    assert cfg.processing.decimate_method == "parallel"
    assert cfg.validation.rows == (29250, 45000)
    # every key the README shows uncommented is understood, and the README mentions every section
    for section_name in ("[robot]", "[data]", "[validation]", "[processing]", "[identification]", "[output]"):
        assert section_name in block


def test_readme_opens_with_the_two_commands():
    lines = (REPO / "README.md").read_text().splitlines()
    code = lines[lines.index("```bash") + 1 : lines.index("```bash") + 3]
    assert code[0].startswith("make demo") and code[1].startswith("make test")
