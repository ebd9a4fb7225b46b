"""The steady-state rule of the friction extraction (paper 003, Sec. 3.1: "only data sampled
during steady constant velocity motion phases are retained"): :func:`settled_start` on windows
with a known transient, and ``dynid simulate`` -> ``dynid friction`` on a closed-loop log whose
PID transient outlasts the fixed ``skip``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import seed

from dynid.cli import main
from dynid.model.friction import SmoothStribeck
from dynid.signals.friction_points import SETTLE_MIN_BLOCKS, settled_start

RATE = 250.0
COUNT = 4.794e-5  # the encoder step of the paper-003 twin [rad]


def _window(duration, v, amp=0.0, tau=1.0, omega=4.0, quantise=True):
    """A window at speed ``v`` whose speed rings about it: q = v t + amp e^{-t/tau} sin(omega t),
    read by an encoder of step COUNT. The speed error's envelope is about amp * omega * e^{-t/tau}."""
    t = np.arange(0.0, duration, 1.0 / RATE)
    q = v * t + amp * np.exp(-t / tau) * np.sin(omega * t)
    return t, (np.round(q / COUNT) * COUNT if quantise else q)


def test_a_steady_window_loses_nothing():
    t, q = _window(3.0, 0.02, quantise=False)
    i0, info = settled_start(t, q)
    assert i0 == 0 and info["tested"] and info["v_ref"] == pytest.approx(0.02, rel=1e-12)


def test_a_decaying_transient_is_cut_where_it_enters_the_band():
    """The cut lies where the speed error's envelope amp * omega * e^{-t/tau} meets the band
    max(k s_L, tol v) (block-averaged: within a period of the ringing, 2 pi / omega = 1.6 s, of it)."""
    v, amp, tau, omega = 0.005, 2e-3, 0.6, 4.0
    t, q = _window(6.0, v, amp, tau, omega)
    i0, info = settled_start(t, q)
    assert info["tested"] and i0 is not None
    t_cut = t[i0]
    t_env = tau * np.log(amp * omega / info["band"])  # the envelope reaches the band here
    assert t_env > 1.0  # the transient is longer than a 1 s skip would remove
    assert t_env - 2 * np.pi / omega <= t_cut <= t_env + 0.1, (t_cut, t_env)
    # the band is the encoder's noise level or 2 % of the speed, whichever is larger: a few % here
    assert 0.02 * v <= info["band"] < 0.2 * v


def test_a_hunting_window_never_settles_and_a_short_one_is_not_tested():
    # a speed that rings undamped (tau >> window): it leaves any band in the last third
    t, q = _window(6.0, 0.003, amp=3e-4, tau=1e3, omega=3.0)
    i0, info = settled_start(t, q)
    assert i0 is None and info["worst"] > info["band"]
    t, q = _window(0.1 * (SETTLE_MIN_BLOCKS - 1), 0.1, quantise=False)
    i0, info = settled_start(t, q)
    assert i0 == 0 and not info["tested"]


# The paper-003 twin's joint 4 (Eq. 15 with Table 3's coefficients, a 10 ms frictional memory,
# its PID, encoder and torque noise), alone at 0.005 and 0.008 rad/s in 8 s windows: after each
# reversal its PID rings for 2-3 s (its integral swings by 2 F_f while arctan(K_v v) is steep).
SIM = """
[robot]
model = "builtin:cobot6r"
[robot.friction]
model = "smooth_stribeck"
fc = [6.321, 4.831, 7.781, 1.033, 1.601, 1.109]
fs = [8.217, 6.280, 10.115, 1.343, 2.081, 1.442]
fv = [7.167, 8.341, 8.516, 2.536, 3.175, 2.327]
vs = [0.05, 0.05, 0.06, 0.08, 0.08, 0.1]
kv = [225.245, 325.565, 456.368, 558.961, 769.659, 865.974]
alpha = [1.036, 0.589, 0.678, 0.469, 1.006, 0.853]
memory = 0.01
[trajectory]
kind = "constant_velocity"
joints = ["joint_4"]
speeds = [0.005, 0.008]
window = 8.0
pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
[control]
kind = "pid"
rate_hz = 250
kp = [1500, 1800, 800, 180, 200, 110]
kd = [50, 60, 27, 6, 7, 3.6]
ki = [15000, 18000, 8000, 1800, 2000, 1100]
substeps = 4
[sensors]
encoder_resolution = 4.794e-5
force_noise_std = [0.3, 0.3, 0.2, 0.1, 0.05, 0.05]
seed = 1
"""

FRICTION = """
[robot]
model = "builtin:cobot6r"
[data]
file = "sim/log.csv"
time = { column = "t" }
position = { columns = ["q_joint_1", "q_joint_2", "q_joint_3", "q_joint_4", "q_joint_5", "q_joint_6"] }
effort = { columns = ["tau_joint_1", "tau_joint_2", "tau_joint_3", "tau_joint_4", "tau_joint_5", "tau_joint_6"] }
[friction]
models = ["coulomb_viscous"]
held_out = "none"
"""

TRUE = SmoothStribeck(fc=1.033, fs=1.343, fv=2.536, vs=0.08, kv=558.961, alpha=0.469)


@pytest.fixture(scope="module")
def closed_loop(tmp_path_factory):
    """friction.json of the fixed default skip (0.5 s, settle off: the default), of the rule on
    that floor and of the rule on a 1 s floor."""
    d = tmp_path_factory.mktemp("settle")
    (d / "sim.toml").write_text(SIM.replace("\nseed = 1\n", f"\nseed = {seed(1)}\n"))  # the sensor noise's
    assert main(["simulate", str(d / "sim.toml"), "--out", str(d / "sim"), "-q"]) == 0
    out = {}
    for name, extra in (("fixed", ""), ("settled", "settle = true\n"), ("settled_skip1", "settle = true\nskip = 1.0\n")):
        (d / f"{name}.toml").write_text(FRICTION + extra)
        assert main(["friction", str(d / f"{name}.toml"), "--out", str(d / name), "-q"]) == 0
        out[name] = json.loads((d / name / "friction.json").read_text())
    return out


def _errors(doc):
    """Per point: (speed level, (F - F_true(measured speed)) / sigma, dropped fwd, dropped bwd)."""
    return [(p["speed_cmd"], (p["force"] - float(TRUE.force(np.array([[p["speed"]]]))[0, 0])) / p["sigma"],
             p["dropped_fwd_s"], p["dropped_bwd_s"]) for p in doc["points"]]


@pytest.mark.numerics
def test_the_steady_state_rule_removes_the_transient_bias(closed_loop):
    """Fixed skip (the default 0.5 s): the means run over the ringing and miss the steady Eq. 15
    value at both speeds by many of their standard errors (and the notes say so). With the rule each window
    is cut where its measured speed has settled, 2-3 s after the reversal, and both points agree
    with the truth within their reported standard errors (which ignore the noise's correlation: if
    anything too small). The cut does not depend on the floor below it.

    The line between the two: an unbiased point's |z| exceeds 3.5 with probability 5e-4. Over 8
    draws of the sensor noise the fixed skip's z were 4.9-9.9 (at 0.008 rad/s 6.8 +- 0.9: 3.5 is 3.8
    of that spread below) and the rule's -1.3-1.6 (std 0.9). The bounds 4 and 3 were 3.2 and 3.3
    spreads away (5e-4 and 1e-3 per point)."""
    fixed, settled = _errors(closed_loop["fixed"]), _errors(closed_loop["settled"])
    assert [p[0] for p in fixed] == [p[0] for p in settled] == [0.005, 0.008]
    for speed, err, d_fwd, d_bwd in fixed:
        assert abs(err) > 3.5, (speed, err)
        assert d_fwd == d_bwd == 0.5  # the fixed skip, reported as such
    for speed, err, d_fwd, d_bwd in settled:
        assert abs(err) < 3.5, (speed, err)
        # the ringing outlasts a 1 s skip (cut after 1.7-2.9 s, the same for the 8 draws)
        assert min(d_fwd, d_bwd) > 1.0, (speed, d_fwd, d_bwd)
    forces = {k: [p["force"] for p in closed_loop[k]["points"]] for k in ("settled", "settled_skip1")}
    assert forces["settled"] == forces["settled_skip1"]
    assert closed_loop["settled"]["settings"]["settle"] is True and closed_loop["fixed"]["settings"]["settle"] is False
    assert not closed_loop["settled"]["notes"]
    late = [n for n in closed_loop["fixed"]["notes"] if "settles" in n and "likely biased" in n]
    assert len(late) == 2 and all("forward" in n and "backward" in n for n in late), closed_loop["fixed"]["notes"]
