"""bench/kalman_twins.py (issue 36, item 4), quick version: it runs both twins through the two
processings and exact states and prints its tables. A comparison, not a check: only that it runs
and that its reference figures are what they must be (exact states: the truth at the force noise)."""

from __future__ import annotations

import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "bench"))
import kalman_twins as study  # noqa: E402


def test_quick_run_prints_both_tables(capsys):
    assert study.main(["--quick"]) == 0
    out = capsys.readouterr().out
    for robot in ("rps3", "hexapod"):
        assert f"{robot}, draw 0: training" in out
    assert out.count("(c) gap processed / exact, sum") == 2


def test_exact_states_are_the_floor(tmp_path):
    run = study.run_robot("rps3", True, tmp_path)
    exact = run["columns"]["exact states"]
    # on exact states the truth's error is the force noise (5 N a leg), its gap 1
    for t, n in zip(exact["truth_exact"], exact["noise"]):
        assert abs(t - n) < 0.05 * n and 4.5 < n < 5.5
    for p in study.PROCESSINGS:
        c = run["columns"][p]
        assert sum(c["truth_processed"]) > sum(c["truth_exact"])
