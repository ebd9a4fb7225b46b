"""A newcomer's mistakes with a log of their own 4-DOF arm: each one still gives a fit, so each
must give a warning naming its likely cause, on the console and in summary.txt (issue 34, items
10 and 13).

The arm is a small URDF written here (four revolute joints with position and effort limits and
nominal friction); the product's own virtual experiment (:func:`dynid.pipeline.simulate.run_simulation`,
the true robot 20 % off the nominal one) makes a training and a validation log, written as CSV
the way a user's logger would. The mistakes are made on the CSV, as a user makes them: positions
in degrees read as radians, every effort's sign flipped, two effort columns swapped, efforts in
mN·m read as N·m. The correct log must give none of the warnings (no false alarm).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import seed
from dynid.cli import main

URDF = """<?xml version="1.0"?>
<robot name="newcomer4">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0 0 0.1"/><mass value="3.0"/>
    <inertia ixx="0.03" iyy="0.03" izz="0.012" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0 0"/><mass value="2.0"/>
    <inertia ixx="0.004" iyy="0.02" izz="0.02" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l3"><inertial><origin xyz="0.12 0 0"/><mass value="1.2"/>
    <inertia ixx="0.002" iyy="0.008" izz="0.008" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l4"><inertial><origin xyz="0.03 0.02 0.01"/><mass value="0.5"/>
    <inertia ixx="0.0008" iyy="0.0006" izz="0.0006" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-2.8" upper="2.8" effort="60" velocity="3"/><dynamics damping="0.5" friction="1.0"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>
    <limit lower="-2.0" upper="2.0" effort="60" velocity="3"/><dynamics damping="0.4" friction="0.8"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5" effort="30" velocity="3"/><dynamics damping="0.3" friction="0.5"/></joint>
  <joint name="j4" type="revolute"><parent link="l3"/><child link="l4"/><origin xyz="0.25 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-3.0" upper="3.0" effort="10" velocity="4"/><dynamics damping="0.1" friction="0.2"/></joint>
</robot>
"""

HEADER = ["t", "q1", "q2", "q3", "q4", "tau1", "tau2", "tau3", "tau4"]
CONFIG = """\
[robot]
model = "arm4.urdf"
[data]
file = "{prefix}train.csv"
time = {{ column = "t", unit = "s" }}
position = {{ columns = ["q1", "q2", "q3", "q4"], unit = "rad" }}
effort = {{ columns = [{effort}], kind = "torque", unit = "N*m" }}
[validation]
file = "{prefix}valid.csv"
[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4 }}
derivatives = "central"
[identification]
method = "wls"
streaming = "{streaming}"
[output]
plots = {plots}
"""
EFFORT = '"tau1", "tau2", "tau3", "tau4"'

# the mistakes, made on the logged table (columns as HEADER), with the alarm each must raise and
# words of the cause it must name
MISTAKES = {
    "degrees": (lambda a: np.column_stack([a[:, :1], np.degrees(a[:, 1:5]), a[:, 5:]]),
                "position_limits", "the log is in degrees, read as radians"),
    "sign": (lambda a: np.column_stack([a[:, :5], -a[:, 5:]]), "effort_sign", "is flipped"),
    "swap": (lambda a: a[:, [0, 1, 2, 3, 4, 5, 7, 6, 8]], "swapped_columns", "the effort columns of j2 and j3 are swapped"),
    "millinewton": (lambda a: np.column_stack([a[:, :5], 1000.0 * a[:, 5:]]), "effort_limits",
                    "mN*m read as N*m"),
}
ALARMS = {"position_limits", "effort_limits", "effort_sign", "swapped_columns", "nominal_fit", "friction_sign"}


def _write(path: Path, table: np.ndarray) -> None:
    np.savetxt(path, table, delimiter=",", header=",".join(HEADER), comments="", fmt="%.17g")


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """The arm's training (2 periods of 4 s) and validation (1 period, another trajectory) logs,
    0.05 N*m of effort noise, and every mistaken copy of them."""
    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation

    d = tmp_path_factory.mktemp("newcomer")
    (d / "arm4.urdf").write_text(URDF)
    for name, s, periods in (("train", seed(1), 2), ("valid", seed(2), 1)):
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": str(d / "arm4.urdf"), "perturbation": 0.2, "perturbation_seed": 5},
            "trajectory": {"kind": "fourier", "base_frequency_hz": 0.25, "harmonics": 4, "fill": 0.6,
                           "max_velocity": 2.5, "max_acceleration": 6.0, "periods": periods, "seed": s},
            "control": {"rate_hz": 200, "kp": 400, "kd": 40, "model": "true", "substeps": 2},
        }, d))
        if name == "train":  # what dynid simulate prints
            (d / "simulate_summary.txt").write_text(sim.summary_text())
        m = sim.motion
        tau = m.tau + 0.05 * np.random.default_rng(s).standard_normal(m.tau.shape)
        table = np.column_stack([m.t, m.q, tau])
        _write(d / f"{name}.csv", table)
        for mistake, (make, _, _) in MISTAKES.items():
            _write(d / f"{mistake}_{name}.csv", make(table))
    return d


def _identify(d: Path, capsys, prefix: str = "", *, effort: str = EFFORT, plots: bool = False,
              streaming: str = "off") -> tuple[int, str, str, Path]:
    name = f"{prefix or 'correct'}{'_plots' if plots else ''}_{streaming}"
    cfg = d / f"{name}.toml"
    cfg.write_text(CONFIG.format(prefix=prefix, effort=effort, plots=str(plots).lower(), streaming=streaming))
    out = d / f"out_{name}"
    rc = main(["identify", str(cfg), "--out", str(out)])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err, out


@pytest.mark.numerics
def test_the_correct_log_raises_no_alarm_and_names_the_robot(logs, capsys):
    rc, stdout, _, out = _identify(logs, capsys)
    assert rc == 0
    summary = (out / "summary.txt").read_text()
    doc = json.loads((out / "result.json").read_text())
    assert doc["warnings"] == [], doc["warnings"]
    assert "WARNING" not in summary and "WARNING" not in stdout
    # the nominal model is 20 % off, the noise 0.05 N*m: the identified model beats it by far more
    # than the tie tolerance (its mean relative RMSE about 12 % against 19 %)
    assert doc["prior_comparison"]["beats_nominal"] and not doc["prior_comparison"]["tie"]
    # item 13: the summary names the robot identified and its description's file
    line = f"Robot: newcomer4 ({logs / 'arm4.urdf'})"
    assert summary.startswith(line) and line in stdout
    assert doc["robot"] == {"name": "newcomer4", "source": str(logs / "arm4.urdf")}
    # and the virtual experiment that made the log says which robot it simulated, from which file
    assert (logs / "simulate_summary.txt").read_text().startswith(
        f"robot            : newcomer4 (serial, 4 actuators; {logs / 'arm4.urdf'})")


@pytest.mark.numerics
@pytest.mark.parametrize("mistake", list(MISTAKES))
def test_each_mistake_is_named(logs, capsys, mistake):
    _, kind, cause = MISTAKES[mistake]
    rc, stdout, _, out = _identify(logs, capsys, f"{mistake}_")
    assert rc == 0  # the fit itself succeeds: that is why the warning matters
    summary = (out / "summary.txt").read_text()
    doc = json.loads((out / "result.json").read_text())
    kinds = [w["kind"] for w in doc["warnings"]]
    assert kind in kinds, doc["warnings"]
    assert set(kinds) <= ALARMS
    found = next(w for w in doc["warnings"] if w["kind"] == kind)
    assert cause in found["likely_cause"], found
    for text in (summary, stdout):
        assert "WARNING: " in text and cause in text
    # the verdict is not left standing alone
    assert "not to be trusted before the" in summary
    if mistake == "sign":  # friction dissipates: every coefficient negative is the same sign flip
        assert "friction_sign" in kinds and "swapped_columns" not in kinds
    if mistake == "swap":  # only the swapped pair: the other two joints keep their sign
        assert "effort_sign" not in kinds
    if mistake == "degrees":  # scaled by pi/180 every position fits: the unit to set is named
        assert 'data.position.unit = "deg"' in found["likely_cause"]


@pytest.mark.numerics
@pytest.mark.parametrize("mistake, kinds", [("", set()), ("degrees", {"position_limits", "nominal_fit"}),
                                            ("millinewton", {"effort_limits", "nominal_fit"}),
                                            ("sign", {"nominal_fit", "friction_sign"})])
def test_a_streamed_run_raises_the_alarms_its_data_allow(logs, capsys, mistake, kinds):
    """Streamed (a long log read chunk by chunk: no arrays kept) the limits are checked on the
    processed training log's extremes, the nominal fit on its error sums, the friction signs on the
    estimate; the correlations and the per-pair fits need the arrays and are not computed."""
    rc, stdout, _, out = _identify(logs, capsys, f"{mistake}_" if mistake else "", streaming="on")
    assert rc == 0
    doc = json.loads((out / "result.json").read_text())
    assert doc["data_path"]["mode"] == "streamed"
    assert {w["kind"] for w in doc["warnings"]} == kinds, doc["warnings"]
    assert ("WARNING: " in stdout) == bool(kinds)


@pytest.mark.numerics
def test_predict_on_a_mistaken_log_says_so(logs, capsys):
    """dynid predict runs a saved identification on a new log: the same alarms on that log (here the
    validation log in degrees), and its summary names the robot."""
    rc, _, _, out = _identify(logs, capsys)
    assert rc == 0
    (logs / "new.toml").write_text('[data]\nfile = "degrees_valid.csv"\ntime = { column = "t", unit = "s" }\n'
                                   'position = { columns = ["q1", "q2", "q3", "q4"], unit = "rad" }\n'
                                   f'effort = {{ columns = [{EFFORT}], kind = "torque", unit = "N*m" }}\n')
    assert main(["predict", str(out), str(logs / "new.toml"), "--out", str(logs / "pred"), "--no-plots"]) == 0
    stdout = capsys.readouterr().out
    assert f"robot: newcomer4 ({logs / 'arm4.urdf'})" in stdout
    assert "WARNING: data: positions far beyond" in stdout and "the log is in degrees, read as radians" in stdout
    doc = json.loads((logs / "pred" / "predict.json").read_text())
    assert {w["kind"] for w in doc["warnings"]} >= {"position_limits", "nominal_fit"}


@pytest.mark.numerics
def test_flagged_and_inconsistent_parameters_are_counted_in_the_summary(logs, capsys):
    """A flipped sign gives negative masses: with the report on (the physical-consistency check),
    the summary counts the flagged and the physically inconsistent parameters as result.json
    lists them, on the console too."""
    rc, stdout, _, out = _identify(logs, capsys, "sign_", plots=True)
    assert rc == 0
    flags = json.loads((out / "result.json").read_text())["parameter_flags"]
    phys = flags["physical"]
    assert phys["checked"] and not phys["feasible"]
    flagged = set(flags["rel_std_above"]) | set(flags["undetermined"]) | set(phys["parameters"])
    n = len(json.loads((out / "result.json").read_text())["params"])
    line = next(li for li in (out / "summary.txt").read_text().splitlines() if li.startswith("Flagged parameters:"))
    assert line.startswith(f"Flagged parameters: {len(flagged)} of {n} ({len(flags['rel_std_above'])} with relative "
                           f"standard deviation >= 15 %, {len(flags['undetermined'])} undetermined, "
                           f"{len(phys['parameters'])} physically inconsistent)")
    assert "physically INCONSISTENT" in line and line in stdout


def test_a_tie_is_never_called_beating():
    """Both models with equal errors (99.8 % against 99.8 %): a tie, not "beats"; a difference
    below the tolerance max(1 %, 1/sqrt(2 n)) is a tie as well, one above it is a win."""
    from dynid.estimation.validation import ValidationMetrics, prior_comparison, tie_tolerance
    from dynid.report.html import verdict

    n = 800
    t = np.arange(n) / 100.0
    meas = np.column_stack([np.sin(t), 2 * np.cos(t)])
    sq = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)  # errors of exactly known RMS

    def model(a: float, b: float) -> ValidationMetrics:
        return ValidationMetrics.of(("a", "b"), t, meas, meas - np.outer(sq, [a, b]), "x")

    nominal = model(0.7, 1.4)
    same = prior_comparison(model(0.7, 1.4), nominal)
    assert same["tie"] and not same["beats_nominal"]
    assert same["identified_mean_rel_rmse_pct"] == same["nominal_mean_rel_rmse_pct"]
    assert "TIES with the nominal model" in same["verdict"] and "beats" not in same["verdict"]
    line, good = verdict(model(0.7, 1.4), nominal, same, ("N", "N"))
    assert not good and "TIES" in line and "beats" not in line
    tol = tie_tolerance(n)
    assert tol == pytest.approx(1 / np.sqrt(2 * n)) and tol > 0.01  # 800 rows resolve 2.5 %, not 1 %
    inside, outside = 1 - 0.5 * tol, 1 - 2 * tol  # both errors scaled: the relative RMSEs scale alike
    assert prior_comparison(model(0.7 * inside, 1.4 * inside), nominal)["tie"]
    win = prior_comparison(model(0.7 * outside, 1.4 * outside), nominal)
    assert win["beats_nominal"] and not win["tie"] and "beats the nominal model" in win["verdict"]
    assert tie_tolerance(10**6) == 0.01  # however many rows: at least 1 %


def test_a_misspelled_column_names_the_path_and_the_nearest_name(logs, capsys):
    rc, stdout, stderr, out = _identify(logs, capsys, effort='"tau1", "tau_2", "tau3", "tau4"')
    assert rc == 2 and stdout == ""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"dynid: error: {logs / 'train.csv'}: missing columns ['tau_2']")
    assert "nearest to 'tau_2': 'tau2'" in lines[0]


def test_limits_come_from_the_description_and_absent_ones_are_not_checked(tmp_path):
    """The URDF's limits per joint; a continuous joint has no position limit and keeps its effort
    limit (the loader's rebuilt joint once invented 1000 N*m); a DH robot gives no effort limit."""
    from dynid.model.loading import load_robot
    from dynid.model.system import as_system
    from dynid.pipeline.diagnostics import actuator_limits, limit_alarms

    (tmp_path / "arm4.urdf").write_text(URDF.replace('type="revolute"><parent link="base"', 'type="continuous"><parent link="base"'))
    system = as_system(load_robot(str(tmp_path / "arm4.urdf")))
    lo, hi, eff = actuator_limits(system)
    np.testing.assert_array_equal(lo, [-np.inf, -2.0, -2.5, -3.0])
    np.testing.assert_array_equal(hi, [np.inf, 2.0, 2.5, 3.0])
    np.testing.assert_array_equal(eff, [60.0, 60.0, 30.0, 10.0])
    names, kinds = system.actuator_names, system.actuator_kinds()
    # j1 turns 40 rad (continuous: fine); j4 at 3.2 rad is 0.2 rad past its limit, within the 10 %
    # margin of its 6 rad range; j2's effort 65 N*m is 8 % over its 60 N*m, within the margin too
    q = np.array([[40.0, 0.0, 0.0, 3.2], [-40.0, 0.0, 0.0, -3.0]])
    tau = np.array([[-55.0, 65.0, 0.0, 0.0]])
    assert limit_alarms(q, tau, names, kinds, system, "data") == []
    q[0, 3] = 3.7  # 0.7 rad past: beyond the margin; degrees fit, but so may an offset (less than a range)
    (alarm,) = limit_alarms(q, None, names, kinds, system, "data")
    assert alarm.kind == "position_limits" and "j4 -3 to 3.7" in alarm.seen
    assert "degrees" in alarm.cause and "encoder offset" in alarm.cause
    q[0, 3] = 250.0  # 4.4 rad as degrees: beyond too, no unit fits
    (alarm,) = limit_alarms(q, None, names, kinds, system, "data")
    assert "degrees" not in alarm.cause and "data.position.unit" in alarm.cause and "encoder offset" in alarm.cause
    _, _, eff6 = actuator_limits(as_system(load_robot("builtin:cobot6r")))
    assert np.all(np.isinf(eff6))  # a DH table whose rows name no effort limit has none
    _, _, eff6 = actuator_limits(as_system(load_robot("builtin:generic6r")))
    np.testing.assert_array_equal(eff6, [300.0, 300.0, 150.0, 40.0, 40.0, 25.0])  # its rows' effort keys


def test_mjcf_limits_of_a_mechanism_s_actuators(tmp_path):
    """A closed-loop MJCF: the actuated joints' ``range``, the joint's own ``actuatorfrcrange``
    (pinocchio reads it) and an actuator's ``forcerange`` times its gear (dynid reads it); the
    passive joints are not actuators and are not checked."""
    from dynid.model import load_model
    from dynid.model.system import as_system
    from dynid.pipeline.diagnostics import actuator_limits

    import dynid.model.robots as robots

    xml = (Path(robots.__file__).parent / "fivebar.xml").read_text()
    xml = xml.replace('<joint name="qa1" type="hinge" axis="0 1 0" range="-2.5 2.5"',
                      '<joint name="qa1" type="hinge" axis="0 1 0" range="-2.5 2.5" actuatorfrcrange="-7 7"')
    xml = xml.replace('<motor name="m2" joint="qa2" gear="1"/>', '<motor name="m2" joint="qa2" gear="2" forcerange="-2.5 2"/>')
    assert "actuatorfrcrange" in xml and "forcerange=" in xml
    (tmp_path / "fivebar.xml").write_text(xml)
    lo, hi, eff = actuator_limits(as_system(load_model(str(tmp_path / "fivebar.xml"))))
    np.testing.assert_array_equal(lo, [-2.5, -2.5])
    np.testing.assert_array_equal(hi, [2.5, 2.5])
    np.testing.assert_array_equal(eff, [7.0, 5.0])  # qa2: 2.5 N*m of the motor through a gear of 2
