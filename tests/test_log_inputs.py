"""The other log inputs (issue 20): ROS bags (ROS 1 .bag, ROS 2 sqlite3 folder, ROS 2 mcap folder and
file), Parquet, headerless CSV with column indices, ``${VAR}`` and ``data_root`` in configs.

Every input holds the same simulated log as tests/_bad_inputs.py's ``log.csv`` (the rp2 arm, 3 s at
100 Hz, float64 values written exactly); ``dynid identify`` on it must give the CSV's estimate. The
values are the same doubles and the time differs at most by the rounding of ``k * 1e-9`` against
``k / 100`` (1 ulp), so the estimates agree to ~1e-11 of their standard deviations; the tests allow
1e-6 std. Bad bags and configs are refused through the command with one line (exit 2).
"""

from __future__ import annotations

import json
import re
import tomllib

import numpy as np
import pytest
from _bad_inputs import IDENTIFY, Work, assert_refused, make_table, snapshot
from conftest import doc_text

from dynid.cli import main

rosbags = pytest.importorskip("rosbags", reason="the [ros] extra (rosbags) is not installed")
from _bags import EPOCH_NS, BagWriter, stamps_ns, write_table_bag  # noqa: E402


BAG_DATA = """\
[data]
file = "{file}"
topic = "/joint_states"
rows = [0, 240]
position = {{ columns = ["shoulder", "slide"], unit = ["rad", "m"] }}
effort = {{ columns = ["shoulder", "slide"], unit = ["N*m", "N"]{effort_extra} }}
{extra}
"""
CSV_DATA = """\
[data]
file = "log.csv"
time = { column = "t", unit = "s" }
rows = [0, 240]
position = { columns = ["q1", "q2"], unit = ["rad", "m"] }
effort = { columns = ["tau1", "tau2"], unit = ["N*m", "N"] }
"""
assert CSV_DATA in IDENTIFY


@pytest.fixture(scope="module")
def table() -> np.ndarray:
    return make_table()


@pytest.fixture(scope="module")
def reference(table, tmp_path_factory) -> dict:
    """``dynid identify`` of the CSV log: the estimate every other input must reproduce."""
    w = Work(tmp_path_factory.mktemp("csv"), table)
    assert main(w.run("identify") + ["-q"]) == 0
    return json.loads((w.out / "result.json").read_text())


def run_argv(w: Work, data: str, top: str = "") -> list[str]:
    """``dynid identify`` of the good configuration with its [data] replaced, ``top`` (top-level keys) first."""
    w.write("cfg.toml", top + IDENTIFY.replace(CSV_DATA, data))
    return ["identify", str(w.dir / "cfg.toml"), "--out", str(w.out)]


def identify(w: Work, data: str, capfd, top: str = "") -> dict:
    """``dynid identify`` of the good configuration with its [data] replaced; the result."""
    argv = run_argv(w, data, top) + ["-q"]
    capfd.readouterr()
    code = main(argv)
    out, err = capfd.readouterr()
    assert code == 0, err
    return json.loads((w.out / "result.json").read_text())


def assert_same_estimate(res: dict, ref: dict) -> None:
    names = [p["name"] for p in ref["params"]]
    assert [p["name"] for p in res["params"]] == names
    value, ref_value = (np.array([p["value"] for p in r["params"]]) for r in (res, ref))
    std = np.array([p["std"] for p in ref["params"]])
    assert np.all(std > 0)
    np.testing.assert_array_less(np.abs(value - ref_value), 1e-6 * std)
    np.testing.assert_allclose(res["validation"]["rmse_per_joint"], ref["validation"]["rmse_per_joint"], rtol=1e-6)
    assert res["validation"]["n_samples"] == ref["validation"]["n_samples"]


def bag_data(file: str, extra: str = "", effort_extra: str = "") -> str:
    return BAG_DATA.format(file=file, extra=extra, effort_extra=effort_extra)


def swap_odd(k: int) -> tuple[int, int]:
    """Joint order of message k: (slide, shoulder) in every other message."""
    return (1, 0) if k % 2 else (0, 1)


# ---------------------------------------------------------------------- ROS bags: same estimate as CSV
@pytest.mark.parametrize("kind, name", [("ros1", "log.bag"), ("sqlite3", "log_ros2"), ("mcap", "log_mcap"),
                                        ("mcap", "log_mcap/log_mcap.mcap"), ("sqlite3", "log_ros2/log_ros2.db3")])
def test_bag_gives_the_csv_estimate(kind, name, tmp_path, table, reference, capfd):
    """A ROS 1 bag, a ROS 2 bag folder (sqlite3, mcap) or its one storage file, the joints in another
    order in every other message and a third joint (a gripper) in every message: values are picked by name."""
    w = Work(tmp_path, table)
    folder = name.split("/")[0]
    write_table_bag(tmp_path / folder, kind, table, order=swap_odd, extra_joint=True)
    res = identify(w, bag_data(name), capfd)
    assert_same_estimate(res, reference)
    prov = res["provenance"]["training_data"]
    assert prov["ros_topics"] == {"position": "/joint_states", "effort": "/joint_states"}
    assert prov["time_source"] == "header"
    assert list(prov["sha256"]) == [str(tmp_path / name)]


def test_efforts_on_another_topic(tmp_path, table, reference, capfd):
    """Positions on /joint_states, efforts on /joint_efforts with the same stamps: message for message."""
    w = Work(tmp_path, table)
    write_table_bag(tmp_path / "log.bag", "ros1", table, effort_topic="/joint_efforts", order=swap_odd)
    res = identify(w, bag_data("log.bag", effort_extra=', topic = "/joint_efforts"'), capfd)
    assert_same_estimate(res, reference)
    assert res["provenance"]["training_data"]["ros_topics"] == {"position": "/joint_states", "effort": "/joint_efforts"}


def test_receive_time_when_asked(tmp_path, table, reference, capfd):
    """Header stamps that jump back once (a driver's clock reset) are refused naming the message and the
    way out; time = "receive" reads the bag's receive times (here the stamps + 3 ms) and gives the CSV estimate."""
    stamps = stamps_ns(table[:, 0])
    stamps[100] = stamps[0]
    write_table_bag(tmp_path / "log.bag", "ros1", table, stamps=stamps, latency_ns=3_000_000)
    w = Work(tmp_path, table)
    argv = run_argv(w, bag_data("log.bag"))
    capfd.readouterr()
    code = main(argv)
    out, err = capfd.readouterr()
    assert_refused(code, out, err, ["topic '/joint_states': the header stamps do not increase at message 101",
                                    "data.time = 'receive'"], tmp_path, w.out, None)
    # the receive times: t = (receive - first receive), the CSV's time to 1 ulp
    res = identify(w, bag_data("log.bag", extra='time = "receive"'), capfd)
    assert_same_estimate(res, reference)
    assert res["provenance"]["training_data"]["time_source"] == "receive"


def test_other_topic_interpolated_onto_the_position_times(tmp_path, table):
    """Efforts published on their own clock, half a sample after the positions: they are interpolated
    linearly onto the position stamps, and the position samples outside the effort topic's span are
    left out. Efforts linear in time are interpolated exactly (to rounding)."""
    from dynid.config import load_config
    from dynid.pipeline.data import read_log

    t = table[:, 0]
    w = BagWriter(tmp_path / "log.bag", "ros1")
    for k, tk in enumerate(t):
        w.joint_state("/joint_states", int(stamps_ns([tk])[0]), ["shoulder", "slide"], position=table[k, 1:3])
        te = tk + 0.005
        w.joint_state("/currents", int(stamps_ns([te])[0]), ["slide", "shoulder"], effort=[1.0 - 2.0 * te, 2.0 + 3.0 * te])
    w.close()
    work = Work(tmp_path, table)
    cfg = load_config(work.config("identify", CSV_DATA, bag_data("log.bag", effort_extra=', topic = "/currents"')))
    ds = read_log(cfg.data, 2, ("shoulder", "slide"), "data")
    # the first position sample (t = 0) precedes the first effort (t = 5 ms): left out; rows [0, 240) of the rest
    np.testing.assert_allclose(ds.t, t[1:241], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ds.tau, np.column_stack([2.0 + 3.0 * t[1:241], 1.0 - 2.0 * t[1:241]]), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(ds.q, table[1:241, 1:3])
    assert ds.meta["ros_topics"]["effort"] == "/currents (interpolated linearly onto the /joint_states times)"


# ---------------------------------------------------------------------- ROS bags: refused with one line
def _refused(tmp_path, table, capfd, data: str, *fragments: str, make=None, top: str = "") -> str:
    w = Work(tmp_path, table)
    if make is not None:
        make(tmp_path)
    argv = run_argv(w, data, top)
    capfd.readouterr()
    before = snapshot(w.out)
    code = main(argv)
    out, err = capfd.readouterr()
    return assert_refused(code, out, err, fragments, tmp_path, w.out, before)


def _bag(table, **kw):
    return lambda d: write_table_bag(d / "log.bag", "ros1", table, **kw)


def _float_bag(d):
    w = BagWriter(d / "log.bag", "ros1")
    w.float64("/joint_states", EPOCH_NS, 1.0)
    w.close()


def _empty_bag(d):
    BagWriter(d / "log.bag", "ros1").close()


def _empty_topic(d):
    w = BagWriter(d / "log.bag", "ros1")
    w.connection("/joint_states")
    w.close()


def _no_efforts(table):
    def make(d):
        w = BagWriter(d / "log.bag", "ros1")
        for k, row in enumerate(table):
            w.joint_state("/joint_states", int(stamps_ns(row[:1])[0]), ["shoulder", "slide"], position=row[1:3])
        w.close()
    return make


BAD_BAGS = {
    "no-such-topic": (lambda table: (bag_data("log.bag").replace('"/joint_states"', '"/joint_state"'), _bag(table)),
                      ["log.bag: no topic '/joint_state'", "the bag has /joint_states (sensor_msgs/msg/JointState)"]),
    "wrong-message-type": (lambda table: (bag_data("log.bag"), _float_bag),
                           ["topic '/joint_states' carries std_msgs/msg/Float64", "dynid reads sensor_msgs/msg/JointState"]),
    "empty-bag": (lambda table: (bag_data("log.bag"), _empty_bag), ["log.bag: the bag holds no topics"]),
    "topic-without-messages": (lambda table: (bag_data("log.bag"), _empty_topic), ["topic '/joint_states' has no messages"]),
    "missing-joint": (lambda table: (bag_data("log.bag").replace('"slide"]', '"elbow"]', 1), _bag(table, order=swap_odd)),
                      ["message 1 of '/joint_states' has no joint 'elbow'", "it names ['shoulder', 'slide']"]),
    "no-efforts-published": (lambda table: (bag_data("log.bag"), _no_efforts(table)),
                             ["message 1 of '/joint_states' has 0 effort values for 2 joint names"]),
    "unreadable-bag": (lambda table: (bag_data("log.bag"), lambda d: (d / "log.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\x07" * 64)),
                       ["cannot read ROS bag", "log.bag"]),
    "not-a-bag-folder": (lambda table: (bag_data("logs"), lambda d: (d / "logs").mkdir()),
                         ["logs is a folder without metadata.yaml, not a ROS 2 bag"]),
    "unset-variable": (lambda table: (bag_data("${DYNID_TEST_UNSET_ROOT}/log.bag"), _bag(table)),
                       ["data.file: environment variable DYNID_TEST_UNSET_ROOT is not set", "${DYNID_TEST_UNSET_ROOT}/log.bag"]),
    "no-topic": (lambda table: (bag_data("log.bag").replace('topic = "/joint_states"\n', ""), _bag(table)),
                 ["data.topic: name the sensor_msgs/JointState topic of the bag log.bag"]),
    "sample-rate": (lambda table: (bag_data("log.bag", extra="sample_rate_hz = 100.0"), _bag(table)),
                    ["data.sample_rate_hz: a ROS bag's messages carry their own time"]),
    "time-column": (lambda table: (bag_data("log.bag", extra='time = { column = "t" }'), _bag(table)),
                    ["data.time of a ROS bag log is 'header'", "or 'receive'"]),
    "acceleration": (lambda table: (bag_data("log.bag", extra='acceleration = { columns = ["shoulder", "slide"] }'), _bag(table)),
                     ["data.acceleration: a JointState message has no accelerations"]),
    "topic-for-a-csv": (lambda table: (CSV_DATA + 'topic = "/joint_states"\n', None),
                        ["data.topic is for ROS bags"]),
    "unknown-key": (lambda table: (bag_data("log.bag", extra='topics = ["/joint_states"]'), _bag(table)),
                    ["unknown key data.topics; allowed keys in [data] are"]),
}


@pytest.mark.parametrize("name", list(BAD_BAGS))
def test_bad_bag_is_refused_with_one_line(name, tmp_path, table, capfd, monkeypatch):
    monkeypatch.delenv("DYNID_TEST_UNSET_ROOT", raising=False)
    build, fragments = BAD_BAGS[name]
    data, make = build(table)
    _refused(tmp_path, table, capfd, data, *fragments, make=make)


# ---------------------------------------------------------------------- Parquet, headerless CSV, ${VAR}, data_root
def test_parquet_gives_the_csv_estimate(tmp_path, table, reference, capfd):
    """pyarrow is installed by make setup (extra [parquet]): a Parquet log reads as the CSV."""
    pytest.importorskip("pyarrow", reason="the [parquet] extra (pyarrow) is not installed")
    import pandas as pd

    w = Work(tmp_path, table)
    pd.DataFrame(table, columns=["t", "q1", "q2", "tau1", "tau2"]).to_parquet(tmp_path / "log.parquet")
    assert_same_estimate(identify(w, CSV_DATA.replace("log.csv", "log.parquet"), capfd), reference)


HEADERLESS = """\
[data]
file = "log.csv"
header = false
time = { column = 0, unit = "s" }
rows = [0, 240]
position = { columns = [1, 2], unit = ["rad", "m"] }
effort = { columns = [3, 4], unit = ["N*m", "N"] }
"""


def test_headerless_csv_by_column_index(tmp_path, table, reference, capfd):
    w = Work(tmp_path, table)
    lines = (tmp_path / "log.csv").read_text().splitlines()
    assert lines[0] == "t,q1,q2,tau1,tau2"
    (tmp_path / "log.csv").write_text("\n".join(lines[1:]) + "\n")
    assert_same_estimate(identify(w, HEADERLESS, capfd), reference)


@pytest.mark.parametrize("data, fragments", [
    (HEADERLESS.replace("[3, 4]", '["tau1", "tau2"]'),
     ["data.effort.columns[0]: the file has no header row (header = false): name columns by index", "'tau1'"]),
    (HEADERLESS.replace("[3, 4]", "[3, 7]"), ["log.csv: missing columns ['7']; the file has 5 columns (0 to 4"]),
    (HEADERLESS.replace("[3, 4]", "[3, -1]"), ["data.effort.columns[1]: must be >= 0, got -1"]),
    (HEADERLESS.replace("header = false", 'header = "no"'), ["data.header: expected true or false"]),
])
def test_headerless_csv_errors(data, fragments, tmp_path, table, capfd):
    def strip_header(d):
        lines = (d / "log.csv").read_text().splitlines()
        (d / "log.csv").write_text("\n".join(lines[1:]) + "\n")

    _refused(tmp_path, table, capfd, data, *fragments, make=strip_header)


def test_variables_and_data_root(tmp_path, table, reference, capfd, monkeypatch):
    """data_root = "${DYNID_LOGS}/runs": the logs' relative paths start there (and ${VAR} in a file)."""
    w = Work(tmp_path, table)
    (tmp_path / "store" / "runs" / "day1").mkdir(parents=True)
    (tmp_path / "log.csv").rename(tmp_path / "store" / "runs" / "day1" / "log.csv")
    monkeypatch.setenv("DYNID_LOGS", str(tmp_path / "store"))
    monkeypatch.setenv("DYNID_DAY", "day1")
    data = CSV_DATA.replace('"log.csv"', '"${DYNID_DAY}/log.csv"')
    res = identify(w, data, capfd, top='data_root = "${DYNID_LOGS}/runs"\n\n')
    assert_same_estimate(res, reference)
    assert res["provenance"]["training_data"]["source"]["position"] == str(tmp_path / "store" / "runs" / "day1" / "log.csv")


@pytest.mark.parametrize("root, fragments", [
    ('"${DYNID_TEST_UNSET_ROOT}"', ["data_root: environment variable DYNID_TEST_UNSET_ROOT is not set"]),
    ('"${DYNID_EMPTY}/x"', ["data_root: environment variable DYNID_EMPTY is empty"]),
    ('"${1X}"', ["data_root: '${1X}' is not a variable name"]),
    ('"nowhere"', ["data_root:", "nowhere is not found"]),
    ('"rp2.toml"', ["data_root:", "rp2.toml is not a folder"]),
    ("3", ["data_root: expected a string, got 3"]),
])
def test_data_root_errors(root, fragments, tmp_path, table, capfd, monkeypatch):
    monkeypatch.delenv("DYNID_TEST_UNSET_ROOT", raising=False)
    monkeypatch.setenv("DYNID_EMPTY", "")
    _refused(tmp_path, table, capfd, CSV_DATA, *fragments, top=f"data_root = {root}\n\n")


# ------------------------------------------------------------------------ the guide shows each input
def test_readme_shows_each_new_input(tmp_path, table):
    """The guide's "Other log inputs" snippets (docs/guide/data.md): one per input, each a [data] table the
    schema accepts."""
    from dynid.config import parse_config

    text = doc_text("data").split("\n## Other log inputs", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```toml\n(.*?)```", text, re.S)
    shown = "\n".join(blocks)
    for needle in ("run.bag", ".mcap", 'topic = "/joint_states"', 'time = "receive"', ".parquet", "header = false",
                   "data_root", "${"):
        assert needle in shown, needle
    for block in blocks:
        doc = tomllib.loads(block)
        doc = {"robot": {"model": "builtin:puma560"}, "validation": {"rows": [2000, 3000]},
               **doc, "data": {"rows": [0, 2000], **doc["data"]}}
        (tmp_path / "lab3").mkdir(exist_ok=True)
        env = {"DYNID_DATA": str(tmp_path)}
        with pytest.MonkeyPatch.context() as mp:
            for k, v in env.items():
                mp.setenv(k, v)
            cfg = parse_config(doc, tmp_path)
        assert cfg.data.file is not None
        assert cfg.data.bag == ("topic" in doc["data"])
        if "data_root" in doc:
            assert cfg.data.file == tmp_path / "lab3" / "2026-11-20" / "run.csv"


def test_bag_without_rosbags_names_the_extra(tmp_path, table, capfd, monkeypatch):
    """Without rosbags installed (its import fails), reading a bag names the extra to install."""
    import sys

    write_table_bag(tmp_path / "log.bag", "ros1", table)
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # import rosbags.highlevel raises ImportError
    _refused(tmp_path, table, capfd, bag_data("log.bag"), "reading ROS bags needs rosbags: pip install 'dynid[ros]'")


def test_measured_velocities_from_the_velocity_field(tmp_path, table):
    """velocity = { columns = [...] } reads the JointState velocity field, by name like the others."""
    from dynid.config import parse_config
    from dynid.pipeline.data import read_log

    dq = np.column_stack([np.cos(table[:, 0]), -2.0 * np.sin(table[:, 0])])
    w = BagWriter(tmp_path / "log_ros2", "sqlite3")
    for k, row in enumerate(table):
        idx = swap_odd(k)
        names = [("shoulder", "slide")[i] for i in idx]
        w.joint_state("/joint_states", int(stamps_ns(row[:1])[0]), names, position=row[1:3][list(idx)],
                      velocity=dq[k][list(idx)], effort=row[3:5][list(idx)])
    w.close()
    text = IDENTIFY.replace(CSV_DATA, bag_data("log_ros2", extra='velocity = { columns = ["shoulder", "slide"] }'))
    text = text.replace("lowpass = { cutoff_hz = 10.0, order = 2, filter_effort = false }", 'derivatives = "measured"')
    cfg = parse_config(tomllib.loads(text), tmp_path)
    ds = read_log(cfg.data, 2, ("shoulder", "slide"), "data")
    np.testing.assert_array_equal(ds.dq, dq[:240])
    np.testing.assert_array_equal(ds.q, table[:240, 1:3])
    np.testing.assert_array_equal(ds.tau, table[:240, 3:5])


@pytest.mark.parametrize("data, what", [(bag_data("log.bag"), "a ROS bag"), (HEADERLESS, "a headerless CSV")])
def test_friction_refuses_a_bag_and_a_headerless_csv(data, what, tmp_path):
    """dynid friction reads its label columns by name: a bag or a headerless CSV is refused at once."""
    from dynid.config.friction import parse_friction_config
    from dynid.errors import ConfigError

    doc = tomllib.loads(data)
    doc["data"].pop("rows")
    with pytest.raises(ConfigError, match=f"dynid friction reads the label columns .* not {what}$"):
        parse_friction_config({"robot": {"model": "builtin:puma560"}, **doc}, tmp_path)
