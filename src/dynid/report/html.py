"""A self-contained HTML report of one identification."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from dynid.estimation.results import IdentificationResult

__all__ = ["write_html_report"]

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px}
table{border-collapse:collapse;margin:1em 0;font-size:13px}
td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}
th{background:#f3f3f3} td:first-child,th:first-child{text-align:left}
img{max-width:100%}
"""


def _prior_html(metrics: Any, nominal: Any, prior: dict) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(c)}</td><td>{a:.4g}</td><td>{b:.4g}</td><td>{'yes' if a < b else '<b>no</b>'}</td></tr>"
        for c, a, b in zip(metrics.channel_names, metrics.rmse, nominal.rmse)
    )
    return ("<h2>Against the prior: the nominal model on the same data</h2>"
            "<table><tr><th>channel</th><th>RMSE identified</th><th>RMSE nominal</th><th>identified better</th></tr>"
            f"{rows}</table><p><b>{html.escape(prior['verdict'])}</b></p>")


def _other_view_html(view: Any) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(c)}</td><td>{a:.4g}</td><td>{p:.3g}</td>"
        + (f"<td>{b:.4g}</td>" if view.nominal is not None else "") + "</tr>"
        for k, (c, a, p) in enumerate(zip(view.metrics.channel_names, view.metrics.rmse, view.metrics.rel_rmse_pct))
        for b in [view.nominal.rmse[k] if view.nominal is not None else 0.0]
    )
    head = "<th>RMSE nominal</th>" if view.nominal is not None else ""
    return (f"<h2>The same predictions in the other form</h2><p>{html.escape(view.label)}</p>"
            f"<table><tr><th>channel</th><th>RMSE identified</th><th>rel RMSE %</th>{head}</tr>{rows}</table>")


def _selected_html(sel: Any) -> str:
    m, n = sel.metrics, sel.nominal
    rows = "".join(
        f"<tr><td>{html.escape(c)}</td><td>{int(k)}</td><td>{a:.4g}</td>"
        + (f"<td>{n.rmse[i]:.4g}</td><td>{'yes' if a < n.rmse[i] else '<b>no</b>'}</td>" if n is not None else "") + "</tr>"
        for i, (c, k, a) in enumerate(zip(m.channel_names, m.rows_per_channel, m.rmse)))
    head = "<th>RMSE nominal</th><th>identified better</th>" if n is not None else ""
    verdict = f"<p><b>{html.escape(sel.prior['verdict'])}</b></p>" if sel.prior is not None else ""
    return (f"<h2>On the rows the row selection keeps</h2><p>{html.escape(sel.heading())}</p>"
            f"<table><tr><th>channel</th><th>rows</th><th>RMSE identified</th>{head}</tr>{rows}</table>{verdict}")


def write_html_report(result: IdentificationResult, metrics: Any, path: str | Path, plot: str | None = None,
                      nominal: Any = None, prior: dict | None = None, other_view: Any = None,
                      selected: Any = None) -> Path:
    """Summary, validation table and (optionally) the validation plot in one HTML file; with
    ``nominal`` (the nominal model's validation metrics) and ``prior`` (their comparison), the
    nominal model's errors next to the identified model's and the verdict; with ``other_view``
    (a redundant robot's :class:`~dynid.pipeline.identification.OtherView`) that table too; with
    ``selected`` (:class:`~dynid.pipeline.identification.SelectedRows`) both models' errors on the
    held-out rows the training's row selection keeps."""
    rows = "".join(
        f"<tr><td>{html.escape(c)}</td><td>{r:.4g}</td><td>{p:.3g}</td><td>{q:.4f}</td></tr>"
        for c, r, p, q in zip(metrics.channel_names, metrics.rmse, metrics.rel_rmse_pct, metrics.r2)
    )
    body = (
        f"<h1>dynid identification report</h1>{result.summary().as_html()}"
        + (f"<h2>Held-out validation ({metrics.n_samples} samples)</h2>" if not getattr(metrics, "in_sample", False)
           else f"<h2>In-sample validation ({metrics.n_samples} samples)</h2><p><b>{html.escape(metrics.heading())}</b></p>")
        + f"<table><tr><th>joint</th><th>RMSE [N·m]</th><th>rel RMSE %</th><th>R²</th></tr>{rows}</table>"
        + (f"<img src='{html.escape(plot)}' alt='validation plot'>" if plot else "")
        + (_prior_html(metrics, nominal, prior) if nominal is not None and prior is not None else "")
        + (_selected_html(selected) if selected is not None else "")
        + (_other_view_html(other_view) if other_view is not None else "")
    )
    path = Path(path)
    path.write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>dynid report</title><style>{_STYLE}</style></head><body>{body}</body></html>")
    return path
