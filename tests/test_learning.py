"""PI-LSTM residual friction (issue 19 item 3; paper 003 Sec. 3.4): on a simulated 6R arm whose
friction is the improved Stribeck model (which the identified Coulomb + viscous columns cannot
represent) the network trained on the WLS model's training residual lowers its held-out error by
a margin derived from the truth; training is deterministic for a seed; the saved network reloads
and predicts the same; without torch a one-line error; the RNN/GRU/LSTM ablation runs."""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np
import pytest

import torch  # noqa: E402,F401  the [learning] extra: make setup installs it, so its absence fails loudly

from dynid.config import load_config, parse_config  # noqa: E402
from dynid.errors import ConfigError, MissingExtraError  # noqa: E402
from dynid.model.friction import SmoothStribeck  # noqa: E402
from _cobot_twin import COBOT_LOGS, PUMA_DOC
from conftest import seed

torch.set_num_threads(1)

SIM = """[robot]
model = "builtin:cobot6r"

[robot.friction]
model = "smooth_stribeck"
fc = [3.0, 3.5, 2.5, 1.2, 1.0, 0.8]
fs = [5.0, 5.5, 4.0, 1.8, 1.6, 1.2]
fv = [4.0, 5.0, 3.0, 1.5, 1.2, 1.0]
vs = [0.15, 0.12, 0.15, 0.2, 0.15, 0.2]
kv = [30.0, 30.0, 30.0, 30.0, 30.0, 30.0]
alpha = [0.7, 0.6, 0.8, 0.9, 0.7, 0.8]

[trajectory]
kind = "fourier"
base_frequency_hz = 0.2
harmonics = 3
fill = 0.5
max_velocity = 1.0
max_acceleration = 3.0
quintic = true
seed = {seed}

[control]
kind = "pid"
rate_hz = 250
kp = [1500, 1800, 800, 180, 200, 110]
kd = [50, 60, 27, 6, 7, 3.6]
ki = [15000, 18000, 8000, 1800, 2000, 1100]

[sensors]
encoder_resolution = 4.794e-5
force_noise_std = {noise}
seed = {seed}
"""

NOISE = 0.05

IDENTIFY = COBOT_LOGS + """
[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
min_velocity = 0.05

[identification]
method = "wls"

{learning}

[output]
plots = false
"""

LEARNING = """[learning]
model = "lstm"
window = 6
hidden = 24
epochs = 150
lambda = 0.2
seed = {seed}
max_seconds = 300
""".format(seed=seed(0))  # the network's initial weights and shuffling: another draw of the method


def _cli(args):
    from dynid.cli import main

    return main(args)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("learning")
    for name, k in (("train", 6), ("val", 7)):
        (d / f"{name}.toml").write_text(SIM.format(seed=seed(k), noise=NOISE))
        assert _cli(["simulate", str(d / f"{name}.toml"), "--out", str(d / name), "-q"]) == 0
    (d / "identify.toml").write_text(IDENTIFY.format(learning=LEARNING))
    return d


@pytest.fixture(scope="module")
def outcome(logs):
    from dynid.pipeline.identification import identify

    return identify(load_config(logs / "identify.toml"))


def _residuals(outcome):
    from dynid.pipeline.identification import _model_rows

    out = []
    for ds in (outcome.train, outcome.held_out):
        y, p = _model_rows(outcome.system, outcome.base, outcome.result.params, ds, 20000)
        out.append((ds, y - p))
    return out


@pytest.mark.numerics
def test_the_network_removes_most_of_the_friction_error_the_linear_model_leaves(logs, outcome):
    """The margin from the truth: the held-out residual of the linear-friction WLS model, corrected
    by the true friction error (the improved Stribeck truth minus the identified f_c sign(q̇) +
    f_v q̇, at the processed velocities), is the best any function of the velocity can do; it is
    above the force noise because the fit's rigid-body parameters absorbed part of the friction.
    The network must remove at least half of the mean square error between the linear model and
    that ideal correction, and cannot beat the noise."""
    from dynid.pipeline.learning import linear_friction

    lo = outcome.learning
    assert lo is not None
    truth = json.loads((logs / "train" / "truth.json").read_text())["ground_truth_friction"]
    true_f = SmoothStribeck(**{k: v for k, v in truth.items() if k != "model"})
    (_, _), (held, r_val) = _residuals(outcome)
    fr = linear_friction(outcome.base.names, outcome.result.params, 6)
    ideal = r_val - (true_f.force(held.dq) - (fr["fc"] * np.sign(held.dq) + fr["fv"] * held.dq))
    mse_lin = float(np.mean(r_val**2))
    mse_ideal = float(np.mean(ideal**2))
    mse_net = float(np.mean(np.asarray(lo.with_network.rmse) ** 2))
    np.testing.assert_allclose(np.mean(np.asarray(lo.without.rmse) ** 2), mse_lin, rtol=1e-12)
    assert mse_ideal < 0.3 * mse_lin  # the scenario: friction is most of what the linear model misses (0.04-0.05)
    # a training outcome, not a bound of the method: 0.71-0.91 of the removable error over 3 draws of the data and
    # the network's initial weights
    assert mse_net < mse_lin - 0.5 * (mse_lin - mse_ideal), (mse_lin, mse_ideal, mse_net)
    # no prediction beats the force noise of held-out data: it is independent of every prediction, so the mean
    # square is at least its sample variance, within sqrt(2 / N) ~ 1 % of NOISE^2 (the rest of the model error
    # keeps it at 2.9-5.3 NOISE here)
    assert np.sqrt(mse_net) > NOISE
    # the low-speed region (Table 1's |v| < 0.5 rad/s) improves too (0.33-0.56 of it over 3 draws)
    assert lo.low_speed["overall_with"] < 0.8 * lo.low_speed["overall_without"]
    text = outcome.summary_text()
    assert "Learned residual friction (PI-LSTM" in text and "result_learning.pt" in text


def test_training_is_deterministic_for_a_seed(outcome):
    """Two trainings with the same seed in one process give identical weights; another seed does not."""
    from dynid.learning import LearningConfig, fit_residual
    from dynid.pipeline.learning import linear_friction

    (train, r_tr), _ = _residuals(outcome)
    fr = linear_friction(outcome.base.names, outcome.result.params, 6)
    cfg = LearningConfig(epochs=4, hidden=16, seed=3)
    a, b = (fit_residual(cfg, train.dq[:, :2], train.ddq[:, :2], r_tr[:, :2], {k: v[:2] for k, v in fr.items()})
            for _ in range(2))
    c = fit_residual(dataclasses.replace(cfg, seed=4), train.dq[:, :2], train.ddq[:, :2], r_tr[:, :2],
                     {k: v[:2] for k, v in fr.items()})
    for sa, sb, sc in zip(a.states, b.states, c.states):
        assert sa.keys() == sb.keys()
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
        assert not all(torch.equal(sa[k], sc[k]) for k in sa)
    np.testing.assert_array_equal(a.predict(train.dq[:, :2], train.ddq[:, :2]), b.predict(train.dq[:, :2], train.ddq[:, :2]))
    assert not torch.are_deterministic_algorithms_enabled()  # the global settings are restored


@pytest.mark.numerics
def test_saved_network_reloads_and_predicts_the_same(logs, outcome, tmp_path):
    from dynid.pipeline.identification import write_outputs
    from dynid.pipeline.learning import LEARNING_FILE, load_networks, predict

    files = write_outputs(outcome, tmp_path / "out")
    assert LEARNING_FILE in files
    doc = json.loads(files["result.json"].read_text())
    ln = doc["learning"]
    assert ln["file"] == LEARNING_FILE and ln["config"]["model"] == "lstm" and ln["config"]["lambda"] == 0.2
    assert ln["validation_with_network"]["overall_rmse"] < ln["validation_without_network"]["overall_rmse"]
    nets = load_networks(tmp_path / "out")
    held = outcome.held_out
    np.testing.assert_array_equal(nets.predict(held.dq, held.ddq), outcome.learning.networks.predict(held.dq, held.ddq))
    model = outcome.learning.without.predicted
    np.testing.assert_allclose(predict(model, held.dq, held.ddq, nets), outcome.learning.with_network.predicted, rtol=0,
                               atol=1e-12)
    # a run without [learning] into the same folder removes the stale network
    cfg = dataclasses.replace(outcome.config, learning=None)
    out2 = dataclasses.replace(outcome, config=cfg, learning=None)
    assert LEARNING_FILE not in write_outputs(out2, tmp_path / "out")
    assert not (tmp_path / "out" / LEARNING_FILE).exists()


def test_without_torch_a_one_line_error(logs, monkeypatch, capsys):
    """dynid imports and parses [learning] without torch; asking for the network is one line that
    says how to install it (exit 2), before any identification work."""
    monkeypatch.setitem(sys.modules, "torch", None)  # `import torch` raises ImportError
    from dynid.learning import require_torch

    with pytest.raises(MissingExtraError, match=r"pip install 'dynid\[learning\]' \(or make setup\)"):
        require_torch()
    assert load_config(logs / "identify.toml").learning is not None
    assert _cli(["identify", str(logs / "identify.toml"), "--out", str(logs / "no_torch"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dynid: error:") and "dynid[learning]" in err[0], err
    assert not (logs / "no_torch").exists()


def test_dynid_imports_without_torch():
    """Nothing imports torch at module level: a fresh interpreter without it imports every module
    that touches [learning]."""
    import subprocess

    # a finder that refuses torch (sys.modules['torch'] = None would break scipy, which looks torch up there)
    code = ("import sys, importlib.abc\n"
            "class NoTorch(importlib.abc.MetaPathFinder):\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] == 'torch':\n"
            "            raise ImportError('no torch here')\n"
            "sys.meta_path.insert(0, NoTorch())\n"
            "import dynid.cli, dynid.learning, dynid.pipeline.learning, dynid.pipeline.identification\n"
            "import dynid.studies.learning, dynid.config.learning\n"
            "from dynid.learning import require_torch\n"
            "try:\n"
            "    require_torch()\n"
            "except Exception as exc:\n"
            "    print(type(exc).__name__, exc)\n"
            "print('torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[0].startswith("MissingExtraError [learning] needs torch") and "pip install 'dynid[learning]'" in lines[0]
    assert lines[1:] == ["False"]


DOC = PUMA_DOC


@pytest.mark.parametrize(("learning", "match"), [
    ({"modle": "lstm"}, r"unknown key learning\.modle"),
    ({"model": "transformer"}, r"learning\.model: must be one of \['lstm', 'gru', 'rnn'\]"),
    ({"lambda": 0.5}, r"learning\.lambda: must be in \[0\.1, 0\.3\]"),
    ({"window": 0}, r"learning\.window: must be >= 1"),
    ({"max_seconds": 0}, r"learning\.max_seconds: must be positive"),
    ({"stribeck_velocity": [0.1, -1.0]}, r"learning\.stribeck_velocity\[1\]: must be positive"),
    ({"validation_fraction": 0.7}, r"learning\.validation_fraction: must be below 0\.5"),
])
def test_bad_learning_configs_are_one_line_errors(tmp_path, learning, match):
    with pytest.raises(ConfigError, match=match):
        parse_config({**DOC, "learning": learning}, tmp_path)


def test_unsupported_setups_are_refused_before_training(logs, capsys):
    text = IDENTIFY.format(learning=LEARNING).replace('min_velocity = 0.05', 'min_velocity = 0.05\ndecimate = 2\n'
                                                                             'decimate_method = "parallel"')
    (logs / "parallel.toml").write_text(text)
    assert _cli(["identify", str(logs / "parallel.toml"), "--out", str(logs / "parallel"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "decimate_method = 'plain'" in err[0], err


@pytest.mark.numerics
def test_ablation_quick_version(outcome):
    """Table 1's ablation in its quick version (25 epochs, 16 hidden units): every kind is trained
    on the same residual; the gated cells (LSTM, GRU) lower the held-out error of the identified
    model alone. By how much is the draw's (by 8-65 % over 3 draws of the data and initial
    weights: the 10 % once asserted failed on one); the full study's figures are in bench. The
    Elman RNN is only reported: on this budget it need not (it made the held-out error 13 % worse
    when this test was written), and the order among the three is not asserted (on a few epochs it
    is not a property of the method)."""
    from dynid.studies.learning import ablation_from_outcome, table

    rows = ablation_from_outcome(outcome, quick=True)
    assert [r["model"] for r in rows] == ["identified model alone", "PI-LSTM", "PI-GRU", "PI-RNN"]
    base = rows[0]["rmse"]
    assert np.isclose(base, np.sqrt(np.mean(np.asarray(outcome.learning.without.rmse) ** 2)), rtol=1e-12)
    for r in rows[1:]:
        assert np.isfinite(r["rmse"]) and np.isfinite(r["low_speed_rmse"]), table(rows)
        assert 1 <= r["epochs_to_converge"] <= 25
    for r in rows[1:3]:
        assert r["rmse"] < base, table(rows)
    assert "PI-GRU" in table(rows)


def test_time_bound_and_bad_inputs(outcome, tmp_path):
    """max_seconds ends training after the epoch in which the clock ran out (recorded); a file that
    is not a saved network, wrong shapes and too few samples are one-line InputErrors."""
    from dynid.errors import InputError
    from dynid.learning import LearningConfig, ResidualNetworks, fit_residual

    (train, r_tr), _ = _residuals(outcome)
    nets = fit_residual(LearningConfig(epochs=50, hidden=8, max_seconds=1e-3), train.dq[:, :2], train.ddq[:, :2],
                        r_tr[:, :2])
    assert [(r.stopped_by, r.epochs_run) for r in nets.records] == [("max_seconds", 1)] * 2
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a network")
    for call, match in (
        (lambda: ResidualNetworks.load(bad), "is not a saved dynid network"),
        (lambda: ResidualNetworks.load(tmp_path / "none.pt"), "no trained network at"),
        (lambda: nets.predict(train.dq, train.ddq), "expected velocities and accelerations of 2 joints"),
        (lambda: fit_residual(LearningConfig(), train.dq[:100], train.ddq[:100], r_tr[:100]), "too few"),
        (lambda: fit_residual(LearningConfig(), train.dq, train.ddq, r_tr[:, :3]), "shapes"),
    ):
        with pytest.raises(InputError, match=match) as info:
            call()
        assert "\n" not in str(info.value)


@pytest.mark.numerics
def test_network_on_a_hierarchical_identification(logs):
    """[learning] with hierarchical = true (paper 003 Sec. 3.4 stacked on Sec. 3.3, the +PI-LSTM row
    of Tables 6/8): the model the network corrects is the rigid-body part plus the fitted friction
    curves, so its held-out errors without the network are the identification's own validation,
    and the physical loss acts on those curves (no linear friction columns are left)."""
    from dynid.pipeline.identification import identify

    text = IDENTIFY.format(learning=LEARNING.replace("epochs = 150", "epochs = 8")).replace(
        'method = "wls"', 'method = "wls"\nhierarchical = true\nfriction_model = "arctan"')
    (logs / "hier.toml").write_text(text)
    out = identify(load_config(logs / "hier.toml"))
    lo = out.learning
    np.testing.assert_allclose(lo.without.rmse, out.validation.rmse, rtol=1e-12)
    assert lo.networks.linear_friction == {"fc": [0.0] * 6, "fv": [0.0] * 6}
    # the curves' friction is what the network's physical terms see: the prior fitted to it has the
    # curves' Coulomb level, not 0
    fr = out.result.solver["hierarchical"]["friction"]
    for j, p in enumerate(lo.networks.priors):  # 0.99-4.2 of the curves' level over 3 draws
        assert p["fc"] > 0.3 * fr[f"joint_{j + 1}"]["fc"]["value"]
