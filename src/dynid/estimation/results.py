"""The results of an identification: estimates, uncertainty, diagnostics, provenance.

Modelled on statsmodels' regression results: attributes computed once by the
estimator, derived statistics as properties, a text/HTML summary, and explicit
persistence as JSON + NPZ (no pickle).

Statistics (paper 002 Eqs. 29–30; paper 001 Eq. 20):

- standard errors :math:`\\sigma_{\\hat\\beta_i} = \\sqrt{\\Sigma_{ii}}`;
- relative standard deviation :math:`100\\,\\sigma_{\\hat\\beta_i}/|\\hat\\beta_i|` [%];
- two-sided :math:`100(1-\\alpha)` % intervals
  :math:`\\hat\\beta_i \\pm t_{1-\\alpha/2}(\\nu)\\,\\sigma_{\\hat\\beta_i}` with
  :math:`\\nu = N - p` degrees of freedom;
- the confidence ellipsoid of the whole parameter set (paper 002, Eq. 29): a point
  :math:`\\theta` lies in the :math:`100(1-\\alpha)` % ellipsoid iff
  :math:`(\\hat\\beta-\\theta)^T\\Sigma^{-1}(\\hat\\beta-\\theta) \\le \\chi^2_{p,1-\\alpha}`;
- the condition number of the correlation matrix of the estimates (paper 004, Eq. 11).
"""

from __future__ import annotations

import dataclasses
import html
import json
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from dynid._files import save_npz
from dynid._typing import FloatArray
from dynid.errors import InputError
from dynid.stats import chi2_radius, correlation_condition_number, ellipsoid_statistic, relative_std, t_quantile

__all__ = ["IdentificationResult", "Summary"]

_FORMAT = "dynid.IdentificationResult/1"


@dataclasses.dataclass(frozen=True)
class Summary:
    """A printable summary (``str()`` gives text, ``as_html()`` an HTML fragment)."""

    title: str
    info: tuple[tuple[str, str], ...]
    channel_table: tuple[tuple[str, ...], ...]
    param_table: tuple[tuple[str, ...], ...]
    notes: tuple[str, ...]

    @staticmethod
    def _fmt_table(rows: tuple[tuple[str, ...], ...]) -> list[str]:
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        out = []
        for k, r in enumerate(rows):
            cells = [r[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(r[1:], widths[1:])]
            out.append("  ".join(cells).rstrip())
            if k == 0:
                out.append("-" * len(out[-1]))
        return out

    def as_text(self) -> str:
        lines = [self.title, "=" * len(self.title)]
        kw = max(len(k) for k, _ in self.info)
        lines += [f"{k.ljust(kw)} : {v}" for k, v in self.info]
        lines += [""] + self._fmt_table(self.channel_table)
        lines += [""] + self._fmt_table(self.param_table)
        if self.notes:
            lines += [""] + [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.as_text()

    def as_html(self) -> str:
        def table(rows: tuple[tuple[str, ...], ...]) -> str:
            head = "".join(f"<th>{html.escape(c)}</th>" for c in rows[0])
            body = "".join(
                "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows[1:]
            )
            return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

        info = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in self.info)
        notes = "".join(f"<li>{html.escape(n)}</li>" for n in self.notes)
        return (
            f"<div class='dynid-summary'><h3>{html.escape(self.title)}</h3><table>{info}</table>"
            f"{table(self.channel_table)}{table(self.param_table)}"
            + (f"<ul>{notes}</ul>" if notes else "")
            + "</div>"
        )

    def _repr_html_(self) -> str:
        return self.as_html()


def _freeze(a: FloatArray | None) -> FloatArray | None:
    if a is None:
        return None
    arr = np.array(a, dtype=float)
    arr.setflags(write=False)
    return arr


@dataclasses.dataclass(frozen=True, eq=False)
class IdentificationResult:
    """Estimates of one identification run.

    Attributes
    ----------
    method : str
        Estimator name (``"OLS"``, ``"WLS"``, ...).
    names : tuple of str
        Parameter names.
    params : array, shape (p,)
        Estimates.
    cov_params : array, shape (p, p) or None
        Covariance of the estimates; ``None`` for methods that give none (then
        ``bse``, ``rel_std`` and ``conf_int`` raise, instead of reusing another's).
    dof : int
        Residual degrees of freedom ``N - p``.
    scale : float
        Residual variance factor of the (whitened) fit.
    channel_names : tuple of str
    n_obs : int array, shape (n_ch,)
        Samples per channel.
    rss_per_channel : array, shape (n_ch,)
        Training residual sums of squares, in output units².
    noise_std : array, shape (n_ch,)
        Per-channel noise standard deviation estimated from the residuals
        (for WLS the values that set the weights).
    condition_number : float
        Condition number of the (whitened) regressor used for the solve.
    expressions : tuple of str or None
        Grouping expressions (display only).
    solver, provenance : mapping
        How the estimate was computed; where inputs came from (versions, hashes, config).
    notes : tuple of str
        Statements about assumptions a reader must know.
    """

    method: str
    names: tuple[str, ...]
    params: FloatArray
    cov_params: FloatArray | None
    dof: int
    scale: float
    channel_names: tuple[str, ...]
    n_obs: np.ndarray
    rss_per_channel: FloatArray
    noise_std: FloatArray
    condition_number: float
    expressions: tuple[str, ...] | None = None
    solver: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    provenance: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", _freeze(self.params))
        object.__setattr__(self, "cov_params", _freeze(self.cov_params))
        object.__setattr__(self, "rss_per_channel", _freeze(self.rss_per_channel))
        object.__setattr__(self, "noise_std", _freeze(self.noise_std))
        n_obs = np.array(self.n_obs, dtype=np.int64)
        n_obs.setflags(write=False)
        object.__setattr__(self, "n_obs", n_obs)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "channel_names", tuple(self.channel_names))
        if self.expressions is not None:
            object.__setattr__(self, "expressions", tuple(self.expressions))
        object.__setattr__(self, "solver", MappingProxyType(dict(self.solver)))
        object.__setattr__(self, "provenance", MappingProxyType(dict(self.provenance)))
        object.__setattr__(self, "notes", tuple(self.notes))
        if self.params.shape != (len(self.names),):
            raise InputError(f"{len(self.names)} names for {self.params.shape} parameters")

    # ------------------------------------------------------------------ statistics
    def _need_cov(self) -> FloatArray:
        if self.cov_params is None:
            raise InputError(f"{self.method} gives no covariance of the estimates")
        return self.cov_params

    @property
    def bse(self) -> FloatArray:
        """Standard errors of the estimates."""
        return np.sqrt(np.clip(np.diag(self._need_cov()), 0.0, None))

    @property
    def rel_std(self) -> FloatArray:
        """Relative standard deviation [%] (paper 001 Eq. 20)."""
        return relative_std(self.params, self.bse)

    def conf_int(self, alpha: float = 0.05) -> FloatArray:
        """Two-sided ``100(1-alpha)`` % intervals, shape (p, 2) (paper 002 Eq. 30)."""
        half = t_quantile(alpha, self.dof) * self.bse
        return np.column_stack([self.params - half, self.params + half])

    @property
    def covariance_kind(self) -> str | None:
        """Which covariance the standard errors and intervals use: ``"model"`` (the estimator's own,
        e.g. :math:`s^2 (W^T W)^{-1}`), ``"hac"`` or ``"block_bootstrap"`` (block-robust,
        :mod:`dynid.estimation.block_covariance`); None when the method gives none."""
        if self.cov_params is None:
            return None
        c = self.solver.get("covariance")
        return str(c.get("kind", "model")) if isinstance(c, Mapping) else "model"

    @property
    def rmse_per_channel(self) -> FloatArray:
        """Training RMSE per output channel."""
        return np.sqrt(self.rss_per_channel / np.maximum(self.n_obs, 1))

    @property
    def correlation(self) -> FloatArray:
        """Correlation matrix of the estimates."""
        cov = self._need_cov()
        s = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
        return cov / np.outer(s, s)

    @property
    def correlation_condition_number(self) -> float:
        """Condition number of the correlation matrix of the estimates (paper 004, Eq. 11).

        Independent of the parameters' units; the criterion of paper 004 for choosing a
        friction structure (lower is better; see
        :func:`dynid.estimation.identifiability.select_friction_structure`).
        """
        return correlation_condition_number(self._need_cov())

    def _reference_vector(self, reference: FloatArray | Mapping[str, float]) -> FloatArray:
        if isinstance(reference, Mapping):
            missing = [n for n in self.names if n not in reference]
            if missing:
                raise InputError(f"reference lacks parameters {missing}")
            return np.array([float(reference[n]) for n in self.names])
        ref = np.asarray(reference, dtype=float)
        if ref.shape != self.params.shape:
            raise InputError(f"reference has shape {ref.shape}, the estimate {self.params.shape}")
        return ref

    def chi2_statistic(self, reference: FloatArray | Mapping[str, float]) -> float:
        """:math:`(\\hat\\beta - \\theta)^T \\Sigma^{-1} (\\hat\\beta - \\theta)` of a reference point.

        Parameters
        ----------
        reference : array of shape (p,), or mapping name -> value
            The point :math:`\\theta` (true, nominal or another run's parameters).

        Returns
        -------
        float
            :math:`\\chi^2(p)`-distributed when the estimate is unbiased with the
            reported covariance (paper 002, Eq. 29 and Fig. 9).
        """
        return ellipsoid_statistic(self.params, self._reference_vector(reference), self._need_cov())

    def in_confidence_ellipsoid(self, reference: FloatArray | Mapping[str, float], alpha: float = 0.05) -> bool:
        """Whether ``reference`` lies in the ``100(1-alpha)`` % confidence ellipsoid (paper 002, Eq. 29).

        True iff :meth:`chi2_statistic` is at most :func:`dynid.stats.chi2_radius`
        ``(p, alpha)`` (36.42 for 24 parameters at 95 %).
        """
        return bool(self.chi2_statistic(reference) <= chi2_radius(len(self.names), alpha))

    def predict(self, W: FloatArray) -> FloatArray:
        """Outputs ``W @ params`` for a regressor of shape (..., p)."""
        return np.asarray(W) @ self.params

    @property
    def timing(self) -> dict[str, Any]:
        """The wall-clock figures of the solver information (``wall_time_s``, ``solve_time_s``,
        nested as in :attr:`solver`). They differ between equal runs, so :meth:`to_dict` and
        :meth:`save` leave them out; ``dynid identify`` writes them to ``timing.json``."""
        return _timing_only(self.solver)

    def with_provenance(self, **entries: Any) -> IdentificationResult:
        return dataclasses.replace(self, provenance={**self.provenance, **entries})

    def with_notes(self, *notes: str) -> IdentificationResult:
        return dataclasses.replace(self, notes=self.notes + tuple(notes))

    # ------------------------------------------------------------------ presentation
    def summary(self, alpha: float = 0.05) -> Summary:
        pct = int(round(100 * (1 - alpha)))
        info = (
            ("method", self.method),
            ("parameters", str(len(self.names))),
            ("observations", f"{int(self.n_obs.sum())} ({len(self.channel_names)} channels)"),
            ("degrees of freedom", str(self.dof)),
            ("condition number", f"{self.condition_number:.4g}"),
            ("residual scale", f"{self.scale:.4g}"),
        )
        if self.cov_params is not None:
            info += (("covariance", str(self.covariance_kind)),
                     ("correlation cond. number", f"{self._corr_cond_text()}"))
        ch_rows = [("channel", "samples", "train RMSE", "noise std")]
        for c, n, r, s in zip(self.channel_names, self.n_obs, self.rmse_per_channel, self.noise_std):
            ch_rows.append((c, str(int(n)), f"{r:.4g}", f"{s:.4g}"))
        has_cov = self.cov_params is not None
        header = ("parameter", "value", "std", "rel std %", f"{pct}% low", f"{pct}% high")
        rows = [header if has_cov else ("parameter", "value")]
        if has_cov:
            ci = self.conf_int(alpha)
            for n, v, s, r, (lo, hi) in zip(self.names, self.params, self.bse, self.rel_std, ci):
                rows.append((n, f"{v:.6g}", f"{s:.3g}", f"{r:.3g}", f"{lo:.6g}", f"{hi:.6g}"))
        else:
            rows += [(n, f"{v:.6g}") for n, v in zip(self.names, self.params)]
        notes = list(self.notes)
        if not has_cov:
            notes.append(f"{self.method} gives no covariance; no standard errors are reported")
        if self.expressions is not None:
            notes.append("base parameters (grouping expressions):")
            notes += [f"  {n} := {e}" for n, e in zip(self.names, self.expressions) if e != n]
        return Summary(
            title=f"dynid identification result ({self.method})",
            info=info,
            channel_table=tuple(ch_rows),
            param_table=tuple(rows),
            notes=tuple(notes),
        )

    def _corr_cond_text(self) -> str:
        try:
            return f"{self.correlation_condition_number:.4g}"
        except InputError as exc:  # e.g. a zero variance: say why instead of failing the summary
            return f"undefined ({exc})"

    def _repr_html_(self) -> str:
        return self.summary().as_html()

    def to_frame(self, alpha: float = 0.05):  # -> pandas.DataFrame
        """A pandas DataFrame with one row per parameter."""
        import pandas as pd

        data: dict[str, Any] = {"value": self.params}
        if self.cov_params is not None:
            ci = self.conf_int(alpha)
            data.update(std=self.bse, rel_std_pct=self.rel_std, ci_low=ci[:, 0], ci_high=ci[:, 1])
        if self.expressions is not None:
            data["expression"] = list(self.expressions)
        return pd.DataFrame(data, index=pd.Index(self.names, name="name"))

    # ------------------------------------------------------------------ persistence
    def to_dict(self, alpha: float = 0.05) -> dict[str, Any]:
        """JSON-ready description (parameters as a list of records)."""
        params = []
        ci = self.conf_int(alpha) if self.cov_params is not None else None
        for i, n in enumerate(self.names):
            rec: dict[str, Any] = {"name": n, "value": float(self.params[i])}
            if ci is not None:
                rec.update(
                    std=float(self.bse[i]),
                    rel_std_pct=float(self.rel_std[i]) if np.isfinite(self.rel_std[i]) else None,
                    ci_low=float(ci[i, 0]),
                    ci_high=float(ci[i, 1]),
                )
            else:  # no covariance for this method: the fields are present and explicitly null
                rec.update(std=None, rel_std_pct=None, ci_low=None, ci_high=None)
            if self.expressions is not None:
                rec["expression"] = self.expressions[i]
            params.append(rec)
        return {
            "format": _FORMAT,
            "method": self.method,
            "confidence_level": 1 - alpha,
            "params": params,
            "dof": int(self.dof),
            "scale": float(self.scale),
            "condition_number": float(self.condition_number),
            "channels": [
                {"name": c, "n_obs": int(n), "train_rmse": float(r), "noise_std": float(s), "rss": float(q)}
                for c, n, r, s, q in zip(
                    self.channel_names, self.n_obs, self.rmse_per_channel, self.noise_std, self.rss_per_channel
                )
            ],
            "has_covariance": self.cov_params is not None,
            "covariance": self.covariance_kind,
            "solver": _jsonable(_without_timing(self.solver)),
            "provenance": _jsonable(self.provenance),
            "notes": list(self.notes),
        }

    def save(self, path: str | Path, extra: Mapping[str, Any] | None = None) -> tuple[Path, Path]:
        """Write ``<path>.json`` (readable) and ``<path>.npz`` (exact arrays).

        ``extra`` entries (e.g. validation metrics) are added to the JSON document;
        :meth:`load` ignores them.
        """
        base = Path(path)
        if base.suffix in (".json", ".npz"):
            base = base.with_suffix("")
        jpath, npath = base.with_suffix(".json"), base.with_suffix(".npz")
        arrays = {"params": self.params, "n_obs": self.n_obs, "rss_per_channel": self.rss_per_channel, "noise_std": self.noise_std}
        if self.cov_params is not None:
            arrays["cov_params"] = self.cov_params
        save_npz(npath, arrays)
        doc = self.to_dict()
        if extra:
            clash = set(extra) & set(doc)
            if clash:
                raise InputError(f"extra result entries {sorted(clash)} would overwrite the result's own")
            doc.update(_jsonable(extra))
        jpath.write_text(json.dumps(doc, indent=2, allow_nan=False))
        return jpath, npath

    @classmethod
    def load(cls, path: str | Path) -> IdentificationResult:
        """Read a result written by :meth:`save` (exact arrays from the NPZ)."""
        base = Path(path)
        if base.suffix in (".json", ".npz"):
            base = base.with_suffix("")
        jpath, npath = base.with_suffix(".json"), base.with_suffix(".npz")
        for p in (jpath, npath):
            if not p.is_file():
                raise InputError(f"result file not found: {p}")
        doc = json.loads(jpath.read_text())
        if doc.get("format") != _FORMAT:
            raise InputError(f"{jpath}: not a dynid result (format {doc.get('format')!r})")
        with np.load(npath, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        exprs = [p.get("expression") for p in doc["params"]]
        return cls(
            method=doc["method"],
            names=tuple(p["name"] for p in doc["params"]),
            params=arrays["params"],
            cov_params=arrays.get("cov_params"),
            dof=doc["dof"],
            scale=doc["scale"],
            channel_names=tuple(c["name"] for c in doc["channels"]),
            n_obs=arrays["n_obs"],
            rss_per_channel=arrays["rss_per_channel"],
            noise_std=arrays["noise_std"],
            condition_number=doc["condition_number"],
            expressions=tuple(exprs) if all(e is not None for e in exprs) else None,
            solver=doc.get("solver", {}),
            provenance=doc.get("provenance", {}),
            notes=tuple(doc.get("notes", ())),
        )


_TIMING_KEYS = frozenset({"wall_time_s", "solve_time_s"})


def _without_timing(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {k: _without_timing(v) for k, v in x.items() if k not in _TIMING_KEYS}
    return x


def _timing_only(x: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in x.items():
        if k in _TIMING_KEYS:
            out[k] = v
        elif isinstance(v, Mapping) and (sub := _timing_only(v)):
            out[k] = sub
    return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (str, int, bool)) or x is None:
        return x
    return str(x)
