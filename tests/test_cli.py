"""The ``dynid`` command, run as a real subprocess on logs simulated with the library.

Each command costs about a second of interpreter start-up (scipy, pinocchio), so all of
them are started together, in parallel, by the module fixture ``runs``; every test then
checks the outcome of its own case. A case is one or more command lines run in order in
a folder of its own.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import subprocess
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import doc_text, dynid_command, snapshot

from dynid.model import load_robot, robot_base_parameters
from dynid.simulation import FourierTrajectory, simulate_serial

FS = 100.0  # Hz
TORQUE_NOISE = np.array([1.0, 1.5, 0.6, 0.08, 0.08, 0.05])  # N*m
POSITION_NOISE = 2e-5  # rad
N_TRAIN, N_VALID = 2000, 1000  # 20 s and 10 s at 100 Hz
JOINTS = 6
Q = [f"q{j + 1}" for j in range(JOINTS)]
TAU = [f"tau{j + 1}" for j in range(JOINTS)]


# ---------------------------------------------------------------------- simulated logs
@dataclass(frozen=True)
class Log:
    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray

    def table(self) -> np.ndarray:
        return np.column_stack([self.t, self.q, self.tau])


@dataclass(frozen=True)
class Logs:
    folder: Path
    train: Log
    valid: Log
    truth_base: np.ndarray
    base_names: tuple[str, ...]

    @property
    def train_csv(self) -> Path:
        return self.folder / "train.csv"

    @property
    def valid_csv(self) -> Path:
        return self.folder / "valid.csv"


def write_table(path: Path, header: list[str], table: np.ndarray) -> Path:
    with open(path, "w") as fh:
        fh.write(",".join(header) + "\n")
        for row in table:
            fh.write(",".join(repr(float(v)) for v in row) + "\n")
    return path


def write_log(path: Path, table: np.ndarray) -> Path:
    return write_table(path, ["t", *Q, *TAU], table)


def config(train: Path | str, valid: Path | str, *, plots: bool = False, lowpass: bool = True, extra: str = "") -> str:
    """A configuration of builtin:puma560 logs (the shape of docs/guide/configuration.md's example)."""
    lp = "lowpass = { cutoff_hz = 5.0, order = 4, filter_effort = false }" if lowpass else ""
    return f"""\
[robot]
model = "builtin:puma560"
extras = ["Ia", "fv", "fc", "offset"]

[data]
file = "{train}"
time = {{ column = "t", unit = "s" }}
position = {{ columns = {json.dumps(Q)}, unit = "rad" }}
effort = {{ columns = {json.dumps(TAU)}, kind = "torque", unit = "N*m" }}

[validation]
file = "{valid}"

[processing]
{lp}
derivatives = "central"

[identification]
method = "wls"

[output]
plots = {str(plots).lower()}
{extra}"""


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Logs:
    robot = load_robot("builtin:puma560")
    truth = robot.nominal_parameters()
    rng = np.random.default_rng(2026)
    lo, hi = robot.position_limits()
    train_traj = FourierTrajectory.random(JOINTS, 5, 0.1, rng, lo, hi, max_velocity=1.5, max_acceleration=4.0, fill=0.6)
    valid_traj = FourierTrajectory.random(JOINTS, 4, 0.125, rng, lo, hi, max_velocity=1.2, max_acceleration=3.0, fill=0.5)
    sim = dict(fs=FS, torque_noise_std=TORQUE_NOISE, position_noise_std=POSITION_NOISE, rng=rng)
    train = simulate_serial(robot, truth, train_traj, duration=N_TRAIN / FS, **sim)
    valid = simulate_serial(robot, truth, valid_traj, duration=N_VALID / FS, **sim)
    base = robot_base_parameters(robot)  # seed 0, as identification.base_seed defaults to
    folder = tmp_path_factory.mktemp("logs")
    out = Logs(folder, Log(train.t, train.q, train.tau), Log(valid.t, valid.q, valid.tau), base.from_standard(truth), base.names)
    write_log(out.train_csv, out.train.table())
    write_log(out.valid_csv, out.valid.table())
    return out


# ---------------------------------------------------------------------- cases
Setup = Callable[[Path, Logs], list[list[str]]]
CASES: dict[str, Setup] = {}


def case(name: str):
    def register(fn: Setup) -> Setup:
        CASES[name] = fn
        return fn

    return register


def identify(d: Path, cfg_text: str, *extra: str) -> list[str]:
    (d / "cfg.toml").write_text(cfg_text)
    return ["identify", str(d / "cfg.toml"), "--out", str(d / "out"), *extra]


def variant(d: Path, logs: Logs, change: Callable[[np.ndarray], np.ndarray], **kw) -> list[list[str]]:
    """Identify on a modified copy of the training log."""
    table = change(logs.train.table().copy())
    write_log(d / "train.csv", table)
    return [identify(d, config(d / "train.csv", logs.valid_csv, **kw))]


@case("ok")
def _(d, logs):
    return [identify(d, config(logs.train_csv, logs.valid_csv))]


@case("plots_then_rerun_without")
def _(d, logs):
    first = identify(d, config(logs.train_csv, logs.valid_csv, plots=True), "-q")
    (d / "cfg2.toml").write_text(config(logs.train_csv, logs.valid_csv, plots=False))
    return [first, ["identify", str(d / "cfg2.toml"), "--out", str(d / "out"), "-q"]]


@case("missing_config")
def _(d, logs):
    return [["identify", str(d / "none.toml"), "--out", str(d / "out")]]


@case("missing_data")
def _(d, logs):
    return [identify(d, config(d / "nope.csv", logs.valid_csv))]


@case("wrong_columns")
def _(d, logs):
    text = config(logs.train_csv, logs.valid_csv).replace('"q1", "q2"', '"joint1", "q2"')
    return [identify(d, text)]


def set_cell(row: int, col: int, value: float):
    def change(table):
        table[row, col] = value
        return table

    return change


@case("nan")
def _(d, logs):
    return variant(d, logs, set_cell(49, 1 + 1, math.nan))  # q2 at sample 49


@case("inf")
def _(d, logs):
    return variant(d, logs, set_cell(120, 1 + JOINTS + 4, math.inf))  # tau5 at sample 120


@case("non_monotonic")
def _(d, logs):
    def swap(table):
        table[[100, 101]] = table[[101, 100]]
        return table

    return variant(d, logs, swap)


@case("mismatched_lengths")
def _(d, logs):
    table = logs.train.table()
    write_table(d / "pos.csv", ["t", *Q], table[:, : 1 + JOINTS])
    write_table(d / "eff.csv", TAU, table[:-5, 1 + JOINTS :])
    text = config(d / "pos.csv", logs.valid_csv).replace('unit = "N*m" }', f'unit = "N*m", file = "{d / "eff.csv"}" }}')
    assert "eff.csv" in text
    return [identify(d, text)]


@case("fewer_samples_than_parameters")
def _(d, logs):
    # 10 samples, no filter: 2 trimmed at each end leaves 6 x 6 = 36 equations for 58 parameters
    return variant(d, logs, lambda table: table[:10], lowpass=False)


@case("joint_never_moves")
def _(d, logs):
    (d / "out").mkdir()  # an existing output folder: must be left as it is
    (d / "out" / "result.json").write_text("{}")
    (d / "out" / "notes.txt").write_text("mine")

    def freeze(table):
        table[:, 1 + 2] = 0.25  # joint 3 held still
        return table

    return variant(d, logs, freeze)


@case("out_is_a_file")
def _(d, logs):
    (d / "out").write_text("not a folder")
    return [identify(d, config(logs.train_csv, logs.valid_csv))]


@case("unknown_key")
def _(d, logs):
    return [identify(d, config(logs.train_csv, logs.valid_csv).replace("[processing]\n", "[processing]\nlowpass_hz = 5.0\n"))]


@case("bad_toml")
def _(d, logs):
    return [identify(d, config(logs.train_csv, logs.valid_csv).replace("[output]", "[output"))]


@case("info_json")
def _(d, logs):
    return [["info", "builtin:puma560", "--json"]]


@case("info_generic_no_extras")
def _(d, logs):
    return [["info", "builtin:generic6r", "--json", "--extras", ""]]


@case("info_unknown_robot")
def _(d, logs):
    return [["info", "builtin:nope"]]


for _mech in ("shang2dof", "rps3", "hexapod", "fivebar"):
    case(f"info_{_mech}_json")(lambda d, logs, _m=_mech: [["info", f"builtin:{_m}", "--json"]])
case("info_hexapod_text")(lambda d, logs: [["info", "builtin:hexapod"]])


def _readme_mjcf(d: Path, name: str, old: str, new: str) -> str:
    text = doc_text("parallel-robots")  # the guide's MJCF example (docs/guide/parallel-robots.md)
    xml = re.search(r"```xml\n(.*?)```", text, re.S).group(1)
    assert old in xml
    (d / name).write_text(xml.replace(old, new))
    return name


case("info_mechanism_bad_closure_body")(
    lambda d, logs: [["info", _readme_mjcf(d, "bad.xml", 'body1="dist1"', 'body1="dist9"')]])
case("info_mechanism_under_actuated")(
    lambda d, logs: [["info", _readme_mjcf(d, "one_motor.xml", '<motor joint="qa2"/>', "")]])


@dataclass
class Run:
    folder: Path
    steps: list[subprocess.CompletedProcess]
    before: dict | None  # snapshot of out/ before the last step (None: absent)
    after: list[dict | None]  # snapshot of out/ after each step

    @property
    def last(self) -> subprocess.CompletedProcess:
        return self.steps[-1]

    @property
    def out(self) -> Path:
        return self.folder / "out"


@pytest.fixture(scope="module")
def runs(logs, tmp_path_factory) -> dict[str, Run]:
    root = tmp_path_factory.mktemp("cli")
    plans = {}
    for name, setup in CASES.items():
        d = root / name
        d.mkdir()
        plans[name] = (d, setup(d, logs))
    # one BLAS thread per process: the cases already run in parallel
    env = {**os.environ, "COLUMNS": "120", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

    def execute(name: str) -> Run:
        d, steps = plans[name]
        done, before, after = [], None, []
        for argv in steps:
            before = snapshot(d / "out")
            done.append(subprocess.run(dynid_command() + argv, cwd=d, env=env, capture_output=True, text=True, timeout=300))
            after.append(snapshot(d / "out"))
        return Run(d, done, before, after)

    with ThreadPoolExecutor(max_workers=max(4, os.cpu_count() or 4)) as pool:
        return dict(zip(plans, pool.map(execute, plans)))


def assert_input_error(run: Run, *needles: str) -> str:
    """Exit 2, one line 'dynid: error: ...' naming the problem, no traceback, no output."""
    r = run.last
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 2, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    line = lines[0]
    assert line.startswith("dynid: error: "), line
    for needle in needles:
        assert needle in line, line
    assert r.stdout == ""
    assert snapshot(run.out) == run.before  # not created, or unchanged
    assert not [p for p in run.folder.iterdir() if "staging" in p.name]
    return line


# ---------------------------------------------------------------------- info
def test_info_json(runs):
    r = runs["info_json"].last
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert (info["dof"], info["n_actuators"]) == (6, 6)
    # 10 inertial parameters per body + Ia, fv, fc, offset per joint
    assert info["n_standard_params"] == 6 * 10 + 6 * 4 == 84
    assert info["n_base_params"] == 58
    assert len(info["base_param_names"]) == 58 == len(set(info["base_param_names"]))
    assert info["base_param_names"][0] == "Izz1"
    assert info["extras"] == ["Ia", "fv", "fc", "offset"]


def test_info_without_extras(runs):
    r = runs["info_generic_no_extras"].last
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["extras"] == []
    assert info["n_standard_params"] == 6 * 10
    assert info["n_base_params"] == 36
    assert len(info["base_param_names"]) == 36


@pytest.mark.parametrize(
    "name, dof, n_actuators, redundant",
    [("shang2dof", 2, 3, True), ("rps3", 3, 3, False), ("hexapod", 6, 6, False), ("fivebar", 2, 2, False)],
)
def test_info_json_of_every_mechanism(runs, name, dof, n_actuators, redundant):
    r = runs[f"info_{name}_json"].last
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["kind"] == "closed-loop"
    assert (info["dof"], info["n_actuators"], info["redundant_actuation"]) == (dof, n_actuators, redundant)
    assert info["n_base_params"] == info["n_base_rigid_body"] + info["n_base_joint_terms"] == len(info["base_param_names"])
    assert 0 < info["n_base_params"] < info["n_standard_params"]
    if name == "shang2dof":
        assert (info["n_base_rigid_body"], info["n_base_joint_terms"]) == (10, 15)
    # the reduced structures of the identical chains each built-in declares or dynid finds in it (shang2dof's
    # chains 2 and 3: equal a, b, c in paper 001's Table 3), and the papers' symmetric bodies
    counts = {st: (d["n_base_rigid_body"], d["n_base_params"]) for st, d in info["structures"].items()}
    assert counts == {"shang2dof": {"identical_chains": (7, 22)}, "rps3": {"identical_chains": (15, 24)}, "fivebar": {},
                      "hexapod": {"identical_chains": (23, 37), "paper": (10, 24)}}[name]


def test_info_text_of_a_mechanism(runs):
    r = runs["info_hexapod_text"].last
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "degrees of freedom: 6" in out and "actuators        : 6" in out
    assert re.search(r"base params      : \d+ \(\d+ rigid-body \+ 14 joint terms\)", out), out
    assert "structure paper           : 54 parameters, 24 base (10 rigid-body + 14 joint terms)" in out, out


def test_info_mechanism_errors_are_one_line(runs):
    assert_input_error(runs["info_mechanism_bad_closure_body"], "bad.xml", "any body named dist9")
    assert_input_error(runs["info_mechanism_under_actuated"], "one_motor.xml",
                       "actuated joints ['qa1'] are fewer than the mobility 2: the mechanism is under-actuated")


def test_info_unknown_robot(runs):
    assert_input_error(runs["info_unknown_robot"], "unknown built-in robot 'nope'", "puma560")


# ---------------------------------------------------------------------- identify
def test_identify_recovers_the_simulated_robot(runs, logs):
    run = runs["ok"]
    r = run.last
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""  # no progress bar when stderr is not a terminal
    assert "Validation on held-out data" in r.stdout  # the summary, as -q is not given
    assert r.stdout.rstrip().endswith(f"outputs in {run.out}: model.urdf, params.csv, result.json, result.npz, summary.txt, timing.json")
    assert sorted(p.name for p in run.out.iterdir()) == ["model.urdf", "params.csv", "result.json", "result.npz", "summary.txt",
                                                       "timing.json"]

    res = json.loads((run.out / "result.json").read_text())
    assert res["method"] == "WLS"
    params = res["params"]
    assert [p["name"] for p in params] == list(logs.base_names)
    for p in params:
        assert set(p) >= {"name", "value", "std", "rel_std_pct", "ci_low", "ci_high"}
        assert p["std"] > 0
        assert p["ci_low"] < p["value"] < p["ci_high"]
        # 95 % interval of a t distribution with ~10^4 degrees of freedom: +-1.960 std
        assert (p["ci_high"] - p["ci_low"]) / 2 == pytest.approx(1.960 * p["std"], rel=2e-3)
        assert p["rel_std_pct"] == pytest.approx(100 * p["std"] / abs(p["value"]), rel=1e-4)

    # ground truth: the reported intervals cover the true base parameters ~95 % of the time
    value = np.array([p["value"] for p in params])
    std = np.array([p["std"] for p in params])
    inside = np.array([p["ci_low"] <= t <= p["ci_high"] for p, t in zip(params, logs.truth_base)])
    assert inside.sum() >= 50, f"{inside.sum()} of 58 true parameters inside their 95 % intervals"
    assert np.max(np.abs(value - logs.truth_base) / std) < 4.5

    # validation on the held-out log: prediction error ~ the simulated torque noise
    val = res["validation"]
    rmse = np.array(val["rmse_per_joint"])
    assert rmse.shape == (6,)
    np.testing.assert_array_less(0.85 * TORQUE_NOISE, rmse)
    np.testing.assert_array_less(rmse, 1.2 * TORQUE_NOISE)
    # 10 s at 100 Hz minus the filter transients trimmed at both ends
    # (5 time constants of a 4th-order 5 Hz filter: ceil(5 * 4 * 100 / (2 pi 5)) = 64 samples)
    assert val["n_samples"] == N_VALID - 2 * 64

    with open(run.out / "params.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [row["name"] for row in rows] == list(logs.base_names)
    for row, p in zip(rows, params):
        assert float(row["value"]) == p["value"]
        assert float(row["std"]) == p["std"]
        assert float(row["ci_low"]) == p["ci_low"] and float(row["ci_high"]) == p["ci_high"]
    summary = (run.out / "summary.txt").read_text()
    assert "Validation on held-out data (872 samples; never used for training)" in summary
    assert "Izz1" in summary


def test_identify_with_plots_writes_figure_and_report(runs):
    run = runs["plots_then_rerun_without"]
    first, files = run.steps[0], run.after[0]
    assert first.returncode == 0, first.stderr
    assert first.stdout.strip() == (
        f"outputs in {run.out}: model.urdf, params.csv, processing.png, report.html, result.json, result.npz, summary.txt, timing.json, validation.png"
    )
    for name in ("validation.png", "processing.png"):
        png = files[name]
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    html = files["report.html"].decode()
    assert "<html" in html.lower() and "validation.png" in html
    assert sorted(files) == ["model.urdf", "params.csv", "processing.png", "report.html", "result.json", "result.npz", "summary.txt", "timing.json",
                             "validation.png"]


def test_rerun_lists_only_the_files_it_wrote(runs):
    # A second run into the same folder with plots off must not claim the first run's
    # validation.png and report.html as its own outputs.
    run = runs["plots_then_rerun_without"]
    assert [s.returncode for s in run.steps] == [0, 0], run.last.stderr
    listed = run.last.stdout.strip().split(": ", 1)[1].split(", ")
    assert listed == ["model.urdf", "params.csv", "result.json", "result.npz", "summary.txt", "timing.json"]


# ---------------------------------------------------------------------- bad input
def test_missing_config_file(runs):
    assert_input_error(runs["missing_config"], "config file not found", "none.toml")


def test_missing_data_file(runs):
    assert_input_error(runs["missing_data"], "data file not found", "nope.csv")


def test_wrong_column_names(runs):
    line = assert_input_error(runs["wrong_columns"], "missing columns ['joint1']", "train.csv")
    assert "'q1'" in line.split("the file has")[1]  # lists what the file does have


def test_nan_in_data(runs):
    assert_input_error(runs["nan"], "data: positions contains NaN values", "first at sample 49")


def test_inf_in_data(runs):
    assert_input_error(runs["inf"], "data: efforts contains inf values", "first at sample 120")


def test_non_monotonic_time(runs):
    assert_input_error(runs["non_monotonic"], "data: time is not strictly increasing at sample 101 (t=1.0 after t=1.01)")


def test_mismatched_lengths(runs):
    line = assert_input_error(runs["mismatched_lengths"], "data: mismatched lengths")
    assert re.search(r"position \(\S*pos.csv\) 2000", line) and re.search(r"effort \(\S*eff.csv\) 1995", line), line


def test_fewer_samples_than_parameters(runs):
    assert_input_error(runs["fewer_samples_than_parameters"], "6 processed samples x 6 joints are fewer than the 58 base parameters")


def test_joint_that_never_moves(runs):
    run = runs["joint_never_moves"]
    line = assert_input_error(run, "joint never moves: joint_3")
    for name in ("Ia3", "fv3", "fc3"):
        assert name in line
    assert run.before == {"notes.txt": b"mine", "result.json": b"{}"}  # and so is after


def test_out_is_an_existing_file(runs):
    run = runs["out_is_a_file"]
    assert_input_error(run, "exists and is not a folder")
    assert run.out.read_text() == "not a folder"


def test_unknown_config_key(runs):
    assert_input_error(runs["unknown_key"], "unknown key processing.lowpass_hz")


def test_bad_toml_syntax(runs):
    assert_input_error(runs["bad_toml"], "cfg.toml: invalid TOML")


def test_design_that_violates_a_limit_writes_nothing(tmp_path, monkeypatch, capsys):
    """``dynid design`` whose best design still violates a limit on the fine grid (the search's
    outcome flagged unsuccessful): one line naming the limit, exit 2, no output folder (nor a
    changed one). The real search on the corpus' good config, with its design marked infeasible."""
    import dataclasses

    import dynid.pipeline.design as pd
    from _bad_inputs import DESIGN, ROBOT
    from dynid.cli import main
    from dynid.excitation.design import Violation

    (tmp_path / "rp2.toml").write_text(ROBOT)
    (tmp_path / "design.toml").write_text(DESIGN)
    real = pd.run_design

    def infeasible(cfg, progress=None):
        out = real(cfg, progress)
        bad = Violation(limit="velocity", actuator="q1", value=2.5, bound=2.0)
        return dataclasses.replace(out, design=dataclasses.replace(out.design, success=False, violation=bad))

    monkeypatch.setattr(pd, "run_design", infeasible)
    for existing in (False, True):
        out = tmp_path / ("kept" if existing else "new")
        if existing:
            out.mkdir()
            (out / "design.json").write_text("{}")
        before = snapshot(out)
        rc = main(["design", str(tmp_path / "design.toml"), "--out", str(out), "-q"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and err[0].startswith("dynid: error: no design within the limits"), err
        assert "velocity" in err[0] and snapshot(out) == before
