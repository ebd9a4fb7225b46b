"""
A real arm: the Stäubli TX40 log
================================

FIGAROH, the reference tool for serial arms, publishes a real log of a Stäubli TX40: motor-side
encoders and motor currents at 5 kHz, a coupled wrist (motor 6 turns with ``q5 + q6``), and its
held-out torque errors per joint. ``examples/tx40/identify.toml`` identifies the arm from that log
with FIGAROH's processing replicated (25 Hz zero-phase Butterworth, central differences, parallel
decimation by 100, its velocity dead-band), so that the two can be compared on the same data, the
same held-out window and the same metric (:doc:`/guide/results`).

The log is not shipped with dynid: it lives in ``../shared/data/tx40`` beside the checkout
(``DYNID_SHARED_DATA`` names another folder). Without it this tutorial says so and stops.
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

here = Path(globals().get("__file__", Path.cwd() / "x")).resolve().parent
repo = next(f for f in (here, *here.parents) if (f / "examples" / "tx40").is_dir())
shared = Path(os.environ.get("DYNID_SHARED_DATA", repo.parent / "shared" / "data"))
available = all((shared / "tx40" / f).is_file() for f in ("pos_read_data.csv", "curr_data.csv", "tx40_mdh_modified.urdf"))
print(f"TX40 log in {shared / 'tx40'}:", "found" if available else "NOT FOUND: the rest of this tutorial is skipped")

# %%
# The configuration
# -----------------
# The robot is FIGAROH's URDF; ``gear_ratios``, ``couplings`` and ``position_offset`` describe the
# drive train from the motor encoders to the joints; ``kind = "current"`` says the efforts are motor
# currents (the drive gains are folded into the parameters). ``coulomb_smoothing = "auto"`` models
# the Coulomb force of a noisy velocity by its expectation, ``erf(v / (sqrt(2) w))``: the held-out
# window has the arm at rest for long stretches, where ``sign(v)`` of a noisy velocity chatters.
config = (repo / "examples" / "tx40" / "identify.toml").read_text()
print(config[config.index("[robot]"):])

# %%
# Identify and validate
# ---------------------
# The paths of the shipped config are relative to ``examples/tx40``; the run below writes a copy
# with absolute paths into a temporary folder.
FIGAROH_RMSE = [6.64, 8.32, 4.28, 1.80, 2.65, 1.72]  # FIGAROH's published held-out RMSE at 5 kHz
if available:
    work = Path(tempfile.mkdtemp(prefix="dynid-tutorial-"))
    (work / "identify.toml").write_text(config.replace("../../../shared/data", shared.as_posix()))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(dynid.__file__).parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "dynid.cli", "identify", "identify.toml", "--out", "id", "-q"],
                          cwd=work, env=env, capture_output=True, text=True)
    print(proc.stdout + proc.stderr)
    proc.check_returncode()
    result = json.loads((work / "id" / "result.json").read_text())

# %%
# Against FIGAROH, like for like
# ------------------------------
# FIGAROH scores every held-out sample at the log's full 5 kHz; dynid scores its decimated rows
# and, for this comparison, the full-rate samples too (``validation_full_rate``). Same log, same
# window (rows 29 250-45 000), same rate, same metric:
if available:
    full = result["validation_full_rate"]
    print(f"held-out RMSE at 5 kHz, {full['identified']['n_samples']} samples (nominal: the URDF's own parameters)")
    print(f"{'joint':8s}{'FIGAROH':>10s}{'dynid':>10s}{'nominal':>10s}")
    for j, name in enumerate(full["identified"]["joints"]):
        print(f"{name:8s}{FIGAROH_RMSE[j]:10.2f}{full['identified']['rmse_per_joint'][j]:10.2f}"
              f"{full['nominal']['rmse_per_joint'][j]:10.2f}")

# %%
# The first base parameters, with their standard deviations (``params.csv`` and ``summary.txt``
# list them all, with their grouping expressions and 95 % intervals):
if available:
    for p in result["params"][:12]:
        print(f"{p['name']:10s} {p['value']:+10.4f} +- {p['std']:.4f}")
    shutil.rmtree(work)
