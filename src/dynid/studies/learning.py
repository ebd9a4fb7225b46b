"""Ablation of paper 003, Table 1: PI-RNN, PI-GRU and PI-LSTM trained on the same residual, the
same features, loss and seed; held-out RMSE overall and in the low-speed region (|q̇| < 0.5 rad/s),
and the epochs to converge (the epoch of the kept weights, mean over joints).

    from dynid.studies.learning import ablation_from_outcome, table
    rows = ablation_from_outcome(identify(load_config("identify.toml")))   # any [learning] section
    print(table(rows))

``quick=True`` trains a few epochs with a small hidden layer (the test's version).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.learning import MODELS, LearningConfig, fit_residual
from dynid.pipeline.outcome import IdentifyOutcome
from dynid.pipeline.rows import _model_rows
from dynid.pipeline.learning import LOW_SPEED, linear_friction

__all__ = ["ablation", "ablation_from_outcome", "table", "QUICK"]

QUICK = dict(epochs=25, hidden=16, patience=10, max_seconds=60.0)


def _row(name: str, err: FloatArray, slow: np.ndarray, epochs: float, seconds: float) -> dict[str, Any]:
    return {"model": name, "rmse": float(np.sqrt(np.mean(err**2))),
            "rmse_per_joint": np.sqrt(np.mean(err**2, axis=0)).tolist(),
            "low_speed_rmse": float(np.sqrt(np.mean(err[slow] ** 2))) if slow.any() else float("nan"),
            "epochs_to_converge": epochs, "seconds": seconds}


def ablation(train: tuple[FloatArray, FloatArray, FloatArray], held_out: tuple[FloatArray, FloatArray, FloatArray],
             friction: dict[str, FloatArray] | None = None, config: LearningConfig | None = None,
             models: tuple[str, ...] = MODELS, quick: bool = False, progress=None) -> list[dict[str, Any]]:
    """``train`` and ``held_out``: (velocities, accelerations, residual of the identified model),
    each (n, n_j). One row for the identified model alone, then one per network kind."""
    base = config or LearningConfig()
    if quick:
        base = dataclasses.replace(base, **QUICK)
    dq_v, ddq_v, r_v = held_out
    slow = np.abs(dq_v) < LOW_SPEED
    rows = [_row("identified model alone", r_v, slow, float("nan"), float("nan"))]
    for kind in models:
        cfg = dataclasses.replace(base, model=kind)
        t0 = time.perf_counter()
        nets = fit_residual(cfg, *train, friction, progress=progress)
        err = r_v - nets.predict(dq_v, ddq_v)
        rows.append(_row(f"PI-{kind.upper()}", err, slow, float(np.mean([r.best_epoch for r in nets.records])),
                         time.perf_counter() - t0))
    return rows


def ablation_from_outcome(outcome: IdentifyOutcome, models: tuple[str, ...] = MODELS, quick: bool = False,
                          config: LearningConfig | None = None, progress=None) -> list[dict[str, Any]]:
    """:func:`ablation` on an identification's processed training and held-out logs (serial robot)."""
    system, base, params = outcome.system, outcome.base, outcome.result.params
    parts = []
    for ds in (outcome.train, outcome.held_out):
        y, p = _model_rows(system, base, params, ds, 20000)
        parts.append((ds.dq, ds.ddq, y - p))
    fr = linear_friction(base.names, params, outcome.train.dq.shape[1])
    cfg = config or outcome.config.learning or LearningConfig()
    return ablation(parts[0], parts[1], fr, cfg, models, quick, progress)


def table(rows: list[dict[str, Any]]) -> str:
    """The rows as paper 003's Table 1 lays them out."""
    out = [f"{'model':<24}{'RMSE (all joints)':>18}{f'low-speed (<{LOW_SPEED:g})':>18}{'epochs':>8}{'seconds':>9}"]
    for r in rows:
        ep = "" if np.isnan(r["epochs_to_converge"]) else f"{r['epochs_to_converge']:.0f}"
        sec = "" if np.isnan(r["seconds"]) else f"{r['seconds']:.1f}"
        out.append(f"{r['model']:<24}{r['rmse']:>18.4g}{r['low_speed_rmse']:>18.4g}{ep:>8}{sec:>9}")
    return "\n".join(out)
