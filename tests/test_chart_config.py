"""Independent coordinates and actuated joints from the configs and the CLI (issue 18, items 2 and 7).

A redundantly actuated robot written outside the project (the five-bar of the built-ins with a
third motor on a passive joint, in MJCF) has 3 actuators for 2 degrees of freedom: its default
chart (the actuated joints) has the wrong size. The error must list valid choices; naming one in
``[robot] independent`` (or ``dynid info --independent``) must make every command work, and the
simulated robot must be identified from its configs alone.
"""

from __future__ import annotations

import json
import re
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from conftest import seed
from dynid.cli import main
from dynid.config import load_config, parse_config
from dynid.config.montecarlo import parse_montecarlo_config
from dynid.errors import ConfigError, ModelError
from dynid.model.loading import load_model
from dynid.pipeline.identification import identify

FIVEBAR = Path(str(resources.files("dynid.model.robots") / "fivebar.xml"))


EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "own_robot" / "planar3"


@pytest.fixture(scope="module")
def fivebar3(tmp_path_factory) -> Path:
    """The walk-through's redundant planar robot (examples/own_robot/planar3/planar3.xml): the
    built-in five-bar with a third motor on the elbow qb1."""
    d = tmp_path_factory.mktemp("fivebar3")
    text = (EXAMPLE / "planar3.xml").read_text()
    assert text.replace('<mujoco model="planar3">', '<mujoco model="fivebar">').count('<motor ') == 3
    assert 'joint="qb1"' in text and FIVEBAR.is_file()
    path = d / "fivebar3.xml"
    path.write_text(text)
    return path


def _listed(msg: str) -> list[list[str]]:
    """The joint-name lists after "e.g." in a chart error."""
    return [re.findall(r"'([^']+)'", group) for group in re.findall(r"\[([^\]]*)\]", msg.split("e.g. ")[1])]


def _chart_is_valid(mech, names) -> bool:
    try:
        mech.with_chart(independent=names)
        return True
    except ModelError:
        return False


def test_a_redundant_robot_gets_the_best_conditioned_chart_of_its_actuators(fivebar3):
    """No chart given: the subset of the actuated joints whose velocity map is best conditioned over a
    sample of the workspace (issue 34, item 3), recorded; its condition number at the reference
    configuration checked against the mechanism's own velocity map (the [J_c; J_u] solve of states)."""
    mech = load_model(str(fivebar3))
    assert mech.redundant and mech.dof == 2 and mech.independent.size == 2
    assert set(mech.independent.joints) <= set(mech.actuated)
    assert mech.independent_choice.startswith("chosen automatically among the actuated joints")
    ranked = mech.rank_charts(mech.q_ref)
    zero = np.zeros((1, 2))
    for combo, cond in ranked:  # at one configuration the worst case is that configuration's condition number
        G = mech.with_chart(independent=[mech.pin_model.names[j + 1] for j in combo]).states(mech.q_ref[None], zero, zero).G[0]
        assert cond == pytest.approx(np.linalg.cond(G), rel=1e-9)  # an orthonormal change of basis: equal up to rounding
    workspace = mech.rank_charts(mech._workspace_samples(mech.q_ref, mech._constraint_jacobian(
        mech.q_ref, mech.pin_model.createData())[mech.constraint_rows], mech.pin_model.createData()))
    assert tuple(mech.independent.joints) == workspace[0][0] and workspace[0][1] < workspace[1][1]
    # given by hand, the chart stays as given
    assert load_model(str(fivebar3), independent=["qa1", "qa2"]).independent_choice == ""


def test_a_chart_of_the_wrong_size_lists_valid_choices_that_load(fivebar3):
    with pytest.raises(ModelError) as err:
        load_model(str(fivebar3), independent=["qa1", "qa2", "qb1"])
    msg = str(err.value)
    assert "\n" not in msg and "mobility 2" in msg and "3 independent coordinates were given" in msg
    choices = _listed(msg)
    assert choices and all(len(c) == 2 for c in choices)
    for names in choices:  # every listed choice is a chart: the mechanism loads with it
        mech = load_model(str(fivebar3), independent=names)
        assert mech.redundant and mech.dof == 2 and mech.actuated_names == ["qa1", "qa2", "qb1"]


def test_a_singular_chart_is_refused_with_valid_choices():
    hexapod = load_model("builtin:hexapod")
    wrong = list(hexapod.joint_names[:6])  # the cardan angles and slider of two legs: not a chart
    with pytest.raises(ModelError) as err:
        hexapod.with_chart(independent=wrong)
    msg = str(err.value)
    assert "do not determine the motion" in msg and str(wrong) in msg
    (suggestion,) = _listed(msg)
    assert _chart_is_valid(hexapod, suggestion)
    # the independent route: the Jacobian of the suggested chart stacked on the closures is regular
    assert suggestion == hexapod.actuated_names


def test_unknown_or_repeated_joint_names_are_refused(fivebar3):
    with pytest.raises(ModelError, match=r"independent coordinates \['zz'\] are not joints of the model; joints: "):
        load_model(str(fivebar3), independent=["qa1", "zz"])
    shang = load_model("builtin:shang2dof")
    with pytest.raises(ModelError, match="name a joint twice"):
        shang.with_chart(independent=["qa1", "qa1"])
    with pytest.raises(ModelError, match="serial robot"):
        load_model("builtin:puma560", independent=["j1"])


def test_dynid_info_takes_the_chart(fivebar3, capsys):
    assert main(["info", str(fivebar3), "--json"]) == 0  # the redundant file as it is: the chart chosen and named
    info = json.loads(capsys.readouterr().out)
    chosen = [load_model(str(fivebar3)).pin_model.names[j + 1] for j in load_model(str(fivebar3)).independent.joints]
    assert info["independent_coordinates"] == chosen and info["independent_choice"].startswith("chosen automatically")
    assert main(["info", str(fivebar3), "--independent", "qa1,qa2,qb1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dynid: error: ") and err.count("\n") == 1 and "--independent" in err
    assert main(["info", str(fivebar3), "--independent", "qa1,qa2", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_actuators"] == 3 and info["dof"] == 2
    assert main(["info", str(fivebar3), "--independent", ","]) == 2
    assert "--independent: no joint names" in capsys.readouterr().err


ROBOT = '[robot]\nmodel = "{model}"\nindependent = ["qa1", "qa2"]\n'


def test_robot_chart_keys_parse_and_refuse_bad_values(fivebar3):
    doc = tomllib.loads(ROBOT.format(model=fivebar3) + '[data]\nfile = "x.csv"\nsample_rate_hz = 100.0\nrows = [1, 10]\nposition = { columns = ["a"] }\n'
                        'effort = { columns = ["b"] }\n[validation]\nrows = [0, 1]\n')
    cfg = parse_config(doc, fivebar3.parent)
    assert cfg.robot.independent == ("qa1", "qa2") and cfg.robot.actuated is None
    for value, match in (([], "empty list"), (["qa1", "qa1"], "names a joint twice"), ([1, 2], r"robot.independent\[0\]")):
        bad = dict(doc, robot={"model": str(fivebar3), "independent": value})
        with pytest.raises(ConfigError, match=match):
            parse_config(bad, fivebar3.parent)


def _example_body(name: str) -> str:
    """The walk-through's config ``name`` without its comment and [robot] table (the tests put the
    robot file of their own folder there)."""
    text = (EXAMPLE / name).read_text()
    robot = ROBOT.format(model="planar3.xml")
    assert robot in text
    return text.split(robot, 1)[1]


SIMULATE = _example_body("simulate.toml")
VALIDATE = _example_body("validate.toml")

IDENTIFY = _example_body("identify.toml").replace("{", "{{").replace("}", "}}") + "\n[output]\nplots = false\n"


@pytest.mark.numerics
def test_a_redundant_robot_from_its_own_files_is_simulated_and_identified_from_configs(fivebar3, capsys):
    """The walk-through as shipped: its seeds stay the example's (not conftest.seed), as
    docs/guide/parallel-robots.md records its figures (2.6 % against 33.7 %, 0 of 19 outside): those
    are this draw's."""
    d = fivebar3.parent
    (d / "sim.toml").write_text(ROBOT.format(model=fivebar3.name) + SIMULATE)
    assert main(["simulate", str(d / "sim.toml"), "--out", str(d / "sim")]) == 0
    (d / "val.toml").write_text(ROBOT.format(model=fivebar3.name) + VALIDATE)  # the held-out motion
    assert main(["simulate", str(d / "val.toml"), "--out", str(d / "val")]) == 0
    assert json.loads((d / "val" / "truth.json").read_text())["true_parameters"] == \
        json.loads((d / "sim" / "truth.json").read_text())["true_parameters"]  # the same (perturbed) robot
    header = (d / "sim" / "log.csv").read_text().splitlines()[0].split(",")
    assert {"q_qa1", "q_qa2", "q_qb1", "tau_qb1"} <= set(header)
    (d / "id.toml").write_text(ROBOT.format(model=fivebar3.name) + IDENTIFY.format())
    assert main(["identify", str(d / "id.toml"), "--out", str(d / "id")]) == 0
    res = json.loads((d / "id" / "result.json").read_text())
    assert "redundant actuation" in json.dumps(res)
    assert [c["name"] for c in res["channels"]] == ["u_qa1", "u_qa2"]  # projected on the chart's coordinates
    assert res["validation_other_view"]["identified"]["joints"] == ["qa1", "qa2", "qb1"]  # item 5
    assert "minimum-norm" in res["validation_other_view"]["label"]
    # the file's model is 15 % off the simulated robot: on another motion the identified model
    # predicts the forces better than that nominal model, on every channel (2.6 % against 34 %)
    prior = res["prior_comparison"]
    assert prior["comparable"] and prior["beats_nominal"] and all(prior["better_per_channel"])
    assert prior["identified_mean_rel_rmse_pct"] < 0.5 * prior["nominal_mean_rel_rmse_pct"]
    # the simulated truth (the perturbed model) inside the intervals: 19 base parameters, at most 3
    # outside their 95 % intervals (binomial: P(more) < 2 %), none beyond 4.5 std
    outcome = identify(load_config(d / "id.toml"))
    truth = json.loads((d / "sim" / "truth.json").read_text())
    z = (outcome.result.params - outcome.base.from_standard(np.asarray(truth["true_parameters"]))) / outcome.result.bse
    assert outcome.system.model.independent.joints == (0, 2)  # qa1, qa2 (velocity indices)
    assert int(np.sum(np.abs(z) > 1.96)) <= 3 and np.abs(z).max() < 4.5, np.round(z, 2)
    # round trip (item 4): the physically consistent fit exports model.mjcf, which carries the chart
    (d / "lmi.toml").write_text((d / "id.toml").read_text().replace('method = "wls"', 'method = "wls"\nphysical_consistency = true'))
    assert main(["identify", str(d / "lmi.toml"), "--out", str(d / "lmi")]) == 0
    exported = d / "lmi" / "model.mjcf"
    assert exported.is_file()
    capsys.readouterr()
    assert main(["info", str(exported), "--json"]) == 0  # no --independent: the file says it
    info = json.loads(capsys.readouterr().out)
    assert info["n_actuators"] == 3 and info["dof"] == 2
    again = IDENTIFY.format().replace('file = "sim/log.csv"', f'file = "{d / "sim" / "log.csv"}"') \
        .replace('file = "val/log.csv"', f'file = "{d / "val" / "log.csv"}"')
    (d / "again.toml").write_text(f'[robot]\nmodel = "{exported}"\n' + again)
    assert main(["identify", str(d / "again.toml"), "--out", str(d / "again")]) == 0
    capsys.readouterr()


@pytest.mark.numerics
def test_a_redundant_robot_is_initialised_and_identified_without_a_hand_chart(fivebar3, tmp_path, capsys):
    """Issue 34, item 3: the walk-through's simulations and configs with no [robot] independent at all.
    ``dynid init`` names the automatic chart (chosen over the workspace); identify chooses it again over
    the training log, says so, projects on it, and beats the file's model on the held-out motion."""
    d = tmp_path
    (d / "fivebar3.xml").write_text(fivebar3.read_text())
    robot = '[robot]\nmodel = "fivebar3.xml"\n'
    (d / "sim.toml").write_text(robot + SIMULATE)  # the example's seeds (its figures are this draw's)
    assert main(["simulate", str(d / "sim.toml"), "--out", str(d / "sim"), "-q"]) == 0
    (d / "val.toml").write_text(robot + VALIDATE)
    assert main(["simulate", str(d / "val.toml"), "--out", str(d / "val"), "-q"]) == 0
    mech = load_model(str(d / "fivebar3.xml"))
    chart = [mech.pin_model.names[j + 1] for j in mech.independent.joints]
    assert main(["init", str(d / "fivebar3.xml"), str(d / "sim" / "log.csv"), "--out", str(d / "init.toml")]) == 0
    text = (d / "init.toml").read_text()
    assert f"# independent = [{', '.join(json.dumps(c) for c in chart)}]   # chosen automatically" in text
    assert 'structure = "auto"' in text
    (d / "id.toml").write_text(robot + IDENTIFY.format())
    capsys.readouterr()
    assert main(["identify", str(d / "id.toml"), "--out", str(d / "id"), "-q"]) == 0
    res = json.loads((d / "id" / "result.json").read_text())
    note = next(n for n in res["notes"] if n.startswith("independent coordinates"))
    assert "over 200 samples of the training log" in note and "[robot] independent overrides" in note
    used = note.split(":")[0].removeprefix("independent coordinates ").split(", ")
    assert [c["name"] for c in res["channels"]] == [f"u_{j}" for j in used]  # projected on the chosen chart
    assert res["prediction_inputs"]["robot"]["independent"] == used  # predict rebuilds the same chart
    assert res["structure"]["chosen"] == "full"  # the five-bar's two arms differ: nothing to tie
    prior = res["prior_comparison"]
    assert prior["beats_nominal"] and prior["identified_mean_rel_rmse_pct"] < 0.5 * prior["nominal_mean_rel_rmse_pct"]


def test_montecarlo_passes_the_simulated_chart_to_identify(fivebar3):
    doc = tomllib.loads(f"[simulate]\n{ROBOT.format(model=fivebar3.name).replace('[robot]', '[simulate.robot]')}"
                        + SIMULATE.replace("[trajectory]", "[simulate.trajectory]").replace("[control]", "[simulate.control]")
                        .replace("[sensors]", "[simulate.sensors]"))
    cfg = parse_montecarlo_config(doc, fivebar3.parent)
    icfg = cfg.identify_config(fivebar3.parent / "log.npz", ["qa1", "qa2", "qb1"], "torque", 1000)
    assert icfg.robot.independent == ("qa1", "qa2")
    assert np.all(np.array(icfg.robot.independent) == np.array(cfg.simulate.robot.independent))
    # every trial identifies one model: structure "full" unless named, "auto" refused (it could choose per trial)
    assert icfg.identification.structure == "full"
    doc["identify"] = {"identification": {"structure": "auto"}}
    with pytest.raises(ConfigError, match="structure = 'auto' is not available in dynid montecarlo"):
        parse_montecarlo_config(doc, fivebar3.parent)


NOISE = 0.01  # N*m, the simulated force noise per actuator (SIMULATE)


def _nominal_actuator_rmse(folder: Path, fivebar3: Path, distribution: str) -> np.ndarray:
    import shutil

    folder.mkdir()
    shutil.copy(fivebar3, folder / fivebar3.name)
    for name, text in (("sim", SIMULATE), ("val", VALIDATE)):  # the truth is the nominal model here (no perturbation)
        text = re.sub(r"perturbation(_seed)? = \S+\n", "", text).replace("kd = 40", f'kd = 40\ndistribution = "{distribution}"')
        text = re.sub(r"(?m)^seed = (\d+)$", lambda m: f"seed = {seed(int(m.group(1)))}", text)  # the motions' and noise's
        assert "perturbation" not in text and "distribution" in text
        (folder / f"{name}.toml").write_text(ROBOT.format(model=fivebar3.name) + text)
        assert main(["simulate", str(folder / f"{name}.toml"), "--out", str(folder / name), "-q"]) == 0
    (folder / "id.toml").write_text(ROBOT.format(model=fivebar3.name) + IDENTIFY.format())
    out = identify(load_config(folder / "id.toml"))
    view = out.other_view
    assert view is not None and "minimum-norm" in view.label
    assert list(view.metrics.channel_names) == ["qa1", "qa2", "qb1"]
    return np.asarray(view.nominal.rmse)


@pytest.mark.numerics
def test_per_actuator_errors_of_a_redundant_robot_under_the_min_norm_assumption(fivebar3, tmp_path):
    """Issue 18 item 5: the projected identification also reports per-actuator errors under the
    minimum-norm distribution. When the controller shares the forces that way, the true model
    (the nominal one here) predicts each actuator to about the force noise (plus the processing
    error at reversals, which the held-out score keeps); when it does not (the simulator's
    default keeps each actuator's own friction local), the same motion's view is several times
    worse: the assumption, not the model, is then wrong, and the label says it is one."""
    matched = _nominal_actuator_rmse(tmp_path / "min_norm", fivebar3, "min_norm")
    other = _nominal_actuator_rmse(tmp_path / "local", fivebar3, "min_norm_local_friction")
    # the noise and the processing error at the motion's reversals (in quadrature: up to twice the noise
    # on one actuator): 1.1-2.3 times the noise over 5 draws of the motions (2.5 held to 1.1x on one)
    assert np.all(matched < 3 * NOISE), matched
    # the wrong assumption, actuator by actuator: 3.6-4.4 times the matched error on its worst actuator over
    # 5 draws (the largest of one against the largest of the other, 2x, fell to 1.8 on one draw, when the
    # processing error and the assumption's hit different actuators)
    assert np.max(other / matched) > 2, (other, matched)


def test_the_other_view_is_the_minimum_norm_distribution_and_projects_back():
    from dynid.pipeline.identification import _other_view

    rng = np.random.default_rng(3)
    Ga = rng.standard_normal((50, 3, 2))
    y = rng.standard_normal((50, 2))
    tau = rng.standard_normal((50, 3))
    measured, shared, _ = _other_view(Ga, tau, y, None, "projected")
    assert measured is tau
    np.testing.assert_allclose(np.einsum("nau,na->nu", Ga, shared), y, atol=1e-12)  # G_a^T tau_a = y
    for i in range(50):  # minimum norm: no component in the null space of G_a^T
        null = np.linalg.svd(Ga[i].T)[2][-1]
        assert abs(null @ shared[i]) < 1e-12
    # the other way: actuator forces -> projected equations
    proj_meas, proj_pred, _ = _other_view(Ga, tau, shared, None, "min_norm")
    np.testing.assert_allclose(proj_pred, y, atol=1e-12)
    np.testing.assert_allclose(proj_meas, np.einsum("nau,na->nu", Ga, tau), atol=1e-14)


DESIGN = """
[design]
harmonics = 2
base_frequency_hz = 0.5
samples = 16
starts = 1
max_iter = 5
seed = 1

[limits]
velocity = 1.0
acceleration = 5.0

[output]
plots = false
"""


def test_dynid_design_takes_the_chart(fivebar3, capsys):
    d = fivebar3.parent
    (d / "design0.toml").write_text(f'[robot]\nmodel = "{fivebar3.name}"\nindependent = ["qa1", "qa2", "qb1"]\n' + DESIGN)
    assert main(["design", str(d / "design0.toml"), "--out", str(d / "design0")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "e.g. ['qa1', 'qa2']" in err and not (d / "design0").exists()
    (d / "design.toml").write_text(ROBOT.format(model=fivebar3.name) + DESIGN)
    assert main(["design", str(d / "design.toml"), "--out", str(d / "design")]) == 0
    header = (d / "design" / "trajectory.csv").read_text().splitlines()[0]
    assert "qa1" in header and "qa2" in header  # the designed motion is in the chart's coordinates
