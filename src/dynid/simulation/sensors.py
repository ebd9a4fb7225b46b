"""Sensors of a virtual experiment: what a real log would contain (issue 4, item 4).

:class:`Sensors` turns true signals sampled at the control instants into measurements:

* positions: quantized to the encoder resolution (``round(q / res) * res``) plus white
  Gaussian noise;
* forces: white Gaussian noise with a full covariance across actuators (cross-correlated
  noise, as the period averaging of paper 004 estimates it), and optionally expressed as
  motor currents :math:`i = \\tau / k_\\tau`;
* sampling: every ``decimation``-th control sample is logged (a log slower than the control);
* time stamps: jitter added to the logged times (the values stay those of the nominal
  instants: the logger stamps late or early, which is what resampling then has to undo).

All randomness comes from one ``numpy.random.Generator`` seeded by ``seed``: the same
seed gives bit-identical measurements.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["Measurements", "Sensors"]


@dataclasses.dataclass(frozen=True, eq=False)
class Measurements:
    """Logged signals: time stamps (n,), positions (n, n_q), efforts (n, n_a) in ``effort_kind``
    units (N·m / N for ``"torque"``, A for ``"current"``), and the indices of the control
    samples they come from."""

    t: FloatArray
    q: FloatArray
    effort: FloatArray
    effort_kind: str
    index: FloatArray


@dataclasses.dataclass(frozen=True, eq=False)
class Sensors:
    """Sensor models (see module docstring).

    Parameters
    ----------
    encoder_resolution : float or array (n_q,), optional
        Position quantum [rad or m]; None: no quantization.
    position_noise_std : float or array (n_q,)
        White noise on positions after quantization.
    force_covariance : array (n_a, n_a) or (n_a,) or float
        Covariance of the force noise [(N·m)^2]; a vector or scalar is a diagonal.
    torque_constants : array (n_a,), optional
        :math:`k_\\tau` [N·m/A]: efforts are logged as currents ``tau / k`` (the noise is
        added to the torque first).
    decimation : int
        Log every ``decimation``-th control sample.
    time_jitter_std : float
        Standard deviation of the jitter of the logged time stamps [s] (clipped so that the
        time stays increasing).
    seed : int
    """

    encoder_resolution: FloatArray | float | None = None
    position_noise_std: FloatArray | float = 0.0
    force_covariance: FloatArray | float = 0.0
    torque_constants: FloatArray | None = None
    decimation: int = 1
    time_jitter_std: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.decimation < 1:
            raise InputError(f"decimation must be >= 1, got {self.decimation}")
        if self.time_jitter_std < 0:
            raise InputError("time jitter must be >= 0")
        if self.encoder_resolution is not None and np.any(np.asarray(self.encoder_resolution) <= 0):
            raise InputError("encoder resolution must be positive")
        if self.torque_constants is not None and np.any(np.asarray(self.torque_constants) == 0):
            raise InputError("torque constants must be non-zero")

    def check(self, n_a: int) -> None:
        """Refuse settings that do not fit ``n_a`` actuators (before a long simulation)."""
        self._covariance(n_a)

    def _covariance(self, n_a: int) -> FloatArray:
        c = np.asarray(self.force_covariance, dtype=float)
        if c.ndim < 2:
            c = np.diag(np.broadcast_to(c, (n_a,)))
        if c.shape != (n_a, n_a):
            raise InputError(f"force covariance must be ({n_a}, {n_a}), got {c.shape}")
        if not np.allclose(c, c.T) or np.linalg.eigvalsh(c).min() < -1e-12 * max(1.0, np.abs(c).max()):
            raise InputError("force covariance must be symmetric positive semi-definite")
        return c

    def measure(self, t: FloatArray, q: FloatArray, tau: FloatArray) -> Measurements:
        """Measurements of true signals ``t`` (n,), ``q`` (n, n_q), ``tau`` (n, n_a)."""
        t = np.asarray(t, dtype=float)
        q = np.atleast_2d(np.asarray(q, dtype=float))
        tau = np.atleast_2d(np.asarray(tau, dtype=float))
        if not (t.shape[0] == q.shape[0] == tau.shape[0]):
            raise InputError(f"mismatched lengths: t {t.shape[0]}, q {q.shape[0]}, tau {tau.shape[0]}")
        rng = np.random.default_rng(self.seed)
        idx = np.arange(0, t.shape[0], self.decimation)
        t, q, tau = t[idx], q[idx], tau[idx]
        n, n_a = tau.shape
        if self.encoder_resolution is not None:
            res = np.asarray(self.encoder_resolution, dtype=float)
            q = np.round(q / res) * res
        q = q + rng.standard_normal(q.shape) * np.asarray(self.position_noise_std, dtype=float)
        cov = self._covariance(n_a)
        if np.any(cov != 0):
            w, V = np.linalg.eigh(cov)
            tau = tau + (rng.standard_normal((n, n_a)) * np.sqrt(np.clip(w, 0, None))) @ V.T
        kind = "torque"
        if self.torque_constants is not None:
            tau = tau / np.asarray(self.torque_constants, dtype=float)
            kind = "current"
        if self.time_jitter_std > 0 and n > 1:
            step = np.min(np.diff(t))
            jitter = np.clip(rng.standard_normal(n) * self.time_jitter_std, -0.45 * step, 0.45 * step)
            t = t + jitter
        return Measurements(t=t, q=q, effort=tau, effort_kind=kind, index=idx)
