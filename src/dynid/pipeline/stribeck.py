"""``[identification] friction_model = "stribeck"``: :class:`~dynid.estimation.nonlinear.StribeckLS`
inside ``dynid identify`` (paper 000 §6.1, Eq. 32; issue 8, item 5).

The linear model's Coulomb and viscous columns of every *friction joint* (a serial robot's joints
with ``fc`` and ``fv`` extras; a mechanism's actuated joints with a ``coulomb`` and a ``viscous``
term of their own) gain the Stribeck term :math:`\\Delta F\\,e^{-|v/v_S|^\\delta}\\mathrm{sign}(v)`;
the other joint terms stay linear. How the friction of joint :math:`k` enters the channels
(:math:`P_{:,:,k}`, the identity for a serial arm, the projection through the loops for a
mechanism) is read from its Coulomb column, :math:`W_{:,:,c_k} = P_{:,:,k}\\,\\mathrm{sign}(v_k)`;
:class:`~dynid.estimation.stribeck_problem.SampleProblem` checks the viscous column against
:math:`P_{:,:,k}\\,v_k`.

The nonlinear fit works on uncompressed rows: ``max_samples`` samples evenly spread over the
processed training log (all of them when there are fewer). The held-out log is predicted in full
with :func:`~dynid.estimation.stribeck_problem.stribeck_predict`.

``processing.min_velocity`` leaves out, per actuator equation (whole samples for the projected
equations of a redundant mechanism), the samples where the actuator is slower than the threshold: where a joint sticks at a reversal its friction is whatever
holds it, which no static friction curve describes (a simulated twin shows it: the friction a
sticking joint needs is below the Stribeck curve's). Keep the threshold well below the Stribeck
velocity, or the data no longer see the Stribeck term.

Refused with a one-line error (never replaced by the linear model): methods other than ``ols``
and ``wls``, regularization, per-body bounds, nominal weighting, parallel decimation (a low-pass
of the regressor columns does not commute with the nonlinear term), and models without Coulomb
and viscous friction terms. In the ``pose`` domain of periodic processing the rows of the whole
period are built first (the pose is filtered over whole periods), then thinned to ``max_samples``.
"""

from __future__ import annotations

import dataclasses
import numpy as np

from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, IdentifiabilityError
from dynid.estimation import IdentificationResult
from dynid.estimation.nonlinear import SampleProblem, StribeckLS, stribeck_predict
from dynid.model.base_parameters import BaseParameters, StandardMap

__all__ = ["FrictionJoints", "check_config", "friction_joints", "subsample", "sample_problem", "estimator", "predict",
           "describe"]


@dataclasses.dataclass(frozen=True)
class FrictionJoints:
    """The joints with Stribeck friction: their names, the base-parameter indices of their
    Coulomb and viscous coefficients and their velocity columns in the processed dataset."""

    names: tuple[str, ...]
    coulomb: tuple[int, ...]
    viscous: tuple[int, ...]
    velocity: tuple[int, ...]
    units: tuple[str, ...]  # of their velocities: "rad/s" or "m/s"

    def projection(self, W: FloatArray, dq: FloatArray) -> FloatArray:
        """:math:`P` (n, n_ch, n_f) from the Coulomb columns of the base regressor ``W`` and the
        joint velocities ``dq`` (rows where a joint is at rest get 0: its Stribeck term is 0)."""
        return W[:, :, list(self.coulomb)] * np.sign(dq[:, list(self.velocity)])[:, None, :]


def check_config(cfg: Config, system) -> None:
    """The settings a Stribeck fit cannot honour and a model without friction joints (module
    docstring); before any data is read."""
    icfg, p = cfg.identification, cfg.processing
    w = "identification.friction_model = 'stribeck'"
    if icfg.method not in ("ols", "wls"):
        raise ConfigError(f"{w} is available with methods 'ols' and 'wls', not {icfg.method!r}")
    if icfg.regularization != "none":
        raise ConfigError(f"{w} does not take a regularization yet; remove identification.regularization")
    if icfg.bodies:
        raise ConfigError(f"{w} takes the margin and the sign constraints, not per-body bounds (identification.bodies)")
    if icfg.nominal_weighting:
        raise ConfigError(f"{w} weights by the noise of each channel; remove identification.nominal_weighting")
    if p.decimate > 1 and p.decimate_method == "parallel":
        raise ConfigError(f"{w} needs unfiltered regressor columns (a low-pass does not commute with the Stribeck "
                          "term): use processing.decimate_method = 'samples'")
    _pairs(system)


def _pairs(system) -> tuple[list[tuple[str, str, str, int]], list[str]]:
    pairs, units = system.friction_pairs()
    if not pairs:
        what = ("the robot has no fc and fv extras (robot.extras)" if system.kind == "serial" else
                "the actuated joints have no Coulomb and viscous terms of their own (robot.extras = [\"fv\", \"fc\", ...] adds them)")
        raise ConfigError(f"identification.friction_model = 'stribeck' adds a Stribeck term to Coulomb and viscous "
                          f"friction, but {what}")
    return pairs, units


def friction_joints(system, base: BaseParameters) -> FrictionJoints:
    """The friction joints of a :class:`~dynid.model.system.System` (module docstring)."""
    pairs, units = _pairs(system)
    grouped = [n for _, c, v, _ in pairs for n in (c, v) if n not in base.names]
    if grouped:
        raise IdentifiabilityError(f"friction coefficients {grouped} are not base parameters of their own: their Stribeck "
                                   "terms are not identifiable", tuple(grouped))
    return FrictionJoints(names=tuple(p[0] for p in pairs), coulomb=tuple(base.names.index(p[1]) for p in pairs),
                          viscous=tuple(base.names.index(p[2]) for p in pairs), velocity=tuple(p[3] for p in pairs),
                          units=tuple(units))


def sample_indices(n: int, max_samples: int) -> np.ndarray:
    """At most ``max_samples`` indices evenly spread over ``n`` samples (all when fewer)."""
    if n <= max_samples:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, max_samples)).astype(int))


def subsample(ds: Dataset, max_samples: int) -> Dataset:
    """At most ``max_samples`` samples of ``ds``, evenly spread over it (all when it has fewer)."""
    n = ds.n_samples
    if n <= max_samples:
        return ds
    idx = sample_indices(n, max_samples)
    return ds.select(idx, f"stribeck_rows[{idx.size} of {n}]")


def sample_problem(W: FloatArray, y: FloatArray, dq: FloatArray, mask: np.ndarray | None, fj: FrictionJoints,
                   base: BaseParameters, channels: tuple[str, ...], standard: StandardMap, meta: dict) -> SampleProblem:
    """The :class:`SampleProblem` of base-regressor rows ``W`` (n, n_ch, r), outputs ``y``, actuator
    velocities ``dq`` (n, n_a) and the rows kept per channel (``mask``, None: all)."""
    return SampleProblem(names=base.names, channel_names=channels, W=W, y=y, velocity=dq[:, list(fj.velocity)],
                         friction_names=fj.names, coulomb=fj.coulomb, viscous=fj.viscous, standard=standard,
                         projection=fj.projection(W, dq), mask=mask, meta=meta)


def estimator(cfg: Config) -> StribeckLS:
    """The :class:`StribeckLS` of ``[identification]``."""
    from dynid.pipeline.data import physical_options

    opts = physical_options(cfg.identification)
    return StribeckLS(weighting=cfg.identification.method, constraints=opts["constraints"], solver=opts["solver"])


def predict(result: IdentificationResult, fj: FrictionJoints, W: FloatArray, dq: FloatArray) -> FloatArray:
    """Outputs of a Stribeck result for base-regressor rows ``W`` and joint velocities ``dq``."""
    return stribeck_predict(result, W, np.asarray(dq)[:, list(fj.velocity)], fj.projection(W, dq))


def describe(result: IdentificationResult, base: BaseParameters, fj: FrictionJoints, n_rows: int,
             n_total: int, min_velocity: tuple[float, ...] | None = None) -> IdentificationResult:
    """The result with base-parameter expressions for every name and a note listing each joint's
    friction curve and the rows the fit used."""
    fr = result.solver["stribeck"]
    lines = [f"  {j}: Fc {f['Fc']:.4g}, Fs {f['Fs']:.4g}, Fv {f['Fv']:.4g}, vS {f['vs']:.4g} {u}, delta {f['delta']:.3g}"
             for (j, f), u in zip(fr.items(), fj.units)]
    used = (f"the nonlinear fit used {n_rows} of the {n_total} processed training samples (identification.max_samples)"
            if n_rows < n_total else f"the nonlinear fit used all {n_total} processed training samples")
    if min_velocity is not None:
        used += (f"; per joint equation, the samples slower than processing.min_velocity = {list(min_velocity)} are left "
                 f"out (rows kept: {[int(k) for k in result.n_obs]})")
    exprs = tuple(base.expressions()) + tuple(result.names[len(base.names):])
    return dataclasses.replace(result, expressions=exprs).with_notes(
        used, "Stribeck friction per joint (F = [Fc + (Fs - Fc) exp(-|v/vS|^delta)] sign(v) + Fv v):", *lines)
