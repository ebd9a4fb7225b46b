"""The configuration reference of the documentation (docs/_ext/dynid_config_reference.py) is generated
from the parser; these checks make sure it cannot drift from the schema: every key the schema's public
names know is in it, in the right table, and the page it renders is valid reStructuredText.
(The documentation build itself is CI's job: `make docs`.)"""

from __future__ import annotations

import dataclasses
import importlib.util
import io
import sys
from pathlib import Path

import pytest

import dynid.config as config
from dynid.config.learning import LEARNING_KEYS
from dynid.pipeline.arrays import OPTION_SECTIONS

EXT = Path(__file__).resolve().parents[1] / "docs" / "_ext" / "dynid_config_reference.py"


@pytest.fixture(scope="module")
def ref():
    spec = importlib.util.spec_from_file_location("dynid_config_reference", EXT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


@pytest.fixture(scope="module")
def sections(ref):
    return {s.path: s for s in ref.collect()}


def keys(sections, *path):
    return {k.name for k in sections[path].keys}


def test_every_key_of_the_public_key_lists_is_documented_in_its_table(sections):
    assert {"model", *config.ROBOT_KEYS} == keys(sections, "robot")
    assert set(config.PROCESSING_KEYS) == keys(sections, "processing")
    assert set(config.IDENTIFICATION_KEYS) == keys(sections, "identification")
    assert set(LEARNING_KEYS) == keys(sections, "learning")
    for key, section in OPTION_SECTIONS.items():  # the keywords of dynid.identify_arrays
        assert key in keys(sections, section), (key, section)


def test_the_tables_follow_the_configuration_dataclasses(sections):
    """Every field of a table's dataclass that the file sets has its key (the dataclasses name a few
    values the parser derives: those are listed here, by name)."""
    derived = {"extras_given", "source", "raw", "experiments", "validations", "payload", "learning", "bag"}
    top = {f.name for f in dataclasses.fields(config.Config)} - derived
    assert top <= keys(sections)
    for path, cls in ((("robot",), config.RobotConfig), (("data",), config.DataConfig),
                      (("data", "time"), config.TimeConfig), (("data", "effort"), config.SignalConfig),
                      (("processing",), config.ProcessingConfig), (("processing", "lowpass"), config.LowpassConfig),
                      (("processing", "periodic"), config.PeriodicConfig), (("output",), config.OutputConfig)):
        fields = {f.name for f in dataclasses.fields(cls)} - derived
        assert fields <= keys(sections, *path), (path, fields - keys(sections, *path))


def test_required_keys_types_and_choices_come_from_the_parser(sections):
    robot = {k.name: k for k in sections[("robot",)].keys}
    assert robot["model"].required and not robot["extras"].required
    ident = {k.name: k for k in sections[("identification",)].keys}
    assert "wls" in ident["method"].choices and "didim" in ident["method"].choices
    assert ident["physical_consistency"].type == "boolean" and ident["physical_consistency"].default == "false"
    assert {"data", "validation", "robot"} == {k.name for k in sections[()].keys if k.required}
    assert "hac" in ident["covariance_lags"].condition and ident["covariance_lags"].type == "integer"
    assert "physical_consistency = true" in ident["margin"].condition


def test_the_rendered_page_is_valid_restructuredtext_naming_every_key(ref, sections):
    from docutils.core import publish_doctree

    text = ref.to_rst(list(sections.values()))
    for s in sections.values():
        assert s.title in text
        for k in s.keys:
            assert f"``{k.name}``" in text
    stream = io.StringIO()
    publish_doctree(text, settings_overrides={"warning_stream": stream, "report_level": 2, "halt_level": 5})
    assert stream.getvalue() == ""


def test_every_key_has_a_description(sections):
    """The reference describes every key from the code's own comments (the dataclass fields, a nested
    dataclass's fields that name the key, the function that reads a top-level key): none is left blank,
    so a key added without a comment fails here."""
    blank = [(".".join(path) or "(top)", k.name) for path, s in sections.items() for k in s.keys if not k.description]
    assert blank == []
    ident = {k.name: k for k in sections[("identification",)].keys}
    assert ident["covariance_blocks"].description.startswith("covariance_blocks")  # from CovarianceConfig.blocks
