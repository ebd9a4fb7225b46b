"""``dynid montecarlo``: repeated virtual experiments with known truth (paper 002 §5).

The statistical check runs 100 trials of OLS on a serial 6R arm (builtin:cobot6r) whose log
has exact positions and 2 N*m of white torque noise: there the covariance OLS reports is the
true one, so the 95 % intervals must cover the truth in about 95 % of the cases and the
chi-square statistic must average p. The same trials then run on a local Dask cluster and must
give the same numbers.
"""

from __future__ import annotations

import dataclasses
import json
import re
import socket
import tomllib
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, doc_text, seed
from dynid.cli import main
from dynid.config.montecarlo import load_montecarlo_config, parse_montecarlo_config
from dynid.config.simulate import load_simulate_config
from dynid.errors import ConfigError, IdentifiabilityError
from dynid.pipeline import montecarlo as mc
from dynid.pipeline.simulate import measure_signals, run_simulation

# Exact positions (no encoder, no position noise) and white torque noise: no errors in the
# variables, so the reported covariance is the true one. Rows where a joint is slower than
# 0.05 rad/s are dropped (Coulomb friction at velocity reversals). The motion and the first
# trial's sensor seed through conftest.seed (the true robot keeps its perturbation seed).
SENSOR_SEED = seed(0)
DOC = {
    "simulate": {
        "robot": {"model": "builtin:cobot6r", "perturbation": 0.1},
        "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 4, "fill": 0.6, "periods": 2,
                       "seed": seed(1), "max_velocity": 1.5, "max_acceleration": 6.0},
        "control": {"rate_hz": 500, "kp": 400, "kd": 40, "substeps": 2},
        "sensors": {"force_noise_std": 2.0, "seed": SENSOR_SEED},
    },
    "identify": {"processing": {"min_velocity": 0.05}, "identification": {"method": "ols"}},
    "montecarlo": {"trials": 100, "workers": 2},
}

SMALL = """
[simulate.robot]
model = "builtin:cobot6r"
perturbation = 0.1

[simulate.trajectory]
kind = "fourier"
base_frequency_hz = 0.5
harmonics = 3
fill = 0.5
seed = 2

[simulate.control]
rate_hz = 500
substeps = 1

[simulate.sensors]
force_noise_std = 1.0
seed = 3

[identify.processing]
min_velocity = 0.05

[identify.identification]
method = "wls"

[montecarlo]
trials = 3
workers = 1
"""


def _cfg(**changes) -> mc.MonteCarloConfig:
    return dataclasses.replace(parse_montecarlo_config(DOC, Path(".")), **changes)


@pytest.fixture(scope="module")
def coverage_run():
    return mc.run_montecarlo(_cfg())


@pytest.mark.numerics
def test_intervals_cover_the_truth_95_percent_of_the_time(coverage_run):
    """With the true covariance each interval covers the truth with probability 0.95 in each trial,
    independently across the 100 trials (another noise draw each): the counts are binomial."""
    from scipy import stats

    r = coverage_run
    p = r.n_params
    assert r.ok.all() and not r.failures and r.trial.tolist() == list(range(100))
    # sensor seed = the simulation's seed + trial
    assert r.seed.tolist() == list(range(SENSOR_SEED, SENSOR_SEED + 100))
    # the overall share: the mean over the trials of each trial's share of the p intervals (iid across trials;
    # within one they are correlated, through the estimates' correlations): within 4.5 of its std, the trials'
    # own spread / sqrt(100) (0.44 % here; a binomial over all 100 p intervals would say 0.29 %)
    spread = 100 * float(np.std(r.inside.mean(axis=1), ddof=1)) / np.sqrt(100)
    assert abs(r.overall_coverage - 95.0) <= 4.5 * spread, (r.overall_coverage, spread)
    # each parameter's count is binomial(100, 0.95): above its 1e-3 / p quantile (84 of 100 at p = 58)
    assert r.coverage.min() >= stats.binom.ppf(1e-3 / p, 100, 0.95), dict(zip(r.names, r.coverage))
    # the mean of 100 chi2_p draws: std sqrt(2 p / 100) (1.1 at p = 58); the bounds are 8 and 11 std away, room
    # for the small errors in the variables that differentiating exact positions leaves
    assert 0.85 * p <= r.mean_chi2 <= 1.2 * p, (r.mean_chi2, p)
    assert r.ellipsoid_share >= 85.0  # binomial(100, 0.95) below 85: 3.7e-5
    # the reported standard deviations are the observed spread of the estimates (each ratio ~ sqrt(chi2_99 / 99),
    # 7 % (1 std); their median over the p parameters ~1.2 %: 15 % is > 10 std)
    ratio = np.array([row["std"] / row["mean_reported_std"] for row in r.parameter_table()])
    assert 0.85 <= np.median(ratio) <= 1.15, np.median(ratio)
    # the truth is the same robot in every trial (only the sensor noise is drawn again)
    assert np.array_equal(r.truth, np.broadcast_to(r.truth[0], r.truth.shape))
    assert r.radius == pytest.approx(__import__("scipy").stats.chi2.ppf(0.95, p))
    inside = r.inside[:, :]
    assert np.array_equal(inside, (r.ci[..., 0] <= r.truth) & (r.truth <= r.ci[..., 1]))


def test_dask_cluster_gives_the_same_trials(coverage_run):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        r = mc.run_montecarlo(_cfg(trials=4, scheduler=cluster.scheduler_address))
    assert "Dask" in r.timing["backend"] and r.timing["workers"] == 2
    ref = coverage_run
    assert r.names == ref.names and r.seed.tolist() == list(range(SENSOR_SEED, SENSOR_SEED + 4))
    assert np.array_equal(r.estimates, ref.estimates[:4])
    assert np.array_equal(r.std, ref.std[:4])
    np.testing.assert_allclose(r.chi2, ref.chi2[:4], rtol=1e-9)


def test_trial_zero_is_the_simulate_experiment_and_resimulate_varies_the_robot(coverage_run):
    cfg = _cfg(trials=2, resimulate=True, workers=1)
    sim = run_simulation(cfg.simulate)
    meas, columns = measure_signals(sim.signals, cfg.simulate.sensors.seed)
    assert list(columns) == list(sim.columns)
    assert all(np.array_equal(columns[k], sim.columns[k]) for k in columns)  # the log of dynid simulate
    r = mc.run_montecarlo(cfg)
    assert r.settings["mode"] == mc.MODE_TEXT[True]
    assert np.array_equal(r.estimates[0], coverage_run.estimates[0])  # seeds offset by 0: the same experiment
    assert np.array_equal(r.truth[0], coverage_run.truth[0])
    assert not np.array_equal(r.truth[1], r.truth[0])  # perturbation seed + 1: another true robot


def test_failed_trials_are_counted_and_reported(monkeypatch, tmp_path):
    import importlib

    identify_module = importlib.import_module("dynid.pipeline.identification")

    real = identify_module.identify
    calls = []

    def flaky(cfg, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise IdentifiabilityError("base parameter Ia1 is not identifiable from these data")
        return real(cfg, *args, **kwargs)

    monkeypatch.setattr(identify_module, "identify", flaky)
    cfg = parse_montecarlo_config(tomllib.loads(SMALL), tmp_path)
    r = mc.run_montecarlo(cfg)
    assert r.ok.tolist() == [True, False, True]
    assert r.failures == ({"trial": 1, "seed": 4, "error": "IdentifiabilityError: base parameter Ia1 is not identifiable "
                                                              "from these data"},)
    assert np.isnan(r.estimates[1]).all() and np.isfinite(r.estimates[[0, 2]]).all()
    doc = r.to_dict()
    assert doc["failures"]["count"] == 1 and doc["n_succeeded"] == 2
    assert "1 failed" in r.summary_text() and "failed trial 1 (seed 4)" in r.summary_text()

    monkeypatch.setattr(identify_module, "identify", lambda cfg, *a, **k: (_ for _ in ()).throw(IdentifiabilityError("no")))
    with pytest.raises(IdentifiabilityError, match="all 3 trials failed"):
        mc.run_montecarlo(cfg)


# ---------------------------------------------------------------------- configuration
@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[montecarlo]\ntrials = 0", "montecarlo.trials: must be >= 1"),
        ("[montecarlo]\nworker = 2", "unknown key montecarlo.worker"),
        ("[montecarlo]\nworkers = \"many\"", "montecarlo.workers: expected an integer >= 0 or \"auto\""),
        ("[montecarlo]\nalpha = 1.5", "montecarlo.alpha: must be in (0, 1)"),
        ("[identify.data]\nfile = \"log.csv\"\n[identify.validation]\nrows = [0, 10]", "unknown key identify.data.file"),
        ("[identify.data]\nrows = [0, 100]", "[identify.data] needs [identify.validation]"),
        ("[identify.processing]\nlowpas = 3", "identify: unknown key processing.lowpas"),
        ("[identify.output]\nplots = true", "unknown key identify.output"),
        ("[simulate.sensors]\nnoise = 1", "simulate: unknown key sensors.noise"),
        ("[extra]\na = 1", "unknown key extra"),
    ],
)
def test_config_errors_name_the_key(text, message):
    doc = tomllib.loads(SMALL)
    extra = tomllib.loads(text)
    for section, table in extra.items():
        if isinstance(table, dict) and section in doc:
            for k, v in table.items():
                doc[section][k] = {**doc[section].get(k, {}), **v} if isinstance(v, dict) else v
        else:
            doc[section] = table
    with pytest.raises(ConfigError) as info:
        parse_montecarlo_config(doc, Path("."))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_config_defaults_and_simulate_file(tmp_path):
    twin = REPO / "examples" / "twins" / "shang2dof_circle.toml"
    (tmp_path / "mc.toml").write_text(f'[simulate]\nfile = "{twin}"\n')
    cfg = load_montecarlo_config(tmp_path / "mc.toml")
    assert cfg.simulate == dataclasses.replace(load_simulate_config(twin), source=cfg.simulate.source)
    assert (cfg.trials, cfg.workers, cfg.resimulate, cfg.alpha, cfg.scheduler) == (100, 1, False, 0.05, None)
    assert cfg.seed == 1  # the simulation's sensors.seed
    icfg = cfg.identify_config(tmp_path / "log.npz", ["qa1", "qa2", "qa3"], "torque", 1000)
    assert icfg.data.rows == (0, 800) and icfg.validation.rows == (800, 1000)
    assert icfg.robot.model == "builtin:shang2dof" and icfg.data.effort.columns == ("tau_qa1", "tau_qa2", "tau_qa3")
    doc = {"simulate": {"file": str(twin), "robot": {}}}
    with pytest.raises(ConfigError, match="either file"):
        parse_montecarlo_config(doc, tmp_path)
    auto = parse_montecarlo_config({"simulate": {"file": str(twin)}, "montecarlo": {"workers": "auto"}}, tmp_path)
    assert auto.workers == 0 and auto.n_workers >= 1


def test_example_config_parses():
    cfg = load_montecarlo_config(REPO / "examples" / "montecarlo" / "shang2dof_wls.toml")
    assert cfg.simulate.robot.model == "builtin:shang2dof" and cfg.trials == 100
    assert cfg.identify["identification"]["method"] == "wls"


def test_readme_montecarlo_section():
    text = doc_text("montecarlo")  # the guide's page "Monte Carlo robustness"
    assert "dynid montecarlo" in text and "the motion is simulated once; each trial redraws the sensor noise" in text
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    cfg = parse_montecarlo_config(tomllib.loads(block), REPO / "examples" / "montecarlo")
    example = load_montecarlo_config(REPO / "examples" / "montecarlo" / "shang2dof_wls.toml")
    assert cfg.simulate.robot == example.simulate.robot and cfg.simulate.trajectory == example.simulate.trajectory
    assert cfg.identify == example.identify
    for section in ("[simulate.robot]", "[identify.processing]", "[montecarlo]"):
        assert section in block


# ---------------------------------------------------------------------- command line
def _run(argv, capsys) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_writes_the_outputs(tmp_path, capsys):
    (tmp_path / "mc.toml").write_text(SMALL)
    out = tmp_path / "out"
    code, stdout, err = _run(["montecarlo", str(tmp_path / "mc.toml"), "--out", str(out), "--trials", "2",
                              "--no-progress"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == sorted(mc.MONTECARLO_FILES)
    doc = json.loads((out / "montecarlo.json").read_text())
    assert doc["n_trials"] == 2 and doc["settings"]["trials"] == 2 and doc["settings"]["mode"] == mc.MODE_TEXT[False]
    p = doc["ellipsoid"]["p"]
    assert len(doc["parameters"]) == p and {"coverage_pct", "mean", "std", "truth", "bias"} <= set(doc["parameters"][0])
    with np.load(out / "trials.npz") as z:
        assert z["estimates"].shape == (2, p) and z["chi2"].shape == (2,) and z["names"].shape == (p,)
        assert z["seed"].tolist() == [3, 4]
    assert "coverage" in stdout and "ellipsoid" in stdout and f"outputs in {out}" in stdout


def test_cli_bad_config_exits_2_with_one_line(tmp_path, capsys):
    (tmp_path / "mc.toml").write_text(SMALL + "\nbogus = 1\n")
    out = tmp_path / "out"
    code, _, err = _run(["montecarlo", str(tmp_path / "mc.toml"), "--out", str(out)], capsys)
    assert code == 2 and err.count("\n") == 1 and "montecarlo.bogus" in err
    assert not out.exists()


def test_cli_unreachable_scheduler_exits_2_with_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(mc, "SCHEDULER_TIMEOUT_S", 1.0)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (tmp_path / "mc.toml").write_text(SMALL)
    out = tmp_path / "sub" / "out"
    code, _, err = _run(["montecarlo", str(tmp_path / "mc.toml"), "--out", str(out), "--scheduler",
                         f"tcp://127.0.0.1:{port}"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Dask scheduler" in err, err
    assert not (tmp_path / "sub").exists()
