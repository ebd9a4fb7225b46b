"""
Your own parallel robot in MJCF: a Stewart platform
===================================================

``examples/own_robot/stewart/`` is a 6-UPS Stewart platform written as a user would write their own
robot: ``stewart.xml`` is an MJCF file with, per leg, a universal joint at the base (two hinges), an
actuated slide, and the platform on leg 1 by a ``ball`` joint; legs 2-6 reach the platform through
``<connect>`` loop closures. Every body has an ``<inertial>``. ``simulate.toml`` and
``validate.toml`` run a training and a held-out experiment on the "real" robot (every parameter of
the file off by 15 %), ``identify.toml`` identifies it from the actuator positions and forces.
For your robot, replace ``[data]`` and ``[validation]`` with your logs and keep the rest.
"""

# %%
# A helper that runs the ``dynid`` command line as a shell would, and prints what it prints.
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
        if (folder / "examples" / "serial_arm").is_dir():
            return folder / "examples"
    raise FileNotFoundError("examples/ of the dynid checkout")


ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(dynid.__file__).parents[1]),
                                                    os.environ.get("PYTHONPATH", "")])}


def run(*args: str, cwd: Path) -> None:
    print("$ dynid", " ".join(args))
    proc = subprocess.run([sys.executable, "-m", "dynid.cli", *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True)
    print(proc.stdout + proc.stderr)
    proc.check_returncode()



work = Path(tempfile.mkdtemp(prefix="dynid-tutorial-")) / "stewart"
shutil.copytree(find_examples() / "own_robot" / "stewart", work, ignore=shutil.ignore_patterns("id", "sim", "val"))

# %%
# The description: the first leg and the platform (the other legs are alike, each closed on the
# platform by a ``<connect>``).
xml = (work / "stewart.xml").read_text().splitlines()
print("\n".join(xml[6:26]))
print("...")
print("\n".join(line for line in xml if line.strip().startswith(("<connect", "<actuator", "<motor", "</actuator"))))

# %%
# What dynid sees: 21 joints, the closures, 6 degrees of freedom driven by 6 slides, and the base
# parameters of the closed chains (computed on samples that satisfy the loop closures).
info = subprocess.run([sys.executable, "-m", "dynid.cli", "info", "stewart.xml"], cwd=work, env=ENV,
                      capture_output=True, text=True, check=True).stdout.splitlines()
print("\n".join(info[:16]), "\n...")

# %%
# Two virtual experiments
# -----------------------
# Computed torque with the file's (nominal) model at 250 Hz along a 5-harmonic excitation of the
# platform; the held-out run is another motion of the same robot.
print((work / "simulate.toml").read_text())
run("simulate", "simulate.toml", "--out", "sim", "-q", cwd=work)
run("simulate", "validate.toml", "--out", "val", "-q", cwd=work)

# %%
# Identification
# --------------
print((work / "identify.toml").read_text())
run("identify", "identify.toml", "--out", "id", "-q", cwd=work)
print((work / "id" / "summary.txt").read_text())

# %%
# Measured and predicted held-out forces of the six struts:
import matplotlib.pyplot as plt

image = plt.imread(work / "id" / "validation.png")
fig, ax = plt.subplots(figsize=(9, 9 * image.shape[0] / image.shape[1]))
ax.imshow(image)
ax.set_axis_off()
fig.tight_layout()

shutil.rmtree(work.parent)
