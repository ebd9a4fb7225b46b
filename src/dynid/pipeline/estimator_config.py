"""The estimator a configuration asks for (``[identification]``): the method with its options, the
noise covariances maximum likelihood takes from the period averaging or the config, and the physical
constraints' options. Split from :mod:`dynid.pipeline.data`, which re-exports these functions."""

from __future__ import annotations

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ConfigError, InputError


def _periodic_covariance(steps: list, kind: str, key: str) -> np.ndarray:
    """Noise covariance of the averaged period: one sample's (``noise_covariance_<kind>``)
    over the number of averaged periods (paper 004 §3.2)."""
    rec = next((s for s in steps if s.get("step") == "periodic"), None)
    if rec is None or not rec.get("averaged"):
        raise ConfigError(f"identification.{key} = 'periodic' needs [processing.periodic] averaging over at least two periods")
    return np.asarray(rec[f"noise_covariance_{kind}"], dtype=float) / rec["periods"]


def _channels_are_efforts(channel_names, effort_names, key: str) -> None:
    if tuple(channel_names) != tuple(effort_names):
        raise ConfigError(f"identification.{key} = 'periodic' needs equations that are the measured "
                          f"efforts; these are {list(channel_names)}")


def _given_covariance(value, n: int, names, key: str) -> np.ndarray:
    cov = np.asarray(value, dtype=float)
    if cov.shape != (n, n):
        raise ConfigError(f"identification.{key} is {cov.shape[0]} x {cov.shape[1]}; "
                          f"there are {n} channels ({', '.join(names)})")
    return cov


def ml_covariances(icfg, steps: list, channel_names: tuple[str, ...], effort_names: tuple[str, ...]):
    """:math:`\\Sigma_{\\eta\\eta}` and :math:`\\Sigma_{\\delta\\delta}` of the averaged period for
    ``method = "ml"`` (paper 004 Eq. 24): from the period averaging (default) or given. A
    singular position covariance (positions that repeat exactly from period to period, e.g.
    noise-free or coarsely quantized) is an error: the likelihood would not be defined."""
    if icfg.noise_covariance == "periodic":
        _channels_are_efforts(channel_names, effort_names, "noise_covariance")
        cov_e = _periodic_covariance(steps, "effort", "noise_covariance")
    else:
        cov_e = _given_covariance(icfg.noise_covariance, len(channel_names), channel_names, "noise_covariance")
    if icfg.position_covariance == "periodic":
        cov_d = _periodic_covariance(steps, "position", "position_covariance")
    else:
        cov_d = _given_covariance(icfg.position_covariance, len(effort_names), effort_names, "position_covariance")
    for cov, what in ((cov_e, "force covariance Sigma_eta"), (cov_d, "position covariance Sigma_dd")):
        w = np.linalg.eigvalsh(0.5 * (cov + cov.T))
        if not w.min() > 1e-12 * max(w.max(), 1e-300):
            raise InputError(f"identification (ml): the {what} is singular (eigenvalues {w.min():.3g}..{w.max():.3g}); "
                             "the positions or forces repeat exactly from period to period: give it as a matrix")
    return cov_e, cov_d


def configured_estimator(icfg, steps: list, channel_names: tuple[str, ...], effort_names: tuple[str, ...],
                         nominal_base: FloatArray | None):
    """The estimator of ``[identification]`` with its data-dependent options.

    ``noise_covariance = "periodic"`` (method ``"gm"``) takes the effort noise covariance of one
    sample from the period averaging (paper 004 §3.2) divided by the number of averaged periods:
    the covariance of the averaged period the estimator sees. It needs channels that are the
    efforts themselves (not, e.g., the projected equations of a redundant mechanism).
    Method ``"ml"`` is not a single-problem estimator (see :func:`ml_covariances`).
    """
    from dynid.estimation import make_estimator

    cov = None
    if icfg.method == "gm":
        if icfg.noise_covariance == "periodic":
            _channels_are_efforts(channel_names, effort_names, "noise_covariance")
            cov = _periodic_covariance(steps, "effort", "noise_covariance")
        elif icfg.noise_covariance != "residuals":
            cov = _given_covariance(icfg.noise_covariance, len(channel_names), channel_names, "noise_covariance")
    nominal = None
    if icfg.nominal_weighting:
        if nominal_base is None:
            raise ConfigError("identification.nominal_weighting needs a model with nominal parameter values")
        nominal = nominal_base
    return make_estimator(icfg.method, icfg.physical_consistency, noise_covariance=cov, nominal=nominal,
                          iterations=icfg.iterations, physical=physical_options(icfg) if icfg.physical_consistency else None)


def physical_options(icfg) -> dict:
    """Options of :class:`dynid.estimation.PhysicalLS` from ``[identification]`` (issue 8)."""
    from dynid.estimation import BodyBounds, PhysicalConstraints

    try:
        bodies = {name: BodyBounds(**b) for name, b in icfg.bodies.items()}
        constraints = PhysicalConstraints(margin=icfg.margin, bodies=bodies)
    except InputError as exc:
        raise ConfigError(f"identification: {exc}") from None
    return {"constraints": constraints, "regularization": icfg.regularization,
            "regularization_weight": icfg.regularization_weight, "solver": icfg.solver}
