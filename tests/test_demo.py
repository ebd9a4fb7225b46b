"""``dynid demo``, the main job on a built-in default: the parallel-robot study of paper 001
(simulate shang2dof under control, identify with DIDIM and WLS, validate, track again).

The demo runs as a real process and its outputs are checked (``test_demo``, marked ``numerics``:
``make test-robust`` reruns it with another sensor-noise seed); ``test_two_demos_write_the_same_bytes``
runs it a second time (another output folder, another working directory), which must write the
same bytes in every file (``timing.json``, the wall-clock times, aside).
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import run_dynid, seed
from dynid.pipeline.demo import DEMO_SEED


def _run(root: Path, name: str) -> tuple[subprocess.CompletedProcess, Path]:
    (root / name).mkdir()
    out = root / name / "out"
    # the sensor noise from conftest.seed (docs/guide/demo.md's figures with the default 2026); the true robot is fixed
    return run_dynid(["demo", "--out", str(out), "--seed", str(seed(DEMO_SEED)), "-q"], root / name), out


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    return _run(tmp_path_factory.mktemp("demo"), "a")


@pytest.fixture(scope="module")
def demos(demo, tmp_path_factory) -> list[tuple[subprocess.CompletedProcess, Path]]:
    """The demo again, into another folder from another working directory (after the first: one core)."""
    return [demo, _run(tmp_path_factory.mktemp("demo"), "b")]


@pytest.mark.numerics
def test_demo(demo):
    """The parallel-robot study: simulate shang2dof, identify (DIDIM and WLS), validate, track again.

    The story the demo tells: the model identified through the control loop tracks the rectangle
    better than the nominal model it started from (paper 001, Table 5: 19-25 %; the issue's bar:
    at least 15 % lower P-RSME), and it beats the nominal model on the held-out forces."""
    r, out = demo
    assert r.returncode == 0, r.stderr
    for label in ("DIDIM", "WLS"):
        m = re.search(rf"Ground truth check \({label}\): (\d+) of (\d+) true base parameters", r.stdout)
        assert m and int(m.group(2)) == 25, r.stdout
    m = re.search(r"nominal\s+([0-9.e+-]+)\s+[0-9.e+-]+\nidentified \(DIDIM\)\s+([0-9.e+-]+)\s+[0-9.e+-]+\ntrue\s+([0-9.e+-]+)", r.stdout)
    assert m, r.stdout
    nominal, identified, true = (float(x) for x in m.groups())
    assert true < nominal  # the true model tracks best (paper 001, Table 5)
    assert identified < 0.85 * nominal, (identified, nominal)
    assert "the identified model beats the nominal model on held-out data" in r.stdout
    # it names the robot it identified (issue 34, item 13), and its logs raise no alarm (no false one)
    assert r.stdout.startswith("Robot: shang2dof (builtin:shang2dof)") and "WARNING: " not in r.stdout
    for name in ("summary.txt", "result.json", "params.csv", "config.toml", "tracking.png", "tracking.json"):
        assert f"{out / name}" in r.stdout
        assert (out / name).is_file()
    assert (out / "wls" / "result.json").is_file()
    for part in ("train", "validation"):
        assert (out / "data" / part / "log.csv").is_file() and (out / "data" / part / "truth.json").is_file()
    # DIDIM replayed the delivered experiment: the config it names is the one in the output
    doc = json.loads((out / "result.json").read_text())
    assert doc["method"] == "DIDIM + WLS+LMI (projected)" and doc["solver"]["experiment"] == "data/train/config.toml"
    # physically consistent: no friction coefficient of the wrong sign (fc- is the Coulomb force of
    # negative velocities, <= 0 by convention)
    params = {p["name"]: p for p in doc["params"]}
    for name, p in params.items():
        if name.startswith(("fv", "fc+")):
            assert p["value"] >= 0, (name, p["value"])
        if name.startswith("fc-"):
            assert p["value"] <= 0, (name, p["value"])
    # DIDIM removes WLS's errors-in-the-variables bias: the truth's chi^2 against each method's own
    # covariance is far smaller for DIDIM (draws 0-4 of the sensor noise: 24-77 on 25 parameters,
    # WLS 3330-3600; WLS's bias is deterministic, its chi^2 moves by +-150 between draws), asserted
    # with a factor 10, 4x inside the worst draw. The coverage of DIDIM's 95 % intervals is NOT
    # asserted: over those draws its chi^2 exceeded chi^2_25's 99.9 % quantile (52.6) three times
    # out of five, with a bias of about -1.2 standard deviations on the actuated joints' friction
    # parameters (same sign on every draw; tests/README.md, "Known limitations"): the reported
    # intervals are too narrow for this experiment, a finding, not a margin to widen here.
    truth = json.loads((out / "data" / "train" / "truth.json").read_text())["base_parameters"]
    true = dict(zip(truth["names"], truth["true_values"]))
    names = [p["name"] for p in doc["params"]]
    wls_doc = json.loads((out / "wls" / "result.json").read_text())
    chi2 = {}
    for label, folder, d in (("DIDIM", out, doc), ("WLS", out / "wls", wls_doc)):
        values = {p["name"]: p["value"] for p in d["params"]}
        e = np.array([values[n] - true[n] for n in names])
        chi2[label] = float(e @ np.linalg.solve(np.load(folder / "result.npz")["cov_params"], e))
    assert chi2["DIDIM"] < chi2["WLS"] / 10, chi2
    assert (out / "data" / "train" / "config.toml").is_file()
    assert "Ground truth check" in (out / "summary.txt").read_text()


def test_demo_provenance_points_at_the_delivered_files(demo):
    # result.json records the config and data files it was computed from; they must be the files
    # in the output folder (named relative to the result's folder), not the staging folder that
    # no longer exists
    r, out = demo
    assert r.returncode == 0, r.stderr
    for folder in (out, out / "wls"):
        doc = json.loads((folder / "result.json").read_text())
        prov = doc["provenance"]
        sources = [prov["config_file"], *prov["training_data"]["source"].values(),
                   *prov["validation_data"]["source"].values(), *doc["validation"]["source"].values()]
        assert all(not Path(s).is_absolute() for s in sources), sources
        missing = sorted({s for s in sources if not (folder / s).is_file()})
        assert not missing, f"provenance names files that do not exist: {missing}"


def test_two_demos_write_the_same_bytes(demos):
    (ra, a), (rb, b) = demos
    assert ra.returncode == 0 and rb.returncode == 0, ra.stderr + rb.stderr
    files = lambda root: {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}  # noqa: E731
    fa, fb = files(a), files(b)
    assert set(fa) == set(fb)
    timing = {n for n in fa if Path(n).name == "timing.json"}
    assert timing >= {"timing.json", "data/train/timing.json", "wls/timing.json"}
    differ = sorted(n for n in fa if n not in timing and fa[n] != fb[n])
    assert not differ, f"files differ between two equal demo runs: {differ}"
    assert json.loads(fa["timing.json"])["demo_s"] > 0
