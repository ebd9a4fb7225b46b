"""Byte-reproducible outputs: the same inputs and seeds give the same bytes in every file.

Each command runs twice as a real ``dynid`` process (a fresh interpreter each time, so hash
seeds, import order and caches differ), into two different output folders, and every file of
the two folders must be byte-identical, ``timing.json`` (the wall-clock times, documented as
the one non-reproducible file) aside. ``dynid demo`` is checked the same way in
``tests/test_demo.py``. The commands run in parallel pairs to keep the suite short.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from conftest import run_dynid

TIMING = "timing.json"

SIMULATE = """\
[robot]
model = "builtin:cobot6r"
perturbation = 0.1
perturbation_seed = 6

[trajectory]
kind = "fourier"
base_frequency_hz = 0.5
harmonics = 3
fill = 0.5
max_velocity = 1.0
max_acceleration = 3.0
seed = 6

[control]
rate_hz = 500
kp = 400
kd = 40
substeps = 1

[sensors]
encoder_resolution = 4.794e-5
force_noise_std = 0.05
seed = 6

[simulation]
duration = {duration}

[output]
format = "npz"
"""

_Q = [f"q_joint_{j}" for j in range(1, 7)]
_TAU = [f"tau_joint_{j}" for j in range(1, 7)]

IDENTIFY = f"""\
[robot]
model = "builtin:cobot6r"

[data]
file = "sim/log.npz"
time = {{ column = "t", unit = "s" }}
position = {{ columns = {json.dumps(_Q)}, unit = "rad" }}
effort = {{ columns = {json.dumps(_TAU)}, unit = "N*m" }}
rows = [0, 1500]

[validation]
rows = [1500, 2000]

[processing]
lowpass = {{ cutoff_hz = 20.0, order = 4, filter_effort = false }}

[identification]
method = "wls"
physical_consistency = true

[output]
plots = true
"""

DESIGN = """\
[robot]
model = "builtin:generic6r"

[design]
criterion = "d_opt"
harmonics = 2
base_frequency_hz = 0.2
samples = 24
starts = 1
seed = 1
max_iter = 5

[limits]
velocity = 2.0
acceleration = 8.0
"""

MONTECARLO = """\
[simulate]
file = "sim_short.toml"

[identify.processing]
lowpass = { cutoff_hz = 20.0, order = 4, filter_effort = false }

[identify.identification]
method = "ols"

[montecarlo]
trials = 3
workers = 1
"""


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _pair(root: Path, name: str, args: list[str]) -> tuple[Path, Path]:
    """Run ``dynid <args> --out X`` twice: from ``root`` into ``root/<name>_a``, and from a
    sub-folder (another working directory) into ``root/<name>_b``."""
    other = root / f"{name}_cwd"
    other.mkdir(exist_ok=True)
    with ThreadPoolExecutor(2) as pool:
        runs = list(pool.map(lambda job: run_dynid(args + ["--out", str(job[1])], job[0]),
                             [(root, root / f"{name}_a"), (other, root / f"{name}_b")]))
    for r in runs:
        assert r.returncode == 0, r.stderr
    return root / f"{name}_a", root / f"{name}_b"


@pytest.fixture(scope="module")
def pairs(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    root = tmp_path_factory.mktemp("repro")
    (root / "sim.toml").write_text(SIMULATE.format(duration=4.0))
    (root / "sim_short.toml").write_text(SIMULATE.format(duration=2.0))
    (root / "identify.toml").write_text(IDENTIFY)
    (root / "design.toml").write_text(DESIGN)
    (root / "mc.toml").write_text(MONTECARLO)

    # the identified model as the controller's (control.model = a result.json, relative to the config)
    (root / "sim_identified.toml").write_text(
        SIMULATE.format(duration=1.0).replace("kp = 400\nkd = 40\nsubsteps = 1",  # joint PID gains the wrist's inertia tolerates
                                              'kp = 20\nkd = 0.2\nsubsteps = 1\nkind = "feedforward_pid"\nmodel = "identify_a/result.json"'))

    def serial_chain():
        sim = _pair(root, "simulate", ["simulate", str(root / "sim.toml"), "-q"])
        (root / "sim").symlink_to(sim[0])  # the identify config reads sim/log.npz
        ident = _pair(root, "identify", ["identify", str(root / "identify.toml"), "-q"])
        return {"simulate": sim, "identify": ident,
                "simulate-identified": _pair(root, "simulate-identified", ["simulate", str(root / "sim_identified.toml"), "-q"])}

    with ThreadPoolExecutor(2) as pool:
        chain = pool.submit(serial_chain)
        design = pool.submit(_pair, root, "design", ["design", str(root / "design.toml"), "-q"])
        mc = pool.submit(_pair, root, "montecarlo", ["montecarlo", str(root / "mc.toml"), "--no-progress"])
        return {**chain.result(), "design": design.result(), "montecarlo": mc.result()}


@pytest.mark.parametrize("command, expected", [
    ("simulate", {"log.npz", "truth.json", "metadata.json", "config.toml"}),
    ("simulate-identified", {"log.npz", "truth.json", "metadata.json", "config.toml"}),
    ("identify", {"result.json", "result.npz", "params.csv", "summary.txt", "model.urdf", "validation.png",
                  "processing.png", "report.html"}),
    ("design", {"design.json", "trajectory.csv", "params.csv", "summary.txt", "trajectory.png", "spectrum.png"}),
    ("montecarlo", {"trials.npz", "montecarlo.json", "history.png", "chi2.png", "config.toml"}),
])
def test_two_runs_write_the_same_bytes(pairs, command, expected):
    a, b = (_files(p) for p in pairs[command])
    assert set(a) == set(b) == expected | {TIMING}
    differ = sorted(name for name in a if name != TIMING and a[name] != b[name])
    assert not differ, f"{command}: files differ between two equal runs: {differ}"
    # the wall-clock times are there, and only there
    for side in (a, b):
        timing = json.loads(side[TIMING])
        assert timing and all(v is None or v >= 0 for v in _leaves(timing) if isinstance(v, float))
        for name, content in side.items():
            if name.endswith(".json") and name != TIMING:
                assert not _timing_keys(json.loads(content)), (command, name)
            if name.endswith(".npz"):
                with np.load(pairs[command][0] / name) as z:
                    assert not [k for k in z.files if k.endswith("_s")], (command, name, z.files)


def test_the_identified_model_is_recorded_relative_to_the_config(pairs):
    meta = json.loads((pairs["simulate-identified"][0] / "metadata.json").read_text())
    used = meta["control"]["model_used"]
    assert used["kind"] == "identified" and used["result"] == "identify_a/result.json" and used["method"] == "WLS+LMI"
    assert meta["control"]["model"] == "identify_a/result.json"


def _leaves(x):
    if isinstance(x, dict):
        for v in x.values():
            yield from _leaves(v)
    elif isinstance(x, list):
        for v in x:
            yield from _leaves(v)
    else:
        yield x


def _timing_keys(x, path: str = "") -> list[str]:
    """Keys that look like wall-clock times (``*_s`` seconds, ``elapsed``, ``timing``)."""
    found = []
    if isinstance(x, dict):
        for k, v in x.items():
            if k in ("timing", "elapsed_s", "wall_time_s", "solve_time_s", "identify_s") or k.endswith("time_s"):
                found.append(f"{path}.{k}")
            found += _timing_keys(v, f"{path}.{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            found += _timing_keys(v, f"{path}[{i}]")
    return found


def test_timing_files_hold_the_run_times(pairs):
    t = {c: json.loads((pairs[c][0] / TIMING).read_text()) for c in pairs}
    assert t["simulate"]["simulation_s"] > 0
    assert t["identify"]["identify_s"] > 0 and t["identify"]["solver"]  # the SDP's wall and solve times
    assert t["design"]["design_s"] > 0
    mc = t["montecarlo"]
    assert mc["total_s"] >= mc["trials_s"] > 0 and len(mc["identify_s_per_trial"]) == 3
    assert mc["workers"] == 1 and mc["backend"]
