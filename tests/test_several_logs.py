"""Several experiments in one identification: ``[[data]]`` / ``[[validation]]`` (issue 35 item 1).

Two virtual experiments of the serial arm arm3 (its URDF's parameters perturbed by 10 %: the truth) under
computed torque, logged with their exact states (derivatives "measured") and efforts with different noise
levels (0.02 and 0.4 N*m). The [[data]] estimate must be the WLS of the two experiments' rows stacked with a
weight per (experiment, joint) from the pooled OLS residuals, computed here with dense numpy rows; the truth
must lie within the reported 95 % intervals; the naive concatenation of the two logs, filtered across the join,
must give another estimate; the pooled held-out table must be the row-weighted mean of the per-log MSEs;
methods that cannot stack experiments refuse them in one line.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import doc_text, seed
from scipy import stats

from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import ConfigError
from dynid.pipeline import identify
from dynid.pipeline.data import build_system
from dynid.pipeline.simulate import run_simulation

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "examples" / "several_logs" / "arm3.urdf"
SIGMAS = (0.02, 0.4)  # N*m: a clean and a noisy log
JOINTS = ("j1", "j2", "j3")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("several")
    rng = np.random.default_rng(seed(35))
    truth = None
    names = {}
    for name, k, sigma in (("a", 1, SIGMAS[0]), ("b", 2, SIGMAS[1]), ("va", 3, SIGMAS[0]), ("vb", 4, SIGMAS[1])):
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": str(URDF), "rotor_inertia": [0.05, 0.04, 0.02], "perturbation": 0.1,
                      "perturbation_seed": 1},
            "trajectory": {"kind": "fourier", "base_frequency_hz": 0.2, "harmonics": 3, "fill": 0.5,
                           "max_velocity": 1.5, "max_acceleration": 6.0, "periods": 1, "seed": seed(k)},
            "control": {"rate_hz": 200, "kp": 400, "kd": 40, "model": "true"},
        }, d))
        m = sim.motion
        truth = sim.truth
        cols = {"t": m.t}
        for j, jn in enumerate(JOINTS):
            cols[f"q_{jn}"], cols[f"dq_{jn}"], cols[f"ddq_{jn}"] = m.q[:, j], m.dq[:, j], m.ddq[:, j]
            cols[f"tau_{jn}"] = m.tau[:, j] + sigma * rng.standard_normal(len(m.t))
        save_npz(d / f"{name}.npz", cols)
        names[name] = cols
    return d, truth, names


def _table(path, measured: bool = True) -> dict:
    sig = lambda p: {"columns": [f"{p}_{j}" for j in JOINTS]}  # noqa: E731
    states = {"velocity": sig("dq"), "acceleration": sig("ddq")} if measured else {}
    return {"file": str(path), "time": {"column": "t"}, "position": sig("q"), **states, "effort": sig("tau")}


def _doc(d, **identification) -> dict:
    return {"robot": {"model": str(URDF), "rotor_inertia": [0.05, 0.04, 0.02]},
            "data": [_table(d / "a.npz"), {**_table(d / "b.npz"), "payload": False}],
            "validation": [_table(d / "va.npz"), _table(d / "vb.npz")],
            "processing": {"derivatives": "measured", "trim_samples": 0},
            "identification": {"method": "wls", **identification}, "output": {"plots": False}}


def _rows(cfg, base, cols):
    """Dense base-regressor rows (n, joints, p) and efforts (n, joints) of a log, straight from the model."""
    system = build_system(cfg.robot)
    q, dq, ddq, tau = (np.column_stack([cols[f"{p}_{j}"] for j in JOINTS]) for p in ("q", "dq", "ddq", "tau"))
    r = system.rows(None)(q, dq, ddq, tau, 0)
    return base.regressor(r.W), r.y


@pytest.mark.numerics
def test_several_logs_are_the_wls_of_their_stacked_rows_and_cover_the_truth(logs, tmp_path):
    d, truth, cols = logs
    cfg = parse_config(_doc(d), d)
    out = identify(cfg)
    res = out.result
    # independent route: dense rows of each log, pooled OLS, a noise variance per (log, joint) from its
    # residuals (dof: rows - parameters acting on the joint), then the weighted solve of everything stacked
    blocks = [_rows(cfg, out.base, cols[n]) for n in ("a", "b")]
    A = np.vstack([W[:, j, :] for W, _ in blocks for j in range(3)])
    y = np.concatenate([Y[:, j] for _, Y in blocks for j in range(3)])
    beta_ols = np.linalg.lstsq(A, y, rcond=None)[0]
    w = []
    for W, Y in blocks:
        for j in range(3):
            Wj = W[:, j, :]
            rank = np.count_nonzero(np.linalg.norm(Wj, axis=0) > 1e-10 * np.linalg.norm(Wj, axis=0).max())
            w.append(np.full(len(Y), 1.0 / np.sqrt(np.sum((Y[:, j] - Wj @ beta_ols) ** 2) / (len(Y) - rank))))
    w = np.concatenate(w)
    beta = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
    # two solves of the same weighted problem differ by ~cond * eps relative to |beta| (backward-stable QR)
    cond = np.linalg.cond(A * w[:, None])
    assert np.linalg.norm(res.params - beta) <= 1e3 * cond * np.finfo(float).eps * np.linalg.norm(beta)
    # the weights: each log's noise level, not one per joint for both. 1001 rows a joint: a residual std is known
    # to 1/sqrt(2 n) = 2.2 %; the noisy log's is its noise (0.4 N*m; 10 % = 4.5 of those std, and a model
    # mismatch of the clean log's size adds < 0.5 % in quadrature); the clean log's cannot be below its noise
    # (0.02 N*m, same 10 %) and is at most twice it (what the simulated plant adds beyond the model, < 0.035 N*m)
    exps = res.provenance["experiments"]
    assert [e["payload"] for e in exps] == [None, False]
    np.testing.assert_allclose(exps[1]["noise_std"], SIGMAS[1], rtol=0.1)
    assert np.all(np.array(exps[0]["noise_std"]) > 0.9 * SIGMAS[0]) and np.all(np.array(exps[0]["noise_std"]) < 2 * SIGMAS[0])
    for e in exps:
        assert e["rows_used"] == [1001] * 3 and e["rate_hz"] == pytest.approx(200.0)
    # truth: Bonferroni family of 99.9 % for all base parameters (exact states, white noise: normal z-scores)
    names = truth["base_parameters"]["names"]
    assert tuple(names) == tuple(res.names)
    z = (res.params - np.asarray(truth["base_parameters"]["true_values"])) / res.bse
    assert np.max(np.abs(z)) < stats.norm.ppf(1 - 0.0005 / len(z)), dict(zip(names, np.round(z, 2)))
    # outside the 95 % intervals: at most the binomial 99.9 % quantile of p draws at 5 %
    assert np.sum(np.abs(z) > 1.96) <= stats.binom.ppf(0.999, len(z), 0.05)
    # result.json and summary.txt carry the experiments and the per-log validation tables
    from dynid.pipeline.identification import write_outputs
    import json

    write_outputs(out, tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    prov = doc["result"]["provenance"] if "result" in doc else doc["provenance"]
    assert [Path(e["files"][0]).name for e in prov["experiments"]] == ["a.npz", "b.npz"]
    assert [v["label"] for v in prov["validation_logs"]] == ["validation[0]", "validation[1]"]
    summary = (tmp_path / "out" / "summary.txt").read_text()
    assert "Experiments ([[data]])" in summary and "validation[1]" in summary and "pooled" in summary
    # dynid predict with the two validation logs as [[data]]: each scored on its own as identify scored it
    from dynid.pipeline.predict import predict_logs, write_predictions

    sig = lambda p: "{ columns = [" + ", ".join(f'"{p}_{j}"' for j in JOINTS) + "] }"  # noqa: E731
    (tmp_path / "logs.toml").write_text("".join(
        f'[[data]]\nfile = "{d / n}"\ntime = {{ column = "t" }}\nposition = {sig("q")}\nvelocity = {sig("dq")}\n'
        f'acceleration = {sig("ddq")}\neffort = {sig("tau")}\n\n' for n in ("va.npz", "vb.npz")))
    outcomes, per_log, pooled = predict_logs(tmp_path / "out", tmp_path / "logs.toml")
    for mine, theirs in zip(per_log, prov["validation_logs"]):
        np.testing.assert_allclose(mine["rmse"], theirs["rmse"], rtol=1e-9)  # the same model, rows and processing
    np.testing.assert_allclose(pooled["rmse"], prov["validation_pooled"]["rmse"], rtol=1e-9)
    written = write_predictions(outcomes, per_log, pooled, tmp_path / "pred", plots=False)
    assert written == ["predict.json", "summary.txt"]
    assert "pooled" in (tmp_path / "pred" / "summary.txt").read_text()


@pytest.mark.numerics
def test_per_log_validation_tables_and_the_pooled_one(logs):
    d, _, cols = logs
    cfg = parse_config(_doc(d), d)
    out = identify(cfg)
    res = out.result
    per_log, pooled = res.provenance["validation_logs"], res.provenance["validation_pooled"]
    errs = []
    for v, n in zip(per_log, ("va", "vb")):  # each log's table = its own dense residuals
        W, Y = _rows(cfg, out.base, cols[n])
        e = Y - np.einsum("njp,p->nj", W, res.params)
        errs.append(e)
        np.testing.assert_allclose(v["rmse"], np.sqrt(np.mean(e**2, axis=0)), rtol=1e-9)
        assert v["rows"] == [len(e)] * 3
    # pooled: the sum of squared errors over both logs' rows; RMSE^2 = row-weighted mean of the logs' MSEs
    np.testing.assert_allclose(pooled["rmse"], np.sqrt(np.mean(np.vstack(errs) ** 2, axis=0)), rtol=1e-9)
    n = np.array([v["rows"] for v in per_log], float)
    mse = np.array([v["rmse"] for v in per_log]) ** 2
    np.testing.assert_allclose(np.square(pooled["rmse"]), (n * mse).sum(0) / n.sum(0), rtol=1e-12)
    # the noisy log's held-out error is its noise (0.4 N*m), the clean one's 0.02: the tables differ
    assert np.all(np.array(per_log[1]["rmse"]) > 5 * np.array(per_log[0]["rmse"]))


@pytest.mark.numerics
def test_a_filter_across_the_join_of_concatenated_logs_changes_the_estimate(logs, tmp_path):
    """The naive route: the two logs concatenated by hand (b's time following a's) and differentiated and
    low-passed as one log: the filter runs across the join, where the positions jump."""
    d, _, cols = logs
    a, b = cols["a"], cols["b"]
    dt = a["t"][1] - a["t"][0]
    joined = {k: np.concatenate([a[k], b[k] + (a["t"][-1] + dt - b["t"][0]) if k == "t" else b[k]]) for k in a}
    from dynid._files import save_npz

    save_npz(tmp_path / "joined.npz", joined)
    processing = {"derivatives": "central", "lowpass": {"cutoff_hz": 10.0}, "trim_samples": 10}
    doc = {**_doc(d), "processing": processing, "data": [_table(d / "a.npz", False), _table(d / "b.npz", False)],
           "validation": _table(d / "va.npz", False)}
    several = identify(parse_config(doc, d)).result
    single = identify(parse_config({**doc, "data": _table(tmp_path / "joined.npz", False)}, d)).result
    # the join: the positions jump by |q_b(0) - q_a(end)|; differentiated and filtered across it, the
    # accelerations there are spikes no motion had: the estimates differ by many standard errors
    jump = np.abs([b[f"q_{j}"][0] - a[f"q_{j}"][-1] for j in JOINTS]).max()
    assert jump > 0.05
    z = np.abs(single.params - several.params) / several.bse
    assert z.max() > 10, z


def test_methods_that_cannot_stack_experiments_refuse_them(logs, tmp_path):
    d, _, _ = logs
    for ident, word in (({"method": "iv"}, "method = 'iv'"), ({"method": "ml"}, "method = 'ml'"),
                        ({"method": "gm"}, "method = 'gm'"), ({"method": "ols", "covariance": "hac"}, "covariance")):
        with pytest.raises(ConfigError, match=word) as e:
            identify(parse_config(_doc(d, **ident), d))
        assert "\n" not in str(e.value) and "[[data]] experiments" in str(e.value)
    doc = _doc(d)
    doc["processing"] = {**doc["processing"], "periodic": {"period_s": 5.0}}
    with pytest.raises(ConfigError, match="processing.periodic"):
        identify(parse_config(doc, d))
    # a single [data] table in an array keeps the single-log path (no experiments in the result)
    one = _doc(d)
    one["data"], one["validation"] = one["data"][:1], one["validation"][:1]
    res = identify(parse_config(one, d)).result
    assert "experiments" not in res.provenance


def test_each_experiment_converts_its_currents_with_its_own_drive_gains(logs, tmp_path):
    """Experiment b logged as motor currents through other sensors (gains 2.5, 0.8, 1.7 N*m/A): with
    those gains in its effort table the identification is the one of the torque logs (the currents are
    the torques divided by the gains: the same numbers to rounding; 1e-9 of each std is many
    orders above the rounding a division and a product add, ~1e-16 relative, through cond ~1e3)."""
    d, _, names = logs
    gains = np.array([2.5, 0.8, 1.7])
    cols = dict(names["b"])
    for j, jn in enumerate(JOINTS):
        cols[f"tau_{jn}"] = cols[f"tau_{jn}"] / gains[j]
    save_npz(tmp_path / "b_current.npz", cols)
    ref = identify(parse_config(_doc(d), d)).result
    doc = _doc(d)
    current = _table(tmp_path / "b_current.npz")
    current["effort"] = {**current["effort"], "kind": "current", "unit": "A", "drive_gains": gains.tolist()}
    doc["data"] = [doc["data"][0], current]
    res = identify(parse_config(doc, d)).result
    np.testing.assert_allclose(res.params, ref.params, rtol=0, atol=1e-9 * np.min(ref.bse))
    # without its gains (the robot has none) the log's currents are not torques: not mixed with torque logs
    doc["data"][1]["effort"] = {k: v for k, v in current["effort"].items() if k != "drive_gains"}
    with pytest.raises(ConfigError, match=r"data\[1\]: its efforts are current \(unknown gains\), data\[0\]'s torque"):
        identify(parse_config(doc, d))
    with pytest.raises(ConfigError, match=r"drive_gains convert motor currents: they need .*kind = 'current'"):
        parse_config({**doc, "data": [doc["data"][0], {**_table(d / "b.npz"), "effort": {
            "columns": [f"tau_{j}" for j in JOINTS], "drive_gains": [1.0, 1.0, 1.0]}}]}, d)
    with pytest.raises(ConfigError, match="2 gains for 3 columns"):
        parse_config({**doc, "data": [doc["data"][0], {**current, "effort": {**current["effort"], "drive_gains": [1.0, 2.0]}}]}, d)


def test_the_several_logs_example_runs_as_the_readme_says(tmp_path):
    """The guide's "Several logs in one identification" (docs/guide/several-logs.md): the three commands, as
    written there, in a copy of the folder."""
    import json
    import shutil

    from conftest import run_dynid

    ex = tmp_path / "several_logs"
    shutil.copytree(ROOT / "examples" / "several_logs", ex)
    section = doc_text("several-logs")
    block = section[section.index("```bash") + 7:section.index("```", section.index("```bash") + 7)]
    commands = [line.split("#")[0].split()[1:] for line in block.strip().splitlines() if line.startswith("dynid ")]
    assert len(commands) == 3
    for args in commands:
        p = run_dynid(args, ex)
        assert p.returncode == 0, p.stderr
    doc = json.loads((ex / "id" / "result.json").read_text())
    prov = doc["result"]["provenance"] if "result" in doc else doc["provenance"]
    clean, noisy = (np.array(e["noise_std"]) for e in prov["experiments"])
    # the noisy run adds 1.0 N*m of white noise, low-passed at 15 Hz of a 50 Hz band: about 1.0^2 * 15/50 = 0.3
    # N^2 m^2 more variance than the clean run (a factor 2 either way: the two motions' own processing errors
    # and the filter's transition band)
    extra = noisy**2 - clean**2
    assert np.all((extra > 0.15) & (extra < 0.6)), extra
    per_log, pooled = prov["validation_logs"], prov["validation_pooled"]
    n = np.array([v["rows"] for v in per_log], float)
    np.testing.assert_allclose(np.square(pooled["rmse"]),
                               (n * np.square([v["rmse"] for v in per_log])).sum(0) / n.sum(0), rtol=1e-12)
    summary = (ex / "id" / "summary.txt").read_text()
    assert "Held-out error per validation log" in summary and "the identified model beats the nominal model" in summary
    report = (ex / "id" / "report.html").read_text()
    assert "Experiments ([[data]])" in report and "<td>validation[1]</td>" in report and "pooled" in report


def test_the_cli_refuses_in_one_line(logs, tmp_path):
    from conftest import run_dynid

    d, _, _ = logs
    sig = lambda p: "{ columns = [" + ", ".join(f'"{p}_{j}"' for j in JOINTS) + "] }"  # noqa: E731
    table = lambda n: (f'file = "{d / n}"\ntime = {{ column = "t" }}\nposition = {sig("q")}\n'  # noqa: E731
                       f'velocity = {sig("dq")}\nacceleration = {sig("ddq")}\neffort = {sig("tau")}\n')
    text = (f'[robot]\nmodel = "{URDF}"\nrotor_inertia = [0.05, 0.04, 0.02]\n\n[[data]]\n{table("a.npz")}\n'
            f'[[data]]\n{table("b.npz")}\n[validation]\n{table("va.npz")}\n'
            '[processing]\nderivatives = "measured"\ntrim_samples = 0\n\n[identification]\nmethod = "didim"\n')
    (tmp_path / "c.toml").write_text(text)
    p = run_dynid(["identify", str(tmp_path / "c.toml"), "--out", str(tmp_path / "id")], tmp_path)
    assert p.returncode == 2 and p.stderr.startswith("dynid: error: data: 2 [[data]] experiments, but "
                                                     "identification.method = 'didim'"), p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and not (tmp_path / "id").exists()
