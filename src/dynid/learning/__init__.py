"""Physics-informed recurrent residual friction (paper 003, Section 3.4): PI-RNN, PI-GRU, PI-LSTM.

What the identified linear model leaves in the joint torques (the residual
:math:`r = \\tau - \\Phi_b\\hat\\beta` of the training log: friction the Coulomb + viscous columns
cannot represent, Stribeck dip and hysteresis) is learned per joint by a small recurrent network
in torch; prediction is the identified model plus the network. torch is an optional extra
(``pip install 'dynid[learning]'`` or ``make setup``); it is imported only when a network is
trained or loaded.

Our reading of Section 3.4 (the extracted text lost its operators):

* **Features (§3.4.1)**: per joint, the last ``k`` velocities and accelerations and two priors,
  ``sign(q̇)`` and the Stribeck attenuation ``exp(-(q̇/v_s)^2)`` (2k + 2 numbers). The recurrent
  cell reads the window step by step, each step (q̇, q̈, sign, Stribeck) with the two priors of
  the newest sample repeated along the window. dynid predicts logged samples, so the window ends
  at the current sample; the paper's control loop ends it at the last measured one. ``v_s`` comes
  from a Stribeck model fitted to the training log's measured friction (:func:`fit_stribeck_prior`)
  unless ``[learning] stribeck_velocity`` gives it.
* **Network (§3.4.1, Eqs. of the gates)**: one recurrent layer (LSTM, GRU or Elman RNN: the ablation
  of Table 1), hidden size 16-32, a linear head on the last hidden state.
* **Loss (§3.4.1)**: :math:`L = L_{MSE} + \\lambda(L_{dir} + L_{limit} + L_{stribeck})`, λ in
  [0.1, 0.3]. The physical terms apply to the total friction the model then predicts,
  :math:`\\hat f = f_c\\,\\mathrm{sign}(\\dot q) + f_v\\dot q + \\hat r` (the identified Coulomb and
  viscous parameters plus the network), in dynid's convention (friction is part of the torque the
  motor supplies, so it has the sign of the velocity):

  - ``L_dir = mean max(0, -f̂ sign(q̇))``: friction that drives the motion is penalised (the
    paper's ``max(0, τ̂_f sign(q̇))`` in its convention of friction acting on the joint);
  - ``L_limit = mean max(0, |f̂| - τ_f,max)``, ``τ_f,max`` = 1.5 x the largest measured friction
    magnitude of the training log;
  - ``L_stribeck = mean max(0, |f̂| - C(|q̇| + ε))``, ε = 1e-6: the paper's
    ``max(0, |τ̂_f|/(|q̇| + ε) - C)`` has the same zero set; multiplied out it is a torque like the
    other terms (the ratio form explodes at rest). ``C`` is the largest friction per unit speed
    the fitted Stribeck prior reaches on the training velocities: the network may not claim more
    friction near rest than the physical model does. Honestly: with the paper's ε this bound is
    loose and rarely active; it matters only where a network would put friction at rest.

  Sums over t in the paper are means here (λ then weighs per-sample quantities, whatever the
  log's length); every term is in units of the training residual's std per joint.
* **Compensation (§3.4.3)**: :func:`compensate`.

Training is deterministic on the CPU for a seed (``torch.manual_seed``, deterministic algorithms,
one thread, a seeded shuffle), stops early on a validation split (every fifth block of 10
consecutive samples of the training log), and is bounded by ``max_seconds`` (then the epoch where the clock stopped it depends
on the machine: the result records which bound ended training).
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError, MissingExtraError

__all__ = ["MODELS", "LearningConfig", "ResidualNetworks", "TrainingRecord", "compensate", "fit_residual",
           "fit_stribeck_prior", "features", "require_torch", "FORMAT"]

MODELS = ("lstm", "gru", "rnn")
FORMAT = "dynid-learning-1"
EPS = 1e-6  # paper 003, §3.4.1 (L_stribeck)
N_STEP_FEATURES = 4  # per step of the window: velocity, acceleration, sign prior, Stribeck prior

Progress = Callable[[str, int, int], None]


def require_torch():
    """torch, or the one-line error that says how to install it."""
    try:
        import torch
    except ImportError:
        raise MissingExtraError("[learning] needs torch, which is not installed: pip install 'dynid[learning]' "
                                "(or make setup)") from None
    return torch


@dataclasses.dataclass(frozen=True)
class LearningConfig:
    """``[learning]``: the residual network and its training."""

    model: str = "lstm"  # "lstm" | "gru" | "rnn" (paper 003 Table 1's ablation)
    window: int = 6  # k: the network reads the last k samples (paper: 5-8 control cycles; at most 64)
    hidden: int = 24  # hidden units of the one recurrent layer (4-256)
    epochs: int = 150  # the most training epochs (early stopping may end sooner)
    lam: float = 0.2  # λ ("lambda"): weight of the physical loss terms, in [0.1, 0.3] as paper 003 says
    seed: int = 0  # seed of the initial weights and the shuffling
    max_seconds: float = 120.0  # s: wall-clock bound of the whole training
    patience: int = 20  # epochs without a better validation MSE before stopping
    learning_rate: float = 5e-3  # Adam's learning rate
    batch_size: int = 128  # samples per training batch
    validation_fraction: float = 0.2  # share of the training samples (interleaved blocks) kept for early stopping (< 0.5)
    stribeck_velocity: tuple[float, ...] | None = None  # rad/s: v_s of the Stribeck prior, one or per joint (default: fitted)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["lambda"] = d.pop("lam")
        if d["stribeck_velocity"] is not None:
            d["stribeck_velocity"] = list(d["stribeck_velocity"])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LearningConfig:
        d = dict(d)
        d["lam"] = d.pop("lambda")
        if d.get("stribeck_velocity") is not None:
            d["stribeck_velocity"] = tuple(d["stribeck_velocity"])
        return cls(**d)


# ---------------------------------------------------------------------- features and priors
def _windows(x: FloatArray, k: int) -> FloatArray:
    """(n,) -> (n, k): the last k samples up to and including each one (the first padded with the first sample)."""
    pad = np.concatenate([np.full(k - 1, x[0]), x])
    return np.lib.stride_tricks.sliding_window_view(pad, k)


def features(dq: FloatArray, ddq: FloatArray, window: int, vs: float, v_scale: float, a_scale: float) -> FloatArray:
    """One joint's network input (n, window, 4), oldest step first: scaled velocity and acceleration,
    and at every step the priors of the newest sample, sign(q̇) and exp(-(q̇/v_s)^2) (paper 003,
    §3.4.1: 2k + 2 numbers)."""
    dq, ddq = np.asarray(dq, float), np.asarray(ddq, float)
    n, k = dq.shape[0], int(window)
    out = np.empty((n, k, N_STEP_FEATURES))
    out[:, :, 0] = _windows(dq, k) / v_scale
    out[:, :, 1] = _windows(ddq, k) / a_scale
    out[:, :, 2] = np.sign(dq)[:, None]
    out[:, :, 3] = np.exp(-((dq / vs) ** 2))[:, None]
    return out


def fit_stribeck_prior(dq: FloatArray, friction: FloatArray, grid: int = 60) -> dict[str, float]:
    """Stribeck model ``f = [f_c + (f_s - f_c) exp(-(q̇/v_s)^2)] sign(q̇) + f_v q̇ + b`` fitted to one
    joint's measured friction (paper 000 Eq. 32 with δ = 2; paper 003 Eq. 15 without its smoothing):
    linear least squares for each ``v_s`` of a log grid between 1e-3 and the largest speed, the
    ``v_s`` of the smallest residual. Returns fc, fs, fv, vs, offset and the residual RMS."""
    v, f = np.asarray(dq, float), np.asarray(friction, float)
    s = np.sign(v)
    vmax = float(np.max(np.abs(v)))
    if not vmax > 1e-3:
        raise InputError("learning: a joint never moves faster than 1e-3; no Stribeck prior can be fitted")
    best = None
    for vs in np.geomspace(1e-3, vmax, grid):
        A = np.c_[s, np.exp(-((v / vs) ** 2)) * s, v, np.ones_like(v)]
        coef, *_ = np.linalg.lstsq(A, f, rcond=None)
        sse = float(np.sum((A @ coef - f) ** 2))
        if best is None or sse < best[0]:
            best = (sse, vs, coef)
    sse, vs, (fc, ds, fv, b) = best
    return {"fc": float(fc), "fs": float(fc + ds), "fv": float(fv), "vs": float(vs), "offset": float(b),
            "rms": float(np.sqrt(sse / len(v)))}


def _prior_force(p: dict[str, float], v: FloatArray) -> FloatArray:
    s = np.sign(v)
    return (p["fc"] + (p["fs"] - p["fc"]) * np.exp(-((v / p["vs"]) ** 2))) * s + p["fv"] * v


def compensate(tau_cmd: FloatArray, friction: FloatArray) -> FloatArray:
    """Friction-compensated torque command (paper 003, §3.4.3). dynid's friction is the part of the
    torque the motor supplies (the sign of the velocity), so the compensated command adds it:
    ``τ_comp = τ_cmd + f̂``; this is the paper's ``τ_cmd - τ̂_f`` with τ̂_f the friction acting on
    the joint."""
    return np.asarray(tau_cmd, float) + np.asarray(friction, float)


# ---------------------------------------------------------------------- network
def _net(torch, kind: str, hidden: int):
    nn = torch.nn
    cell = {"lstm": nn.LSTM, "gru": nn.GRU, "rnn": nn.RNN}[kind]

    class PIRecurrent(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.rec = cell(N_STEP_FEATURES, hidden, num_layers=1, batch_first=True)
            self.head = nn.Linear(hidden, 1)

        def forward(self, x):
            out, _ = self.rec(x)
            return self.head(out[:, -1, :]).squeeze(-1)

    return PIRecurrent()


@dataclasses.dataclass(frozen=True)
class TrainingRecord:
    """How one joint's network was trained."""

    epochs_run: int
    best_epoch: int  # the epoch of the kept weights ("epochs to converge", Table 1)
    stopped_by: str  # "early_stopping" | "epochs" | "max_seconds"
    train_mse: float  # scaled units (residual std = 1)
    validation_mse: float
    seconds: float


class _Deterministic:
    """torch settings of deterministic single-thread training, restored afterwards."""

    def __init__(self, torch) -> None:
        self.torch = torch

    def __enter__(self):
        t = self.torch
        self.saved = (t.get_num_threads(), t.are_deterministic_algorithms_enabled())
        t.set_num_threads(1)
        t.use_deterministic_algorithms(True)
        return self

    def __exit__(self, *exc) -> None:
        self.torch.set_num_threads(self.saved[0])
        self.torch.use_deterministic_algorithms(self.saved[1])


@dataclasses.dataclass(eq=False)
class ResidualNetworks:
    """One trained network per joint and everything prediction needs (scales, priors, settings)."""

    config: LearningConfig
    joint_names: tuple[str, ...]
    scales: dict[str, list[float]]  # velocity, acceleration, residual std per joint
    priors: list[dict[str, float]]  # fitted Stribeck prior per joint
    linear_friction: dict[str, list[float]]  # fc, fv of the identified model per joint (0 where absent)
    bounds: dict[str, list[float]]  # tau_f_max and C per joint
    states: list[dict[str, Any]]  # torch state dicts
    records: list[TrainingRecord]
    _nets: list[Any] | None = None

    # -------------------------------------------------------------- prediction
    def _modules(self):
        if self._nets is None:
            torch = require_torch()
            nets = []
            for st in self.states:
                net = _net(torch, self.config.model, self.config.hidden)
                net.load_state_dict(st)
                net.eval()
                nets.append(net)
            self._nets = nets
        return self._nets

    def inputs(self, dq: FloatArray, ddq: FloatArray, j: int) -> FloatArray:
        sc = self.scales
        return features(dq[:, j], ddq[:, j], self.config.window, self.priors[j]["vs"], sc["velocity"][j],
                        sc["acceleration"][j])

    def predict(self, dq: FloatArray, ddq: FloatArray) -> FloatArray:
        """The learned residual torque (n, n_joints) of a processed motion (consecutive samples)."""
        torch = require_torch()
        dq, ddq = np.atleast_2d(np.asarray(dq, float)), np.atleast_2d(np.asarray(ddq, float))
        if dq.shape != ddq.shape or dq.shape[1] != len(self.joint_names):
            raise InputError(f"learning: expected velocities and accelerations of {len(self.joint_names)} joints, "
                             f"got shapes {dq.shape} and {ddq.shape}")
        out = np.empty(dq.shape)
        with torch.no_grad():
            for j, net in enumerate(self._modules()):
                x = torch.as_tensor(self.inputs(dq, ddq, j), dtype=torch.float32)
                out[:, j] = net(x).numpy().astype(float) * self.scales["residual"][j]
        return out

    def friction(self, dq: FloatArray, ddq: FloatArray) -> FloatArray:
        """Total friction of the model with the network: f_c sign(q̇) + f_v q̇ + network."""
        dq = np.atleast_2d(np.asarray(dq, float))
        lf = self.linear_friction
        return np.asarray(lf["fc"]) * np.sign(dq) + np.asarray(lf["fv"]) * dq + self.predict(dq, ddq)

    # -------------------------------------------------------------- files
    def describe(self) -> dict[str, Any]:
        """For result.json: the configuration, priors, bounds and how each network was trained."""
        return {"format": FORMAT, "config": self.config.to_dict(), "joints": list(self.joint_names),
                "scales": self.scales, "stribeck_prior": self.priors, "linear_friction": self.linear_friction,
                "bounds": self.bounds, "training": [dataclasses.asdict(r) for r in self.records],
                "torch": str(require_torch().__version__)}

    def save(self, path: str | Path) -> None:
        torch = require_torch()
        torch.save({**self.describe(), "states": self.states}, str(path))

    @classmethod
    def load(cls, path: str | Path) -> ResidualNetworks:
        torch = require_torch()
        p = Path(path)
        if not p.is_file():
            raise InputError(f"learning: no trained network at {p}")
        try:
            d = torch.load(str(p), weights_only=True)
        except Exception as exc:  # noqa: BLE001 - any unreadable file is one line
            raise InputError(f"learning: {p} is not a saved dynid network ({type(exc).__name__})") from None
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise InputError(f"learning: {p} is not a saved dynid network (format {FORMAT!r} expected)")
        return cls(LearningConfig.from_dict(d["config"]), tuple(d["joints"]), d["scales"], d["stribeck_prior"],
                   d["linear_friction"], d["bounds"], d["states"], [TrainingRecord(**r) for r in d["training"]])


# ---------------------------------------------------------------------- training
BLOCK = 10  # samples per block of the early-stopping split


def _validation_blocks(n: int, fraction: float) -> np.ndarray:
    """The early-stopping split: every m-th block of ``BLOCK`` consecutive samples (m = round(1 /
    fraction)), so that it covers the whole motion (the log's tail alone is one stretch of it)."""
    m = max(2, int(round(1.0 / fraction)))
    return (np.arange(n) // BLOCK) % m == m - 1


def _train_joint(torch, cfg: LearningConfig, x: FloatArray, y: FloatArray, flin: FloatArray, v: FloatArray,
                 sr: float, fmax: float, c: float, seed: int, deadline: float, progress: Progress, task: str):
    """Train one joint's network on scaled inputs x (n, k, 4) and scaled targets y (n,)."""
    n = x.shape[0]
    val_mask = _validation_blocks(n, cfg.validation_fraction)
    n_fit = int(n - val_mask.sum())
    if n_fit < cfg.batch_size or not val_mask.any():
        raise InputError(f"learning: {n} training samples are too few for batches of {cfg.batch_size} and a validation split")
    torch.manual_seed(seed)
    net = _net(torch, cfg.model, cfg.hidden)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.learning_rate)
    T = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731 - a copy
    X, Y, F, V = T(x), T(y), T(flin / sr), T(v)
    S = torch.sign(V)
    fmax_s, c_s = fmax / sr, c / sr

    def loss_terms(idx):
        pred = net(X[idx])
        mse = torch.mean((pred - Y[idx]) ** 2)
        f = F[idx] + pred  # total friction, scaled
        l_dir = torch.mean(torch.relu(-f * S[idx]))
        l_lim = torch.mean(torch.relu(torch.abs(f) - fmax_s))
        l_str = torch.mean(torch.relu(torch.abs(f) - c_s * (torch.abs(V[idx]) + EPS)))
        return mse, mse + cfg.lam * (l_dir + l_lim + l_str)

    gen = torch.Generator().manual_seed(seed)
    fit_idx, val_idx = torch.as_tensor(np.flatnonzero(~val_mask)), torch.as_tensor(np.flatnonzero(val_mask))
    best = (float("inf"), 0, copy.deepcopy(net.state_dict()), float("nan"))
    stopped, epoch, t0 = "epochs", 0, time.perf_counter()
    for epoch in range(1, cfg.epochs + 1):
        net.train()
        perm = fit_idx[torch.randperm(n_fit, generator=gen)]
        total = 0.0
        for a in range(0, n_fit, cfg.batch_size):
            idx = perm[a:a + cfg.batch_size]
            opt.zero_grad()
            mse, loss = loss_terms(idx)
            loss.backward()
            opt.step()
            total += float(mse.detach()) * len(idx)
        net.eval()
        with torch.no_grad():
            val = float(loss_terms(val_idx)[0])
        if val < best[0]:
            best = (val, epoch, copy.deepcopy(net.state_dict()), total / n_fit)
        progress(task, epoch, cfg.epochs)
        if epoch - best[1] >= cfg.patience:
            stopped = "early_stopping"
            break
        if time.perf_counter() > deadline:
            stopped = "max_seconds"
            break
    progress(task, cfg.epochs, cfg.epochs)
    net.load_state_dict(best[2])
    rec = TrainingRecord(epochs_run=epoch, best_epoch=best[1], stopped_by=stopped, train_mse=best[3],
                         validation_mse=best[0], seconds=time.perf_counter() - t0)
    return best[2], rec


def fit_residual(cfg: LearningConfig, dq: FloatArray, ddq: FloatArray, residual: FloatArray,
                 linear_friction: dict[str, FloatArray] | None = None, joint_names: tuple[str, ...] | None = None,
                 progress: Progress | None = None, model_friction: FloatArray | None = None) -> ResidualNetworks:
    """Train one network per joint on a processed training motion: velocities and accelerations
    (n, n_j) and the residual torque the identified model leaves (n, n_j). ``linear_friction``:
    the identified ``fc`` and ``fv`` per joint (the physical terms of the loss act on their friction
    plus the network's; zeros without). ``model_friction`` (n, n_j): instead, the identified
    model's friction at each training sample when it is not linear (the fitted curves of a
    hierarchical identification, paper 003 Sec. 3.3, on which Sec. 3.4's network is stacked)."""
    torch = require_torch()
    prog = progress or (lambda task, done, total: None)
    dq, ddq, r = (np.atleast_2d(np.asarray(a, float)) for a in (dq, ddq, residual))
    if not (dq.shape == ddq.shape == r.shape):
        raise InputError(f"learning: shapes of velocities {dq.shape}, accelerations {ddq.shape} and residual {r.shape} differ")
    if not (np.all(np.isfinite(dq)) and np.all(np.isfinite(ddq)) and np.all(np.isfinite(r))):
        raise InputError("learning: the training motion or residual has non-finite values")
    n, nj = dq.shape
    names = tuple(joint_names) if joint_names is not None else tuple(f"joint_{j + 1}" for j in range(nj))
    lf = {k: np.zeros(nj) for k in ("fc", "fv")}
    if linear_friction is not None:
        lf = {k: np.broadcast_to(np.asarray(linear_friction.get(k, 0.0), float), (nj,)).copy() for k in ("fc", "fv")}
    if model_friction is not None:
        model_friction = np.atleast_2d(np.asarray(model_friction, float))
        if model_friction.shape != r.shape or not np.all(np.isfinite(model_friction)):
            raise InputError(f"learning: the model friction {model_friction.shape} must be finite and shaped like the "
                             f"residual {r.shape}")
    if cfg.stribeck_velocity is not None and len(cfg.stribeck_velocity) not in (1, nj):
        raise InputError(f"learning.stribeck_velocity: {len(cfg.stribeck_velocity)} values for {nj} joints")
    scales = {"velocity": [], "acceleration": [], "residual": []}
    priors, bounds, states, records = [], {"tau_f_max": [], "C": []}, [], []
    deadline = time.perf_counter() + cfg.max_seconds
    with _Deterministic(torch):
        for j in range(nj):
            v, a = dq[:, j], ddq[:, j]
            flin = lf["fc"][j] * np.sign(v) + lf["fv"][j] * v if model_friction is None else model_friction[:, j]
            measured = flin + r[:, j]  # the friction the log shows, as far as the rigid-body model is right
            prior = fit_stribeck_prior(v, measured)
            if cfg.stribeck_velocity is not None:
                prior["vs"] = float(cfg.stribeck_velocity[0 if len(cfg.stribeck_velocity) == 1 else j])
            sv, sa, sr = (float(np.std(x)) or 1.0 for x in (v, a, r[:, j]))
            fmax = 1.5 * float(np.max(np.abs(measured)))
            c = float(np.max(np.abs(_prior_force(prior, v)) / (np.abs(v) + EPS)))
            x = features(v, a, cfg.window, prior["vs"], sv, sa)
            st, rec = _train_joint(torch, cfg, x, r[:, j] / sr, flin, v, sr, fmax, c, cfg.seed + j, deadline, prog,
                                   f"learning ({cfg.model}) {names[j]}")
            for key, val in (("velocity", sv), ("acceleration", sa), ("residual", sr)):
                scales[key].append(val)
            priors.append(prior)
            bounds["tau_f_max"].append(fmax)
            bounds["C"].append(c)
            states.append(st)
            records.append(rec)
    return ResidualNetworks(cfg, names, scales, priors, {k: v.tolist() for k, v in lf.items()}, bounds, states, records)
