"""
Getting started: identify a shipped arm in two commands
=======================================================

``examples/serial_arm/`` holds a small 3-joint arm (``arm3.urdf``: joint and effort limits,
inertias, friction) and a 10 s log of it (``log.csv``: time, joint positions, joint torques at
100 Hz). Two commands identify it: ``dynid init`` writes a starting configuration from the robot
and the log, ``dynid identify`` runs it.

The tutorial works in a temporary copy of the folder; from a checkout, run the same commands from
inside ``examples/serial_arm/``.
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


work = Path(tempfile.mkdtemp(prefix="dynid-tutorial-")) / "serial_arm"
shutil.copytree(find_examples() / "serial_arm", work, ignore=shutil.ignore_patterns("id", "sim", "design"))
print(sorted(p.name for p in work.iterdir()))

# %%
# A starting configuration
# ------------------------
# ``dynid init ROBOT LOG`` matches the log's columns to the robot's joints (by name here), finds
# the time unit and the sampling rate, and derives the processing an expert would choose from the
# log: the low-pass cut-off, decimation, ``min_velocity``. Each choice is written with its reason.
run("init", "arm3.urdf", "log.csv", "--out", "identify.toml", cwd=work)
print((work / "identify.toml").read_text())

# %%
# Identification
# --------------
# ``dynid identify`` trains on the first three quarters of the log and validates on the last
# quarter, which it never saw. The summary ends with the held-out errors of the identified model
# beside those of the URDF's own (nominal) parameters.
run("identify", "identify.toml", "--out", "id", "-q", cwd=work)
print((work / "id" / "summary.txt").read_text())

# %%
# The folder ``id/`` holds ``result.json`` (estimates, covariance, validation, provenance),
# ``params.csv``, ``report.html`` and the plots; ``validation.png`` compares the measured and
# predicted held-out torques.
import matplotlib.pyplot as plt

image = plt.imread(work / "id" / "validation.png")
fig, ax = plt.subplots(figsize=(9, 9 * image.shape[0] / image.shape[1]))
ax.imshow(image)
ax.set_axis_off()
fig.tight_layout()

# %%
# The estimates are a table of base parameters (identifiable combinations of the standard ones)
# with their standard deviations and 95 % intervals:
import json

result = json.loads((work / "id" / "result.json").read_text())
for p in result["params"][:8]:
    print(f"{p['name']:6s} {p['value']:+.4f} +- {p['std']:.4f}   = {p['expression']}")

shutil.rmtree(work.parent)
