"""The array API ``dynid.identify_arrays`` (issue 20, item 5): the pipeline of ``dynid identify``
on arrays, equal to the command on the same data written to CSV; options map to config keys;
unknown keywords are refused; the notebook view; the guide's example (docs/guide/python.md) runs."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest
from conftest import REPO, doc_text, seed

import dynid
from dynid.cli import main
from dynid.errors import ConfigError, InputError
from dynid.model import load_robot
from dynid.simulation import FourierTrajectory, simulate_serial

ROBOT = "builtin:generic6r"
SIGMA = 0.3  # N*m, torque noise of the simulated logs


@pytest.fixture(scope="module")
def logs():
    """A training run (30 s) and a held-out run (10 s, another trajectory) of generic6r at 200 Hz;
    the truth has viscous friction 0.5 N*m*s/rad where the description says 6 ... 0.4."""
    robot = load_robot(ROBOT)
    truth = robot.nominal_parameters()
    truth[robot.layout.extra_index["fv"]] = 0.5
    lo, hi = robot.position_limits()
    rng = np.random.default_rng(seed(0))

    def run(k, duration):
        traj = FourierTrajectory.random(6, 5, 0.1, np.random.default_rng(seed(k)), lo, hi, max_velocity=1.5,
                                        max_acceleration=4.0, fill=0.6)
        return simulate_serial(robot, truth, traj, fs=200.0, duration=duration, torque_noise_std=np.full(6, SIGMA), rng=rng)

    return run(1, 30.0), run(2, 10.0), robot.joint_names


def _write_csv(path, ds, joints):
    header = ["t"] + [f"q_{j}" for j in joints] + [f"tau_{j}" for j in joints]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in np.column_stack([ds.t, ds.q, ds.tau]):
            w.writerow([repr(float(x)) for x in row])  # shortest repr: the exact doubles


def _config_text(joints, validation: str, data_extra: str = "") -> str:
    cols = lambda p: "[" + ", ".join(f'"{p}{j}"' for j in joints) + "]"  # noqa: E731
    return (f'[robot]\nmodel = "{ROBOT}"\n\n[data]\nfile = "train.csv"\ntime = {{ column = "t" }}\n{data_extra}'
            f"position = {{ columns = {cols('q_')} }}\neffort = {{ columns = {cols('tau_')} }}\n\n"
            f"[validation]\n{validation}\n\n[processing]\nlowpass = {{ cutoff_hz = 5.0, filter_effort = false }}\n"
            'min_velocity = 0.05\n\n[identification]\nmethod = "wls"\n\n[output]\nplots = false\n')


def _params_csv(path):
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    return [r["name"] for r in rows], np.array([float(r["value"]) for r in rows]), np.array([float(r["std"]) for r in rows])


def _same_as_cli(out, folder):
    names, values, std = _params_csv(folder / "params.csv")
    res = out.result
    assert names == list(res.names)
    # the CSV's numbers are the arrays' doubles read back (pandas' parser may differ in the last
    # bit): the estimates agree far inside their standard deviations, relative 1e-9
    np.testing.assert_allclose(res.params, values, rtol=1e-9, atol=1e-9 * std.max())
    np.testing.assert_allclose(res.bse, std, rtol=1e-9)
    import json

    saved = json.loads((folder / "result.json").read_text())
    np.testing.assert_allclose(out.validation.rmse, saved["validation"]["rmse_per_joint"], rtol=1e-9)
    np.testing.assert_allclose(out.nominal_validation.rmse, saved["nominal_validation"]["rmse_per_joint"], rtol=1e-9)
    assert out.prior["verdict"] == saved["prior_comparison"]["verdict"]


@pytest.mark.numerics
def test_arrays_equal_dynid_identify_on_the_same_csv(logs, tmp_path):
    train, held, joints = logs
    out = dynid.identify_arrays(ROBOT, train.t, train.q, train.tau, held_out=(held.t, held.q, held.tau),
                                lowpass={"cutoff_hz": 5.0, "filter_effort": False}, min_velocity=0.05)
    _write_csv(tmp_path / "train.csv", train, joints)
    _write_csv(tmp_path / "held.csv", held, joints)
    (tmp_path / "c.toml").write_text(_config_text(joints, 'file = "held.csv"'))
    assert main(["identify", str(tmp_path / "c.toml"), "--out", str(tmp_path / "out"), "-q"]) == 0
    _same_as_cli(out, tmp_path / "out")
    # the physics: held-out errors are the sensor noise (filter_effort = false keeps the noise in
    # the output, 1744 held-out rows per joint: the RMSE's relative standard error ~1.7 %, 0.1 is 6 of
    # them), and the true viscous friction is inside 4.5 standard deviations (6 joints: 4e-5); the nominal
    # model's viscous friction (6 ... 0.4 against 0.5 N*m*s/rad) puts its mean error far beyond the noise
    np.testing.assert_allclose(out.validation.rmse, SIGMA, rtol=0.1)
    names = list(out.result.names)
    fv = np.array([out.result.params[names.index(f"fv{j}")] for j in range(1, 7)])
    fv_std = np.array([out.result.bse[names.index(f"fv{j}")] for j in range(1, 7)])
    assert np.all(np.abs(fv - 0.5) < 4.5 * fv_std), (fv, fv_std)
    assert out.prior["beats_nominal"]
    assert out.validation.label == "held-out"


def test_holdout_fraction_is_the_rows_windows_of_one_log(logs, tmp_path):
    train, _, joints = logs
    n = train.t.size
    out = dynid.identify_arrays(ROBOT, train.t, train.q, train.tau, holdout=0.25,
                                processing={"lowpass": {"cutoff_hz": 5.0, "filter_effort": False}, "min_velocity": 0.05})
    split = n - round(0.25 * n)
    _write_csv(tmp_path / "train.csv", train, joints)
    (tmp_path / "c.toml").write_text(_config_text(joints, f"rows = [{split}, {n}]", f"rows = [0, {split}]\n"))
    assert main(["identify", str(tmp_path / "c.toml"), "--out", str(tmp_path / "out"), "-q"]) == 0
    _same_as_cli(out, tmp_path / "out")


def test_options_are_config_keys_and_the_rest_is_refused(logs):
    train, held, _ = logs
    args = (ROBOT, train.t, train.q, train.tau)
    with pytest.raises(InputError, match="unknown keyword lowpas; the options are the keys of"):
        dynid.identify_arrays(*args, lowpas={"cutoff_hz": 5.0})
    with pytest.raises(InputError, match="min_velocity given twice"):
        dynid.identify_arrays(*args, min_velocity=0.1, processing={"min_velocity": 0.1})
    with pytest.raises(InputError, match="not both"):
        dynid.identify_arrays(*args, held_out=(held.t, held.q, held.tau), holdout=0.2)
    with pytest.raises(InputError, match="holdout"):
        dynid.identify_arrays(*args, holdout=1.5)
    with pytest.raises(InputError, match="q has 6 columns, effort 5"):
        dynid.identify_arrays(ROBOT, train.t, train.q, train.tau[:, :5])
    with pytest.raises(InputError, match="data.position: 5 columns for a robot with 6 joints"):
        dynid.identify_arrays(ROBOT, train.t, train.q[:, :5], train.tau[:, :5])
    # values go through the configuration schema, with its messages
    with pytest.raises(ConfigError, match="identification.method: must be one of"):
        dynid.identify_arrays(*args, method="lsq")
    with pytest.raises(ConfigError, match="processing.lowpass: missing required keys"):
        dynid.identify_arrays(*args, lowpass={"order": 4})
    with pytest.raises(ConfigError, match="identification.margin is for physically consistent identification"):
        dynid.identify_arrays(*args, margin=0.1)


def test_notebook_view_shows_estimates_with_std_and_validation_against_nominal(logs):
    train, held, _ = logs
    out = dynid.identify_arrays(ROBOT, train.t, train.q, train.tau, held_out=(held.t, held.q, held.tau),
                                lowpass={"cutoff_hz": 5.0, "filter_effort": False}, extras=["Ia", "fv", "fc"])
    page = out._repr_html_()
    res = out.result
    assert "offset" not in " ".join(res.names)  # the extras option reached [robot]
    cells = re.findall(r"<td>(.*?)</td>", page)
    for name, value, std in zip(res.names, res.params, res.bse):
        i = cells.index(name)
        assert cells[i + 1] == f"{value:.6g}" and cells[i + 2] == f"{std:.3g}"
    for j, ch in enumerate(out.validation.channel_names):
        i = cells.index(ch, cells.index(ch) + 1)  # the second table (the first is the training channels)
        assert cells[i + 1] == f"{out.validation.rmse[j]:.4g}"
        assert cells[i + 4] == f"{out.nominal_validation.rmse[j]:.4g}"
    assert out.prior["verdict"] in page.replace("&#x27;", "'")


def _readme_example() -> str:
    section = doc_text("python")  # the guide's page "From Python: arrays in, the identify result out"
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.numerics
def test_readme_array_example_runs(capsys):
    """The guide's example (docs/guide/python.md) as written: its seeds are the page's (not conftest.seed),
    one draw."""
    scope: dict = {}
    exec(compile(_readme_example(), "docs/guide/python.md", "exec"), scope)
    out = scope["out"]
    printed = capsys.readouterr().out
    assert out.prior["verdict"] in printed
    # the story the page tells: the identified model beats the nominal one on held-out data,
    # its errors are the simulated noise, the true viscous friction lies in the intervals
    assert out.prior["beats_nominal"] and out.validation.label == "held-out"
    np.testing.assert_allclose(out.validation.rmse, 0.3, rtol=0.1)
    ci = out.result.conf_int(0.001 / 6)  # the six intervals together at 99.9 % (Bonferroni)
    names = list(out.result.names)
    for j in range(1, 7):
        lo, hi = ci[names.index(f"fv{j}")]
        assert lo < 0.5 < hi


def test_import_dynid_stays_light_and_exposes_identify_arrays_lazily():
    import subprocess
    import sys

    code = ("import sys, dynid; before = [m for m in ('dynid.pipeline', 'pinocchio', 'pandas') if m in sys.modules]; "
            "f = dynid.identify_arrays; print(before, f.__module__, 'dynid.pipeline' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**__import__("os").environ, "PYTHONPATH": str(REPO / "src")})
    assert done.stdout.split() == ["[]", "dynid.pipeline.arrays", "True"], done.stderr
