"""``[learning]`` in ``dynid identify``: the residual network of paper 003, Section 3.4 trained on
what the identified model leaves in the training torques, validated on the held-out log with and
without it, saved next to the result (``result_learning.pt``) and loaded for prediction.

The target is the residual ``r = τ - Φ_b β̂`` of the processed training log at every sample (the
row selection of ``processing.min_velocity`` does not apply: the slow samples are where the
linear friction model fails and the network has the most to learn). The network's physical loss
terms act on the identified Coulomb + viscous friction plus the network (:mod:`dynid.learning`).
Prediction = identified model + network: :func:`predict`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ConfigError
from dynid.estimation.validation import ValidationMetrics

if TYPE_CHECKING:
    from dynid.config import Config
    from dynid.dataset import Dataset
    from dynid.estimation import IdentificationResult
    from dynid.model.base_parameters import BaseParameters
    from dynid.model.system import System
    from dynid.pipeline.rows import Progress

__all__ = ["LEARNING_FILE", "LearningOutcome", "check_learning", "linear_friction", "load_networks", "predict",
           "train_and_validate", "LOW_SPEED"]

LEARNING_FILE = "result_learning.pt"
LOW_SPEED = 0.5  # rad/s: paper 003, Table 1's low-speed region


def check_learning(cfg, system) -> None:
    """The set-ups the residual network supports (one-line errors otherwise)."""
    icfg, pcfg = cfg.identification, cfg.processing
    if system.kind != "serial":
        raise ConfigError("learning: the residual network is for serial robots (joint torques), not closed-loop mechanisms")
    if icfg.method not in ("ols", "wls", "gm", "irls", "tls") or (icfg.friction_model != "linear"
                                                                 and not icfg.hierarchical):
        raise ConfigError(f"learning: needs a linear estimator (ols, wls, gm, irls, tls) with friction_model = 'linear' "
                          f"(or hierarchical = true with any family), not method {icfg.method!r} with friction_model "
                          f"{icfg.friction_model!r}")
    if pcfg.periodic is not None:
        raise ConfigError("learning: needs time-domain processing, not processing.periodic")
    if pcfg.decimate > 1 and pcfg.decimate_method == "parallel":
        raise ConfigError("learning: the network reads consecutive processed samples; use decimate_method = 'plain' "
                          "or decimate = 1 with [learning]")


def linear_friction(base_names: tuple[str, ...], params: FloatArray, n_joints: int) -> dict[str, FloatArray]:
    """The identified Coulomb and viscous coefficients per joint (base parameters ``fc<j>``, ``fv<j>``;
    0 where the model has none)."""
    idx = {n: i for i, n in enumerate(base_names)}
    return {k: np.array([float(params[idx[f"{k}{j + 1}"]]) if f"{k}{j + 1}" in idx else 0.0 for j in range(n_joints)])
            for k in ("fc", "fv")}


@dataclasses.dataclass(frozen=True, eq=False)
class LearningOutcome:
    networks: Any  # dynid.learning.ResidualNetworks
    without: ValidationMetrics  # held-out: identified model alone
    with_network: ValidationMetrics  # held-out: identified model + network
    low_speed: dict[str, Any]  # RMSE on the held-out samples slower than LOW_SPEED, both ways
    training_rmse: dict[str, list[float]]  # the training log, both ways
    outside: list[float] = dataclasses.field(default_factory=list)  # held-out share outside the training velocity range

    def summary_lines(self) -> list[str]:
        cfg = self.networks.config
        recs = self.networks.records
        lines = ["", f"Learned residual friction (PI-{cfg.model.upper()}, paper 003 Sec. 3.4; window {cfg.window}, "
                     f"hidden {cfg.hidden}, lambda {cfg.lam:g}, seed {cfg.seed}): held-out torques",
                 f"{'joint':<14}{'RMSE without':>14}{'RMSE with':>12}{'low-speed without':>19}{'low-speed with':>16}"
                 f"{'best epoch':>12}  stopped by"]
        ls = self.low_speed
        for j, n in enumerate(self.without.channel_names):
            lines.append(f"{n:<14}{self.without.rmse[j]:>14.4g}{self.with_network.rmse[j]:>12.4g}"
                         f"{ls['without'][j]:>19.4g}{ls['with'][j]:>16.4g}{recs[j].best_epoch:>12d}  {recs[j].stopped_by}")
        far = [f"{n} {100 * o:.0f} %" for n, o in zip(self.without.channel_names, self.outside) if o > 0.01]
        if far:
            lines.append("held-out samples with velocities outside the training log's range (the network extrapolates there): "
                         + ", ".join(far))
        lines.append(f"overall RMSE without {_overall(self.without):.4g}, with {_overall(self.with_network):.4g} "
                     f"(low-speed |v| < {LOW_SPEED:g}: {ls['overall_without']:.4g} -> {ls['overall_with']:.4g}); "
                     f"network saved as {LEARNING_FILE}")
        return lines

    def to_dict(self) -> dict[str, Any]:
        def rm(v: ValidationMetrics) -> dict[str, Any]:
            d = v.to_dict()
            return {k: d[k] for k in ("joints", "n_samples", "rmse_per_joint", "rel_rmse_pct_per_joint", "r2_per_joint")}

        return {"file": LEARNING_FILE, **self.networks.describe(),
                "validation_without_network": {**rm(self.without), "overall_rmse": _overall(self.without)},
                "validation_with_network": {**rm(self.with_network), "overall_rmse": _overall(self.with_network)},
                "validation_low_speed": self.low_speed, "training_rmse": self.training_rmse,
                "held_out_outside_training_velocities": self.outside}


def _overall(v: ValidationMetrics) -> float:
    return float(np.sqrt(np.mean(np.asarray(v.rmse) ** 2)))


def _rmse(err: FloatArray, mask: np.ndarray | None = None) -> list[float]:
    if mask is None:
        return np.sqrt(np.mean(err**2, axis=0)).tolist()
    return [float(np.sqrt(np.mean(err[mask[:, j], j] ** 2))) if mask[:, j].any() else float("nan")
            for j in range(err.shape[1])]


def train_and_validate(lcfg, names: tuple[str, ...], train, train_measured: FloatArray, train_model: FloatArray,
                       held_out, measured: FloatArray, model: FloatArray, friction: dict[str, FloatArray],
                       progress=None, model_friction: FloatArray | None = None) -> LearningOutcome:
    """Train on the processed training Dataset's residual (measured - model), predict the held-out
    one; both sets of errors. ``model_friction``: the identified model's friction at each training
    sample when it is not linear (hierarchical identification: its fitted curves)."""
    from dynid.learning import fit_residual

    nets = fit_residual(lcfg, train.dq, train.ddq, train_measured - train_model, friction, names, progress,
                        model_friction=model_friction)
    net_tr = nets.predict(train.dq, train.ddq)
    net = nets.predict(held_out.dq, held_out.ddq)
    src = held_out.meta.get("source")
    t = np.asarray(held_out.t)
    without = ValidationMetrics.of(names, t, measured, model, src)
    with_net = ValidationMetrics.of(names, t, measured, model + net, src)
    slow = np.abs(held_out.dq) < LOW_SPEED
    e0, e1 = measured - model, measured - model - net
    low = {"threshold": LOW_SPEED, "samples_per_joint": slow.sum(axis=0).tolist(),
           "without": _rmse(e0, slow), "with": _rmse(e1, slow),
           "overall_without": float(np.sqrt(np.mean(e0[slow] ** 2))) if slow.any() else float("nan"),
           "overall_with": float(np.sqrt(np.mean(e1[slow] ** 2))) if slow.any() else float("nan")}
    r = train_measured - train_model
    lo, hi = train.dq.min(axis=0), train.dq.max(axis=0)
    outside = np.mean((held_out.dq < lo) | (held_out.dq > hi), axis=0).tolist()
    return LearningOutcome(nets, without, with_net, low, {"without": _rmse(r), "with": _rmse(r - net_tr)}, outside)


def load_networks(result_dir: str | Path):
    """The network saved with a result (``result_learning.pt`` in ``result_dir``)."""
    from dynid.learning import ResidualNetworks

    return ResidualNetworks.load(Path(result_dir) / LEARNING_FILE)


def predict(model_torque: FloatArray, dq: FloatArray, ddq: FloatArray, networks) -> FloatArray:
    """Identified model + network: ``Φ_b β̂`` (n, n_j) of a processed motion plus the learned residual."""
    return np.asarray(model_torque, float) + networks.predict(dq, ddq)


def _learn(cfg: Config, system: System, base: BaseParameters, result: IdentificationResult, train: Dataset,
           held_out: Dataset, chunk_size: int, progress: Progress, curves=None):
    """[learning]: the residual network (paper 003 Sec. 3.4) on the training log's residual.
    ``curves``: the friction curves of a hierarchical identification (paper 003 Sec. 3.3): the model
    is then the rigid-body part plus them, and the network's physical loss acts on them."""
    from dynid.pipeline.rows import _model_rows

    names = tuple(system.actuator_names)
    y_tr, p_tr = _model_rows(system, base, result.params, train, chunk_size)
    y_va, p_va = _model_rows(system, base, result.params, held_out, chunk_size)
    fr = linear_friction(base.names, result.params, len(names))
    f_tr = None
    if curves is not None:
        f_tr = curves.force(train.dq)
        p_tr, p_va = p_tr + f_tr, p_va + curves.force(held_out.dq)
    return train_and_validate(cfg.learning, names, train, y_tr, p_tr, held_out, y_va, p_va, fr, progress,
                              model_friction=f_tr)
