"""Configuration: strict schema, dotted keys in errors, paths, train/validation separation."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest

from dynid.config import load_config, parse_config
from dynid.errors import ConfigError, InputError

COMPLETE = """\
[robot]
model = "builtin:puma560"
extras = ["Ia", "fv"]
gear_ratios = [100, 100, 100, 50, 50, 50]
drive_gains = [0.1, 0.1, 0.1, 0.05, 0.05, 0.05]
position_offset = [0.0, 0.0, 0.0, 0.0, 0.0, 0.5]
couplings = [{ motor = 6, joints = [5, 6], weights = [1.0, -1.0] }]

[data]
file = "logs/train.csv"
time = { column = "stamp", unit = "ms" }
position = { columns = ["m1", "m2", "m3", "m4", "m5", "m6"], unit = "deg", side = "motor" }
effort = { columns = ["i1", "i2", "i3", "i4", "i5", "i6"], kind = "current", unit = "mA", side = "motor" }
velocity = { columns = ["v1", "v2", "v3", "v4", "v5", "v6"], unit = "deg", file = "logs/vel.csv" }
rows = [0, 5000]

[validation]
rows = [6000, 8000]

[processing]
resample = 250.0
lowpass = { cutoff_hz = 12.5, order = 6, filter_effort = false }
derivatives = "measured"
decimate = 2
trim_samples = 40
min_velocity = 0.01

[identification]
method = "ols"
chunk_size = 512
base_seed = 3
base_samples = 200
min_joint_motion = 0.05

[output]
plots = false
"""


def write(tmp_path: Path, text: str, name: str = "cfg.toml") -> Path:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def minimal() -> dict:
    """A small valid document (as tomllib would return it)."""
    return {
        "robot": {"model": "builtin:puma560"},
        "data": {
            "file": "train.csv",
            "time": {"column": "t"},
            "position": {"columns": ["q1", "q2"]},
            "effort": {"columns": ["tau1", "tau2"]},
        },
        "validation": {"file": "valid.csv"},
    }


def parse(doc: dict, base: Path = Path("/cfg")):
    return parse_config(doc, base)


def with_(doc: dict, dotted: str, value) -> dict:
    doc = copy.deepcopy(doc)
    *head, last = dotted.split(".")
    node = doc
    for key in head:
        node = node.setdefault(key, {})
    node[last] = value
    return doc


def without(doc: dict, dotted: str) -> dict:
    doc = copy.deepcopy(doc)
    *head, last = dotted.split(".")
    node = doc
    for key in head:
        node = node[key]
    del node[last]
    return doc


# ---------------------------------------------------------------------- a complete file
def test_complete_config(tmp_path):
    cfg = load_config(write(tmp_path / "exp", COMPLETE))
    base = (tmp_path / "exp").resolve()
    assert cfg.source == base / "cfg.toml"
    r = cfg.robot
    assert r.model == "builtin:puma560"
    assert r.extras == ("Ia", "fv")
    assert r.gear_ratios == (100.0,) * 3 + (50.0,) * 3
    assert r.drive_gains == (0.1,) * 3 + (0.05,) * 3
    assert r.position_offset[5] == 0.5
    assert len(r.couplings) == 1
    assert (r.couplings[0].motor, r.couplings[0].joints, r.couplings[0].weights) == (6, (5, 6), (1.0, -1.0))
    assert r.has_transmission

    d = cfg.data
    assert d.file == base / "logs" / "train.csv"
    assert (d.time.column, d.time.unit, d.time.file) == ("stamp", "ms", None)
    assert d.sample_rate_hz is None
    assert d.position.columns == ("m1", "m2", "m3", "m4", "m5", "m6")
    assert (d.position.unit, d.position.side) == ("deg", "motor")
    assert (d.effort.kind, d.effort.unit, d.effort.side) == ("current", "mA", "motor")
    assert d.velocity.file == base / "logs" / "vel.csv"
    assert d.acceleration is None
    assert d.rows == (0, 5000) and d.time_window is None
    assert d.files() == (base / "logs" / "train.csv", base / "logs" / "vel.csv")

    v = cfg.validation
    assert v.rows == (6000, 8000)
    assert (v.file, v.time, v.position, v.effort, v.velocity) == (d.file, d.time, d.position, d.effort, d.velocity)

    p = cfg.processing
    assert p.resample == 250.0
    assert (p.lowpass.cutoff_hz, p.lowpass.order, p.lowpass.filter_effort) == (12.5, 6, False)
    assert (p.derivatives, p.decimate, p.trim_samples, p.min_velocity) == ("measured", 2, 40, (0.01,))

    i = cfg.identification
    assert (i.method, i.chunk_size, i.base_seed, i.base_samples, i.min_joint_motion) == ("ols", 512, 3, 200, 0.05)
    assert cfg.output.plots is False
    assert cfg.raw["processing"]["decimate"] == 2


def test_defaults():
    cfg = parse(minimal())
    assert cfg.robot.extras == ("Ia", "fv", "fc", "offset")
    assert cfg.robot.gear_ratios is None and not cfg.robot.has_transmission
    # no unit: SI for each joint (rad or m, N*m or N), checked against the joints once the model is known
    assert (cfg.data.position.unit, cfg.data.position.side) == (None, "joint")
    assert (cfg.data.effort.kind, cfg.data.effort.unit, cfg.data.effort.side) == ("torque", None, "joint")
    assert cfg.data.time.unit == "s"
    assert cfg.processing.resample == "auto" and cfg.processing.lowpass is None
    assert (cfg.processing.derivatives, cfg.processing.decimate, cfg.processing.trim_samples) == ("central", 1, None)
    assert (cfg.identification.method, cfg.identification.chunk_size) == ("wls", 20000)
    assert cfg.output.plots is True
    assert parse(with_(minimal(), "data.effort.kind", "current")).data.effort.unit is None  # A
    assert parse(with_(minimal(), "data.effort.unit", ["N*m", "N"])).data.effort.unit == ("N*m", "N")


# ---------------------------------------------------------------------- paths
def test_relative_paths_resolve_against_the_config_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a different working directory
    text = """\
[robot]
model = "../robots/arm.urdf"
[data]
file = "logs/train.csv"
time = { column = "t", file = "logs/time.csv" }
position = { columns = ["q1"] }
effort = { columns = ["tau1"], file = "/abs/effort.csv" }
[validation]
file = "logs/valid.csv"
"""
    write(tmp_path / "experiments" / "one", text)
    cfg = load_config(Path("experiments/one/cfg.toml"))  # relative to the working directory
    folder = tmp_path.resolve() / "experiments" / "one"
    assert Path(cfg.robot.model) == tmp_path.resolve() / "experiments" / "robots" / "arm.urdf"
    assert cfg.data.file == folder / "logs" / "train.csv"
    assert cfg.data.time.file == folder / "logs" / "time.csv"
    assert cfg.data.effort.file == Path("/abs/effort.csv")
    assert cfg.validation.file == folder / "logs" / "valid.csv"
    assert all(p.is_absolute() for p in cfg.data.files() + cfg.validation.files())


def test_home_is_expanded(monkeypatch):
    monkeypatch.setenv("HOME", "/home/tester")
    cfg = parse(with_(minimal(), "data.file", "~/logs/train.csv"))
    assert cfg.data.file == Path("/home/tester/logs/train.csv")


def test_a_signal_without_any_file():
    doc = without(minimal(), "data.file")
    doc["validation"] = {"file": "v.csv"}
    with pytest.raises(ConfigError, match=r"data.position: no file \(set data.file or data.position.file\)"):
        parse(doc)


# ---------------------------------------------------------------------- unknown keys
UNKNOWN = [
    ("bogus", "bogus"),
    ("robot.bogus", "robot.bogus"),
    ("robot.couplings", "robot.couplings[0].bogus"),
    ("data.bogus", "data.bogus"),
    ("data.time.bogus", "data.time.bogus"),
    ("data.position.bogus", "data.position.bogus"),
    ("data.position.kind", "data.position.kind"),  # 'kind' belongs to efforts only
    ("data.effort.bogus", "data.effort.bogus"),
    ("data.velocity", "data.velocity.bogus"),
    ("validation.bogus", "validation.bogus"),
    ("validation.position", "validation.position.bogus"),
    ("processing.bogus", "processing.bogus"),
    ("processing.lowpass", "processing.lowpass.bogus"),
    ("identification.bogus", "identification.bogus"),
    ("output.bogus", "output.bogus"),
]


@pytest.mark.parametrize("where, dotted", UNKNOWN, ids=[d for _, d in UNKNOWN])
def test_unknown_keys_are_named_with_their_dotted_path(where, dotted):
    values = {
        "robot.couplings": [{"motor": 1, "joints": [1], "bogus": 1}],
        "data.velocity": {"columns": ["v1", "v2"], "bogus": 1},
        "validation.position": {"columns": ["q1", "q2"], "bogus": 1},
        "processing.lowpass": {"cutoff_hz": 5.0, "bogus": 1},
    }
    doc = with_(minimal(), where, values.get(where, 1))
    with pytest.raises(ConfigError) as exc:
        parse(doc)
    msg = str(exc.value)
    assert f"unknown key {dotted};" in msg
    assert "allowed keys" in msg and "\n" not in msg


def test_several_unknown_keys_in_one_message():
    doc = with_(with_(minimal(), "output.colour", 1), "output.size", 2)
    with pytest.raises(ConfigError, match=r"unknown keys output.colour, output.size; allowed keys in \[output\] are \['plots'\]"):
        parse(doc)


def test_unknown_key_in_a_file(tmp_path):
    path = write(tmp_path, COMPLETE.replace("[output]\n", "[output]\nplot = true\n"))
    with pytest.raises(ConfigError, match="unknown key output.plot;"):
        load_config(path)


# ---------------------------------------------------------------------- types and values
WRONG = [
    ("data.rows", [0, 1.5], None, r"data.rows\[1\]: expected an integer, got 1.5"),
    ("data.rows", [0], None, r"data.rows: expected 2 entries, got 1"),
    ("data.rows", [5, 5], None, r"data.rows: stop 5 must exceed start 5"),
    ("data.rows", [-1, 5], None, r"data.rows\[0\]: must be >= 0, got -1"),
    ("data.time_window", [2.0, 1.0], None, r"data.time_window: end must exceed start"),
    ("data.position.columns", [], None, r"data.position.columns: empty"),
    ("data.position.columns", ["q1", 2], None, r"data.position.columns\[1\]: expected a string, got 2"),
    ("data.position.unit", "furlong", None, r"data.position.unit: must be one of \['rad', 'deg', 'm', 'mm'\]"),
    ("data.position.side", "left", None, r"data.position.side: must be one of \['joint', 'motor'\]"),
    ("data.effort.unit", "A", None, r"data.effort.unit: must be one of \['N\*m'"),
    ("data.time.unit", "min", None, r"data.time.unit: must be one of \['s', 'ms', 'us', 'ns'\]"),
    ("data.time", "t", None, r"data.time: expected a table, got str"),
    ("data", 3, None, r"data: expected a table, got int"),
    ("robot.model", 5, None, r"robot.model: expected a string, got 5"),
    ("robot.extras", "Ia", None, r"robot.extras: expected a list, got 'Ia'"),
    ("robot.extras", ["Ia", "stiction"], None, r"robot.extras\[1\]: must be one of"),
    ("robot.couplings", 5, None, r"robot.couplings: expected a list of tables"),
    ("robot.couplings", {"motor": 1, "joints": [1]}, None, r"robot.couplings: expected a list of tables"),
    ("robot.gear_ratios", [1, "x"], None, r"robot.gear_ratios\[1\]: expected a number, got 'x'"),
    ("processing.lowpass", {"cutoff_hz": -5.0}, None, r"processing.lowpass.cutoff_hz: must be positive"),
    ("processing.lowpass", {"cutoff_hz": math.nan}, None, r"processing.lowpass.cutoff_hz: expected a finite number, got nan"),
    ("processing.lowpass", {"cutoff_hz": math.inf}, None, r"processing.lowpass.cutoff_hz: expected a finite number, got inf"),
    ("processing.lowpass", {"cutoff_hz": 5.0, "order": 0}, None, r"processing.lowpass.order: must be >= 1, got 0"),
    ("processing.lowpass", {"cutoff_hz": True}, None, r"processing.lowpass.cutoff_hz: expected a number, got True"),
    ("processing.resample", "sometimes", None, r"processing.resample: must be one of \['auto', 'off'\]"),
    ("processing.derivatives", "spline", None, r"processing.derivatives: must be one of \['central', 'measured', 'kalman'\]"),
    ("processing.decimate", 0, None, r"processing.decimate: must be >= 1, got 0"),
    ("processing.min_velocity", -0.1, None, r"processing.min_velocity: must be >= 0"),
    ("processing.min_velocity", math.nan, None, r"processing.min_velocity: expected a finite number, got nan"),
    ("identification.method", "gls", None, r"identification.method: must be one of \['ols', 'wls', 'gm', 'irls', 'tls', 'ml', 'iv', 'didim', 'cloe', 'ekf', 'ukf'\]"),
    ("identification.chunk_size", 2.5, None, r"identification.chunk_size: expected an integer, got 2.5"),
    ("output.plots", "yes", None, r"output.plots: expected true or false, got 'yes'"),
]


@pytest.mark.parametrize("key, value, _, message", WRONG, ids=[f"{k}={v!r}" for k, v, _, _ in WRONG])
def test_wrong_types_and_values(key, value, _, message):
    with pytest.raises(ConfigError, match=message):
        parse(with_(minimal(), key, value))


def test_sample_rate_must_be_a_positive_number():
    doc = without(minimal(), "data.time")
    assert parse(with_(doc, "data.sample_rate_hz", 200)).data.sample_rate_hz == 200.0
    with pytest.raises(ConfigError, match=r"data.sample_rate_hz: expected a number, got '200'"):
        parse(with_(doc, "data.sample_rate_hz", "200"))
    with pytest.raises(ConfigError, match=r"data.sample_rate_hz: must be positive"):
        parse(with_(doc, "data.sample_rate_hz", 0))
    with pytest.raises(ConfigError, match=r"data: give exactly one of 'time' \(a time column\) or 'sample_rate_hz'"):
        parse(doc)


def test_missing_sections():
    with pytest.raises(ConfigError, match=r"config: missing required keys \['validation'\]"):
        parse(without(minimal(), "validation"))
    with pytest.raises(ConfigError, match=r"data: missing required keys \['effort'\]"):
        parse(without(minimal(), "data.effort"))
    with pytest.raises(ConfigError, match=r"robot: missing required keys \['model'\]"):
        parse(without(minimal(), "robot.model"))


def test_rows_and_time_window_together():
    doc = with_(with_(minimal(), "data.rows", [0, 10]), "data.time_window", [0.0, 1.0])
    with pytest.raises(ConfigError, match="data: give 'rows' or 'time_window', not both"):
        parse(doc)


# ---------------------------------------------------------------------- files
def test_missing_config_file(tmp_path):
    with pytest.raises(InputError, match=f"^config file not found: {tmp_path / 'none.toml'}$"):
        load_config(tmp_path / "none.toml")


def test_bad_toml_syntax(tmp_path):
    path = write(tmp_path, "[robot\nmodel = 1\n")
    with pytest.raises(ConfigError, match=r"cfg.toml: invalid TOML \(.*line 1"):
        load_config(path)


def test_binary_file(tmp_path):
    path = tmp_path / "cfg.toml"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ConfigError, match=r"cfg.toml is not UTF-8 text \(byte 0xff at offset 0\); it looks binary"):
        load_config(path)


# ---------------------------------------------------------------------- train / validation separation
def same_file(data_window: dict, val_window: dict) -> dict:
    doc = minimal()
    doc["data"].update(data_window)
    doc["validation"] = dict(val_window)
    return doc


class TestHeldOut:
    def test_validation_using_the_training_file_without_a_window(self):
        with pytest.raises(ConfigError, match="validation: uses the training file without 'rows' or 'time_window'"):
            parse(same_file({"rows": [0, 1000]}, {}))

    def test_training_must_be_windowed_when_validation_reads_its_file(self):
        with pytest.raises(ConfigError, match="data: training uses the whole file that validation also reads"):
            parse(same_file({}, {"rows": [1000, 2000]}))

    @pytest.mark.parametrize(
        "train, valid",
        [([0, 1000], [999, 2000]), ([500, 1500], [0, 501]), ([0, 1000], [100, 200]), ([100, 200], [0, 1000])],
    )
    def test_overlapping_rows(self, train, valid):
        with pytest.raises(ConfigError, match=rf"validation window \[{valid[0]}, {valid[1]}\] overlaps the training window \[{train[0]}, {train[1]}\]"):
            parse(same_file({"rows": train}, {"rows": valid}))

    def test_adjacent_half_open_windows_do_not_overlap(self):
        cfg = parse(same_file({"rows": [0, 1000]}, {"rows": [1000, 1500]}))
        assert (cfg.data.rows, cfg.validation.rows) == ((0, 1000), (1000, 1500))
        cfg = parse(same_file({"time_window": [10.0, 20.0]}, {"time_window": [0.0, 10.0]}))
        assert cfg.validation.time_window == (0.0, 10.0)

    def test_overlapping_time_windows(self):
        with pytest.raises(ConfigError, match="overlaps the training window"):
            parse(same_file({"time_window": [0.0, 20.0]}, {"time_window": [19.5, 30.0]}))

    def test_rows_against_time_window(self):
        with pytest.raises(ConfigError, match="data and validation windows must both be 'rows' or both 'time_window'"):
            parse(same_file({"rows": [0, 1000]}, {"time_window": [30.0, 40.0]}))

    def test_the_same_training_file_named_differently_is_caught(self, tmp_path):
        text = """\
[robot]
model = "builtin:puma560"
[data]
file = "logs/train.csv"
time = { column = "t" }
position = { columns = ["q1"] }
effort = { columns = ["tau1"] }
[validation]
file = "./logs/../logs/train.csv"
"""
        # the paths differ as strings only: it is still the training file
        with pytest.raises(ConfigError, match="validation: uses the training file without"):
            load_config(write(tmp_path, text))


class TestInheritance:
    def test_validation_inherits_everything_but_the_window(self):
        doc = minimal()
        doc["data"]["time"] = {"column": "stamp", "unit": "ms"}
        doc["data"]["position"]["unit"] = "deg"
        doc["data"]["rows"] = [0, 100]
        cfg = parse(doc, Path("/cfg"))
        v = cfg.validation
        assert v.file == Path("/cfg/valid.csv")
        assert (v.time.column, v.time.unit) == ("stamp", "ms")
        assert (v.position.columns, v.position.unit) == (("q1", "q2"), "deg")
        assert v.effort == cfg.data.effort
        assert v.rows is None  # a different file: the whole of it

    def test_validation_overrides_one_signal(self):
        doc = with_(minimal(), "validation.position", {"columns": ["p1", "p2"], "unit": "deg"})
        cfg = parse(doc)
        assert cfg.validation.position.columns == ("p1", "p2")
        assert cfg.validation.position.unit == "deg"
        assert cfg.validation.effort.columns == ("tau1", "tau2")
        assert cfg.data.position.columns == ("q1", "q2")

    def test_validation_with_a_sample_rate_replaces_the_inherited_time_column(self):
        cfg = parse(with_(minimal(), "validation.sample_rate_hz", 500.0))
        assert cfg.validation.time is None and cfg.validation.sample_rate_hz == 500.0
        assert cfg.data.time.column == "t"

    def test_validation_with_a_time_column_replaces_the_inherited_sample_rate(self):
        doc = with_(without(minimal(), "data.time"), "data.sample_rate_hz", 100.0)
        cfg = parse(with_(doc, "validation.time", {"column": "stamp"}))
        assert cfg.validation.sample_rate_hz is None and cfg.validation.time.column == "stamp"

    def test_validation_file_replaces_per_signal_training_files(self):
        # [data] reads positions and time from pos.csv, efforts from eff.csv; [validation]
        # names its own file: every inherited signal must come from it, not from eff.csv.
        doc = minimal()
        doc["data"]["file"] = "pos.csv"
        doc["data"]["effort"]["file"] = "eff.csv"
        doc["validation"] = {"file": "valid.csv"}
        cfg = parse(doc, Path("/cfg"))
        assert cfg.validation.files() == (Path("/cfg/valid.csv"),)
        assert cfg.data.files() == (Path("/cfg/pos.csv"), Path("/cfg/eff.csv"))

    def test_validation_per_signal_files(self):
        doc = minimal()
        doc["validation"] = {
            "file": "vpos.csv",
            "effort": {"columns": ["tau1", "tau2"], "file": "veff.csv"},
        }
        cfg = parse(doc, Path("/cfg"))
        assert cfg.validation.files() == (Path("/cfg/vpos.csv"), Path("/cfg/veff.csv"))
