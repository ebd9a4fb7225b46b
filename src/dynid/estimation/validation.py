"""Validation metrics of an identified model on held-out data, and the checks that make them honest.

* :class:`ValidationMetrics`: per-channel RMSE, relative RMSE, maximum error and R² of predicted
  against measured outputs, labelled held-out or in-sample;
* :func:`motion_overlap`: does the validation motion repeat the training motion (then its
  errors are in-sample errors, whatever file or window they come from);
* :func:`prior_comparison`: does the identified model beat the nominal (CAD) model on the same
  rows (the prior is the first baseline), or tie with it (:func:`tie_tolerance`).

Computed by :mod:`dynid.pipeline.identification`; read by the report and the studies.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.dataset import Dataset
from dynid.stats import REPEAT_THRESHOLD, nearest_distances

__all__ = ["TIE_FLOOR", "ValidationMetrics", "motion_overlap", "overlap_record", "prior_comparison", "tie_tolerance"]


@dataclasses.dataclass(frozen=True, eq=False)
class ValidationMetrics:
    """Prediction errors of an identified model on held-out data."""

    channel_names: tuple[str, ...]
    n_samples: int
    rmse: FloatArray
    rms_measured: FloatArray
    max_abs_error: FloatArray
    r2: FloatArray
    t: FloatArray
    measured: FloatArray
    predicted: FloatArray
    source: dict[str, Any]
    overlap: dict[str, Any] | None = None  # how close the validation motion comes to the training motion
    kept: np.ndarray | None = None  # (n, channels) bool: the errors are over these rows of each channel only
    # rows of each channel the errors are over when the arrays are not kept (a streamed identification,
    # dynid.pipeline.streaming: t, measured and predicted are then empty)
    counts: np.ndarray | None = None
    # a streamed identification with plots: the series of the validation figure already thinned to its pixel
    # columns ({"n_px", "measured", "predicted", "error"}: per channel (t - t0, y); dynid.pipeline.stream_plots)
    thinned: dict[str, Any] | None = None

    @property
    def rows_per_channel(self) -> np.ndarray:
        """Rows each channel's errors are computed over (all ``n_samples`` unless ``kept``)."""
        if self.counts is not None:
            return np.asarray(self.counts)
        if self.kept is None:
            return np.full(len(self.channel_names), self.n_samples)
        return self.kept.sum(axis=0)

    @property
    def in_sample(self) -> bool:
        """The validation motion repeats the training motion (see :func:`motion_overlap`): its
        errors are in-sample errors, whatever window or file they come from."""
        return bool(self.overlap and self.overlap["repeats_training"])

    @property
    def label(self) -> str:
        """``"held-out"`` or ``"in-sample"`` (what the validation errors are)."""
        return "in-sample" if self.in_sample else "held-out"

    def heading(self) -> str:
        """The title of the validation table."""
        if not self.in_sample:
            return f"Validation on held-out data ({self.n_samples} samples; never used for training)"
        return (f"Validation IN-SAMPLE ({self.n_samples} samples): the validation motion repeats the training motion "
                f"(median distance to the nearest training state {self.overlap['median_distance']:.3g} training "
                f"standard deviations, below {self.overlap['threshold']:g}); these errors do not show how the model "
                "predicts new motion: validate on another trajectory")

    @classmethod
    def of(cls, channel_names, t: FloatArray, measured: FloatArray, predicted: FloatArray, source,
           kept: np.ndarray | None = None) -> ValidationMetrics:
        """Errors of ``predicted`` against ``measured`` (n, channels) per channel; with ``kept``
        ((n, channels) bool) over the kept rows of each channel only (NaN for a channel without
        any), the arrays themselves stay whole."""
        if kept is None:
            w = np.ones(measured.shape, dtype=bool)
        else:
            w = np.broadcast_to(np.asarray(kept, dtype=bool), measured.shape)
        n = w.sum(axis=0)
        err = np.where(w, measured - predicted, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = np.sum(np.where(w, measured, 0.0), axis=0) / n
            centred = np.where(w, measured - mean, 0.0)
            r2 = 1.0 - np.sum(err**2, axis=0) / np.sum(centred**2, axis=0)
            rmse = np.sqrt(np.sum(err**2, axis=0) / n)
            rms = np.sqrt(np.sum(np.where(w, measured, 0.0) ** 2, axis=0) / n)
        return cls(
            channel_names=tuple(channel_names),
            n_samples=int(measured.shape[0]),
            rmse=rmse,
            rms_measured=rms,
            max_abs_error=np.where(n > 0, np.max(np.abs(err), axis=0, initial=0.0), np.nan),
            r2=r2,
            t=t,
            measured=measured,
            predicted=predicted,
            source=dict(source) if isinstance(source, dict) else {"source": str(source)},
            kept=None if kept is None else np.array(w),
        )

    @property
    def rel_rmse_pct(self) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * self.rmse / self.rms_measured

    def to_dict(self) -> dict[str, Any]:
        def finite(x) -> list:  # JSON has no NaN: a channel without rows (or without variance) gets null
            return [float(v) if np.isfinite(v) else None for v in np.asarray(x, float)]

        return {
            "joints": list(self.channel_names),
            "n_samples": self.n_samples,
            **({"rows_per_joint": self.rows_per_channel.tolist()} if self.kept is not None or self.counts is not None
               else {}),
            "rmse_per_joint": finite(self.rmse),
            "rel_rmse_pct_per_joint": finite(self.rel_rmse_pct),
            "max_abs_error_per_joint": finite(self.max_abs_error),
            "r2_per_joint": finite(self.r2),
            "rms_measured_per_joint": finite(self.rms_measured),
            "source": self.source,
            "kind": self.label,
            "motion_overlap": self.overlap,
            **({"warning": self.heading()} if self.in_sample else {}),
        }

    def table(self) -> str:
        rows = [("joint", "RMSE", "rel RMSE %", "max |err|", "R^2")]
        for c, r, p, m, q in zip(self.channel_names, self.rmse, self.rel_rmse_pct, self.max_abs_error, self.r2):
            rows.append((c, f"{r:.4g}", f"{p:.3g}", f"{m:.4g}", f"{q:.4f}"))
        if self.kept is not None or self.counts is not None:
            rows = [(*r, k) for r, k in zip(rows, ("rows", *(str(int(x)) for x in self.rows_per_channel)))]
        w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines = ["  ".join([r[0].ljust(w[0])] + [c.rjust(x) for c, x in zip(r[1:], w[1:])]) for r in rows]
        lines.insert(1, "-" * len(lines[0]))
        return "\n".join(lines)


def motion_overlap(train: Dataset, held_out: Dataset) -> dict[str, Any]:
    """Does the validation motion repeat the training motion?

    The processed states ``(q, dq, ddq)`` of every joint (actuator) are compared: each held-out
    state's distance to the nearest training state, in training standard deviations
    (:func:`dynid.stats.nearest_distances`). A median below
    :data:`dynid.stats.REPEAT_THRESHOLD` (0.05) means the validation motion retraces the training
    motion (a tail window of a periodic excitation, a copy of the log): its errors are in-sample
    errors. A new trajectory lies about one standard deviation away.
    """
    states = lambda ds: np.hstack([ds.q, ds.dq, ds.ddq])  # noqa: E731
    return overlap_record(nearest_distances(states(train), states(held_out)))


def overlap_record(d: FloatArray) -> dict[str, Any]:
    """The record of :func:`motion_overlap` from the distances ``d`` of the held-out states."""
    median = float(np.median(d))
    return {"median_distance": median, "p90_distance": float(np.quantile(d, 0.9)), "threshold": REPEAT_THRESHOLD,
            "repeats_training": median < REPEAT_THRESHOLD, "n_compared": int(d.size),
            "metric": "distance of held-out (q, dq, ddq) to the nearest training state, in training standard deviations"}


TIE_FLOOR = 0.01
"""The smallest relative difference of two mean relative RMSEs taken as a difference (1 %), however
many rows: held-out errors are correlated in time, so the rows resolve less than their count says."""


def tie_tolerance(n: int) -> float:
    """The relative difference of two RMSEs on ``n`` held-out rows that the rows cannot resolve:
    ``max(TIE_FLOOR, 1/sqrt(2 n))``. The RMS of n independent Gaussian errors has a relative
    standard error of 1/sqrt(2 n) (the variance of a sample variance is 2 sigma^4 / n); two
    models on the same rows share part of it, so this is a bound, not a test. No rows: 1."""
    return 1.0 if n <= 0 else max(TIE_FLOOR, 1.0 / np.sqrt(2.0 * n))


def prior_comparison(identified: ValidationMetrics, nominal: ValidationMetrics, comparable: bool = True,
                     label: str = "held-out") -> dict[str, Any]:
    """Does the identified model predict the held-out data better than the nominal (CAD) model?

    Per channel the RMSE of both; the headline is the mean relative RMSE over the channels
    (unit-free, so torques and forces can be averaged). ``comparable = False`` when the efforts
    are in units the nominal model does not predict (motor currents with unknown drive gains);
    ``label`` names the data (``"held-out"`` or ``"in-sample"``, :attr:`ValidationMetrics.label`).

    The identified model *beats* the nominal one only when its mean relative RMSE is lower by
    more than :func:`tie_tolerance` of the larger of the two (the fewest rows of a channel set
    it); within it the two *tie* (``"tie": True``, ``beats_nominal`` False): "beats" is never said
    of 99.8 % against 99.8 %."""
    rel_i, rel_n = np.asarray(identified.rel_rmse_pct), np.asarray(nominal.rel_rmse_pct)
    better = [bool(a < b) for a, b in zip(identified.rmse, nominal.rmse)]
    mean_i, mean_n = float(np.nanmean(rel_i)), float(np.nanmean(rel_n))
    rows = np.asarray(identified.rows_per_channel, dtype=float)
    tol = tie_tolerance(int(rows[rows > 0].min()) if np.any(rows > 0) else 0)
    tie = bool(abs(mean_i - mean_n) <= tol * max(mean_i, mean_n))
    beats = bool(comparable and mean_i < mean_n and not tie)
    out: dict[str, Any] = {
        "comparable": comparable,
        "metric": "mean over channels of the held-out RMSE relative to the RMS of the measured output [%]",
        "identified_mean_rel_rmse_pct": mean_i,
        "nominal_mean_rel_rmse_pct": mean_n,
        "channels_better": int(sum(better)),
        "n_channels": len(better),
        "better_per_channel": better,
        "beats_nominal": beats,
        "tie": bool(comparable and tie),
        "tie_tolerance_pct": 100.0 * tol,
        "tie_rule": ("a tie when the two mean relative RMSEs differ by at most max(1 %, 1/sqrt(2 n)) of the larger, n "
                     "the fewest held-out rows of a channel: the relative standard error of an RMS over n independent "
                     "errors"),
    }
    if not comparable:
        out["verdict"] = ("the nominal model cannot be compared: the efforts are motor currents with unit drive gains "
                          "(the identified parameters absorb the unknown gains, the nominal ones do not)")
    elif tie:
        out["verdict"] = (f"the identified model TIES with the nominal model on {label} data: mean relative RMSE "
                          f"{mean_i:.3g} % against {mean_n:.3g} % (a difference within {100 * tol:.3g} % of the larger, "
                          f"which these rows cannot resolve; {sum(better)} of {len(better)} channels better); the "
                          "identification adds nothing the robot description did not already predict")
    elif mean_i < mean_n:
        out["verdict"] = (f"the identified model beats the nominal model on {label} data: mean relative RMSE "
                          f"{mean_i:.3g} % against {mean_n:.3g} % ({sum(better)} of {len(better)} channels better)")
    else:
        out["verdict"] = (f"WARNING: the identified model does NOT beat the nominal model on {label} data: mean "
                          f"relative RMSE {mean_i:.3g} % against the nominal model's {mean_n:.3g} % ({sum(better)} "
                          f"of {len(better)} channels better); use the nominal model, or improve the excitation, the "
                          "processing or the model structure before trusting these parameters")
    return out
