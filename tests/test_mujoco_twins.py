"""dynid against an independent engine (issue 34, item 6): MuJoCo twins of a Stewart platform
with a ball joint and a redundantly actuated planar robot (examples/mujoco_twins,
:mod:`dynid.studies.twin_robots`, :mod:`dynid.studies.mujoco_twin`).

* the engines agree: MuJoCo's inverse dynamics projected to the actuators on its own closure
  Jacobians == dynid's closed-chain inverse dynamics from the actuator data alone;
* the files are what their builder writes, and each prior is 15 % off as documented;
* MuJoCo's logs are what ``dynid init`` reads (every column matched by name, the rate found);
* ``dynid init PRIOR TRAIN`` (+ the validation log) then ``dynid identify``, nothing edited, on
  5 s logs: completes and reports per-channel held-out figures; item 6's thresholds (identified
  within 1.25x the true-parameter error and at least 2x below the prior's, every channel) are
  asserted where they hold on this dynid, and marked as the open part of issue 34 item 6 where
  they do not yet (bench/newcomer_twins.py prints the full-size figures, bench/README.md).
"""

from __future__ import annotations

import argparse
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, seed

pytest.importorskip("mujoco", reason="the MuJoCo twins need mujoco (the test extra)")

from dynid.cli import build_parser, main  # noqa: E402
from dynid.studies import mujoco_twin as mt  # noqa: E402
from dynid.studies import twin_robots as tr  # noqa: E402

TWINS = REPO / "examples" / "mujoco_twins"
ROBOTS = ("stewart", "planar")
QUICK_S = 10.0  # seconds per log (bench/newcomer_twins.py --quick)


@pytest.mark.numerics
@pytest.mark.parametrize("kind", ROBOTS)
def test_engines_agree_on_closed_chain_inverse_dynamics(kind):
    r = mt.inverse_dynamics_check(TWINS / f"{kind}.xml", n=6, seed=seed(5))
    # both routes are exact up to the assembly (Gauss-Newton to 1e-13 m) and MuJoCo's drift term
    # J'(q) qdot, taken by a central difference of step 1e-6: rounding eps/h ~ 1e-10 of it (seen:
    # 1e-10 Stewart, 7e-12 planar); 1e-7 of the RMS force leaves a factor 1000, and a wrong
    # inertia, axis or projection shows at 1e-3 and above
    err = np.abs(r["mujoco"] - r["dynid"]).max(axis=0) / r["scale"]
    assert np.all(err < 1e-7), err
    assert np.all(r["scale"] > 0.1)  # forces of a moving robot, not zeros agreeing


@pytest.mark.parametrize("kind", ROBOTS)
def test_files_are_the_builders_and_the_prior_is_15_percent_off(kind):
    truth = (TWINS / f"{kind}.xml").read_text()
    prior = (TWINS / f"{kind}_prior.xml").read_text()
    assert truth == (tr.stewart_mjcf() if kind == "stewart" else tr.planar_mjcf())
    assert prior == tr.prior_mjcf(truth)
    a, b = tr.inertial_data(truth), tr.inertial_data(prior)
    assert list(a) == list(b) and len(a) == (19 if kind == "stewart" else 6)
    part = tr.parts(truth)
    signs = tr.prior_signs(max(part) + 1)[part]
    f = tr.PRIOR_FRACTION
    # written with 12 significant digits: 1e-9 relative
    for (name, (m, c, I)), (m2, c2, I2), s in zip(a.items(), b.values(), signs):
        assert m2 / m == pytest.approx(1 + f * s[0], rel=1e-9), name
        S = 0.5 * np.trace(I) * np.eye(3) - I  # second moments about the COM, in its principal axes
        lam, V = np.linalg.eigh(S)
        S2 = V.T @ (0.5 * np.trace(I2) * np.eye(3) - I2) @ V
        np.testing.assert_allclose(np.diag(S2), lam * (1 + f * s[1:4]), rtol=1e-8, atol=1e-12 * lam.max())
        np.testing.assert_allclose(S2 - np.diag(np.diag(S2)), 0.0, atol=1e-9 * lam.max())
        k = math.sqrt(np.trace(S) / m)
        np.testing.assert_allclose(c2 - c, f * k * s[4:7], rtol=1e-8, atol=1e-12)
    # the rest of the file is the robot's: joints, closures, actuators
    strip = lambda t: [(e.tag, {k: v for k, v in e.attrib.items() if k != "model"})  # noqa: E731
                       for e in ET.fromstring(t).iter() if e.tag not in ("inertial",) and isinstance(e.tag, str)]
    assert strip(truth) == strip(prior)


def test_stewart_legs_are_one_part():
    """The six legs are identical in their own frames (a structure that ties them can find them),
    so the prior moves all six the same way."""
    part = tr.parts(tr.stewart_mjcf())
    assert len(set(part)) == 4  # ring, cylinder, rod, platform
    R = tr.stewart_leg_frames()
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), (6, 3, 3)), atol=1e-12)


@pytest.mark.parametrize("kind", ROBOTS)
def test_mujoco_log_is_what_init_reads(kind, tmp_path):
    from dynid.pipeline.starter import starting_config

    log = mt.simulate(TWINS / f"{kind}.xml", TWINS / f"{kind}_prior.xml", 0.5, 0.2, seed(3))
    # MuJoCo's stiff closures (solref 0.5 ms, impedance 0.9999) keep the loops closed to well
    # below the encoders' resolution (1 um; seen 1e-9 m)
    assert log.closure_residual < 1e-6
    path = mt.write_log(log, tmp_path / "log.csv")
    cfg = starting_config(str(TWINS / f"{kind}_prior.xml"), path, tmp_path / "identify.toml")
    assert cfg.sample_rate_hz == pytest.approx(1000.0)
    assert [m.how for m in cfg.position + cfg.effort] == ["name"] * (2 * len(log.names))
    assert [m.column for m in cfg.position] == [f"q_{n}" for n in log.names]
    assert [m.column for m in cfg.effort] == [f"tau_{n}" for n in log.names]


def _init_has_validation() -> bool:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return any("--validation" in a.option_strings for a in sub.choices["init"]._actions)


@pytest.fixture(scope="module")
def newcomer(tmp_path_factory):
    """Per robot: the figures of ``dynid init PRIOR TRAIN`` (+ validation) and ``dynid identify``
    on 5 s MuJoCo logs, and the true-parameter error on the same rows."""
    out = {}
    for kind in ROBOTS:
        folder = tmp_path_factory.mktemp(kind)
        truth, prior = TWINS / f"{kind}.xml", TWINS / f"{kind}_prior.xml"
        for name, (f0, s) in (("train", (0.2, 1)), ("valid", (0.27, 2))):
            mt.write_log(mt.simulate(truth, prior, QUICK_S, f0, seed(s)), folder / f"{name}.csv")
        train, valid, cfg = (str(folder / n) for n in ("train.csv", "valid.csv", "cfg.toml"))
        # the CLI in this process: this checkout's dynid (a `dynid` process started in a temporary
        # folder may import another one)
        if _init_has_validation():
            assert main(["init", str(prior), train, "--validation", valid, "--out", cfg]) == 0
        else:  # this dynid's init has no --validation yet: the harness writes it as the flag would
            assert main(["init", str(prior), train, "--out", cfg]) == 0
            mt.validation_into_config(cfg, valid)
        assert main(["identify", cfg, "--out", str(folder / "out"), "-q"]) == 0
        res = json.loads((folder / "out" / "result.json").read_text())
        ref = mt.held_out_errors(folder / "cfg.toml", robot=truth)
        out[kind] = {"result": res, "reference": ref, "config": (folder / "cfg.toml").read_text()}
    return out


@pytest.mark.numerics
@pytest.mark.parametrize("kind", ROBOTS)
def test_init_then_identify_on_mujoco_logs_reports_every_channel(newcomer, kind):
    run = newcomer[kind]
    res, ref = run["result"], run["reference"]
    v, nom = res["validation"], res["nominal_validation"]
    n_ch = 6 if kind == "stewart" else 2  # the redundant robot: its projected equations, one per DOF
    assert len(v["joints"]) == n_ch == len(v["rel_rmse_pct_per_joint"]) == len(nom["rel_rmse_pct_per_joint"])
    assert 'file = "valid.csv"' in run["config"]  # held out: another run, not rows of the training log
    ident = np.array(v["rel_rmse_pct_per_joint"])
    assert np.all(np.isfinite(ident)) and np.all(ident > 0)
    # WLS does not use the nominal model: the run on the true file identifies the same model
    np.testing.assert_allclose(ref["identified"], ident, rtol=1e-6)
    true, prior = np.array(ref["nominal"]), np.array(nom["rel_rmse_pct_per_joint"])
    # the true parameters predict to the noise (1-2 % of the RMS forces, seen 0.3-1.7 %) and the
    # model-class error; the prior, 15 % off, worse on every channel (seen 2.3x to 40x): the data
    # tell the two apart
    assert np.all(true < 5.0), true
    assert np.all(prior > 1.5 * true), (prior, true)


# Issue 34 item 6's thresholds (1.25x the true-parameter error, 2x below the prior's, every channel)
# are measured by bench/newcomer_twins.py at full size, not asserted here: they do not hold yet on
# every channel (bench/README.md); a test that could not fail would hide that.
