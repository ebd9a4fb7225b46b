"""``[processing]`` of the identify configuration: resampling, low-pass, derivatives, decimation,
row selection, and the frequency-domain processing of periodic data."""

from __future__ import annotations

import dataclasses
from typing import Any

from dynid.config._schema import _bool, _int, _num, _num_or_list, _str, _table
from dynid.errors import ConfigError

@dataclasses.dataclass(frozen=True)
class LowpassConfig:
    cutoff_hz: float  # Hz: the cut-off of the zero-phase Butterworth low-pass on the positions
    order: int = 4  # the Butterworth filter's order
    filter_effort: bool = True  # low-pass the efforts too (false with decimate_method = "parallel")


@dataclasses.dataclass(frozen=True)
class PeriodicConfig:
    """``[processing.periodic]``: frequency-domain processing of periodic excitation data
    (paper 004 §3): period averaging and exact DFT filtering and differentiation."""

    period_s: float  # s: the excitation's period (a whole number of samples)
    cutoff_hz: float  # Hz: the DFT filter's cut-off (keep it above the closed loop's bandwidth)
    average: bool = True  # average the whole periods into one (noise covariances to the provenance); false: keep every period
    filter_effort: bool = False  # DFT-filter the efforts too
    domain: str = "actuators"  # "pose": parallel robots, filter the reconstructed platform pose (paper 004)


@dataclasses.dataclass(frozen=True)
class ProcessingConfig:
    """``[processing]``: how raw logs become positions, velocities, accelerations, torques."""

    # "auto": irregular timestamps resampled at the median rate; "off": refuse them; or a rate in Hz
    resample: str | float = "auto"
    lowpass: LowpassConfig | None = None  # zero-phase Butterworth low-pass on the positions (and efforts)
    derivatives: str = "central"  # "central" | "measured" | "kalman" (RTS smoother: dynid.signals.kalman)
    # derivatives = "kalman": the positions' measurement noise std per coordinate (SI, actuator space), e.g.
    # an encoder's resolution / sqrt(12); None: estimated from the log with the smoother's noise ratio
    position_noise_std: tuple[float, ...] | None = None
    decimate: int = 1  # keep one sample in this many (1: every sample)
    # "samples": one sample kept after the low-pass; "parallel": regressor and efforts filtered together (Gautier)
    decimate_method: str = "samples"
    trim_samples: int | None = None  # samples dropped at both ends (default: the low-pass's transient, else 2)
    # rad/s or m/s, one or one per joint: the rows of joint j's equation where |dq_j| is below it are left out
    min_velocity: tuple[float, ...] | None = None
    min_velocity_passive: float | None = None  # mechanisms: samples with a slower passive friction joint left out
    # periodic excitation: whole periods averaged, exact DFT filtering and differentiation (replaces lowpass,
    # decimate and trim_samples)
    periodic: PeriodicConfig | None = None
    reversal_guard: float | str | None = None  # seconds, or "auto" (the low-pass's settling time): rows near a reversal left out

    def reversal_guard_s(self) -> float | None:
        """``reversal_guard`` in seconds (``"auto"``: :func:`dynid.signals.zero_phase_settling_time`
        of ``lowpass``), None when unset."""
        if self.reversal_guard is None:
            return None
        if self.reversal_guard == "auto":
            from dynid.signals import zero_phase_settling_time

            assert self.lowpass is not None  # checked when parsed
            return zero_phase_settling_time(self.lowpass.order, self.lowpass.cutoff_hz)
        return float(self.reversal_guard)

    @property
    def selects_rows(self) -> bool:
        """Whether a row selection (``min_velocity``, ``min_velocity_passive``, ``reversal_guard``) is set."""
        return self.min_velocity is not None or self.min_velocity_passive is not None or self.reversal_guard is not None



PROCESSING_KEYS = ("resample", "lowpass", "derivatives", "position_noise_std", "decimate", "decimate_method", "trim_samples", "min_velocity",
                   "min_velocity_passive", "periodic", "reversal_guard")
"""The keys of ``[processing]``."""


def _noise_std(t: dict, where: str) -> tuple[float, ...] | None:
    """``processing.position_noise_std``: one value or one per coordinate, only with derivatives = 'kalman'."""
    if "position_noise_std" not in t:
        return None
    if t.get("derivatives") != "kalman":
        raise ConfigError(f"{where}.position_noise_std is the measurement noise of the Kalman smoother: it needs "
                          f"{where}.derivatives = 'kalman'")
    v = _num_or_list(t["position_noise_std"], f"{where}.position_noise_std", positive=True)
    return v if isinstance(v, tuple) else (v,)


def _parse_processing(t: Any) -> ProcessingConfig:
    where = "processing"
    t = _table(t, where, set(PROCESSING_KEYS))
    resample: str | float = "auto"
    if "resample" in t:
        r = t["resample"]
        resample = _str(r, f"{where}.resample", ("auto", "off")) if isinstance(r, str) else _num(r, f"{where}.resample", positive=True)
    lowpass = None
    if "lowpass" in t:
        lp = _table(t["lowpass"], f"{where}.lowpass", {"cutoff_hz", "order", "filter_effort"}, {"cutoff_hz"})
        lowpass = LowpassConfig(
            cutoff_hz=_num(lp["cutoff_hz"], f"{where}.lowpass.cutoff_hz", positive=True),
            order=_int(lp.get("order", 4), f"{where}.lowpass.order", 1),
            filter_effort=_bool(lp.get("filter_effort", True), f"{where}.lowpass.filter_effort"),
        )
    mv = None
    if "min_velocity" in t:
        v = t["min_velocity"]
        mv = _num_or_list(v, f"{where}.min_velocity", minimum=0.0)
        mv = mv if isinstance(mv, tuple) else (mv,)
    guard: float | str | None = None
    if "reversal_guard" in t:
        g = t["reversal_guard"]
        guard = (_str(g, f"{where}.reversal_guard", ("auto",)) if isinstance(g, str)
                 else _num(g, f"{where}.reversal_guard", minimum=0.0))
        if "periodic" in t:
            raise ConfigError(f"{where}.reversal_guard applies to the time-domain processing (lowpass, central "
                              f"differences); {where}.periodic filters whole periods in the frequency domain")
        if guard == "auto" and lowpass is None:
            raise ConfigError(f"{where}.reversal_guard = 'auto' is the settling time of {where}.lowpass, which is not "
                              "set; give the guard in seconds or set the low-pass")
    periodic = None
    if "periodic" in t:
        pt = _table(t["periodic"], f"{where}.periodic", {"period_s", "cutoff_hz", "average", "filter_effort", "domain"}, {"period_s", "cutoff_hz"})
        periodic = PeriodicConfig(
            period_s=_num(pt["period_s"], f"{where}.periodic.period_s", positive=True),
            cutoff_hz=_num(pt["cutoff_hz"], f"{where}.periodic.cutoff_hz", positive=True),
            average=_bool(pt.get("average", True), f"{where}.periodic.average"),
            filter_effort=_bool(pt.get("filter_effort", False), f"{where}.periodic.filter_effort"),
            domain=_str(pt.get("domain", "actuators"), f"{where}.periodic.domain", ("actuators", "pose")),
        )
        clash = [k for k in ("lowpass", "decimate", "trim_samples") if k in t] + (["derivatives"] if t.get("derivatives") in ("measured", "kalman") else [])
        if clash:
            raise ConfigError(f"{where}.periodic replaces {clash}: the frequency-domain processing filters, differentiates and keeps whole periods itself")
    return ProcessingConfig(
        periodic=periodic,
        resample=resample,
        lowpass=lowpass,
        derivatives=_str(t.get("derivatives", "central"), f"{where}.derivatives", ("central", "measured", "kalman")),
        position_noise_std=_noise_std(t, where),
        decimate=_int(t.get("decimate", 1), f"{where}.decimate", 1),
        decimate_method=_str(t.get("decimate_method", "samples"), f"{where}.decimate_method", ("samples", "parallel")),
        trim_samples=_int(t["trim_samples"], f"{where}.trim_samples", 0) if "trim_samples" in t else None,
        min_velocity=mv,
        min_velocity_passive=(_num(t["min_velocity_passive"], f"{where}.min_velocity_passive", minimum=0.0)
                              if "min_velocity_passive" in t else None),
        reversal_guard=guard,
    )
