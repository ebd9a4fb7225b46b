"""Bad input, one defect at a time, for every command: exit status 2, exactly one stderr line
``dynid: error: ...`` naming the cause, no traceback, nothing on stdout, and the ``--out`` folder
not created (or, when it already held files, left byte for byte as it was, with no staging folder
beside it). The known-good inputs each case changes, and the checks, are in ``_bad_inputs.py``;
``test_good_inputs_succeed`` runs them unchanged to exit 0, so no case passes because the good
input itself is refused.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _bad_inputs import (
    FIVEBAR,
    HEADER,
    IDENTIFY,
    MONTECARLO,
    ROBOT,
    SIMULATE,
    URDF,
    CASES,
    Work,
    assert_refused,
    case,
    edit,
    make_table,
    snapshot,
)

from dynid.cli import main


@pytest.fixture(scope="module")
def table() -> np.ndarray:
    return make_table()


# ---------------------------------------------------------------------- the cases
# identify: the configuration file itself
@case("identify", "config-missing", "config file not found", "none.toml")
def _(w):
    return ["identify", str(w.dir / "none.toml"), "--out", str(w.out)]


@case("identify", "config-is-a-folder", "is a folder, not a file")
def _(w):
    (w.dir / "cfgdir.toml").mkdir()
    return ["identify", str(w.dir / "cfgdir.toml"), "--out", str(w.out)]


@case("identify", "config-under-a-file", "not found", "log.csv is a file, not a folder")
def _(w):
    return ["identify", str(w.dir / "log.csv" / "cfg.toml"), "--out", str(w.out)]


@case("identify", "config-without-permission", "cannot read config file", "Permission denied",
      marks=pytest.mark.skipif(os.geteuid() == 0, reason="root reads a file whatever its mode; "
                                                        "see the case config-read-error, which fails as root too"))
def _(w):
    path = w.config("identify")
    path.chmod(0)
    return ["identify", str(path), "--out", str(w.out)]


@case("identify", "config-read-error", "cannot read config file", "Input/output error",
      marks=pytest.mark.skipif(not Path("/proc/self/mem").exists(), reason="needs Linux /proc"))
def _(w):
    # a link to /proc/self/mem: an existing regular file whose read fails (EIO), even for root
    (w.dir / "cfg.toml").symlink_to("/proc/self/mem")
    return ["identify", str(w.dir / "cfg.toml"), "--out", str(w.out)]


@case("identify", "config-empty", "cfg.toml is empty")
def _(w):
    return ["identify", str(w.write("cfg.toml", "\n  \n")), "--out", str(w.out)]


@case("identify", "config-binary", "is not UTF-8 text", "binary")
def _(w):
    return ["identify", str(w.write("cfg.toml", bytes(range(256)) * 4)), "--out", str(w.out)]


@case("identify", "config-latin1", "is not UTF-8 text (byte 0xe9")
def _(w):
    text = IDENTIFY.replace("[output]", "# réglage\n[output]")
    return ["identify", str(w.write("cfg.toml", text.encode("latin-1"))), "--out", str(w.out)]


edit("identify", "invalid-toml", "[output]", "[output", "cfg.toml: invalid TOML")
edit("identify", "unknown-top-level-key", "[output]", "[outputs]", "unknown key outputs")
edit("identify", "unknown-key-robot", 'model = "rp2.toml"', 'model = "rp2.toml"\nmodle = 1', "unknown key robot.modle")
edit("identify", "unknown-key-data", "rows = [0, 240]", "rows = [0, 240]\nrow = 1", "unknown key data.row;")
edit("identify", "unknown-key-validation", "rows = [240, 300]", "rows = [240, 300]\nfiles = 1", "unknown key validation.files")
edit("identify", "unknown-key-processing", "lowpass = {", "low_pass = 1\nlowpass = {", "unknown key processing.low_pass")
edit("identify", "unknown-key-identification", 'method = "ols"', 'method = "ols"\nmethods = 1', "identification.methods")
edit("identify", "unknown-key-output", "plots = false", "plots = false\nplot = true", "unknown key output.plot")
edit("identify", "unknown-key-signal", 'unit = ["rad", "m"] }', 'unit = ["rad", "m"], side = "joint", sides = 1 }',
     "unknown key data.position.sides")
edit("identify", "wrong-type", 'method = "ols"', "method = 3", "identification.method: expected a string, got 3")
edit("identify", "wrong-type-bool", "plots = false", 'plots = "no"', "output.plots: expected true or false")
edit("identify", "nan", "cutoff_hz = 10.0", "cutoff_hz = nan", "processing.lowpass.cutoff_hz: expected a finite number, got nan")
edit("identify", "inf", 'model = "rp2.toml"', 'model = "rp2.toml"\nposition_offset = [inf, 0.0]',
     "robot.position_offset[0]: expected a finite number, got inf")
edit("identify", "min-joint-motion-negative", "min_joint_motion = 0.001", "min_joint_motion = -1",
     "identification.min_joint_motion: must be >= 0, got -1")
edit("identify", "covariance-unknown", 'method = "ols"', 'method = "ols"\ncovariance = "sandwich"',
     "identification.covariance: must be one of ['model', 'hac', 'block_bootstrap'], got 'sandwich'")
edit("identify", "covariance-blocks-one", 'method = "ols"', 'method = "ols"\ncovariance = "hac"\ncovariance_blocks = 1',
     "identification.covariance_blocks: must be >= 2, got 1")
edit("identify", "covariance-blocks-too-many", 'method = "ols"', 'method = "ols"\ncovariance = "hac"\ncovariance_blocks = 5000',
     "identification.covariance_blocks = 5000: the training data have")
edit("identify", "covariance-lags-negative", 'method = "ols"', 'method = "ols"\ncovariance = "hac"\ncovariance_lags = -1',
     "identification.covariance_lags: must be >= 0, got -1")
edit("identify", "covariance-lags-for-model", 'method = "ols"', 'method = "ols"\ncovariance_lags = 2',
     "identification.covariance_lags is for covariance = 'hac', not 'model'")
edit("identify", "bootstrap-replicates-one", 'method = "ols"', 'method = "ols"\ncovariance = "block_bootstrap"\nbootstrap_replicates = 1',
     "identification.bootstrap_replicates: must be >= 2, got 1")
edit("identify", "bootstrap-seed-for-hac", 'method = "ols"', 'method = "ols"\ncovariance = "hac"\nbootstrap_seed = 3',
     "identification.bootstrap_seed is for covariance = 'block_bootstrap', not 'hac'")
edit("identify", "covariance-gm", 'method = "ols"', 'method = "gm"\ncovariance = "hac"',
     "identification.covariance = 'hac' is for the linear least-squares methods 'ols' and 'wls'", "not method = 'gm'")
edit("identify", "decimate-zero", "[processing]\n", "[processing]\ndecimate = 0\n", "processing.decimate: must be >= 1")
edit("identify", "min-velocity-negative", "[processing]\n", "[processing]\nmin_velocity = [0.1, -0.1]\n",
     "processing.min_velocity[1]: must be >= 0")
edit("identify", "robot-independent-serial", 'model = "rp2.toml"', 'model = "rp2.toml"\nindependent = ["shoulder"]',
     "is a serial robot: actuated joints and independent coordinates are for closed-loop mechanisms")
edit("identify", "robot-independent-empty", 'model = "rp2.toml"', 'model = "rp2.toml"\nindependent = []',
     "robot.independent: empty list")
edit("identify", "reversal-guard-unknown", "[processing]\n", "[processing]\nreversal_guard = \"wide\"\n",
     "processing.reversal_guard")
edit("identify", "reversal-guard-auto-without-lowpass", "lowpass = { cutoff_hz = 10.0, order = 2, filter_effort = false }",
     "reversal_guard = \"auto\"", "processing.reversal_guard = 'auto' is the settling time of processing.lowpass")
edit("identify", "gear-ratio-zero", 'model = "rp2.toml"', 'model = "rp2.toml"\ngear_ratios = [10.0, 0.0]',
     "robot.gear_ratios[1] is 0")
edit("identify", "gear-ratios-length", 'model = "rp2.toml"', 'model = "rp2.toml"\ngear_ratios = [10.0, 5.0, 2.0]',
     "robot.gear_ratios: 3 entries for a robot with 2 joints")
edit("identify", "unknown-builtin", 'model = "rp2.toml"', 'model = "builtin:puma650"', "unknown built-in robot 'puma650'")
edit("identify", "unknown-extra", 'model = "rp2.toml"', 'model = "rp2.toml"\nextras = ["Ia", "stiction"]',
     "robot.extras[1]: must be one of", "'stiction'")
edit("identify", "robot-file-missing", 'model = "rp2.toml"', 'model = "rp3.toml"', "robot file not found", "rp3.toml")
edit("identify", "rows-beyond-log", "rows = [240, 300]", "rows = [240, 400]", "validation.rows: stop 400 is beyond the 300 rows")
edit("identify", "validation-overlaps", "rows = [240, 300]", "rows = [200, 300]",
     "validation window [200, 300] overlaps the training window [0, 240]")
edit("identify", "rows-reversed", "rows = [0, 240]", "rows = [240, 0]", "data.rows: stop 0 must exceed start 240")
edit("identify", "columns-vs-joints", 'columns = ["q1", "q2"]', 'columns = ["q1"]',
     "data.position: 1 columns for a robot with 2 joints")
edit("identify", "column-named-twice", 'columns = ["q1", "q2"]', 'columns = ["q1", "q1"]',
     "data.position.columns: 'q1' named more than once")
edit("identify", "units-vs-columns", 'unit = ["rad", "m"]', 'unit = ["rad", "m", "m"]', "data.position.unit: 3 units for 2 columns")
@case("identify", "time-without-file", "data.time: no file (set data.file or data.time.file)")
def _(w):
    # position and effort name their own file; the time column has none
    text = IDENTIFY.replace('file = "log.csv"\n', "", 1).replace('unit = ["rad", "m"] }', 'unit = ["rad", "m"], file = "log.csv" }')
    return ["identify", str(w.write("cfg.toml", text.replace('unit = ["N*m", "N"] }', 'unit = ["N*m", "N"], file = "log.csv" }'))),
            "--out", str(w.out)]


edit("identify", "position-m-on-revolute", 'unit = ["rad", "m"]', 'unit = "m"',
     "data.position.unit = 'm' is a length, but joint 'shoulder' is revolute: use 'rad' or 'deg'")
edit("identify", "position-mm-on-revolute", 'unit = ["rad", "m"]', 'unit = ["mm", "m"]',
     "data.position.unit = 'mm' is a length, but joint 'shoulder' is revolute")
edit("identify", "position-rad-on-prismatic", 'unit = ["rad", "m"]', 'unit = "rad"',
     "data.position.unit = 'rad' is an angle, but joint 'slide' is prismatic: use 'm' or 'mm'", "one unit per column")
edit("identify", "position-deg-on-prismatic", 'unit = ["rad", "m"]', 'unit = ["deg", "deg"]',
     "'deg' is an angle, but joint 'slide' is prismatic")
edit("identify", "effort-N-on-revolute", 'unit = ["N*m", "N"]', 'unit = ["N", "N"]',
     "data.effort.unit = 'N' is a force, but joint 'shoulder' is revolute: use 'N*m' or 'Nm'")
edit("identify", "effort-Nm-on-prismatic", 'unit = ["N*m", "N"]', 'unit = "N*m"',
     "data.effort.unit = 'N*m' is a torque, but joint 'slide' is prismatic: use 'N'")
edit("identify", "motor-side-length", 'unit = ["rad", "m"] }', 'unit = ["rad", "m"], side = "motor" }',
     "data.position.unit = 'm' is a length, but the motor of joint 'slide' is a rotary motor")
edit("identify", "validation-unit", "rows = [240, 300]", 'rows = [240, 300]\neffort = { columns = ["tau1", "tau2"], unit = "N" }',
     "validation.effort.unit = 'N' is a force, but joint 'shoulder' is revolute")
edit("identify", "unknown-key-lowpass", "filter_effort = false }", "filter_effort = false, cutoff = 3 }",
     "unknown key processing.lowpass.cutoff")
edit("identify", "sample-rate-zero", 'time = { column = "t", unit = "s" }', "sample_rate_hz = 0", "data.sample_rate_hz: must be positive, got 0")
edit("identify", "time-and-rate", 'time = { column = "t", unit = "s" }', 'time = { column = "t", unit = "s" }\nsample_rate_hz = 100.0',
     "data: give exactly one of 'time' (a time column) or 'sample_rate_hz'")
edit("identify", "window-kinds-mixed", "rows = [240, 300]", "time_window = [2.4, 3.0]",
     "data and validation windows must both be 'rows' or both 'time_window'")


@case("identify", "time-window-beyond-log", "validation.time_window [10.0, 20.0] s selects 0 samples")
def _(w):
    text = IDENTIFY.replace("rows = [0, 240]", "time_window = [0.0, 2.4]").replace("rows = [240, 300]", "time_window = [10.0, 20.0]")
    return ["identify", str(w.write("cfg.toml", text)), "--out", str(w.out)]


edit("identify", "velocity-ignored", "rows = [0, 240]", 'rows = [0, 240]\nvelocity = { columns = ["q1", "q2"] }',
     "data.velocity columns are given but processing.derivatives = 'central' differentiates the positions")
edit("identify", "log-missing", 'file = "log.csv"', 'file = "log2.csv"', "data file not found", "log2.csv")
edit("identify", "log-is-a-folder", 'file = "log.csv"', 'file = "rp2.toml/.."', "is a folder, not a file")
edit("identify", "column-missing", '["tau1", "tau2"]', '["tau1", "torque2"]', "log.csv: missing columns ['torque2']",
     "the file has ['t', 'q1'")
edit("identify", "log-unknown-type", 'file = "log.csv"', 'file = "rp2.toml"', "unknown data file type '.toml'")


def _log_case(name: str, change, *fragments: str):
    """A case whose log.csv is changed by ``change(work)`` (the configuration stays good)."""
    def setup(w):
        change(w)
        return w.run("identify")

    case("identify", name, *fragments)(setup)


_log_case("all-efforts-zero", lambda w: w.set_log(0.0, cols=[3, 4]) or w.fill_out(),
          "data.effort: every column of log.csv (tau1, tau2) is 0 in all 240 samples")
_log_case("one-effort-zero", lambda w: w.set_log(0.0, cols=4), "data.effort: log.csv: 'tau2' is 0 in all 240 samples", "constant channel")
_log_case("one-effort-constant", lambda w: w.set_log(1.5, cols=3), "'tau1' is 1.5 in all 240 samples")
_log_case("validation-effort-zero", lambda w: w.set_log(0.0, rows=slice(240, None), cols=4),
          "validation.effort: log.csv: 'tau2' is 0 in all 60 samples")
_log_case("duplicate-header", lambda w: w.log("log.csv", header=["t", "q1", "q2", "tau1", "q1"]),
          "log.csv: the header names a column more than once ('q1' is columns 2, 5)")
_log_case("semicolons", lambda w: w.log("log.csv", sep=";"),
          "missing columns", "the file seems to be separated by semicolons (';')", "comma-separated CSV")
_log_case("tabs-in-csv", lambda w: w.log("log.csv", sep="\t"), "the file seems to be separated by tabs", "(.tsv for tab-separated)")
_log_case("log-empty", lambda w: w.write("log.csv", b""), "data file", "log.csv is empty")
_log_case("log-header-only", lambda w: w.write("log.csv", ",".join(HEADER) + "\n"), "log.csv: no data rows (the file has a header only)")
_log_case("log-blank-lines", lambda w: w.write("log.csv", "\n\n\n"), "log.csv has no header row")
_log_case("log-binary", lambda w: w.write("log.csv", b"\x89PNG\r\n\x1a\n\x00\x00" + bytes(range(256))), "log.csv is binary, not a CSV text file")
_log_case("log-latin1-header", lambda w: w.write("log.csv", "t,q1,q2,tau1,tau2,température\n1,2,3,4,5,6\n".encode("latin-1")),
          "log.csv is not UTF-8 text (byte 0xe9")
_log_case("log-nan", lambda w: w.set_log(np.nan, 17, 2), "data: positions contains NaN values", "first at sample 17")
_log_case("log-non-numeric", lambda w: w.set_log_text("abc", 5, 2), "log.csv: non-numeric value 'abc' in column 'q2' (row 6)")
_log_case("log-time-backwards", lambda w: w.set_log(0.1, 50, 0), "time is not strictly increasing at sample 50")


@case("identify", "log-too-short", "data: 30 samples; after trimming 16 filter-transient samples at each end none remain",
      "the 13 base parameters need at least 39 samples")
def _(w):
    return w.run("identify", "rows = [0, 240]", "rows = [0, 30]")


@case("identify", "log-without-permission", "cannot read data file", "log.csv: Permission denied",
      marks=pytest.mark.skipif(os.geteuid() == 0, reason="root reads a file whatever its mode; "
                                                        "test_unreadable_log_as_root covers this as root"))
def _(w):
    (w.dir / "log.csv").chmod(0)
    return w.run("identify")


@case("identify", "npz-garbage", "log.npz: not an NPZ file")
def _(w):
    w.write("log.npz", b"this is not a zip archive\n")
    return w.run("identify", 'file = "log.csv"', 'file = "log.npz"')


@case("identify", "npz-truncated", "log.npz: cannot read NPZ")
def _(w):
    import io

    buf = io.BytesIO()
    np.savez(buf, t=w.table[:, 0], q=w.table[:, 1:3], tau=w.table[:, 3:])
    w.write("log.npz", buf.getvalue()[: len(buf.getvalue()) // 2])
    return w.run("identify", 'file = "log.csv"', 'file = "log.npz"')


@case("identify", "out-is-a-file", "exists and is not a folder")
def _(w):
    w.out.write_text("not a folder")
    return w.run("identify")


@case("identify", "out-empty-name", "--out: empty folder name")
def _(w):
    return ["identify", str(w.config("identify")), "--out", ""]


case("identify", "missing-out", "the following arguments are required: --out")(lambda w: ["identify", str(w.config("identify"))])
case("identify", "unknown-option", "unrecognized arguments: --fast")(lambda w: w.run("identify", "", "", "--fast"))


# ---------------------------------------------------------------------- simulate
edit("simulate", "force-noise-negative", "force_noise_std = 0.01", "force_noise_std = -0.1",
     "sensors.force_noise_std: must be >= 0, got -0.1")
edit("simulate", "position-noise-negative", "position_noise_std = 0.0", "position_noise_std = [0.0, -1e-4]",
     "sensors.position_noise_std[1]: must be >= 0")
edit("simulate", "encoder-resolution-zero", "seed = 1\n\n[simulation]", "seed = 1\nencoder_resolution = 0\n\n[simulation]",
     "sensors.encoder_resolution: must be positive, got 0")
edit("simulate", "jitter-negative", "seed = 1\n\n[simulation]", "seed = 1\ntime_jitter_std = -1e-3\n\n[simulation]",
     "sensors.time_jitter_std: must be >= 0")
edit("simulate", "log-rate-zero", "seed = 1\n\n[simulation]", "seed = 1\nlog_rate_hz = 0\n\n[simulation]",
     "sensors.log_rate_hz: must be positive, got 0")
edit("simulate", "log-rate-not-dividing", "seed = 1\n\n[simulation]", "seed = 1\nlog_rate_hz = 30\n\n[simulation]",
     "sensors.log_rate_hz = 30 must divide control.rate_hz = 100")
edit("simulate", "control-rate-negative", "rate_hz = 100", "rate_hz = -100", "control.rate_hz: must be positive, got -100")
edit("simulate", "kp-negative", "kp = 100", "kp = [100, -5]", "control.kp[1]: must be positive, got -5")
edit("simulate", "kd-nan", "kd = 20", "kd = nan", "control.kd: expected a finite number, got nan")
edit("simulate", "gains-length", "kp = 100", "kp = [100, 100, 100]", "control.kp has 3 entries; the robot has 2 independent coordinates")
edit("simulate", "correlation-out-of-range", "force_noise_std = 0.01", "force_noise_std = 0.01\nforce_correlation = 1.5",
     "sensors.force_correlation must be in (-1, 1), got 1.5")
edit("simulate", "covariance-not-psd", "force_noise_std = 0.01", "force_covariance = [[1.0, 2.0], [2.0, 1.0]]",
     "sensors.force_covariance: not positive semi-definite")
edit("simulate", "covariance-not-square", "force_noise_std = 0.01", "force_covariance = [[1.0, 0.0], [0.0]]",
     "sensors.force_covariance: expected a square matrix")
edit("simulate", "noise-length", "force_noise_std = 0.01", "force_noise_std = [0.01, 0.01, 0.01]",
     "sensors.force_noise_std has 3 entries for 2 actuators")
edit("simulate", "resolution-length", "seed = 1\n\n[simulation]", "seed = 1\nencoder_resolution = [1e-5, 1e-5, 1e-5]\n\n[simulation]",
     "sensors.encoder_resolution has 3 entries for 2 actuators")
edit("simulate", "torque-constant-zero", "seed = 1\n\n[simulation]", "seed = 1\ntorque_constants = [0.1, 0.0]\n\n[simulation]",
     "sensors.torque_constants[1] is 0")
edit("simulate", "unknown-key-sensors", "seed = 1\n\n[simulation]", "seed = 1\nnoise = 0.1\n\n[simulation]", "unknown key sensors.noise")
edit("simulate", "unknown-key-control", "kd = 20", "kd = 20\nkv = 1", "unknown key control.kv")
edit("simulate", "unknown-key-simulation", "duration = 0.5", "duration = 0.5\ndt = 0.01", "unknown key simulation.dt")
edit("simulate", "unknown-key-robot", "perturbation = 0.05", "perturbation = 0.05\nperturb = 1", "unknown key robot.perturb")
edit("simulate", "key-of-another-kind", "harmonics = 2", "harmonics = 2\nradius = 0.1",
     "trajectory: keys ['radius'] do not apply to kind 'fourier'")
edit("simulate", "unknown-trajectory-kind", 'kind = "fourier"', 'kind = "spiral"', "trajectory.kind: must be one of")
edit("simulate", "duration-zero", "duration = 0.5", "duration = 0.0", "simulation.duration: must be positive, got 0.0")
edit("simulate", "perturbation-negative", "perturbation = 0.05", "perturbation = -0.1", "robot.perturbation must be >= 0")
edit("simulate", "friction-negative", "perturbation = 0.05", 'perturbation = 0.05\nfriction = { model = "coulomb_viscous", fc = -0.2, fv = 1.0 }',
     "robot.friction.fc: must be >= 0, got -0.2")
edit("simulate", "friction-vs-zero", "perturbation = 0.05",
     'perturbation = 0.05\nfriction = { model = "stribeck", fc = 0.2, fs = 0.3, fv = 1.0, vs = 0.0 }',
     "robot.friction.vs: must be positive, got 0.0")
edit("simulate", "payload-triangle", "perturbation = 0.05",
     "perturbation = 0.05\npayload = { mass = 1.0, inertia = [0.001, 0.001, 0.01] }",
     "robot.payload.inertia [0.001, 0.001, 0.01]: principal moments must satisfy the triangle inequality")
edit("simulate", "payload-negative-inertia", "perturbation = 0.05",
     "perturbation = 0.05\npayload = { mass = 1.0, inertia = [0.001, -0.001, 0.001] }", "robot.payload.inertia[1]: must be >= 0")
edit("simulate", "fill-above-one", "harmonics = 2", "harmonics = 2\nfill = 2.0", "trajectory.fill must be in (0, 1], got 2.0")
edit("simulate", "harmonics-zero", "harmonics = 2", "harmonics = 0", "trajectory.harmonics: must be >= 1, got 0")
edit("simulate", "unknown-key-output", 'format = "csv"', 'format = "csv"\nfile = "log.csv"', "unknown key output.file")
edit("simulate", "unknown-key-friction", "perturbation = 0.05",
     'perturbation = 0.05\nfriction = { model = "coulomb_viscous", fc = 0.2, fv = 1.0, fs = 0.3 }',
     "robot.friction: keys ['fs'] do not apply to model 'coulomb_viscous'")
edit("simulate", "output-format", 'format = "csv"', 'format = "xlsx"', "output.format: must be one of ['csv', 'npz'], got 'xlsx'")
edit("simulate", "robot-missing", 'model = "rp2.toml"', 'model = "robots/rp2.toml"', "robot file not found", "robots/rp2.toml")
edit("simulate", "design-file-missing", "base_frequency_hz = 1.0\nharmonics = 2\nseed = 1", 'design = "design.json"', "design file not found", "design.json")
edit("simulate", "ki-with-computed-torque", "kd = 20", "kd = 20\nki = 1.0",
     "control.ki applies to kind 'pid' or 'feedforward_pid', not 'computed_torque'")


@case("simulate", "design-file-not-json", "design.json: not a design.json of dynid design")
def _(w):
    w.write("design.json", "{ this is not json")
    return w.run("simulate", "base_frequency_hz = 1.0\nharmonics = 2\nseed = 1", 'design = "design.json"')


@case("simulate", "polyline-one-vertex", "trajectory.vertices: a polyline needs at least 2 vertices, got 1")
def _(w):
    return w.run("simulate", 'kind = "fourier"\nbase_frequency_hz = 1.0\nharmonics = 2\nseed = 1',
                 'kind = "polyline"\nvertices = [[0.0, 0.2]]\nspeed = 0.1')


edit("simulate", "unknown-control-kind", 'kind = "computed_torque"', 'kind = "lqr"',
     "control.kind: must be one of ['computed_torque', 'pid', 'feedforward_pid'], got 'lqr'")
edit("simulate", "payload-unknown-body", "perturbation = 0.05", "perturbation = 0.05\npayload = { mass = 1.0, body = \"wrist\" }",
     "robot.payload.body = 'wrist' is no joint of 'rp2'; one of ['shoulder', 'slide']")
edit("simulate", "control-model-missing", "kd = 20", 'kd = 20\nmodel = "id/result.json"',
     "control.model: identification result not found", "id/result.json", "'nominal', 'true' or the result.json")
edit("simulate", "control-model-empty", "kd = 20", 'kd = 20\nmodel = ""', "control.model: empty")


@case("simulate", "payload-body-required", "robot.payload.body: 'shang2dof' declares no platform",
      "one of ['qa1', 'qb1', 'qa2', 'qb2', 'qa3', 'qb3']")
def _(w):
    return ["simulate", str(_shang(w, "payload = { mass = 1.0 }")), "--out", str(w.out)]


@case("simulate", "payload-on-a-massless-body", "robot.payload.body = 'PX' is a massless (virtual) body of 'hexapod'")
def _(w):
    text = SIMULATE.replace('model = "rp2.toml"\nperturbation = 0.05', 'model = "builtin:hexapod"\npayload = { mass = 1.0, body = "PX" }')
    return ["simulate", str(w.write("hexapod.toml", text)), "--out", str(w.out)]


def _shang(w, robot: str = "", control: str = "") -> Path:
    text = SIMULATE.replace('model = "rp2.toml"\nperturbation = 0.05', f'model = "builtin:shang2dof"\n{robot}')
    text = text.replace('kind = "fourier"\nbase_frequency_hz = 1.0\nharmonics = 2\nseed = 1',
                        'kind = "circle"\ncentre = [0.29, 0.25]\nradius = 0.04\nspeed = 0.2')
    text = text.replace("kd = 20\n", f"kd = 20\n{control}\n")
    return w.write("shang.toml", text)


def _rp2_result(w) -> Path:
    """A real result.json of ``dynid identify`` (the rp2 arm of the good identify configuration)."""
    from dynid.config import load_config
    from dynid.pipeline.identification import identify, write_outputs

    write_outputs(identify(load_config(w.config("identify", name="identify.toml"))), w.dir / "id")
    return w.dir / "id" / "result.json"


@case("simulate", "control-model-of-another-robot", "control.model:", "id/result.json (a result of 'rp2') does not identify "
      "the base parameters of 'shang2dof'")
def _(w):
    _rp2_result(w)
    return ["simulate", str(_shang(w, control='model = "id"')), "--out", str(w.out)]


@case("simulate", "control-model-stribeck", "id/result.json is a Stribeck result (WLS+LMI+Stribeck)",
      "nonlinear in the parameters")
def _(w):
    import json

    path = _rp2_result(w)
    doc = json.loads(path.read_text())
    doc["method"], doc["solver"]["stribeck"] = "WLS+LMI+Stribeck", {"shoulder": {"Fc": 0.3, "Fs": 0.5, "Fv": 0.5, "vs": 0.1, "delta": 2.0}}
    path.write_text(json.dumps(doc))
    return w.run("simulate", 'kind = "computed_torque"', 'kind = "feedforward_pid"\nmodel = "id/result.json"')


@case("simulate", "control-model-not-a-result", "control.model:", "truth.json is not a result.json of dynid identify")
def _(w):
    w.write("truth.json", '{"model": "rp2.toml"}')
    return w.run("simulate", "kd = 20", 'kd = 20\nmodel = "truth.json"')


case("simulate", "missing-out", "the following arguments are required: --out")(lambda w: ["simulate", str(w.config("simulate"))])
case("simulate", "config-is-a-folder", "config file", "is a folder, not a file")(
    lambda w: ["simulate", str(w.dir), "--out", str(w.out)])


# ---------------------------------------------------------------------- design
edit("design", "unknown-key-design", "samples = 8", "samples = 8\nsample = 8", "unknown key design.sample")
edit("design", "unknown-key-limits", "velocity = 2.0", "velocity = 2.0\nspeed = 1.0", "unknown key limits.speed")
edit("design", "unknown-key-output", "rate_hz = 20", "rate_hz = 20\nformat = 1", "unknown key output.format")
edit("design", "unknown-top-level-key", "[limits]", "[limit]", "unknown key limit")
edit("design", "criterion", 'criterion = "cond"', 'criterion = "d_optimal"', "design.criterion: must be one of")
edit("design", "velocity-negative", "velocity = 2.0", "velocity = -2.0", "limits.velocity: must be positive, got -2.0")
edit("design", "acceleration-nan", "acceleration = 10.0", "acceleration = nan", "limits.acceleration: expected a finite number")
edit("design", "velocity-length", "velocity = 2.0", "velocity = [2.0, 2.0, 2.0]", "limits.velocity has 3 entries for 2 actuators")
edit("design", "position-reversed", "acceleration = 10.0", "acceleration = 10.0\nposition = { lower = [1.0, 0.4], upper = [-1.0, 0.5] }",
     "limits.position: lower and upper need the same length and lower < upper")
edit("design", "position-length", "acceleration = 10.0", "acceleration = 10.0\nposition = { lower = [-1.0], upper = [1.0] }",
     "limits.position has 1 entries for 2 actuators")
edit("design", "position-outside-box", "acceleration = 10.0",
     "acceleration = 10.0\nposition = { lower = [-1.0, 0.6], upper = [1.0, 0.7] }",
     "limits.position of slide [0.6, 0.7] does not meet the range of the design coordinate slide [0.1, 0.5]")
edit("design", "samples-too-few", "samples = 8", "samples = 4", "design.samples: must be >= 8, got 4")
edit("design", "harmonics-zero", "harmonics = 1", "harmonics = 0", "design.harmonics: must be >= 1, got 0")
edit("design", "frequency-zero", "base_frequency_hz = 0.5", "base_frequency_hz = 0", "design.base_frequency_hz: must be positive")
edit("design", "max-condition-below-one", "acceleration = 10.0", "acceleration = 10.0\nmax_condition = 0.5",
     "limits.max_condition must be > 1 (a condition number is at least 1), got 0.5")
edit("design", "noise-length", "seed = 1", "seed = 1\nnoise_std = [0.1, 0.1, 0.1]", "noise_std has 3 entries for 2 output channels")
edit("design", "box-length", "seed = 1", "seed = 1\nbox = { lower = [-1.0], upper = [1.0] }",
     "box has 1 entries for 2 design coordinates")
edit("design", "rate-zero", "rate_hz = 20", "rate_hz = 0", "output.rate_hz: must be positive, got 0")
edit("design", "task-on-serial", "seed = 1", 'seed = 1\ncoordinates = "task"', "task-space designs are for parallel robots")
edit("design", "circle-keys-on-fourier", "seed = 1", "seed = 1\nradius = 0.1", "design: keys ['radius'] are for kind = 'circle'")
edit("design", "unknown-builtin", 'model = "rp2.toml"', 'model = "builtin:ur5"', "unknown built-in robot 'ur5'")
edit("design", "unknown-key-robot", 'model = "rp2.toml"', 'model = "rp2.toml"\nextras = ["Ia"]', "unknown key robot.extras")
edit("design", "force-below-gravity", "acceleration = 10.0", "acceleration = 10.0\nforce = 0.01",
     "limits.force of shoulder is 0.01, but the nominal model needs", "to hold the rest pose")
case("design", "missing-config", "config file not found")(lambda w: ["design", str(w.dir / "design.toml"), "--out", str(w.out)])


@case("design", "robot-negative-mass", "rp2.toml: joints[1].mass is negative (-1.0)")
def _(w):
    w.write("rp2.toml", ROBOT.replace("mass = 1.0", "mass = -1.0"))
    return w.run("design")


# ---------------------------------------------------------------------- montecarlo
edit("montecarlo", "trials-zero", "trials = 2", "trials = 0", "montecarlo.trials: must be >= 1, got 0")
edit("montecarlo", "alpha", "alpha = 0.05", "alpha = 1.5", "montecarlo.alpha: must be in (0, 1), got 1.5")
edit("montecarlo", "workers-negative", "workers = 1", "workers = -2", "montecarlo.workers: must be >= 0, got -2")
edit("montecarlo", "workers-word", "workers = 1", 'workers = "many"', "montecarlo.workers: expected an integer >= 0 or \"auto\"")
edit("montecarlo", "seed-negative", "alpha = 0.05", "alpha = 0.05\nseed = -1", "montecarlo.seed: must be >= 0")
edit("montecarlo", "scheduler-format", "alpha = 0.05", 'alpha = 0.05\nscheduler = "my cluster"',
     "montecarlo.scheduler: 'my cluster' is not a Dask scheduler address")
edit("montecarlo", "unknown-key", "trials = 2", "trials = 2\ntrails = 3", "unknown key montecarlo.trails")
edit("montecarlo", "unknown-key-identify", 'method = "ols"', 'method = "ols"\nmetod = "wls"', "identify: unknown key identification.metod")
edit("montecarlo", "unknown-identify-table", "[identify.identification]", "[identify.output]\nplots = true\n\n[identify.identification]",
     "unknown key identify.output")
edit("montecarlo", "windows-alone", "[montecarlo]", "[identify.data]\nrows = [0, 30]\n\n[montecarlo]",
     "[identify.data] needs [identify.validation]")
edit("montecarlo", "stribeck", 'method = "ols"', 'method = "ols"\nphysical_consistency = true\nfriction_model = "stribeck"',
     "friction_model = 'stribeck' is not available in dynid montecarlo")
edit("montecarlo", "simulate-file-and-tables", 'file = "sim.toml"', 'file = "sim.toml"\nrobot = { model = "rp2.toml" }',
     "simulate: give either file = \"...\" or the configuration's tables")
edit("montecarlo", "simulate-file-missing", 'file = "sim.toml"', 'file = "simulation.toml"', "simulate.file", "config file not found", "simulation.toml")
edit("montecarlo", "identify-robot-unknown", "[identify.identification]", '[identify.robot]\nmodel = "builtin:nope"\n\n[identify.identification]',
     "identify.robot.model", "unknown built-in robot 'nope'")
edit("montecarlo", "identify-covariance-lags", 'method = "ols"', 'method = "ols"\ncovariance = "hac"\ncovariance_lags = -2',
     "identify: identification.covariance_lags: must be >= 0")
edit("montecarlo", "identify-min-motion", 'method = "ols"', 'method = "ols"\nmin_joint_motion = -1',
     "identify: identification.min_joint_motion: must be >= 0")
case("montecarlo", "cli-trials-zero", "argument --trials: expected an integer >= 1, got '0'")(
    lambda w: w.run("montecarlo", "", "", "--trials", "0"))
case("montecarlo", "cli-workers-negative", "argument --workers")(lambda w: w.run("montecarlo", "", "", "--workers", "-1"))
case("montecarlo", "cli-scheduler-format", "--scheduler: 'http://host:8786' is not a Dask scheduler address")(
    lambda w: w.run("montecarlo", "", "", "--scheduler", "http://host:8786"))


@case("montecarlo", "simulate-noise-negative", "simulate.file", "sensors.force_noise_std: must be >= 0, got -0.1")
def _(w):
    w.write("sim.toml", SIMULATE.replace("force_noise_std = 0.01", "force_noise_std = -0.1"))
    return w.run("montecarlo")


@case("montecarlo", "simulate-inline-unknown-key", "simulate: unknown key sensors.noise")
def _(w):
    inline = "\n".join(line.replace("[", "[simulate.", 1) if line.startswith("[") else line for line in SIMULATE.splitlines())
    text = MONTECARLO.replace('[simulate]\nfile = "sim.toml"\n', inline.replace("seed = 1\n\n[simulate.simulation]",
                                                                                "seed = 1\nnoise = 1\n\n[simulate.simulation]"))
    return ["montecarlo", str(w.write("mc.toml", text)), "--out", str(w.out)]


# ---------------------------------------------------------------------- info
def _info(name: str, text: str | bytes, *fragments: str, extra: tuple[str, ...] = ()):
    case("info", name.split(".")[0], *fragments)(lambda w: ["info", str(w.write(name, text)), *extra])


_info("urdf-negative-mass.urdf", URDF.replace('<mass value="1.5"/>', '<mass value="-1.5"/>'), "link 'upper': mass -1.5 kg is negative")
# an inertia no rigid body has is accepted in a URDF with a warning (tests/test_vendor_urdfs.py); non-finite is not
_info("urdf-inertia-nan.urdf", URDF.replace('ixy="0"', 'ixy="nan"'), "link 'upper': the inertia has non-finite entries")
_info("urdf-no-limits.urdf", URDF.replace('<limit lower="-2" upper="2" effort="10" velocity="2"/>', ""),
      "urdf-no-limits.urdf: cannot parse robot description (Joint [j1] is of type REVOLUTE but it does not specify limits)")
_info("urdf-missing-link.urdf", URDF.replace('<child link="upper"/>', '<child link="lower"/>'), "child link [lower] of joint [j1] not found")
_info("urdf-garbage.urdf", bytes(range(256)), "urdf-garbage.urdf: invalid XML")
_info("urdf-empty.urdf", b"", "robot file", "urdf-empty.urdf is empty")
_info("urdf-root.urdf", "<mujoco model='x'/>", "not a URDF file (its root element is <mujoco>, not <robot>)")
_info("urdf-mass-text.urdf", URDF.replace('<mass value="1.5"/>', '<mass value="heavy"/>'), "link 'upper' <mass value>: 'heavy' is not 1 number")
_info("mjcf-negative-mass.xml", FIVEBAR.replace('mass="0.35"', 'mass="-0.35"', 1), "body 'dist1': mass -0.35 kg is negative")
_info("mjcf-triangle.xml", FIVEBAR.replace('diaginertia="0.006 0.006 0.0002"', 'diaginertia="0.006 0.0001 0.0002"', 1),
      "body 'dist1': the principal moments of inertia", "break the triangle inequality")
_info("mjcf-ball.xml", FIVEBAR.replace('<joint name="qb1" type="hinge" axis="0 1 0"/>', '<joint name="qb1" type="ball"/>'),
      "actuated joints ['qa1', 'qa2'] are fewer than the mobility 3: the mechanism is under-actuated")
_info("mjcf-serial-ball.xml", FIVEBAR.split("  <equality>")[0].replace('<joint name="qb1" type="hinge" axis="0 1 0"/>',
                                                                        '<joint name="qb1" type="ball"/>') + "</mujoco>\n",
      "mjcf-serial-ball.xml: joint 'qb1' is a ball joint (3 DOF); a serial robot needs 1-DOF joints")
_info("mjcf-weld-far.xml", FIVEBAR.replace('<connect name="P" body1="dist1" body2="dist2" anchor="0.27 0 0.36"/>',
                                           '<weld name="P" body1="dist1" body2="dist2" relpose="3 0 0 1 0 0 0"/>'),
      "mjcf-weld-far.xml: cannot assemble the loops of 'fivebar': closure 'P' (6d) cannot close (constraint residual")
_info("mjcf-bad-closure-body.xml", FIVEBAR.replace('body2="dist2"', 'body2="dist9"'), "any body named dist9")
_info("mjcf-two-roots.xml", FIVEBAR.replace("  </worldbody>", '    <body name="extra"><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body>\n  </worldbody>'),
      "<worldbody> has 2 top-level bodies")
_info("dh-triangle.toml", ROBOT.replace("inertia = [0.01, 0.02, 0.02,", "inertia = [0.01, 0.02, 0.05,"),
      "dh-triangle.toml: joints[0] (shoulder): the principal moments of inertia 0.01, 0.02, 0.05 kg*m^2 break the triangle inequality")
_info("dh-unknown-key.toml", ROBOT.replace('type = "prismatic"', 'type = "prismatic"\nstiffness = 3'), "joints[1]: unknown keys ['stiffness']")
_info("dh-bad-type.toml", ROBOT.replace('type = "prismatic"', 'type = "helical"'),
      "dh-bad-type.toml: joints[1]: joint type must be 'revolute' or 'prismatic', got 'helical'")
_info("dh-latin1.toml", ROBOT.replace('name = "rp2"', 'name = "bras à 2 axes"').encode("latin-1"), "dh-latin1.toml is not UTF-8 text")
_info("dh-nan.toml", ROBOT.replace("a = 0.3", "a = nan"), "joints[1].a: expected a finite number, got nan")
_info("robot.stl", "solid x\nendsolid x\n", "unknown robot file type '.stl'")
_info("extras.toml", ROBOT, "unknown joint extras ['stiction']", extra=("--extras", "Ia,stiction"))
_info("closures.urdf", URDF, "closure file not found", "nope.yaml", extra=("--closures", "nope.yaml"))
# a redundant file loads with a chart chosen among its actuators (issue 34); a chart of the wrong size given by hand does not
_info("mjcf-redundant.xml", FIVEBAR.replace('<motor joint="qa2"/>', '<motor joint="qa2"/>\n    <motor joint="qb1"/>'),
      "mechanism 'fivebar' has mobility 2", "but 3 independent coordinates were given", "e.g. ['qa1', 'qa2']",
      extra=("--independent", "qa1,qa2,qb1"))
_info("mjcf-independent-unknown.xml", FIVEBAR, "independent coordinates ['q9'] are not joints of the model",
      extra=("--independent", "qa1,q9"))
_info("mjcf-independent-size.xml", FIVEBAR, "but 1 independent coordinates were given", extra=("--independent", "qa1"))
_info("dh-independent.toml", ROBOT, "is a serial robot: actuated joints and independent coordinates are for closed-loop",
      extra=("--independent", "shoulder"))
case("demo", "cli-seed-negative", "argument --seed: expected an integer in [0, 2**31), got '-3'")(
    lambda w: ["demo", "--out", str(w.dir / "out"), "--seed", "-3"])
case("demo", "cli-seed-text", "argument --seed: expected an integer in [0, 2**31), got 'abc'")(
    lambda w: ["demo", "--out", str(w.dir / "out"), "--seed", "abc"])
case("info", "unknown-builtin", "unknown built-in robot 'pumaa560'")(lambda w: ["info", "builtin:pumaa560"])
case("info", "missing-file", "robot file not found", "nothing.urdf")(lambda w: ["info", str(w.dir / "nothing.urdf")])
case("info", "folder", "robot file", "is a folder, not a file")(lambda w: ["info", str(w.dir / "models.urdf")] if
                                                                   (w.dir / "models.urdf").mkdir() is None else [])


@case("info", "closure-yaml-invalid", "robot.yaml: invalid YAML")
def _(w):
    w.write("robot.yaml", "closed_loop: [[a, b]\ntype: ['6d'")
    return ["info", str(w.write("robot.urdf", URDF))]


_LINK = '<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'
_HINGE = '<axis xyz="0 0 1"/><limit effort="1" velocity="1" lower="-3" upper="3"/></joint>'
FOURBAR_FAR = f"""<robot name="fourbar">
  <link name="base"/> <link name="l1">{_LINK}</link> <link name="l2">{_LINK}</link> <link name="l3">{_LINK}</link>
  <link name="t2"/> <link name="t3"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>{_HINGE}
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="1 0 0"/>{_HINGE}
  <joint name="tip2" type="fixed"><parent link="l2"/><child link="t2"/><origin xyz="0 1.2 0"/></joint>
  <joint name="j3" type="revolute"><parent link="base"/><child link="l3"/><origin xyz="-0.5 1.2 0"/>{_HINGE}
  <joint name="tip3" type="fixed"><parent link="l3"/><child link="t3"/><origin xyz="5 0 0"/></joint>
</robot>
"""


@case("info", "closure-cannot-close", "robot.urdf + robot.yaml: cannot assemble the loops of",
      "closure 'tip2-tip3' (3d) cannot close (constraint residual")
def _(w):
    """A four-bar whose rocker tip (5 m) lies at least 1.5 m from anything the crank side reaches."""
    w.write("robot.yaml", "closed_loop: [[tip2, tip3]]\ntype: [3d]\nname_mot: [j1]\n")
    return ["info", str(w.write("robot.urdf", FOURBAR_FAR))]


@case("info", "robot-read-error", "cannot read robot file", "Input/output error",
      marks=pytest.mark.skipif(not Path("/proc/self/mem").exists(), reason="needs Linux /proc"))
def _(w):
    (w.dir / "arm.urdf").symlink_to("/proc/self/mem")
    return ["info", str(w.dir / "arm.urdf")]


@pytest.mark.parametrize("setup, fragments", CASES)
def test_bad_input_is_refused_with_one_line(setup, fragments, tmp_path, table, capfd):
    work = Work(tmp_path, table)
    argv = setup(work)
    capfd.readouterr()
    before = snapshot(work.out)
    code = main(argv)
    out, err = capfd.readouterr()
    assert_refused(code, out, err, fragments, tmp_path, work.out, before)


def test_the_corpus_covers_every_command():
    per = {}
    for p in CASES:
        command = p.id.split("-", 1)[0]
        per[command] = per.get(command, 0) + 1
    assert len(CASES) >= 90, len(CASES)
    assert all(per.get(c, 0) >= 10 for c in ("identify", "simulate", "design", "montecarlo", "info")), per


def test_unreadable_log_as_root(tmp_path, table, capfd, monkeypatch):
    """The log-without-permission case for a user (root included) whose read fails: the OS refuses
    to open log.csv (PermissionError from open, as for a file without read permission)."""
    import builtins

    work = Work(tmp_path, table)
    argv = work.run("identify")
    real_open = builtins.open

    def refusing_open(file, *args, **kw):
        if str(file).endswith("log.csv"):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kw)

    monkeypatch.setattr(builtins, "open", refusing_open)
    capfd.readouterr()
    code = main(argv)
    monkeypatch.undo()
    out, err = capfd.readouterr()
    assert_refused(code, out, err, ["cannot read data file", "log.csv: Permission denied"], tmp_path, work.out, None)


# ---------------------------------------------------------------------- the good inputs succeed
@pytest.mark.parametrize("command", ["identify", "simulate", "design", "montecarlo", "info-dh", "info-urdf", "info-mjcf"])
def test_good_inputs_succeed(command, tmp_path, table, capfd):
    work = Work(tmp_path, table)
    if command.startswith("info"):
        name = {"info-dh": "rp2.toml", "info-urdf": "arm.urdf", "info-mjcf": "fivebar.xml"}[command]
        work.write("arm.urdf", URDF)
        work.write("fivebar.xml", FIVEBAR)
        argv = ["info", str(tmp_path / name), "--json"]
    else:
        argv = work.run(command) + (["--no-progress"] if command == "montecarlo" else ["-q"])
    code = main(argv)
    out, err = capfd.readouterr()
    assert code == 0, err
    assert err == "" and "Traceback" not in out
    if not command.startswith("info"):
        assert work.out.is_dir() and any(work.out.iterdir())


# ---------------------------------------------------------------------- the real executable
def _dynid() -> list[str]:
    script = Path(sys.executable).with_name("dynid")
    return [str(script)] if script.exists() else [sys.executable, "-m", "dynid.cli"]


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["identify", "cfg.toml"], ["the following arguments are required: --out", "dynid identify --help"]),
        (["calibrate", "cfg.toml"], ["invalid choice: 'calibrate'"]),
        (["montecarlo", "cfg.toml", "--out", "out", "--workers", "-3"], ["argument --workers", "'-3'"]),
        (["info", "noisy.urdf"], ["noisy.urdf: cannot parse robot description",
                                  "Joint [j1] is of type REVOLUTE but it does not specify limits"]),
    ],
    ids=["missing-out", "unknown-command", "negative-workers", "urdf-parser-noise"],
)
def test_the_executable_prints_one_line(argv, fragments, tmp_path):
    (tmp_path / "noisy.urdf").write_text(URDF.replace('<limit lower="-2" upper="2" effort="10" velocity="2"/>', ""))
    r = subprocess.run(_dynid() + argv, cwd=tmp_path, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert_refused(r.returncode, r.stdout, r.stderr, fragments, tmp_path, tmp_path / "out", None)


def test_help_still_prints_the_usage(tmp_path):
    r = subprocess.run(_dynid() + ["identify", "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.startswith("usage: dynid identify") and r.stderr == ""
