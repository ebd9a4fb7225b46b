"""Friction at prediction time without chatter (issue 19, item 4): the Coulomb terms' smooth sign
erf(v / (sqrt 2 w)) with w the velocity noise the processing leaves (estimated from the data), the
same function in identification and prediction, serial robots and mechanisms alike."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from scipy.special import erf

from dynid.config import parse_config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, ModelError
from dynid.model import Coupling, Transmission, load_robot, regressor
from dynid.model.closed_loop import actuator_forces, actuator_regressor, random_consistent_states
from dynid.model.serial_dynamics import inverse_dynamics, smooth_sign
from dynid.pipeline.data import velocity_noise_std
from dynid.config import ProcessingConfig, LowpassConfig
from dynid.model.mechanism_io import load_mechanism
from _cobot_twin import COBOT_LOGS, PUMA_DOC
from conftest import seed


@pytest.mark.numerics
def test_erf_is_the_expected_sign_of_the_true_velocity():
    """E[sign(v + e)] over Gaussian e of std w is erf(v / (sqrt 2 w)): Monte Carlo, 4 standard errors
    (a mean of 200 000 draws: normal; 6e-5 per velocity, 3e-4 for the five)."""
    rng = np.random.default_rng(seed(0))
    w, n = 0.3, 200_000
    for v in (-0.9, -0.2, 0.0, 0.05, 0.4):
        draws = np.sign(v + w * rng.standard_normal(n))
        se = draws.std() / np.sqrt(n)
        assert abs(draws.mean() - float(smooth_sign(np.array([[v]]), [w])[0, 0])) < 4 * se + 1e-12
    # far from zero it is the sign; a zero width is the sign exactly
    np.testing.assert_array_equal(smooth_sign(np.array([[-1.0, 2.0]]), [0.01, 0.01]), [[-1.0, 1.0]])
    np.testing.assert_array_equal(smooth_sign(np.array([[-1e-9, 1e-9, 0.0]]), [0.0, 0.0, 0.0]), [[-1.0, 1.0, 0.0]])


TX40_LIKE = load_robot("builtin:generic6r", transmission=Transmission.from_ratios([32, 32, 45, -48, 45, 32], [Coupling(6, (5, 6))]))


@pytest.mark.parametrize("robot", [load_robot("builtin:puma560"), TX40_LIKE], ids=["puma560", "tx40-like-coupled"])
def test_regressor_times_params_is_inverse_dynamics_with_the_smooth_sign(robot):
    """With ``coulomb_width`` the regressor's Coulomb columns are erf(v / (sqrt 2 w)) (the coupled
    motor's width from the joints', sqrt(sum (c w)^2)) and the library's inverse dynamics agrees."""
    w = np.array([0.05, 0.1, 0.02, 0.2, 0.03, 0.04])
    smooth = robot.replace(coulomb_width=tuple(w))
    rng = np.random.default_rng(1)
    lo, hi = robot.position_limits()
    q = rng.uniform(lo, hi, (20, robot.dof))
    dq = rng.normal(0, 0.1, (20, robot.dof))  # within a few widths of zero: the smoothing matters
    ddq = rng.normal(0, 1, (20, robot.dof))
    pi = robot.nominal_parameters() + rng.uniform(0.1, 1.0, robot.n_standard_params)
    lay = robot.layout
    fc = pi[lay.extra_index["fc"]]
    expected = regressor(robot, q, dq, ddq) @ pi + fc * (erf(dq / (np.sqrt(2) * w)) - np.sign(dq))
    if lay.coupled_motors:
        c = np.array([0, 0, 0, 0, 1.0, 1.0])
        wm, v = np.sqrt(np.sum((c * w) ** 2)), dq @ c
        fcm = pi[lay.names.index("fcm6")]
        expected += (fcm * (erf(v / (np.sqrt(2) * wm)) - np.sign(v)))[:, None] * c[None, :]
    got = regressor(smooth, q, dq, ddq) @ pi
    np.testing.assert_allclose(got, expected, atol=1e-10 * np.abs(expected).max())
    np.testing.assert_allclose(inverse_dynamics(smooth, pi, q, dq, ddq), expected, atol=1e-9 * np.abs(expected).max())
    assert np.abs(got - regressor(robot, q, dq, ddq) @ pi).max() > 0.1  # not the sign


def test_mechanism_regressor_and_forces_agree_with_the_smooth_sign():
    mech = load_mechanism("builtin:hexapod")
    smooth = dataclasses.replace(mech, coulomb_width=tuple(0.01 for _ in range(mech.nv)))
    state = random_consistent_states(mech, 10, np.random.default_rng(2), spread=0.1, vel_scale=0.02)
    p = mech.nominal_parameters()
    tau = actuator_forces(smooth, p, state)
    np.testing.assert_allclose(actuator_regressor(smooth, state).W @ p, tau, atol=1e-9 * np.abs(tau).max())
    assert np.abs(tau - actuator_forces(mech, p, state)).max() > 0.01  # slow joints: erf is not the sign
    with pytest.raises(ModelError, match="coulomb_width needs 24 finite values"):
        dataclasses.replace(mech, coulomb_width=(0.1,))


@pytest.mark.numerics
def test_velocity_noise_std_is_the_noise_left_in_the_processed_velocity():
    """White position noise through the configured low-pass and central differences: the estimate
    from the noisy log alone matches the std of the processed velocity's actual error (the same
    processing applied to the noise-free log).

    Margin: the actual error is noise band-limited to the 20 Hz cut-off, so its std over the 19 s
    kept has about 2 x 20 Hz x 19 s = 760 degrees of freedom: a relative std of 1 / sqrt(2 x 760) =
    2.6 % (3.1 % over 40 draws); the estimate (the MAD of what the low-pass removes, over the whole
    log) is the steadier one, and reads 2.8 % low on average (the filter's transition band). 3 % + 4.5
    of those std: a false alarm of 7e-6 per joint (10 % was 2.3 std beyond the mean: 8.4 % seen)."""
    fs, n = 1000.0, 20000
    t = np.arange(n) / fs
    q0 = np.c_[np.sin(2 * np.pi * 0.3 * t), 0.5 * np.sin(2 * np.pi * 0.7 * t + 1)]
    sigma = np.array([2e-4, 1e-3])
    q = q0 + sigma * np.random.default_rng(seed(3)).standard_normal(q0.shape)
    cfg = ProcessingConfig(lowpass=LowpassConfig(cutoff_hz=20.0, order=4, filter_effort=False))
    ds = Dataset(t=t, q=q, tau=np.zeros_like(q), names=("a", "b"))
    est = velocity_noise_std(ds, cfg)
    from dynid.signals import central_difference, lowpass

    err = (central_difference(lowpass(q, 20.0, fs, 4), 1 / fs) - central_difference(lowpass(q0, 20.0, fs, 4), 1 / fs))[500:-500]
    dof = 2 * 20.0 * (t[-500] - t[500])
    np.testing.assert_allclose(est, err.std(axis=0), rtol=0.03 + 4.5 / np.sqrt(2 * dof))


DOC = PUMA_DOC


@pytest.mark.parametrize(("ident", "match"), [
    ({"coulomb_smoothing": "yes"}, "coulomb_smoothing"),
    ({"coulomb_smoothing": []}, "must be 'none', 'auto' or a list"),
    ({"coulomb_smoothing": [0.1, -1.0]}, "must be >= 0"),
    ({"method": "didim", "experiment": "sim.toml", "coulomb_smoothing": "auto"}, "not method 'didim'"),
    ({"method": "wls", "physical_consistency": True, "friction_model": "stribeck", "coulomb_smoothing": "auto"},
     "friction_model = 'stribeck'"),
])
def test_bad_smoothing_configs_are_refused(tmp_path, ident, match):
    with pytest.raises(ConfigError, match=match):
        parse_config({**DOC, "identification": ident}, tmp_path)


TWIN = """[robot]
model = "builtin:cobot6r"
perturbation = 0.1
perturbation_seed = 6

[trajectory]
kind = "fourier"
base_frequency_hz = 0.25
harmonics = 3
fill = 0.5
max_velocity = 1.0
max_acceleration = 3.0
quintic = true
seed = {seed}

[control]
rate_hz = 500
kp = 400
kd = 40

[sensors]
encoder_resolution = 4.794e-5
force_noise_std = 0.05
seed = {seed}
"""

IDENTIFY = COBOT_LOGS + """
[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
min_velocity = 0.05
decimate = {decimate}
decimate_method = "parallel"

[identification]
method = "wls"
{extra}

[output]
plots = false
"""


@pytest.fixture(scope="module")
def cobot_logs(tmp_path_factory):
    from dynid.cli import main

    d = tmp_path_factory.mktemp("smooth")
    for name, k in (("train", 6), ("val", 7)):  # the true robot keeps its perturbation_seed
        (d / f"{name}.toml").write_text(TWIN.format(seed=seed(k)))
        assert main(["simulate", str(d / f"{name}.toml"), "--out", str(d / name), "-q"]) == 0
    return d


@pytest.mark.numerics
def test_identify_with_auto_smoothing_fits_the_same_and_records_the_widths(cobot_logs):
    """Without decimation the fit's rows are faster than min_velocity, where erf is the sign: the
    estimate is the one without smoothing (with parallel decimation the regressor is low-passed
    before the rows are selected, so slow neighbours reach the kept rows and the fit changes a
    little); the widths (the 17-bit encoders' noise through the 10 Hz low-pass and the differences)
    are recorded and used in validation, full rate included."""
    from dynid.config import load_config
    from dynid.pipeline.identification import identify

    d = cobot_logs
    out = {}
    for key, extra in (("sign", ""), ("auto", 'coulomb_smoothing = "auto"')):
        for dec in (1, 5):
            (d / f"{key}{dec}.toml").write_text(IDENTIFY.format(extra=extra, decimate=dec))
            out[key, dec] = identify(load_config(d / f"{key}{dec}.toml"))
    auto, sign = out["auto", 5], out["sign", 5]
    sm = auto.result.provenance["coulomb_smoothing"]
    assert sm["source"].startswith("auto") and len(sm["width"]) == 6
    # erf(5 / sqrt 2) = 1 - 6e-7 at min_velocity; the widths are 1e-4-2e-4 rad/s (the encoders' quantization,
    # whatever the draw), so erf is 1 to the last bit on every kept row and the two fits are one to rounding
    assert all(0 < w < 0.05 / 5 for w in sm["width"])
    np.testing.assert_allclose(out["auto", 1].result.params, out["sign", 1].result.params, rtol=1e-9, atol=1e-12)
    assert auto.system.model.coulomb_width == tuple(sm["width"])
    assert auto.full_rate is not None and auto.full_rate.metrics.n_samples > 4 * auto.validation.n_samples
    assert out["auto", 1].full_rate is None  # nothing decimated: the held-out score is already at full rate
    assert any("smooth sign erf" in n for n in auto.result.notes)


def test_widths_of_the_wrong_length_and_auto_with_measured_velocities_are_one_line_errors(cobot_logs, capsys):
    from dynid.cli import main

    d = cobot_logs
    (d / "bad1.toml").write_text(IDENTIFY.format(extra="coulomb_smoothing = [0.01, 0.01]", decimate=1))
    (d / "bad2.toml").write_text(IDENTIFY.format(extra='coulomb_smoothing = "auto"', decimate=1).replace(
        'decimate_method = "parallel"', 'decimate_method = "parallel"\nderivatives = "measured"').replace(
        'unit = "rad" }', 'unit = "rad" }\nvelocity = { columns = ["q_joint_1", "q_joint_2", "q_joint_3", "q_joint_4", "q_joint_5", "q_joint_6"], unit = "rad" }'))
    for name, msg in (("bad1", "2 widths for 6 actuators"), ("bad2", "give the widths per actuator")):
        assert main(["identify", str(d / f"{name}.toml"), "--out", str(d / name), "-q"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("dynid: error:") and msg in err[0], err
        assert not (d / name).exists()
