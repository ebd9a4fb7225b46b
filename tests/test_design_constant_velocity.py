"""``dynid design`` with ``kind = "constant_velocity"``: paper 003's friction experiment (Sec. 3.1,
4.4) sized from ``[limits]`` (:mod:`dynid.excitation.friction_design`). The limits hold on the
sampled trajectory, dropped speeds are said, the result is reproducible bit for bit, the design
is built by ``dynid simulate``'s own generator, and the designed experiment run through ``dynid
simulate`` and ``dynid friction`` recovers the truth's friction curve."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from conftest import doc_text, seed
from dynid.cli import main
from dynid.config.design import parse_design_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError, InputError
from dynid.model.friction import SmoothStribeck
from dynid.model.loading import load_model
from dynid.pipeline.design import ConstantVelocityOutcome, run_design, write_design
from dynid.pipeline.simulate import _trajectory, run_simulation

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "friction"
ROBOT = "builtin:cobot6r"


def _toml(d: dict, indent: str = "") -> str:
    lines, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {json.dumps(v)}")
    out = "\n".join(lines) + "\n"
    for k, v in tables:
        out += f"\n[{indent}{k}]\n" + _toml(v, f"{indent}{k}.")
    return out


def _design(tmp_path: Path, design: dict, limits: dict | None = None, output: dict | None = None, model: str = ROBOT):
    doc = {"robot": {"model": model}, "design": {"kind": "constant_velocity", **design},
           "limits": {"velocity": 1.0, "acceleration": 5.0} if limits is None else limits,
           "output": {"plots": False, **(output or {})}}
    return parse_design_config(doc, tmp_path)


def test_limits_hold_on_the_sampled_trajectory(tmp_path):
    """Steady phases at the planned speed (1e-9), accelerations, velocities and positions within
    each joint's own limits, every kept speed at least `window` steady seconds with enough matched
    samples, the speeds that do not fit dropped with a line naming them."""
    vel = [1.0, 0.6, 0.9, 1.2, 1.0, 1.0]
    acc = [5.0, 2.0, 8.0, 3.0, 5.0, 5.0]
    position = {"lower": [-3.1, -1.2, -2.0, -3.1, -2.6, -3.1], "upper": [3.1, 1.0, 2.6, 3.1, 2.6, 3.1]}
    cfg = _design(tmp_path, {"joints": ["joint_2", "joint_3", "joint_4"], "n_speeds": 6, "window": 1.5,
                             "max_window": 3.0, "stroke": [1.0, 3.0, 2.0], "repetitions": 2, "skip": 0.4},
                  {"velocity": vel, "acceleration": acc, "position": position}, {"rate_hz": 400.0})
    out = run_design(cfg)
    assert isinstance(out, ConstantVelocityOutcome)
    names = write_design(out, tmp_path / "o")
    assert "trajectory.csv" in names
    tab = np.genfromtxt(tmp_path / "o" / "trajectory.csv", delimiter=",", names=True)
    lo, hi = np.array(position["lower"]), np.array(position["upper"])
    e = out.design.experiment
    for k in range(6):
        q, dq, ddq = tab[f"q_joint_{k + 1}"], tab[f"dq_joint_{k + 1}"], tab[f"ddq_joint_{k + 1}"]
        assert np.all(q >= lo[k]) and np.all(q <= hi[k])
        assert np.abs(dq).max() <= vel[k] * (1 + 1e-12)
        assert np.abs(ddq).max() <= acc[k] * (1 + 1e-9)
        if k not in (1, 2, 3):  # idle joints hold their pose
            assert np.all(q == e.pose[k]) and np.all(dq == 0)
    steady = tab["cv_direction"] != 0
    assert steady.sum() > 0
    for j in (1, 2, 3):
        on = steady & (tab["cv_joint"] == j + 1)
        err = tab[f"dq_joint_{j + 1}"][on] - tab["cv_direction"][on] * tab["cv_speed"][on]
        assert np.abs(err).max() <= 1e-9
        assert np.all(np.abs(tab[f"ddq_joint_{j + 1}"][on]) <= 1e-9)
    sched = {s.name: s for s in out.design.joints}
    # joint_2: stroke 1.0 with window 1.5 leaves speeds up to 1/1.5 = 0.667 only, and its velocity
    # limit is 0.6: the range stops there; joint_3's limit 0.9 over a stroke of 3.0 keeps all
    j2 = sched["joint_2"]
    for s in out.design.joints:
        for lv in s.levels:
            assert lv.window >= 1.5 and lv.window <= 3.0
            assert abs(lv.span - lv.speed * lv.window) <= 1e-12 * lv.span
            assert lv.span <= s.stroke * (1 + 1e-12)
            assert lv.matched >= 10 and lv.matched == pytest.approx((lv.window - 0.8) * 400, abs=2)
        for w in e.windows():
            if w["joint"] == s.index:
                assert w["end"] - w["start"] >= 1.5 - 1e-12
    assert len(j2.levels) == 6 and not j2.dropped  # all of 0.0015 .. 0.6 get >= 1.5 s over 1.0
    # a stroke that is short for the fast speeds: they are dropped, each with a line
    cfg = _design(tmp_path, {"joints": ["joint_2"], "speeds": [0.05, 0.2, 0.4, 0.6], "window": 2.0, "stroke": 0.5},
                  {"velocity": vel, "acceleration": acc, "position": position})
    out = run_design(cfg)
    kept = [lv.speed for lv in out.design.joints[0].levels]
    assert kept == [0.05, 0.2]
    assert [line.split(" dropped")[0] for line in out.design.dropped] == ["joint_2: speed 0.4", "joint_2: speed 0.6"]
    assert "dropped" in out.summary_text() and "joint_2: speed 0.6" in out.summary_text()


def test_min_span_gives_long_windows_only_at_the_slow_speeds():
    """``min_span``: each speed gets the shortest steady time covering the span, within [window,
    min(max_window, stroke / v)] (paper 003's twin: long windows where K_v is decided, 1.5 s
    elsewhere); without it every speed gets min(stroke / v, max_window)."""
    from dynid.excitation.friction_design import design_constant_velocity

    r = load_model(ROBOT)
    lo, hi = r.position_limits()
    speeds = [0.002, 0.005, 0.01, 0.02, 0.1, 0.8]
    kw = dict(joints=["joint_1"], speeds=speeds, window=1.5, max_window=6.0, skip=0.4, rate_hz=250.0)
    d = design_constant_velocity(r.joint_names, np.zeros(6), lo, hi, 1.0, 5.0, min_span=0.03, **kw)
    plain = design_constant_velocity(r.joint_names, np.zeros(6), lo, hi, 1.0, 5.0, **kw)
    s, p = d.joints[0], plain.joints[0]
    assert s.stroke == p.stroke  # the stroke is sized as before
    for lv, lp in zip(s.levels, p.levels):
        expect = min(max(1.5, 0.03 / lv.speed), 6.0, s.stroke / lv.speed)
        assert lv.window == pytest.approx(expect, rel=1e-12)
        assert lp.window == pytest.approx(min(p.stroke / lp.speed, 6.0), rel=1e-12)
    assert [lv.window for lv in s.levels][:2] == [6.0, 6.0] and s.levels[-1].window == 1.5
    assert d.duration < plain.duration  # the fast speeds no longer cross the whole stroke
    with pytest.raises(InputError, match="min_span"):
        design_constant_velocity(r.joint_names, np.zeros(6), lo, hi, 1.0, 5.0, min_span=-1.0, **kw)


def test_default_stroke_is_the_largest_that_fits():
    """The default stroke puts the fastest kept speed's cycle (switching overshoot included) at
    the position limit, and a slightly longer one would leave it."""
    from dynid.excitation.friction_design import design_constant_velocity
    from dynid.trajectories.constant_velocity import cycle_extent

    r = load_model(ROBOT)
    lo, hi = r.position_limits()
    pose = np.array([0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    d = design_constant_velocity(r.joint_names, pose, lo, hi, 1.0, 5.0, joints=["joint_2"], window=2.0, max_window=4.0)
    s = d.joints[0]
    top = s.levels[-1]
    a, b = cycle_extent(top.speed, s.stroke / top.speed, 0.1, 5.0)
    assert max(lo[1] - (pose[1] + a), pose[1] + b - hi[1]) <= 0 < max(lo[1] - (pose[1] + a * 1.001), pose[1] + b * 1.001 - hi[1])
    assert s.stroke >= top.speed * 2.0


def test_reproducible_bit_for_bit(tmp_path):
    for k in ("a", "b"):
        cfg = _design(tmp_path, {"joints": ["joint_1", "joint_5"], "n_speeds": 4, "max_window": 3.0}, output={"plots": True})
        write_design(run_design(cfg), tmp_path / k)
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert {"design.json", "trajectory.csv", "summary.txt", "speeds.png", "timing.json"} == set(files)
    for f in files:
        if f != "timing.json":
            assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_simulate_replays_the_design_with_its_own_generator(tmp_path):
    """A design whose plan is one speed list with one window (max_window = window, a stroke
    long enough) replayed by `dynid simulate` gives bit for bit the trajectory and the log of
    simulate's own `kind = "constant_velocity"` with those speeds."""
    speeds = [0.01, 0.05, 0.2, 0.6]
    cfg = _design(tmp_path, {"joints": ["joint_2", "joint_3"], "speeds": speeds, "window": 1.0, "max_window": 1.0,
                             "switch": 0.15, "rest": 0.2, "skip": 0.2},
                  {"velocity": 1.0, "acceleration": 4.0})
    write_design(run_design(cfg), tmp_path / "d")
    control = tomllib.loads((EXAMPLES / "simulate.toml").read_text())["control"]  # a stable drive PID
    common = {"robot": {"model": ROBOT}, "control": control, "sensors": {"force_noise_std": 0.05, "seed": 3},
              "simulation": {"duration": 2.0}}
    own = parse_simulate_config({**common, "trajectory": {"kind": "constant_velocity", "joints": ["joint_2", "joint_3"],
                                                          "speeds": speeds, "window": 1.0, "max_acceleration": 4.0,
                                                          "switch": 0.15, "rest": 0.2}}, tmp_path)
    replay = parse_simulate_config({**common, "trajectory": {"kind": "constant_velocity", "design": "d/design.json"}},
                                   tmp_path)
    r = load_model(ROBOT)
    a, b = _trajectory(own, r)[0], _trajectory(replay, r)[0]
    t = np.arange(int(a.duration * 250) + 5) / 250.0
    assert a.duration == b.duration
    for x, y in zip(a.sample(t), b.sample(t)):
        assert x.tobytes() == y.tobytes()
    for k, v in a.labels(t).items():
        assert v.tobytes() == b.labels(t)[k].tobytes()
    la, lb = run_simulation(own).columns, run_simulation(replay).columns
    assert list(la) == list(lb)
    for k in la:
        assert la[k].tobytes() == lb[k].tobytes(), k
    fourier = parse_simulate_config({**common, "trajectory": {"kind": "fourier", "design": "d/design.json"}}, tmp_path)
    with pytest.raises(ConfigError, match="a 'constant_velocity' design; trajectory.kind = 'fourier' replays fourier or fourier_quintic designs; "
                                          "replay it with trajectory.kind = 'constant_velocity'"):
        _trajectory(fourier, r)
    other = parse_simulate_config({**common, "robot": {"model": "builtin:puma560"},
                                   "trajectory": {"kind": "constant_velocity", "design": "d/design.json"}}, tmp_path)
    with pytest.raises(ConfigError, match="the design's position limits leave the joint limits"):
        _trajectory(other, load_model("builtin:puma560"))
    with pytest.raises(ConfigError, match=r"\['speeds'\] are set by the design file"):
        parse_simulate_config({**common, "trajectory": {"kind": "constant_velocity", "design": "d/design.json",
                                                        "speeds": [0.1]}}, tmp_path)


def _gravity_slope(joint: int, lo: float, hi: float) -> float:
    """Largest |dG_j/dq_j| [N·m/rad] along the stroke, the others at 0 (the twin's gravity torque)."""
    import pinocchio as pin

    r = load_model(ROBOT)
    m, d = r.pin_model, r.pin_model.createData()
    qs = np.linspace(lo, hi, 201)
    g = []
    for x in qs:
        q = np.zeros(m.nq)
        q[joint] = x
        g.append(pin.computeGeneralizedGravity(m, d, q)[joint])
    return float(np.abs(np.diff(g) / np.diff(qs)).max())


@pytest.mark.numerics
def test_designed_experiment_recovers_the_truths_friction(tmp_path):
    """examples/friction's truth (paper 003's improved Stribeck model, Eq. 15) and drive PID on
    joint_2 (gravity along the stroke), six designed speeds 0.02 .. 0.8 rad/s: dynid design ->
    dynid simulate -> dynid friction. Every friction point lies on the truth's curve within 4.5 of
    its standard errors (its sigma, spread / sqrt(n), is up to 10 % small: / 0.9; 7e-6 per point)
    plus the zero-order-hold bias (each torque is held one control period while gravity changes by
    up to v dt max|dG/dq|), and the extraction pairs the samples the design counted (same skip,
    same rate)."""
    sim = tomllib.loads((EXAMPLES / "simulate.toml").read_text())
    fr = tomllib.loads((EXAMPLES / "friction.toml").read_text())
    skip, rate = fr["friction"]["skip"], sim["control"]["rate_hz"]
    (tmp_path / "d.toml").write_text(_toml({
        "robot": {"model": ROBOT},
        "design": {"kind": "constant_velocity", "joints": ["joint_2"], "speed_range": [0.02, 0.8], "n_speeds": 6,
                   "window": 1.5, "max_window": 3.0, "skip": skip},
        "limits": {"velocity": 1.0, "acceleration": 5.0}, "output": {"rate_hz": rate, "plots": False}}))
    sim["trajectory"] = {"kind": "constant_velocity", "design": "design/design.json"}
    sim["sensors"]["seed"] = seed(sim["sensors"]["seed"])
    (tmp_path / "s.toml").write_text(_toml(sim))
    fr["data"]["file"] = "sim/log.csv"
    fr["friction"]["held_out"] = "none"
    fr["friction"]["models"] = ["coulomb_viscous"]
    fr["output"] = {"plots": False}
    (tmp_path / "f.toml").write_text(_toml(fr))
    for cmd, cfg, out in (("design", "d.toml", "design"), ("simulate", "s.toml", "sim"), ("friction", "f.toml", "fr")):
        assert main([cmd, str(tmp_path / cfg), "--out", str(tmp_path / out), "-q"]) == 0
    design = json.loads((tmp_path / "design" / "design.json").read_text())
    levels = design["joints"][0]["speeds"]
    pts = np.genfromtxt(tmp_path / "fr" / "points.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert len(pts) == len(levels) == 6
    f = sim["robot"]["friction"]
    truth = SmoothStribeck(fc=f["fc"][1], fs=f["fs"][1], fv=f["fv"][1], vs=f["vs"][1], kv=f["kv"][1], alpha=f["alpha"][1])
    slope = _gravity_slope(1, -design["joints"][0]["stroke"] / 2, design["joints"][0]["stroke"] / 2)
    for p, lv in zip(pts, levels):
        assert p["speed_cmd"] == pytest.approx(lv["speed"], rel=1e-12)
        expect = truth.force(np.array([[p["speed"]]]))[0, 0]
        assert abs(p["force"] - expect) <= 4.5 * p["sigma"] / 0.9 + p["speed"] * slope / rate, (p, expect)
        assert abs(p["n_samples"] - lv["matched"]) <= 2
    # the positions carry no noise here: the measured speed is the commanded one to the loop's steady error (~1e-4)
    assert abs(pts["speed"] / pts["speed_cmd"] - 1).max() < 1e-3


@pytest.mark.parametrize("design, limits, model, message", [
    ({"window": 2.0, "windw": 1.0}, None, ROBOT, "unknown key design.windw"),
    ({"harmonics": 3}, None, ROBOT, "design: keys ['harmonics'] do not apply to kind 'constant_velocity'"),
    ({"speeds": [0.1, 1.5]}, None, ROBOT, "speed 1.5 is above the velocity limit 1 of joint_1"),
    ({"speed_range": [0.01, 2.0]}, None, ROBOT, "speed_range reaches 2, above the velocity limit of joint_1"),
    ({"joints": []}, None, ROBOT, "design.joints: empty list; name the joints"),
    ({"joints": ["joint_9"]}, None, ROBOT, "joints ['joint_9'] are not joints of the robot"),
    ({}, None, "builtin:shang2dof", "design.kind = 'constant_velocity' is for serial robots"),
    ({}, {"acceleration": 5.0}, ROBOT, "needs limits.velocity"),
    ({}, {"velocity": 1.0, "acceleration": 5.0, "force": 10.0}, ROBOT, "limits: ['force'] are not checked"),
    ({"window": 0.8, "skip": 0.4}, None, ROBOT, "window = 0.8 s leaves about 0 matched samples"),
    ({"joints": ["joint_2"], "stroke": 3.5}, None, ROBOT, "stroke 3.5 of joint_2 exceeds 3.2"),
    ({"max_window": 1.0}, None, ROBOT, "max_window = 1 s is shorter than window = 2 s"),
    ({"min_span": 0.0}, None, ROBOT, "design.min_span"),
    ({"speeds": [0.1], "n_speeds": 4}, None, ROBOT, "give speeds or speed_range / n_speeds, not both"),
])
def test_bad_input_is_one_line(tmp_path, capsys, design, limits, model, message):
    doc = {"robot": {"model": model}, "design": {"kind": "constant_velocity", **design},
           "limits": {"velocity": 1.0, "acceleration": 5.0} if limits is None else limits}
    (tmp_path / "c.toml").write_text(_toml(doc))
    assert main(["design", str(tmp_path / "c.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dynid: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert message in err, err
    assert not (tmp_path / "o").exists()


def test_no_speed_fits_is_an_error(tmp_path):
    cfg = _design(tmp_path, {"joints": ["joint_2"], "speeds": [0.8, 0.9], "window": 2.0},
                  {"velocity": 1.0, "acceleration": 5.0, "position": {"lower": [-3, -0.5, -2, -3, -2, -3],
                                                                        "upper": [3, 0.5, 2, 3, 2, 3]}})
    with pytest.raises(ConfigError, match="joint_2: no speed gets 2 s of steady motion"):
        run_design(cfg)


def test_readme_block_and_example_design():
    """The guide's constant_velocity block (docs/guide/excitation.md) and examples/friction/design.toml
    run (no files written), and the example's simulate config replays a design.json."""
    import re

    from dynid.config.design import load_design_config
    from dynid.config.simulate import load_simulate_config

    page = doc_text("excitation")  # the guide's page "Excitation design"
    text = page.split('\n## Friction experiments: `kind = "constant_velocity"`', 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    out = run_design(parse_design_config(tomllib.loads(block), EXAMPLES))
    assert len(out.design.joints) == 6 and all(len(j.levels) + len(j.dropped) == 16 for j in out.design.joints)
    ex = run_design(load_design_config(EXAMPLES / "design.toml"))
    assert [lv.speed for lv in ex.design.joints[1].levels] == list(tomllib.loads(
        (EXAMPLES / "design.toml").read_text())["design"]["speeds"])
    assert load_simulate_config(EXAMPLES / "simulate_design.toml").trajectory.values["design"].endswith("design.json")


def test_quiet_cli_still_says_what_it_dropped(tmp_path, capsys):
    doc = {"robot": {"model": ROBOT}, "design": {"kind": "constant_velocity", "joints": ["joint_2"],
                                                 "speeds": [0.1, 0.5, 0.9], "stroke": 1.0},
           "limits": {"velocity": 1.0, "acceleration": 5.0}, "output": {"plots": False}}
    (tmp_path / "c.toml").write_text(_toml(doc))
    assert main(["design", str(tmp_path / "c.toml"), "--out", str(tmp_path / "o"), "-q"]) == 0
    out = capsys.readouterr().out
    assert "joint_2: speed 0.9 dropped: the stroke 1 takes 1.11 s at it, less than window = 2 s" in out
    kept = json.loads((tmp_path / "o" / "design.json").read_text())["joints"][0]["speeds"]
    assert [lv["speed"] for lv in kept] == [0.1, 0.5]  # 0.5 over 1.0 is exactly the 2 s window
