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
    log) is the steadier one, and reads within 0.5 % of it on average over 40 draws (2.8 % low before
    the correction for the share of the noise the low-pass keeps, ``_white_noise_std``). 3 % + 4.5
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


def _filtfilt_power_gain(cutoff_hz: float, fs: float, order: int) -> float:
    """||h||_2 of the zero-phase Butterworth low-pass, from its frequency response instead of its
    impulse response: the digital Butterworth (bilinear) has |H|^2 = 1 / (1 + (tan(w/2) / tan(wc/2))^(2N))
    and filtfilt squares it, so ||h||^2 = (1/pi) int_0^pi |H|^4 dw (Parseval)."""
    from scipy.integrate import quad

    tc = np.tan(np.pi * cutoff_hz / fs)
    val, _ = quad(lambda w: (1.0 + (np.tan(w / 2) / tc) ** (2 * order)) ** -2, 0.0, np.pi, limit=200,
                  points=[2 * np.pi * cutoff_hz / fs])
    return float(np.sqrt(val / np.pi))


@pytest.mark.numerics
@pytest.mark.parametrize("cutoff", [None, 20.0], ids=["unfiltered", "lowpass20"])
def test_velocity_noise_std_of_measured_velocities_is_their_white_noise_std(cutoff):
    """Exact velocities plus white noise of known std: ``processing.derivatives = "measured"`` reads the
    std of the velocity noise from the log alone; unfiltered it is the noise's std, low-passed it is the
    std times the low-pass's ||h||_2 (from its frequency response here, its impulse response there).

    Margin: the estimate is 1.4826 x MAD of about n = 20 000 residual samples: relative std
    1.166 / sqrt(n) = 0.82 % for independent Gaussian samples; the high-pass residual is slightly
    correlated (0.95 % seen over 40 draws, mean within 0.2 % of the truth), so 1.3 x 0.82 % = 1.07 %
    per std, and 5 of them (5.4 %): a false alarm of 6e-7 per joint."""
    fs, n = 1000.0, 20000
    t = np.arange(n) / fs
    w1, w2 = 2 * np.pi * 0.3, 2 * np.pi * 0.7
    q0 = np.c_[np.sin(w1 * t), 0.5 * np.sin(w2 * t + 1)]
    dq0 = np.c_[w1 * np.cos(w1 * t), 0.5 * w2 * np.cos(w2 * t + 1)]
    sigma = np.array([2e-3, 1e-2])
    dq = dq0 + sigma * np.random.default_rng(seed(31)).standard_normal(dq0.shape)
    lp = None if cutoff is None else LowpassConfig(cutoff_hz=cutoff, order=4, filter_effort=False)
    ds = Dataset(t=t, q=q0, dq=dq, tau=np.zeros_like(q0), names=("a", "b"))
    est = velocity_noise_std(ds, ProcessingConfig(derivatives="measured", lowpass=lp))
    gain = 1.0 if cutoff is None else _filtfilt_power_gain(cutoff, fs, 4)
    np.testing.assert_allclose(est, sigma * gain, rtol=5 * 1.3 * 1.166 / np.sqrt(n))
    # the central-difference route reads the positions instead: noise-free positions give (almost) no width
    assert np.all(velocity_noise_std(ds, ProcessingConfig(lowpass=lp)) < 1e-3 * sigma * gain)


def test_velocity_noise_std_refuses_what_it_cannot_read():
    """Measured derivatives without velocity columns, and period-averaged processing (whose noise is
    the averaging's), are one-line errors that say to give the widths."""
    from dynid.config import PeriodicConfig

    t = np.arange(2000) / 1000.0
    q = np.c_[np.sin(t), np.cos(t)]
    ds = Dataset(t=t, q=q, tau=np.zeros_like(q), names=("a", "b"))
    with pytest.raises(ConfigError, match="has no velocity columns"):
        velocity_noise_std(ds, ProcessingConfig(derivatives="measured"))
    with pytest.raises(ConfigError, match=r"\[processing.periodic\] give the widths"):
        velocity_noise_std(ds, ProcessingConfig(periodic=PeriodicConfig(period_s=1.0, cutoff_hz=10.0)))


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


def test_widths_of_the_wrong_length_are_a_one_line_error(cobot_logs, capsys):
    from dynid.cli import main

    d = cobot_logs
    (d / "bad1.toml").write_text(IDENTIFY.format(extra="coulomb_smoothing = [0.01, 0.01]", decimate=1))
    assert main(["identify", str(d / "bad1.toml"), "--out", str(d / "bad1"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dynid: error:") and "2 widths for 6 actuators" in err[0], err
    assert not (d / "bad1").exists()


# ---------------------------------------------------------------- measured velocities (issue 34, item 4)
SIGMA_V = {"cobot6r": 0.004, "rps3": 0.0008}  # white velocity noise added to the exact velocities [rad/s, m/s]


def _measured_velocity_logs(d, model: str, traj: dict, rate_hz: float, legs: list[int] | None):
    """Train and validation logs of ``model`` with exact positions and accelerations, the exact
    velocities plus white noise of std ``SIGMA_V`` of the model, and the simulated efforts plus a little noise."""
    from dynid._files import save_npz
    from dynid.config.simulate import parse_simulate_config
    from dynid.pipeline.simulate import run_simulation

    rng = np.random.default_rng(seed(41))
    names = None
    for name, k in (("train", 42), ("valid", 43)):
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": model, "perturbation": 0.1, "perturbation_seed": 3},
            "trajectory": {**traj, "seed": seed(k)},
            "control": {"rate_hz": rate_hz, "kp": 2500, "kd": 100, "model": "true"},
        }, d))
        m = sim.motion
        q, dq, ddq = (x if legs is None else x[:, legs] for x in (m.q, m.dq, m.ddq))
        tau = m.tau if legs is None else m.tau_a
        names = [f"j{k}" for k in range(q.shape[1])]
        cols = {"t": m.t}
        for k, j in enumerate(names):
            cols[f"q_{j}"], cols[f"ddq_{j}"] = q[:, k], ddq[:, k]
            cols[f"dq_{j}"] = dq[:, k] + SIGMA_V[model.removeprefix("builtin:")] * rng.standard_normal(q.shape[0])
            cols[f"tau_{j}"] = tau[:, k] + 0.01 * np.abs(tau[:, k]).max() * rng.standard_normal(q.shape[0])
        save_npz(d / f"{name}.npz", cols)
    return names


@pytest.mark.numerics
@pytest.mark.parametrize("model", ["cobot6r", "rps3"])
def test_auto_smoothing_with_measured_velocities_reads_their_noise_through_dynid_identify(tmp_path, model):
    """``coulomb_smoothing = "auto"`` on a log with a velocity column (``processing.derivatives =
    "measured"``), a serial arm (no low-pass: the width is the velocity noise's std) and a parallel
    robot (the legs of the 3-RPS; a 25 Hz low-pass: the std times the low-pass's ||h||_2; the passive
    joints' widths follow through the velocity map, ``ClosedLoopSystem.with_coulomb_width``):
    ``dynid identify`` runs and records the widths the rule gives.

    Margin: 1.4826 x MAD of n residual samples (n = 4 s x 500 Hz minus the trimmed ends for the
    arm, 2 periods x 2 s x 500 Hz for the 3-RPS): relative std 1.3 x 1.166 / sqrt(n) (the residual's
    slight correlation, see the unit test above), 5 of them; plus what the motion itself puts above
    the reference cut-off (50 Hz without a low-pass: a 3-harmonic trajectory at <= 1.5 Hz puts
    nothing there)."""
    from dynid.cli import main
    from dynid.estimation.results import IdentificationResult

    if model == "cobot6r":
        traj = {"kind": "fourier", "base_frequency_hz": 0.25, "harmonics": 3, "fill": 0.5, "max_velocity": 1.0,
                "max_acceleration": 3.0, "quintic": True}
        names, lowpass_hz = _measured_velocity_logs(tmp_path, "builtin:cobot6r", traj, 500.0, None), None
    else:
        traj = {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 3, "fill": 0.4, "max_velocity": 0.1,
                "max_acceleration": 1.0, "periods": 2}
        names, lowpass_hz = _measured_velocity_logs(tmp_path, "builtin:rps3", traj, 500.0, [1, 3, 5]), 25.0
    sig = lambda p, unit, **kw: {"columns": [f"{p}_{j}" for j in names], "unit": unit, **kw}  # noqa: E731
    unit = "rad" if model == "cobot6r" else "m"
    cfg = "\n".join([
        f'[robot]\nmodel = "builtin:{model}"\n',
        f'[data]\nfile = "train.npz"\ntime = {{ column = "t" }}',
        f"position = {{ columns = {sig('q', unit)['columns']}, unit = '{unit}' }}",
        f"velocity = {{ columns = {sig('dq', unit)['columns']}, unit = '{unit}' }}",
        f"acceleration = {{ columns = {sig('ddq', unit)['columns']}, unit = '{unit}' }}",
        f"effort = {{ columns = {sig('tau', unit)['columns']}, unit = '{'N*m' if unit == 'rad' else 'N'}', kind = 'torque' }}\n",
        '[validation]\nfile = "valid.npz"\n',
        '[processing]\nderivatives = "measured"',
        "" if lowpass_hz is None else f"lowpass = {{ cutoff_hz = {lowpass_hz}, order = 4, filter_effort = false }}",
        '\n[identification]\nmethod = "ols"\ncoulomb_smoothing = "auto"\n',
        "[output]\nplots = false\n"])
    (tmp_path / "id.toml").write_text(cfg)
    assert main(["identify", str(tmp_path / "id.toml"), "--out", str(tmp_path / "out"), "-q"]) == 0
    sm = IdentificationResult.load(tmp_path / "out" / "result.json").provenance["coulomb_smoothing"]
    assert sm["source"].startswith("auto") and len(sm["width"]) == len(names)
    n = np.load(tmp_path / "train.npz")["t"].size
    gain = 1.0 if lowpass_hz is None else _filtfilt_power_gain(lowpass_hz, 500.0, 4)
    np.testing.assert_allclose(sm["width"], SIGMA_V[model] * gain, rtol=5 * 1.3 * 1.166 / np.sqrt(0.95 * n))
