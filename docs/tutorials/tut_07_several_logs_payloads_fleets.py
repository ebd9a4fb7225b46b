"""
Several logs, a payload and a fleet
===================================

One identification rarely has one log. This tutorial runs the three shipped examples that use
many: ``examples/several_logs`` (two runs of the same arm in one identification, each weighted by
its own noise), ``examples/payload`` (a 6R cobot without and with a 2 kg payload: the payload's 10
inertial parameters, given the arm or jointly with it) and ``examples/fleet`` (eight arms, four
monthly logs each, on a Dask cluster: spread, outliers and drift). Each step is a command of the
user guide's pages (:doc:`/guide/several-logs`, :doc:`/guide/payloads`, :doc:`/guide/fleets`),
run as written there on simulated logs whose truth is known.
"""

# %%
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import dynid


def find_examples() -> Path:
    here = Path(globals().get("__file__", Path.cwd() / "x")).resolve().parent
    for folder in (here, *here.parents):
        if (folder / "examples" / "several_logs").is_dir():
            return folder / "examples"
    raise FileNotFoundError("examples/ of the dynid checkout")


ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(dynid.__file__).parents[1]),
                                                    os.environ.get("PYTHONPATH", "")])}


def run(*args: str, cwd: Path, quiet: bool = False) -> None:
    print("$", " ".join(args))
    cmd = [sys.executable, *args[1:]] if args[0] == "python" else [sys.executable, "-m", "dynid.cli", *args[1:]]
    proc = subprocess.run(cmd, cwd=cwd, env=ENV, capture_output=True, text=True)
    if not quiet:
        print(proc.stdout + proc.stderr)
    proc.check_returncode()


def section(text: str, start: str, lines: int) -> str:
    """``lines`` lines of ``text`` from the first one that contains ``start``."""
    rows = text.splitlines()
    first = next(k for k, line in enumerate(rows) if start in line)
    return "\n".join(rows[first:first + lines])


root = Path(tempfile.mkdtemp(prefix="dynid-tutorial-"))
for name in ("several_logs", "payload", "fleet"):
    shutil.copytree(find_examples() / name, root / name,
                    ignore=shutil.ignore_patterns("clean", "noisy", "id", "arm", "loaded", "arm_id", "payload",
                                                  "joint_id", "logs", "logs.csv", "out"))

# %%
# Several logs in one identification
# ----------------------------------
# Two virtual experiments of the 3-joint arm: a clean run and a noisier one with another motion.
# ``identify.toml`` lists both as ``[[data]]`` tables (and both last quarters as
# ``[[validation]]``). Each log is read, filtered, differentiated and compressed on its own (no
# filter runs across the two), and each is weighted by its own noise level.
work = root / "several_logs"
run("dynid", "simulate", "clean.toml", "--out", "clean", "-q", cwd=work, quiet=True)
run("dynid", "simulate", "noisy.toml", "--out", "noisy", "-q", cwd=work, quiet=True)
run("dynid", "identify", "identify.toml", "--out", "id", "-q", cwd=work)
summary = (work / "id" / "summary.txt").read_text()
print(section(summary, "Experiments", 9))

# %%
# Above, the held-out error on each validation log and pooled; below, the first log's table
# beside the nominal model's on the same rows (the prior is the first baseline). The summary's
# warning about the exported masses is the base parameters' ambiguity: the data fix only
# combinations of the standard parameters (:doc:`/explanation/model`).
print(section(summary, "Validation on held-out data", 16))

# %%
# A payload
# ---------
# The cobot is simulated twice: the arm alone, and carrying a 2 kg payload along another motion.
# The arm is identified from its own log; ``dynid payload`` then estimates the payload's mass,
# centre of mass and inertia from the loaded log given the arm's result, with intervals that
# include the arm's own uncertainty, and writes the payload as a URDF link and an MJCF body.
work = root / "payload"
run("dynid", "simulate", "arm.toml", "--out", "arm", "-q", cwd=work, quiet=True)
run("dynid", "simulate", "loaded.toml", "--out", "loaded", "-q", cwd=work, quiet=True)
run("dynid", "identify", "identify.toml", "--out", "arm_id", "-q", cwd=work)
run("dynid", "payload", "payload.toml", "--out", "payload", "-q", cwd=work)
print((work / "payload" / "summary.txt").read_text()[:2500])

# %%
# The same two logs identify the arm and the payload *jointly*: ``joint.toml`` marks the loaded run
# ``payload = true``; the arm's base parameters are shared by both runs and the payload's 10
# parameters act only in the marked one.
run("dynid", "identify", "joint.toml", "--out", "joint_id", "-q", cwd=work)
given_arm = json.loads((work / "payload" / "payload.json").read_text())
joint = json.loads((work / "joint_id" / "payload.json").read_text())
truth = json.loads((work / "loaded" / "truth.json").read_text())
print("payload mass [kg]: given the arm", round(given_arm["mass"]["value"], 4), "+-", round(given_arm["mass"]["std"], 4),
      "| jointly", round(joint["mass"]["value"], 4), "+-", round(joint["mass"]["std"], 4))

# %%
# A fleet on a Dask cluster
# -------------------------
# ``make_logs.py`` simulates eight arms, each the URDF's arm perturbed by 5 %, four monthly logs
# each; robot r4 was built with a heavier forearm (an outlier), robot r5's shoulder friction wears
# (a drift), and one log of r3 was never copied off the robot.
# ``dynid fleet`` identifies every log as one task on a local Dask cluster of process workers,
# pools each robot's logs, and compares the robots: spread per parameter, outliers by a
# Mahalanobis distance whose threshold comes from a parametric bootstrap, trends and change
# points over the logs' dates. A bad log fails alone.
work = root / "fleet"
run("python", "make_logs.py", cwd=work)
run("dynid", "fleet", "fleet.toml", "--out", "out", "-q", cwd=work)
print((work / "out" / "summary.txt").read_text()[:2600])

# %%
# ``spread.png`` shows each robot's estimate of every parameter with its interval against the
# fleet's median and spread:
import matplotlib.pyplot as plt

image = plt.imread(work / "out" / "spread.png")
fig, ax = plt.subplots(figsize=(10, 10 * image.shape[0] / image.shape[1]))
ax.imshow(image)
ax.set_axis_off()
fig.tight_layout()

shutil.rmtree(root)
