"""The documentation's examples are valid (the docs stay in step): the configuration example of the user
guide (docs/guide/configuration.md), its parallel-robot, simulate and design examples, and README.md's
opening commands."""

from __future__ import annotations

import re
import tomllib

from conftest import REPO, doc_text

from dynid.config import parse_config


def test_readme_config_example_parses():
    section = doc_text("configuration")  # the guide's page "Configuration"
    block = re.search(r"```toml\n(.*?)```", section, re.S).group(1)
    cfg = parse_config(tomllib.loads(block), REPO / "examples" / "tx40")
    assert cfg.robot.couplings[0].joints == (5, 6)
    assert cfg.processing.decimate_method == "parallel"
    assert cfg.validation.rows == (29250, 45000)
    # every key the page shows uncommented is understood, and the page mentions every section
    for section_name in ("[robot]", "[data]", "[validation]", "[processing]", "[identification]", "[output]"):
        assert section_name in block


def test_readme_opens_with_the_two_commands():
    lines = (REPO / "README.md").read_text().splitlines()
    code = lines[lines.index("```bash") + 1 : lines.index("```bash") + 3]
    assert code[0].startswith("make demo") and code[1].startswith("make test")


def _parallel_section() -> str:
    return doc_text("parallel-robots")  # the guide's page "Parallel robots"


def test_readme_mjcf_example_is_a_mechanism(tmp_path):
    from dynid.model import load_model

    xml = re.search(r"```xml\n(.*?)```", _parallel_section(), re.S).group(1)
    path = tmp_path / "my_fivebar.xml"
    path.write_text(xml)
    mech = load_model(str(path))
    assert (mech.dof, mech.n_actuators, mech.nv) == (2, 2, 4)
    assert abs(mech.constraint_residual(mech.q_ref)).max() < 1e-12
    # armature and damping became nominal joint terms
    nominal = dict(zip(mech.parameter_names, mech.nominal_parameters()))
    assert nominal["Ia_qa1"] == 0.002 and nominal["fv_qb2"] == 0.005


def test_readme_closure_yaml_example_loads_the_gepetto_five_bar(tmp_path, shared):
    from dynid.model.mechanism_io import load_mechanism_urdf

    urdf = shared("parallel_examples", "5bar_linkage", "robot.urdf")
    yaml_text = re.search(r"```yaml\n(.*?)```", _parallel_section(), re.S).group(1)
    path = tmp_path / "closures.yaml"
    path.write_text(yaml_text)
    mech = load_mechanism_urdf(urdf, path)
    assert (mech.dof, mech.n_actuators) == (2, 2)
    assert any("locked idle joint" in note for note in mech.notes)


def test_readme_python_example_runs(capsys):
    code = re.search(r"```python\n(.*?)```", _parallel_section(), re.S).group(1)
    exec(compile(code, "docs/guide/parallel-robots.md", "exec"), {})
    assert capsys.readouterr().out.strip() == "25 projected (2, 2)"


def test_readme_simulate_example_parses_and_matches_the_twin():
    from dynid.config.simulate import load_simulate_config, parse_simulate_config

    text = doc_text("simulation")  # the guide's page "Virtual experiments"
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    cfg = parse_simulate_config(tomllib.loads(block), REPO)
    twin = load_simulate_config(REPO / "examples" / "twins" / "shang2dof_circle.toml")
    assert cfg.trajectory == twin.trajectory and cfg.control == twin.control and cfg.robot == twin.robot
    for section_name in ("[robot]", "[trajectory]", "[control]", "[sensors]", "[simulation]", "[output]"):
        assert section_name in block


def test_readme_design_example_parses():
    from dynid.config.design import parse_design_config

    text = doc_text("excitation")  # the guide's page "Excitation design" (its first block)
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    cfg = parse_design_config(tomllib.loads(block), REPO)
    assert (cfg.criterion, cfg.harmonics, cfg.starts) == ("d_opt", 5, 2)
    assert cfg.limits["velocity"] == 2.0


def test_readme_parallel_robot_with_a_drive_train_parses(tmp_path):
    """The guide's 3-RPS through ball screws (docs/guide/parallel-robots.md, "Identifying one"): a
    mechanism with gear ratios, drive gains, offsets and motor currents builds one system whose drive
    train maps motor signals to its legs."""
    import numpy as np

    from dynid.pipeline.data import build_system

    text = doc_text("parallel-robots").split("\n## Identifying one", 1)[1]
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    cfg = parse_config(tomllib.loads(block), tmp_path)
    system = build_system(cfg.robot)
    assert system.kind == "closed-loop" and system.actuator_names == ("P1", "P2", "P3")
    tr = system.transmission
    np.testing.assert_allclose(np.diag(tr.matrix), 2 * np.pi / 0.005, rtol=1e-6)
    assert cfg.data.effort.kind == "current" and cfg.data.position.side == "motor"
    assert [t.name for t in system.model.terms] == [f"{e}_P{k}" for k in (1, 2, 3) for e in ("Ia", "fv", "fc")]


def test_readme_is_short_and_points_into_the_guide():
    """README.md is the front page (at most 250 lines); the manual is docs/guide/, whose index lists
    every page, and every docs/guide link of the README names a page that exists."""
    text = (REPO / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    pages = {p.stem for p in (REPO / "docs" / "guide").glob("*.md")}
    index = doc_text("index")
    assert all(f"\n{page}\n" in index for page in pages - {"index"}), sorted(pages)
    linked = set(re.findall(r"\]\(docs/guide/([\w-]+)\.md", text))
    assert linked and linked <= pages, sorted(linked - pages)
    # every relative link of the README (guide, site sources, bench record) names a file or folder that exists
    targets = [t.split("#")[0] for t in re.findall(r"\]\(([^)]+)\)", text) if "://" not in t]
    assert targets and all((REPO / t).exists() for t in targets), [t for t in targets if not (REPO / t).exists()]


def test_guide_pages_have_one_title_consecutive_levels_and_resolving_links():
    """Each guide page opens with one ``#`` title, its heading levels never skip one, and its links to
    other pages of the guide (``page.md#anchor``) name a page and a heading that exist (GitHub-style
    heading slugs, as MyST's ``myst_heading_anchors`` writes them)."""
    def slug(heading: str) -> str:
        return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")

    headings = {}
    for page in sorted((REPO / "docs" / "guide").glob("*.md")):
        levels, fenced = [], False
        for line in page.read_text().splitlines():
            if line.startswith("```"):
                fenced = not fenced
            elif not fenced and (m := re.match(r"^(#+) (.*)$", line)):
                levels.append(len(m.group(1)))
                headings.setdefault(page.stem, set()).add(slug(m.group(2)))
        assert levels[0] == 1 and levels.count(1) == 1, page.name
        assert all(b <= a + 1 for a, b in zip(levels, levels[1:])), page.name
    for page in sorted((REPO / "docs" / "guide").glob("*.md")):
        for target, anchor in re.findall(r"\]\(([\w-]*)(?:\.md)?(?:#([\w-]+))?\)", page.read_text()):
            target = target or page.stem
            assert target in headings, (page.name, target)
            assert not anchor or anchor in headings[target], (page.name, target, anchor)
