"""Identical chains found in the description and ``identification.structure = "auto"`` (issue 34, item 1).

The robot: the 6-UPS Stewart platform of tests/test_ball_joints.py written with every leg in its
own frame (its z axis along the leg, the universal joint's hinges about its x and y, the slide
along z), so that the six legs are identical chains in their own frames. Checks:

* detection finds the six legs (and nothing on the example's world-aligned legs, whose cylinders'
  inertia axes do not turn with the leg: they are not identical chains);
* the tied model's compressed factors derived from the full model's (the decision's shortcut)
  equal those compressed from the tied regressor itself;
* simulated forces (regressor times a truth, Gaussian noise): with identical legs in the truth
  the F test does not reject the tie (a 1 % false alarm for a fresh seed) and ``auto`` ties;
  with one leg 30 % heavier it rejects it by far, cross-validation prefers the full model, and
  ``auto`` keeps it;
* the pipeline: ``dynid identify`` writes the decision in summary.txt, result.json and the
  report; ``full`` and ``identical_chains`` force either.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import seed
from dynid.cli import main
from dynid.estimation import ProblemBuilder
from dynid.model.closed_loop import actuator_regressor
from dynid.model.mechanism_io import load_mechanism_mjcf
from dynid.model.reduction import detect_identical_chains
from dynid.model.system import as_system
from dynid.pipeline.structure import ALPHA, decide_structure, tied_factors
from test_ball_joints import stewart_xml


def _quat_z_to(u: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of the smallest rotation taking z to the unit vector ``u``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, u)
    s, c = np.linalg.norm(axis), float(z @ u)
    if s < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    half = np.arctan2(s, c) / 2
    return np.r_[np.cos(half), np.sin(half) * axis / s]


def _rot(qt: np.ndarray) -> np.ndarray:
    w, x, y, z = qt
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def stewart_local_xml() -> str:
    """The Stewart platform of test_ball_joints with each leg in its own frame (module docstring)."""
    rb, rp, h = 0.5, 0.3, 0.8
    ab = np.radians([-15, 15, 105, 135, 225, 255])
    ap = np.radians([-45, 45, 75, 165, 195, 285])
    B = np.c_[rb * np.cos(ab), rb * np.sin(ab), np.zeros(6)]
    c = np.array([0.0, 0.0, h])
    P = np.c_[rp * np.cos(ap), rp * np.sin(ap), np.zeros(6)]

    def v(x) -> str:
        return " ".join(f"{t:.15g}" for t in x)

    legs, closures, acts = [], [], []
    for i in range(6):
        d = c + P[i] - B[i]
        L = float(np.linalg.norm(d))
        qt = _quat_z_to(d / L)
        inner = ""
        if i == 0:  # the platform, world-aligned at c, in the frame of leg 1
            R = _rot(qt)
            inner = f"""
            <body name="platform" pos="{v(R.T @ (c - B[i]))}" quat="{v(qt * [1, -1, -1, -1])}">
              <joint name="platform_ball" type="ball" pos="{v(P[i])}"/>
              <inertial pos="0.01 -0.02 0.03" mass="3.0" fullinertia="0.08 0.09 0.15 0.004 -0.003 0.002"/>
            </body>"""
        legs.append(f"""
      <body name="leg{i + 1}_ring" pos="{v(B[i])}" quat="{v(qt)}">
        <joint name="u{i + 1}x" type="hinge" axis="1 0 0"/>
        <inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>
        <body name="leg{i + 1}_cyl">
          <joint name="u{i + 1}y" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 {0.25 * L:.15g}" mass="0.8" diaginertia="0.01 0.01 0.002"/>
          <body name="leg{i + 1}_rod">
            <joint name="s{i + 1}" type="slide" axis="0 0 1"/>
            <inertial pos="0 0 {0.75 * L:.15g}" mass="0.5" diaginertia="0.006 0.006 0.001"/>{inner}
          </body>
        </body>
      </body>""")
        if i:
            closures.append(f'    <connect name="leg{i + 1}_ball" body1="platform" body2="leg{i + 1}_rod" anchor="{v(P[i])}"/>')
        acts.append(f'    <motor name="m{i + 1}" joint="s{i + 1}"/>')
    return f"""<mujoco model="stewart_local">
  <compiler angle="radian"/>
  <worldbody>
    <body name="base">
      <inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>{''.join(legs)}
    </body>
  </worldbody>
  <equality>
{chr(10).join(closures)}
  </equality>
  <actuator>
{chr(10).join(acts)}
  </actuator>
</mujoco>
"""


LEGS = tuple((f"u{i}x", f"u{i}y", f"s{i}") for i in range(1, 7))
FS = 100.0


@pytest.fixture(scope="module")
def stewart(tmp_path_factory):
    path = tmp_path_factory.mktemp("local") / "stewart_local.xml"
    path.write_text(stewart_local_xml())
    mech = load_mechanism_mjcf(path)
    full = as_system(mech)
    tied = full.with_structure("identical_chains")
    return path, mech, full, tied, full.base_parameters(), tied.base_parameters()


def test_the_six_legs_are_found(stewart, tmp_path):
    _, mech, *_ = stewart
    assert mech.dof == 6 and mech.actuated_names == [f"s{i}" for i in range(1, 7)]
    assert detect_identical_chains(mech) == (LEGS,)  # leg 1 carries the platform: its first three joints
    # the same legs written in the world's axes (test_ball_joints, examples/own_robot/stewart): the cylinders'
    # inertia axes and the slide axes do not turn with the legs, so the legs are not identical chains
    world = tmp_path / "stewart.xml"
    world.write_text(stewart_xml())
    assert detect_identical_chains(load_mechanism_mjcf(world)) == ()
    # one leg's cylinder 1e-5 heavier (above CHAIN_TOL): that leg leaves the group
    heavy = tmp_path / "heavy.xml"
    text = stewart_local_xml()
    k = text.index('mass="0.8"', text.index("leg4_cyl"))
    heavy.write_text(text[:k] + 'mass="0.800008"' + text[k + len('mass="0.8"'):])
    assert detect_identical_chains(load_mechanism_mjcf(heavy)) == (tuple(c for c in LEGS if c[2] != "s4"),)
    # 6 significant digits (a %g export) still match: 5e-7 relative is within CHAIN_TOL
    rounded = tmp_path / "rounded.xml"
    rounded.write_text(text[:k] + 'mass="0.8000004"' + text[k + len('mass="0.8"'):])
    assert detect_identical_chains(load_mechanism_mjcf(rounded)) == (LEGS,)


def _motion(mech, rng, n: int = 1500):
    """Joint states of a smooth motion of the slides: four sines each (0.2-1.3 Hz, 8-18 mm), random phases."""
    t = np.arange(n) / FS
    f = np.array([0.2, 0.45, 0.8, 1.3])
    amp = rng.uniform(0.008, 0.018, (6, 4))
    ph = rng.uniform(0, 2 * np.pi, (6, 4))
    w = 2 * np.pi * f
    arg = w[None, None, :] * t[:, None, None] + ph[None]
    qa = mech.q_ref[list(mech.actuated)] + np.sum(amp * np.sin(arg), axis=2)
    dqa = np.sum(amp * w * np.cos(arg), axis=2)
    ddqa = -np.sum(amp * w**2 * np.sin(arg), axis=2)
    q = mech.solve_positions(qa)
    return mech.states(q, dqa, ddqa)


def _truths(mech, tied):
    """A truth with identical legs (every body 10 % heavier than the file says, the same geometry) and the
    same with leg 3's three bodies 30 % heavier still. The tied model absorbs most of that leg's excess
    (the struts turn a few degrees): what it cannot absorb is 0.03-0.04 N RMS of the struts' forces on
    these motions (seen over 6 draws), above the 0.1 N noise's reach over 9000 equations."""
    red = tied.reduction
    same = red.expand(1.1 * red.reduce(mech.nominal_parameters()))
    differ = same.copy()
    for j in ("u3x", "u3y", "s3"):
        k = mech.bodies.index(list(mech.pin_model.names).index(j))
        differ[10 * k:10 * k + 10] *= 1.3
    return same, differ


def _segments(W, tau, base, channels, k: int = 5):
    edges = np.linspace(0, W.shape[0], k + 1).astype(int)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        pb = ProblemBuilder(base.names, channels)
        pb.add(base.regressor(W[a:b]), tau[a:b])
        out.append(pb.build())
    return out


@pytest.fixture(scope="module")
def simulated(stewart):
    _, mech, full, tied, base_f, base_t = stewart
    rng = np.random.default_rng(seed(34))
    state = _motion(mech, rng)
    W = actuator_regressor(mech, state).W  # (n, 6, p) actuator forces per standard parameter
    same, differ = _truths(mech, tied)
    sigma = 0.1  # N: a force sensor's noise, about 1 % of the struts' forces here
    noise = sigma * rng.standard_normal((W.shape[0], 6))
    return W, W @ same + noise, W @ differ + noise


def test_tied_factors_from_the_full_ones_equal_the_tied_regressors(stewart, simulated):
    _, mech, full, tied, base_f, base_t = stewart
    W, y, _ = simulated
    ch = full.actuator_names
    (pf,) = _segments(W, y, base_f, ch, k=1)
    derived = tied_factors(np.asarray(pf.factors), base_f.B @ tied.reduction.T[:, base_t.independent])
    pt = ProblemBuilder(base_t.names, ch)
    pt.add(base_t.regressor(W @ tied.reduction.T), y)
    direct = pt.build().factors
    # the same Gram matrices [W y]^T [W y] per channel (triangular factors are unique up to row signs); the
    # base map is exact to rounding: relative 1e-9 leaves room for the regrouping's condition number
    for a, b in zip(derived, direct):
        ga, gb = a.T @ a, b.T @ b
        assert np.allclose(ga, gb, rtol=1e-9, atol=1e-9 * np.abs(gb).max())


@pytest.mark.numerics
def test_auto_ties_identical_legs_and_keeps_legs_that_differ(stewart, simulated):
    _, mech, full, tied, base_f, base_t = stewart
    W, y_same, y_differ = simulated
    ch = full.actuator_names
    T = tied.reduction.T
    same = decide_structure(_segments(W, y_same, base_f, ch), base_f, base_t, T, (LEGS,), "test")
    rec = same.record
    # identical legs: the tie is true, F ~ F(df1, df2); p < 1 % would be the test's 1 % false alarm
    assert rec["df"][0] == base_f.n_base - base_t.n_base > 0
    assert rec["p_value"] > ALPHA and not rec["rejected"], rec
    assert same.chosen == "identical_chains" and same.chains == (LEGS,)
    assert rec["bic"]["identical_chains"] < rec["bic"]["full"]
    differ = decide_structure(_segments(W, y_differ, base_f, ch), base_f, base_t, T, (LEGS,), "test")
    rec = differ.record
    # leg 3 30 % heavier: the tied model misses ~0.035 N RMS against the 0.1 N noise over 9000 equations, a
    # non-centrality of ~1000 for 65 degrees of freedom (F ~ 17): p < 1e-12 holds for any draw of the noise
    assert rec["p_value"] < 1e-12 and rec["rejected"], rec
    assert rec["cv"]["full"] < rec["cv"]["identical_chains"]
    assert differ.chosen == "full" and differ.chains == ()


def _log(tmp_path, mech, state, tau) -> None:
    n = tau.shape[0]
    qa = state.q[:, list(mech.actuated)]
    head = ["t"] + [f"q_s{i}" for i in range(1, 7)] + [f"tau_s{i}" for i in range(1, 7)]
    np.savetxt(tmp_path / "log.csv", np.c_[np.arange(n) / FS, qa, tau], delimiter=",", header=",".join(head), comments="")


CONFIG = """[robot]
model = "{model}"
[data]
file = "log.csv"
time = {{ column = "t", unit = "s" }}
rows = [0, 1200]
position = {{ columns = ["q_s1", "q_s2", "q_s3", "q_s4", "q_s5", "q_s6"], unit = "m" }}
effort = {{ columns = ["tau_s1", "tau_s2", "tau_s3", "tau_s4", "tau_s5", "tau_s6"], unit = "N", kind = "torque" }}
[validation]
rows = [1200, 1500]
[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
[identification]
method = "wls"
{ident}
[output]
plots = {plots}
"""


@pytest.mark.numerics
def test_identify_writes_the_decision_and_forcing_works(stewart, simulated, tmp_path, capsys):
    from dynid.config import load_config
    from dynid.pipeline.identification import identify, write_outputs

    path, mech, full, tied, base_f, base_t = stewart
    rng = np.random.default_rng(seed(35))
    state = _motion(mech, rng)
    same, _ = _truths(mech, tied)
    W = actuator_regressor(mech, state).W
    _log(tmp_path, mech, state, W @ same + 0.1 * rng.standard_normal((W.shape[0], 6)))
    # dynid info lists the legs, dynid init writes them with structure "auto"
    capsys.readouterr()
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["identical_chains"] == [[list(c) for c in LEGS]] and info["identical_chains_source"].startswith("found")
    assert main(["init", str(path), str(tmp_path / "log.csv"), "--out", str(tmp_path / "init.toml")]) == 0
    init = load_config(tmp_path / "init.toml").identification
    assert init.structure == "auto" and init.identical_chains == (LEGS,)
    (tmp_path / "auto.toml").write_text(CONFIG.format(model=path, ident="", plots="true"))
    out = identify(load_config(tmp_path / "auto.toml"))
    rec = out.structure
    # identical legs in the truth: tied (the rule keeps the tie unless the F test and the cross-validation both reject it)
    assert rec["mode"] == "auto" and rec["chosen"] == "identical_chains" and rec["chains"] == [[list(c) for c in LEGS]]
    assert out.base.n_base == base_t.n_base
    write_outputs(out, tmp_path / "auto")
    res = json.loads((tmp_path / "auto" / "result.json").read_text())
    assert {"chosen", "F", "p_value", "bic", "cv"} <= set(res["structure"])
    assert res["structure"]["cv"]["segments"] == 5 and len(res["structure"]["cv"]["per_segment"]["full"]) == 5
    assert res["prediction_inputs"]["identification"]["structure"] == "identical_chains"
    assert "Parameter structure: identical_chains (identification.structure = 'auto')" in (tmp_path / "auto" / "summary.txt").read_text()
    assert "<h2 id='structure'>Parameter structure: identical_chains" in (tmp_path / "auto" / "report.html").read_text()
    for forced, n_base in (("full", base_f.n_base), ("identical_chains", base_t.n_base)):
        (tmp_path / f"{forced}.toml").write_text(CONFIG.format(model=path, ident=f'structure = "{forced}"', plots="false"))
        out = identify(load_config(tmp_path / f"{forced}.toml"))
        assert out.structure["mode"] == "forced" and out.structure["chosen"] == forced and out.base.n_base == n_base
