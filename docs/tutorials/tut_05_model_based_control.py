"""
Model-based control with the identified model
=============================================

An identified model is for using: here, the computed-torque controller of the serial arm of
``examples/serial_arm/`` runs once with the URDF's (nominal) model, once with the model
``dynid identify`` estimated, and once with the true model, along the same trajectory and with the
same gains. ``dynid simulate`` takes the controller's model from ``[control] model``: ``"nominal"``,
``"true"``, or a ``result.json`` of ``dynid identify``. Its base parameters become the standard
vector closest to the nominal one that has those base parameters (every such vector gives the same
forces).
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
shutil.copytree(find_examples() / "serial_arm", work, ignore=shutil.ignore_patterns("id", "sim", "design", "log.csv",
                                                                                     "truth.json", "identify.toml"))

# %%
# Identify the arm
# ----------------
# As in the previous tutorials: an excitation, the experiment, the identification (with the rotor
# inertias, as the arm's torques are motor-side; physically consistent, as ``dynid init`` proposes
# for a model a controller or a simulator uses).
run("design", "design.toml", "--out", "design", "-q", cwd=work)
run("simulate", "simulate.toml", "--out", "sim", "-q", cwd=work)
run("init", "arm3.urdf", "sim/log.csv", "--out", "identify.toml", cwd=work)
text = (work / "identify.toml").read_text()
lines = [('extras = ["Ia", "fv", "fc", "offset"]\nrotor_inertia = [0.05, 0.04, 0.02]'
          if line.startswith("extras =") else line) for line in text.splitlines()]
(work / "identify.toml").write_text("\n".join(lines) + "\n")
run("identify", "identify.toml", "--out", "id", "-q", cwd=work)

# %%
# Track with three models
# -----------------------
# The same simulate configuration, with the controller's model changed (the trajectory, the gains,
# the true robot and the sensors are the same):
import json

simulate = (work / "simulate.toml").read_text()
tracking = {}
for label, model in (("nominal", '"nominal"'), ("identified", '"id/result.json"'), ("true", '"true"')):
    (work / f"control_{label}.toml").write_text(
        simulate.replace('kind = "computed_torque"', f'kind = "computed_torque"\nmodel = {model}'))
    run("simulate", f"control_{label}.toml", "--out", f"track_{label}", "-q", cwd=work)
    meta = json.loads((work / f"track_{label}" / "metadata.json").read_text())
    tracking[label] = meta["tracking"]["rms_per_axis"]
    print(f"{label:10s} controller model: {meta['control']['model_used']}")

# %%
# The tracking error (RMS per joint, rad): the identified model tracks closer to the true model
# than the URDF's does.
import matplotlib.pyplot as plt
import numpy as np

joints = ["yaw", "shoulder", "elbow"]
for label, rms in tracking.items():
    print(f"{label:10s} " + "  ".join(f"{j} {r:.2e}" for j, r in zip(joints, rms)))

fig, ax = plt.subplots(figsize=(7, 3.5))
x = np.arange(len(joints))
for i, (label, rms) in enumerate(tracking.items()):
    ax.bar(x + (i - 1) * 0.27, rms, 0.27, label=f"{label} model")
ax.set_xticks(x, joints)
ax.set_ylabel("tracking RMS [rad]")
ax.legend()
fig.tight_layout()

shutil.rmtree(work.parent)
