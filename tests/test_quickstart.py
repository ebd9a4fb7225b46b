"""The README's quickstart runs as written: its four commands, in a copy of examples/serial_arm,
design -> simulate -> init -> identify, each exiting 0 without a warning, and their outputs agree
with each other (the simulated reference is the design, the identified base parameters are the
truth's, in its order)."""

from __future__ import annotations

import json
import shlex
import shutil

import numpy as np

from conftest import REPO
from dynid.cli import main


def _quickstart() -> list[list[str]]:
    text = (REPO / "README.md").read_text()
    section = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    block = section.split("```bash\n", 1)[1].split("```", 1)[0]
    return [shlex.split(line, comments=True) for line in block.splitlines() if line.strip()]


def test_the_readme_quickstart_runs_as_written(tmp_path, monkeypatch, capsys):
    commands = _quickstart()
    assert [c[:2] for c in commands] == [["dynid", "design"], ["dynid", "simulate"], ["dynid", "init"],
                                         ["dynid", "identify"]]
    work = tmp_path / "serial_arm"
    shutil.copytree(REPO / "examples" / "serial_arm", work,
                    ignore=shutil.ignore_patterns("design", "sim", "id", "identify.toml"))
    outputs = []
    monkeypatch.chdir(work)  # the README runs them from inside the folder
    for argv in commands:  # `dynid ARGS` is dynid.cli.main(ARGS)
        code = main(argv[1:])
        out, err = capsys.readouterr()
        assert code == 0, (argv, err)
        assert "warning" not in err, (argv, err)
        outputs.append(out)
    # design printed the table that simulate.toml holds (there with the path relative to it)
    assert 'kind = "fourier"' in outputs[0] and str((work / "design" / "design.json").resolve()) in outputs[0]
    log = np.genfromtxt(work / "sim" / "log.csv", delimiter=",", names=True)
    designed = np.genfromtxt(work / "design" / "trajectory.csv", delimiter=",", names=True)
    n = designed.size
    for j in ("yaw", "shoulder", "elbow"):  # the commanded motion is the design, at its samples
        np.testing.assert_allclose(log[f"ref_{j}"][:n], designed[f"u_{j}"], rtol=0, atol=1e-10)
    meta = json.loads((work / "sim" / "metadata.json").read_text())
    assert meta["warnings"] == []
    truth = json.loads((work / "sim" / "truth.json").read_text())["base_parameters"]
    result = json.loads((work / "id" / "result.json").read_text())
    # init models what the log and the description say: torques and a URDF without rotor inertia give
    # no Ia (link-side torque sensors, README "Starting a config"); every other base parameter is the truth's
    names = [p["name"] for p in result["params"]]
    assert names == [n for n in truth["names"] if n in names] and set(truth["names"]) - set(names) <= {"Ia1", "Ia2", "Ia3"}
    assert result["validation"]["kind"] == "held-out"
    # the README's claim: the identified model predicts the held-out quarter better than the URDF's (4.6 % against
    # 10.7 % mean relative RMSE as shipped: the 10 % perturbation is far above the estimate's error, so any draw of
    # the design's search or the sensor noise keeps the order)
    assert result["prior_comparison"]["beats_nominal"]
