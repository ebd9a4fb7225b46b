"""Paper 000's Tables 4–6 on the 3-RPS twin (dynid.studies.paper000, ``dynid identifiability``).

The quick study runs once per module (simulated logs kept in a temporary folder); the tests
check what the procedure guarantees, each figure recomputed by another route where one exists:
the model sequence (counts, threshold), the condition numbers and ε_RA from the full regressor
of each log (no chunks, no incremental QR), the truth's friction terms, and the command line.
"""

from __future__ import annotations

import csv
import json
import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import draw, run_dynid, snapshot

from dynid.config import parse_config
from dynid.errors import InputError
from dynid.pipeline.data import build_system, preprocess, read_log, to_actuator_space
from dynid.pipeline.identifiability import PAPER_COUNTS, paper_models, truth_base
from dynid.pipeline.identification import row_mask
from dynid.studies.paper000 import LOW_SPEED, TESTS, identify_config, paper000_study


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper000")
    return SimpleNamespace(folder=folder, result=paper000_study(quick=True, folder=folder, draw=draw()))


# ---------------------------------------------------------------------- models 1-4
def test_paper_models_follow_the_papers_counts():
    """A one-at-a-time sequence 37 -> 12 gives the paper's models 37, 24, 18, 12."""
    steps = tuple(SimpleNamespace(names=tuple(f"p{i}" for i in range(n))) for n in range(37, 11, -1))
    picks = paper_models(SimpleNamespace(steps=steps))
    assert [len(steps[i].names) for i in picks] == list(PAPER_COUNTS)
    short = tuple(SimpleNamespace(names=("a",) * n) for n in (5, 4))
    assert paper_models(SimpleNamespace(steps=short)) == (0, 1)  # coinciding models listed once


@pytest.mark.numerics
def test_models_lose_parameters_and_the_last_is_identified(study):
    out = study.result.outcome
    counts = [len(out.step(k).names) for k in range(len(out.models))]
    # the rps3 twin with Ia, fv, fc+, fc- on the legs: 25 rigid-body + 12 joint terms, the paper's model 1
    assert counts[0] == 37 == out.base.n_base
    assert all(a > b for a, b in zip(counts, counts[1:]))
    assert out.models[-1] == len(out.sequence.steps) - 1
    final = out.step(len(out.models) - 1)
    assert np.all(final.result.rel_std < out.sequence.threshold_pct)  # what the search stops on
    for k in range(len(out.models)):
        s = out.step(k)
        assert s.n_identified == int(np.sum(s.result.rel_std < 15.0))
        assert out.properly_identified(k) <= s.n_identified
        assert set(out.marked[k]) <= set(s.names)
        assert (not out.marked[k]) == out.feasibility[k].feasible
    # every removed parameter was, when removed, the least certain one and above the threshold
    for a, b in zip(out.sequence.steps, out.sequence.steps[1:]):
        (gone,) = set(a.names) - set(b.names)
        assert gone == a.worst and a.max_rel_std >= 15.0


def test_the_truth_column_is_the_plants_friction(study):
    out = study.result.outcome
    truth = json.loads((study.folder / "train" / "truth.json").read_text())
    std = dict(zip(truth["parameter_names"], truth["true_parameters"]))
    base = dict(zip(out.base.names, out.truth))
    for leg in ("P1", "P2", "P3"):  # joint terms are base parameters of their own
        assert base[f"fc_{leg}"] == pytest.approx(std[f"fc_{leg}"], rel=1e-12)
        assert base[f"fv_{leg}"] == pytest.approx(std[f"fv_{leg}"], rel=1e-12)
        assert base[f"offset_{leg}"] == 0.0  # the plant has none
    assert any("offset_P1" in note for note in out.notes)
    with pytest.raises(InputError, match="no value"):
        truth_base({"parameter_names": ["m_R1"], "true_parameters": [1.0]}, out.base)


def test_asymmetric_friction_truth_from_a_symmetric_plant():
    """fc+ / fc- of a model without fc carry the plant's symmetric fc (fc- is the force at
    negative velocity: -fc); beside fc they are 0."""
    from dynid.pipeline.identifiability import _derived

    values = {"fc_P1": 228.0, "fv_P1": 3272.0}
    assert _derived("fc+_P1", values, set()) == 228.0
    assert _derived("fc-_P1", values, set()) == -228.0
    assert _derived("fv-_P1", values, set()) == 3272.0
    assert _derived("fc-_P1", values, {"fc_P1"}) == 0.0
    assert _derived("offset_P1", values, set()) == 0.0
    assert _derived("m_P1", values, set()) is None


# ---------------------------------------------------------------------- Table 4 by another route
def _full_rows(folder: Path, k: int, outcome):
    """Processed log ``k`` (0: training) -> the stacked base regressor of each channel over the
    rows the processing keeps, in one piece."""
    log = folder / f"test{max(k, 1)}" / "log.npz"
    cfg = parse_config(identify_config(folder / "train" / "log.npz", log), folder)
    spec = cfg.data if k == 0 else cfg.validation
    system = build_system(cfg.robot)
    raw = read_log(spec, system.n_actuators, system.actuator_names, "log")
    ds, _ = preprocess(to_actuator_space(raw, system, "log")[0], cfg.processing, "log")
    r = system.rows(None)(ds.q, ds.dq, ds.ddq, ds.tau, 0)
    W = outcome.base.regressor(r.W)
    mask = row_mask(system, None, ds.dq, cfg.processing.min_velocity, joint_dq=r.joint_dq)
    n, n_ch = r.y.shape
    m = np.ones((n, n_ch), bool) if mask is None else (np.repeat(mask[:, None], n_ch, 1) if mask.ndim == 1 else mask)
    return [(W[m[:, j], j, :], r.y[m[:, j], j]) for j in range(n_ch)]


def _eps_ra(rows, beta) -> float:
    """Paper 000 Eq. 33, pooled over the channels (each about its own mean)."""
    num = sum(np.sum(np.abs(y - W @ beta)) for W, y in rows)
    den = sum(np.sum(np.abs(y - y.mean())) for W, y in rows)
    return 100.0 * num / den


def test_table4_condition_numbers_and_eps_ra_by_another_route(study):
    out = study.result.outcome
    names = [t.name for t in out.tests]
    assert names == ["training"] + [name for name, *_ in TESTS]
    assert [t.in_sample for t in out.tests] == [True] + [False] * len(TESTS)
    idx = {n: i for i, n in enumerate(out.base.names)}
    betas = {}
    for k, lab in enumerate(out.labels):
        s = out.step(k)
        beta = np.zeros(out.base.n_base)
        beta[[idx[n] for n in s.names]] = s.result.params
        betas[lab] = (beta, [idx[n] for n in s.names])
    for k, t in enumerate(out.tests):
        rows = _full_rows(study.folder, k, out)
        W = np.vstack([w for w, _ in rows])
        assert t.n_rows == W.shape[0]
        for lab, (beta, cols) in betas.items():
            assert t.condition_number[lab] == pytest.approx(np.linalg.cond(W[:, cols]), rel=1e-6)
            Ws = W[:, cols] / np.linalg.norm(W[:, cols], axis=0)
            assert t.scaled_condition_number[lab] == pytest.approx(np.linalg.cond(Ws), rel=1e-6)
            assert t.eps_ra[lab] == pytest.approx(_eps_ra(rows, beta), rel=1e-9)
            assert math.isfinite(t.eps_ra[lab]) and t.eps_ra[lab] > 0
        assert t.eps_ra["true"] == pytest.approx(_eps_ra(rows, out.truth), rel=1e-9)
        assert t.eps_ra["nominal"] == pytest.approx(_eps_ra(rows, out.base.from_standard(
            build_system(out.config.robot).nominal_parameters())), rel=1e-9)
        # the final model against the full one: the triangle inequality on Eq. 33 bounds the change
        # by the forces the two models predict differently, |W (beta_1 - beta_4)|
        b1, b4 = betas[out.labels[0]][0], betas[out.labels[-1]][0]
        den = sum(np.sum(np.abs(y - y.mean())) for _, y in rows)
        margin = 100.0 * np.sum(np.abs(W @ (b1 - b4))) / den
        assert abs(t.eps_ra[out.labels[-1]] - t.eps_ra[out.labels[0]]) <= margin * (1 + 1e-9)
    low = next(t for t in out.tests if t.name == LOW_SPEED)
    speeds = study.result.trajectories
    assert speeds[LOW_SPEED]["max_leg_speed"] < 0.5 * min(speeds[n]["max_leg_speed"] for n, *_ in TESTS[:-1])
    assert low.n_rows > out.base.n_base


def test_table6_eps_av_is_eq34_on_the_nonzero_truth(study):
    out = study.result.outcome
    for k in range(len(out.models)):
        s = out.step(k)
        true = np.array([out.truth[out.base.names.index(n)] for n in s.names])
        keep = true != 0
        expect = 100 * np.mean(np.abs(true[keep] - s.result.params[keep]) / np.abs(true[keep]))
        assert out.eps_av(k) == pytest.approx(expect, rel=1e-12)
    text = out.summary_text()
    for title in ("Table 4", "Table 5", "Table 6"):
        assert title in text


# ---------------------------------------------------------------------- command line
def _toml(doc: dict) -> str:
    d, v = doc["data"], doc["validation"]
    return f"""\
[robot]
model = "builtin:rps3"
extras = {json.dumps(doc["robot"]["extras"])}

[data]
file = "{d["file"]}"
time = {{ column = "t", unit = "s" }}
position = {{ columns = {json.dumps(d["position"]["columns"])}, unit = "m" }}
effort = {{ columns = {json.dumps(d["effort"]["columns"])}, kind = "torque", unit = "N" }}

[validation]
file = "{v["file"]}"

[processing]
lowpass = {{ cutoff_hz = 10.0, order = 4, filter_effort = false }}
min_velocity = {doc["processing"]["min_velocity"]}

[identification]
method = "{doc["identification"]["method"]}"
"""


def test_cli_identifiability_round_trip_and_bad_input(study, tmp_path):
    f = study.folder
    doc = identify_config(f / "train" / "log.npz", f / "test1" / "log.npz")
    (tmp_path / "cfg.toml").write_text(_toml(doc))
    r = run_dynid(["identifiability", "cfg.toml", "--out", "out", "--truth", str(f / "train" / "truth.json"), "-q"],
                  tmp_path)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == ["identifiability.json", "models.csv", "tables.txt", "tests.csv"]
    res = json.loads((out / "identifiability.json").read_text())
    counts = [m["n_params"] for m in res["models"]]
    assert counts[0] == 37 and all(a > b for a, b in zip(counts, counts[1:]))
    with open(out / "models.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == sum(counts)
    final = [row for row in rows if row["model"] == res["models"][-1]["model"]]
    assert all(float(row["rel_std_pct"]) < 15.0 for row in final)
    assert all(row["truth"] != "" for row in rows)
    with open(out / "tests.csv") as fh:
        tests = list(csv.DictReader(fh))
    assert [t["trajectory"] for t in tests] == ["training", "validation"]
    assert all(math.isfinite(float(t["eps_ra_model1"])) and float(t["eps_ra_true"]) > 0 for t in tests)
    assert "Table 6" in (out / "tables.txt").read_text()

    # bad input: one line, exit 2, the output folder untouched
    before = snapshot(out)
    (tmp_path / "ml.toml").write_text(_toml({**doc, "identification": {"method": "ml"}}))
    (tmp_path / "bad.json").write_text("{not json")
    cases = ((["ml.toml", "--out", "out"], "use 'ols' or 'wls'"),
             (["cfg.toml", "--out", "out", "--truth", "bad.json"], "not JSON"),
             (["cfg.toml", "--out", "out", "--threshold", "-5"], "positive number of percent"))
    with ThreadPoolExecutor(len(cases)) as pool:
        results = list(pool.map(lambda c: run_dynid(["identifiability", *c[0]], tmp_path), cases))
    for (_, words), r in zip(cases, results):
        assert r.returncode == 2, r.stderr
        assert "Traceback" not in r.stderr
        lines = r.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("dynid: error:") and words in lines[0], r.stderr
    assert snapshot(out) == before
