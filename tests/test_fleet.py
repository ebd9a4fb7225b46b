"""Fleets on Dask (issue 35 items 3 and 5): ``dynid fleet`` on a real LocalCluster of 2 process workers.

Seven simulated arm3 robots (the URDF perturbed by 5 %, each its own seed), logged with their exact states
(derivatives "measured") and white torque noise, so that each log's reported covariance is its estimate's
true covariance: robot "a" is normal with four dated logs, "b" wears (its shoulder's viscous friction grows
linearly over four dated logs), "e" is an outlier (its forearm twice as heavy as the description's), the
others are normal. Faults: "a" has a log of another robot's joints, "c" a corrupt log, "d" a missing one.
Checked: the pooled estimate is the WLS of the logs' stacked rows (computed here with dense numpy rows); the
outlier is found; the drift is found with the true slope inside its interval and no drift on "a"; the bad
logs fail alone; a worker killed mid-run loses and duplicates nothing; a rerun writes the same bytes.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import doc_text, run_dynid, seed

from dynid._files import save_npz
from dynid.config.fleet import load_fleet_config
from dynid.config.simulate import parse_simulate_config
from dynid.pipeline.simulate import run_simulation

distributed = pytest.importorskip("distributed", reason="dynid fleet runs on dask.distributed (the montecarlo extra)")

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "examples" / "fleet" / "arm3.urdf"
JOINTS = ("yaw", "shoulder", "elbow")
SIGMA = 0.05  # N*m, white torque noise
FV = [0.2, 0.2, 0.1]
FC = [0.3, 0.3, 0.2]
WEAR = 0.1 / 30.0  # robot b: shoulder viscous friction, N*m*s/rad per day
DAYS = (0, 30, 61, 91)
ALPHA = 0.01
ROBOTS = {"a": 4, "b": 4, "c": 2, "d": 2, "e": 2, "f": 2, "g": 2}  # robot -> good logs


def _log(path: Path, robot: int, k: int, urdf: Path, fv: list[float], rng) -> None:
    sim = run_simulation(parse_simulate_config({
        "robot": {"model": str(urdf), "rotor_inertia": [0.05, 0.04, 0.02], "perturbation": 0.05,
                  "perturbation_seed": robot, "friction": {"model": "coulomb_viscous", "fc": FC, "fv": fv}},
        "trajectory": {"kind": "fourier", "base_frequency_hz": 0.2, "harmonics": 3, "fill": 0.5,
                       "max_velocity": 1.5, "max_acceleration": 6.0, "periods": 1, "seed": seed(100 * robot + k)},
        "control": {"rate_hz": 200, "kp": 400, "kd": 40, "model": "true"},
    }, path.parent))
    m = sim.motion
    cols = {"t": m.t}
    for j, jn in enumerate(JOINTS):
        cols[f"q_{jn}"], cols[f"dq_{jn}"], cols[f"ddq_{jn}"] = m.q[:, j], m.dq[:, j], m.ddq[:, j]
        cols[f"tau_{jn}"] = m.tau[:, j] + SIGMA * rng.standard_normal(len(m.t))
    save_npz(path, cols)


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    (d / "logs").mkdir()
    rng = np.random.default_rng(seed(3535))
    heavy = d / "heavy.urdf"  # robot e: a forearm of 2.8 kg where the description says 1.4
    heavy.write_text(URDF.read_text().replace('<mass value="1.4"/>', '<mass value="2.8"/>'))
    rows = ["robot,model,file,date"]
    for n, (robot, count) in enumerate(ROBOTS.items(), start=1):
        for k in range(count):
            fv = list(FV)
            if robot == "b":
                fv[1] += WEAR * DAYS[k]
            name = f"logs/{robot}{k}.npz"
            _log(d / name, n, k, heavy if robot == "e" else URDF, fv, rng)
            date = f"2026-01-{1 + k:02d}" if robot not in ("a", "b") else ["2026-01-01", "2026-01-31", "2026-03-03",
                                                                          "2026-04-02"][k]
            rows.append(f"{robot},arm3,{name},{date}")
    # faults: another robot's joints (a 2-joint log), a corrupt file, a missing file
    save_npz(d / "logs" / "other.npz", {"t": np.arange(1001) * 0.005, **{f"{p}_j{i}": np.zeros(1001) for p in ("q", "tau")
                                                                          for i in (1, 2)}})
    (d / "logs" / "corrupt.npz").write_bytes(b"PK\x03\x04 this is not a zip archive" * 10)
    rows += ["a,arm3,logs/other.npz,2026-05-01", "c,arm3,logs/corrupt.npz,2026-01-09", "d,arm3,logs/missing.npz,"]
    (d / "logs.csv").write_text("\n".join(rows) + "\n")
    sig = lambda p: "{ columns = [" + ", ".join(f'"{p}_{j}"' for j in JOINTS) + "] }"  # noqa: E731
    (d / "arm3.toml").write_text(
        f'[robot]\nmodel = "{URDF}"\nrotor_inertia = [0.05, 0.04, 0.02]\n\n'
        f'[data]\ntime = {{ column = "t" }}\nposition = {sig("q")}\nvelocity = {sig("dq")}\n'
        f'acceleration = {sig("ddq")}\neffort = {sig("tau")}\nrows = [0, 750]\n\n'
        '[validation]\nrows = [750, 1001]\n\n[processing]\nderivatives = "measured"\ntrim_samples = 0\n\n'
        '[identification]\nmethod = "wls"\n')
    (d / "fleet.toml").write_text(f'[fleet]\nlogs = "logs.csv"\nalpha = {ALPHA}\n\n[models]\narm3 = "arm3.toml"\n')
    return d


@pytest.fixture(scope="module")
def cluster():
    """A real LocalCluster: 2 process workers, one thread each (what `dynid fleet` starts by default)."""
    from dynid.fleet.run import local_cluster

    with local_cluster(2) as c, distributed.Client(c, set_as_default=False) as client:
        yield c, client


@pytest.fixture(scope="module")
def run(fleet_dir, cluster):
    from dynid.fleet.run import run_fleet

    cfg = dataclasses.replace(load_fleet_config(fleet_dir / "fleet.toml"), scheduler=cluster[0].scheduler_address)
    return cfg, run_fleet(cfg)


def _rows(cfg, base, path):
    """Dense base-regressor rows (n, joints, p) and efforts (n, joints) of a log's training rows."""
    from dynid.pipeline.data import build_system

    cols = np.load(path)
    q, dq, ddq, tau = (np.column_stack([cols[f"{p}_{j}"] for j in JOINTS])[:750] for p in ("q", "dq", "ddq", "tau"))
    r = build_system(cfg.robot).rows(None)(q, dq, ddq, tau, 0)
    return base.regressor(r.W), r.y


def _homogeneous(rng, n: int, p: int, sig: float):
    """A fleet of ``n`` robots from one population: unit spread per parameter about 5, each robot's own
    estimation error N(0, C_i) with C_i a random correlated matrix of scale ``sig``^2 (robots differ by e^±1)."""
    A = rng.standard_normal((n, p, p))
    covs = (np.einsum("nij,nkj->nik", A, A) / p + 0.1 * np.eye(p)) * (sig**2 * np.exp(rng.uniform(-1, 1, n)))[:, None, None]
    x = 5.0 + rng.standard_normal((n, p)) + np.einsum("nij,nj->ni", np.linalg.cholesky(covs), rng.standard_normal((n, p)))
    return x, covs


def test_the_leave_one_out_distances_are_those_of_their_definition():
    from dynid.fleet.statistics import MAD_TO_STD, _loo_d2

    rng = np.random.default_rng(seed(7))
    for n in (4, 5, 8, 9):  # both parities of the k = n - 1 others (the medians' two cases)
        x, covs = _homogeneous(rng, n, 4, 0.5)
        xs = x + rng.standard_normal((3, n, 4))
        d2 = _loo_d2(xs, covs)[0]
        for b in range(3):
            for r in range(n):
                others = xs[b, [j for j in range(n) if j != r]]
                ref = np.median(others, axis=0)
                s = MAD_TO_STD * np.median(np.abs(others - ref), axis=0)
                total = covs[r] + np.diag((1 + np.pi / (2 * (n - 1))) * s**2)
                want = (xs[b, r] - ref) @ np.linalg.solve(total, xs[b, r] - ref)
                assert d2[b, r] == pytest.approx(want, rel=1e-9)


@pytest.mark.numerics
@pytest.mark.parametrize("sig", [0.1, 1.0])
def test_the_outlier_test_flags_a_homogeneous_fleet_at_most_alpha_of_the_time(sig):
    """100 homogeneous fleets of 8 robots x 10 parameters, the robots' own errors 10 x smaller than their spread
    (``sig`` = 0.1) or as large: the number of fleets with any robot flagged is Binomial(100, q) with q <= alpha
    (conservative: 0.077 and 0.030 measured over 300 fleets); it exceeds the bound below with probability
    below 1e-3 when q = alpha."""
    from scipy.stats import binom

    from dynid.fleet.statistics import outliers

    trials, n, p, alpha = 100, 8, 10, 0.1
    rng = np.random.default_rng(seed(35 + int(10 * sig)))
    flagged = chi2 = 0
    for _ in range(trials):
        res = outliers(*_homogeneous(rng, n, p, sig), alpha)
        flagged += any(o.outlier for o in res)
        chi2 += any(o.d2 > o.chi2_threshold for o in res)
    bound = binom.isf(1e-3, trials, alpha)
    assert flagged <= bound, (flagged, bound)
    if sig == 0.1:
        # why the threshold is simulated: against chi2_p(1 - alpha / n) nearly every such fleet has an "outlier"
        # (0.99 of 300 fleets measured); more than the bound has probability 1e-3 at a rate alpha
        assert chi2 > bound, (chi2, bound)


@pytest.mark.numerics
def test_a_planted_outlier_is_flagged_and_the_threshold_is_reproducible():
    """One robot of a homogeneous fleet moved by 80 population standard deviations in one parameter: its d2
    from that parameter alone is 6400 / ((1 + pi/14) s^2), with s the others' robust spread (relative standard
    error sqrt(1.36 / 7) = 0.44, so s < 2.5 but with probability ~1e-4): above 840, against a simulated
    threshold of about 260 for 8 robots x 10 parameters at alpha = 0.05 (the heavy tail of a MAD of 7 values)."""
    from dynid.fleet.statistics import outliers

    rng = np.random.default_rng(seed(36))
    x, covs = _homogeneous(rng, 8, 10, 0.1)
    x[3, 6] += 80.0
    res = outliers(x, covs, 0.05)
    assert res[3].outlier and res[3].p_value <= 0.05, res[3]
    assert int(np.argmax(res[3].contributions)) == 6
    # a rerun (same machine) gives the same threshold to the bit: the simulation's seed is fixed
    again = outliers(x, covs, 0.05)
    assert [o.threshold for o in again] == [o.threshold for o in res] and [o.p_value for o in again] == [o.p_value for o in res]


@pytest.mark.numerics
def test_pooling_is_the_wls_of_the_stacked_rows(run, fleet_dir):
    from dynid.pipeline import identify

    cfg, res = run
    a = res.robot("a")
    logs = [res.logs[i] for i in a.ok_logs]
    assert len(logs) == 4
    lcfg = cfg.log_config(cfg.logs[0])
    base = identify(lcfg).base
    # independent route: each log's dense rows, its per-joint noise std from its own OLS residuals (dof: rows -
    # parameters acting on the joint) and its WLS residual variance factor s^2 (what its covariance carries);
    # then one weighted solve of all the logs' rows stacked
    blocks = []
    for log in logs:
        W, Y = _rows(lcfg, base, log.file)
        beta_ols = np.linalg.lstsq(np.vstack([W[:, j] for j in range(3)]), Y.T.reshape(-1), rcond=None)[0]
        sig, rss = [], []
        for j in range(3):
            rank = np.count_nonzero(np.linalg.norm(W[:, j], axis=0) > 1e-10 * np.linalg.norm(W[:, j], axis=0).max())
            sig.append(np.sqrt(np.sum((Y[:, j] - W[:, j] @ beta_ols) ** 2) / (len(Y) - rank)))
        A = np.vstack([W[:, j] / sig[j] for j in range(3)])
        b = np.concatenate([Y[:, j] / sig[j] for j in range(3)])
        beta = np.linalg.lstsq(A, b, rcond=None)[0]
        s2 = np.sum((b - A @ beta) ** 2) / (A.shape[0] - A.shape[1])
        blocks.append((A / np.sqrt(s2), b / np.sqrt(s2)))
    A = np.vstack([blk[0] for blk in blocks])
    b = np.concatenate([blk[1] for blk in blocks])
    theta = np.linalg.lstsq(A, b, rcond=None)[0]
    cov = np.linalg.inv(A.T @ A)
    # two backward-stable solves of one least-squares problem agree to ~cond * eps relative to |theta|; the
    # covariances (inverse of A^T A, cond^2) to cond^2 * eps relative to their diagonal
    cond = np.linalg.cond(A)
    eps = np.finfo(float).eps
    assert np.linalg.norm(a.fused.params - theta) <= 1e3 * cond * eps * np.linalg.norm(theta)
    d = np.sqrt(np.diag(cov))
    assert np.max(np.abs(a.fused.cov - cov) / np.outer(d, d)) <= 1e3 * cond**2 * eps
    # the held-out score of the pooled estimate comes from each log's compressed held-out rows: at a log's own
    # estimate they give back what identify reported for that log (the same rows, another route)
    from dynid.fleet.jobs import factor_sse

    for log in logs:
        # the residual sum from the R factor against identify's from the rows: both rounding, amplified by the
        # cancellation |y|^2 / rss (~1e4 with 1 % noise) to ~1e-12 relative; 1e-9 leaves 1e3
        np.testing.assert_allclose(np.sqrt(factor_sse(log.factors, log.params) / log.rows), log.rmse, rtol=1e-9)


@pytest.mark.numerics
def test_the_outlier_and_the_drift_are_found(run):
    cfg, res = run
    e = res.robot("e")
    assert e.outlier is not None and e.outlier.outlier, e.outlier
    b, a = res.robot("b"), res.robot("a")
    assert "fv2" in b.drift_params
    d = b.drift[res.models[0].names.index("fv2")]
    # the true wear rate lies in the trend's interval (level 1 - alpha / p: the parameters' intervals jointly)
    assert d["slope_interval"][0] <= WEAR <= d["slope_interval"][1], d
    # robot a does not change: a drift or change flag on it is a false alarm, at most alpha for each test
    # (Bonferroni over the parameters, conservative): this assertion fails on at most 2 % of the draws
    assert a.drift is not None and a.drift_params == () and a.change_params == (), (a.drift_params, a.change_params)
    # with exact states the logs' covariances are honest: the fleet's scatter factors stay near 1. Each is the
    # square root of a median of 7 ratios chi2(m - 1) / its median (5 robots with m = 2 logs, 2 with 4); with
    # honest covariances the chance that any of the 25 exceeds 2.5 is below 1 % (that null distribution
    # simulated: 99.9 % quantile of one factor 2.32)
    assert np.all(res.models[0].factors < 2.5), res.models[0].factors
    # each robot's pooled estimate beats the nominal model on its held-out rows
    assert all(r.prior["beats_nominal"] for r in res.robots)


def test_bad_logs_fail_alone(run):
    cfg, res = run
    by_file = {Path(log.file).name: log for log in res.logs}
    assert "other.npz" in by_file and "q_yaw" in by_file["other.npz"].error  # the columns it lacks are named
    assert "corrupt.npz" in by_file["corrupt.npz"].error
    assert "not found" in by_file["missing.npz"].error
    assert len(res.failures) == 3
    assert all(log.ok for name, log in by_file.items() if name not in ("other.npz", "corrupt.npz", "missing.npz"))
    assert [len(res.robot(r).ok_logs) for r in ROBOTS] == list(ROBOTS.values())


def test_a_worker_killed_mid_run_loses_and_duplicates_nothing(run, cluster, tmp_path):
    from dynid.fleet.output import write_fleet
    from dynid.fleet.run import run_fleet

    cfg, res = run
    _, client = cluster
    killed = {}

    def kill(done: int) -> None:
        if killed:
            return
        busy = {w: keys for w, keys in client.processing().items() if keys}
        if not busy:
            return
        worker = sorted(busy)[0]
        pid = client.run(os.getpid, workers=[worker])[worker]
        killed.update(done=done, worker=worker, tasks=len(busy[worker]), pid=pid)
        os.kill(pid, signal.SIGKILL)

    again = run_fleet(cfg, on_result=kill)
    assert killed and killed["done"] < len(cfg.logs) and killed["tasks"] > 0, killed  # it died with work on it
    assert [log.index for log in again.logs] == list(range(len(cfg.logs)))  # one result per log, none twice
    # the same results as the undisturbed run, to the byte: the reruns happened elsewhere
    write_fleet(res, tmp_path / "a")
    write_fleet(again, tmp_path / "b")
    for f in sorted((tmp_path / "a").iterdir()):
        if f.name != "timing.json":
            assert f.read_bytes() == (tmp_path / "b" / f.name).read_bytes(), f.name


def test_the_cli_reruns_byte_identical_and_refuses_bad_input(fleet_dir, cluster, tmp_path):
    address = cluster[0].scheduler_address
    for out in ("one", "two"):
        p = run_dynid(["fleet", str(fleet_dir / "fleet.toml"), "--out", str(tmp_path / out), "--scheduler", address,
                       "-q"], tmp_path)
        assert p.returncode == 0, p.stderr
    files = sorted(f.name for f in (tmp_path / "one").iterdir())
    assert {"fleet.json", "report.html", "spread.png", "drift.png", "estimates.npz", "timing.json"} <= set(files)
    for name in files:
        if name != "timing.json":
            assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes(), name
    doc = json.loads((tmp_path / "one" / "fleet.json").read_text())
    assert doc["n_failed"] == 3 and [r["robot"] for r in doc["robots"]] == list(ROBOTS)
    # bad input: one line, exit 2, no output folder
    bad = tmp_path / "bad.toml"
    (tmp_path / "bad.csv").write_text(f"robot,model,file,weight\na,arm3,{fleet_dir / 'logs' / 'a0.npz'},3\n")
    for text, says in ((None, "config file not found"),
                       (f'[fleet]\nlogs = "bad.csv"\n[models]\narm3 = "{fleet_dir / "arm3.toml"}"\n',
                        "unknown column ['weight']"),
                       (f'[fleet]\nlogs = "{fleet_dir / "logs.csv"}"\nalpha = 1.5\n[models]\narm3 = "{fleet_dir / "arm3.toml"}"\n',
                        "fleet.alpha: must be in (0, 1)"),
                       (f'[fleet]\nlogs = "{fleet_dir / "logs.csv"}"\nspeed = 2\n[models]\narm3 = "{fleet_dir / "arm3.toml"}"\n',
                        "unknown key fleet.speed"),
                       (f'[fleet]\nlogs = "{fleet_dir / "logs.csv"}"\n[models]\narm4 = "{fleet_dir / "arm3.toml"}"\n',
                        "'arm3' is not in [models]")):
        bad.unlink(missing_ok=True)
        if text is not None:
            bad.write_text(text)
        p = run_dynid(["fleet", str(bad), "--out", str(tmp_path / "never")], tmp_path)
        assert p.returncode == 2 and p.stderr.startswith("dynid: error:") and says in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1 and not (tmp_path / "never").exists()


@pytest.mark.numerics
def test_the_fleet_example_runs_as_the_readme_says(tmp_path):
    """The guide's "Fleets" (docs/guide/fleets.md): its commands, as written there, in a copy of examples/fleet
    (a LocalCluster of its own)."""
    import subprocess

    ex = tmp_path / "fleet"
    shutil.copytree(ROOT / "examples" / "fleet", ex, ignore=shutil.ignore_patterns("logs", "logs.csv", "out"))
    section = doc_text("fleets")
    block = section[section.index("```bash") + 7:section.index("```", section.index("```bash") + 7)]
    commands = [line.split("#")[0].split() for line in block.strip().splitlines() if line.strip()]
    assert [c[0] for c in commands] == ["python", "dynid"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    p = subprocess.run([sys.executable, *commands[0][1:]], cwd=ex, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    p = run_dynid(commands[1][1:], ex)
    assert p.returncode == 0, p.stderr
    out = ex / commands[1][commands[1].index("--out") + 1]
    doc = json.loads((out / "fleet.json").read_text())
    robots = {r["robot"]: r for r in doc["robots"]}
    assert [r for r, v in robots.items() if v["outlier"]["outlier"]] == ["r4", "r5"]  # the heavy forearm; the wear
    assert robots["r5"]["drifting_parameters"] == ["fv2"]
    fv2 = robots["r5"]["drift"][doc["models"][0]["names"].index("fv2")]
    lo, hi = fv2["slope_interval"]
    assert lo <= 0.1 / 30 <= hi  # make_logs.py's wear: 0.1 N*m*s/rad a month of 30 days
    assert doc["n_failed"] == 1 and "r3_2026-05-15.csv" in [log for log in doc["logs"] if not log["ok"]][0]["file"]
    assert "Fleet report" in (out / "report.html").read_text()
