"""A self-contained HTML report of one identification: one file, images embedded as ``data:``
URIs, no external style sheet, script or link; a one-line verdict at the top.

Sections: the verdict (identified against nominal model on the validation data, held-out or
in-sample as :func:`~dynid.estimation.validation.motion_overlap` found), the fit, the parameters
with the badly identified ones flagged (:func:`dynid.pipeline.reporting.parameter_flags`: relative
standard deviation, paper 001 Eq. 20, at or above 15 %, paper 000 §6.2; undefined relative
standard deviation; physical inconsistency), the validation against the nominal model, the plots
(processing, validation) and the provenance (versions, git commit, configuration and log files
with their SHA-256, date and machine).
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from dynid.estimation.results import IdentificationResult

__all__ = ["structure_lines", "verdict", "write_html_report"]

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px}
table{border-collapse:collapse;margin:1em 0;font-size:13px}
td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}
th{background:#f3f3f3} td:first-child,th:first-child{text-align:left}
img{max-width:100%}
.verdict{font-size:17px;padding:.6em 1em;border-left:6px solid #2a7;background:#eef8f1}
.verdict.bad{border-color:#c33;background:#fbeeee}
tr.flag td{background:#fff3d6} .why{text-align:left;color:#a40}
code{font-size:12px;word-break:break-all}
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
    fl = getattr(sel, "floor", None)
    floor = "" if fl is None else (
        "<p>Held-out-fit floor (the same structure fitted by least squares to these held-out rows themselves: "
        "no model of this structure has a smaller pooled RMS there): "
        + ", ".join(f"{html.escape(c)} {x:.4g}" for c, x in zip(fl.channel_names, fl.rmse))
        + f"; pooled {fl.pooled:.4g}</p>")
    return (f"<h2>On the rows the row selection keeps</h2><p>{html.escape(sel.heading())}</p>"
            f"<table><tr><th>channel</th><th>rows</th><th>RMSE identified</th>{head}</tr>{rows}</table>{verdict}{floor}")


def _fmt(x: float, spec: str = ".3g") -> str:
    return format(float(x), spec) if np.isfinite(x) else "n/a"


def verdict(metrics: Any, nominal: Any = None, prior: Mapping[str, Any] | None = None,
            units: Any = None, flags: Mapping[str, Any] | None = None) -> tuple[str, bool]:
    """The report's one-line verdict and whether it is good news.

    From ``prior`` (:func:`~dynid.estimation.validation.prior_comparison`: the identified model
    beats the nominal one when its mean relative RMSE over the channels is lower by more than
    the tie tolerance, and ties with it within that tolerance), the channels
    on which it is better, the mean RMSE of both in the channels' unit when they share one, the
    kind of validation (held-out, or in-sample when the validation motion repeats the training
    motion) and the number of flagged parameters."""
    label = getattr(metrics, "label", "held-out")
    unit = units[0] if units is not None and len(set(units)) == 1 else None
    mean_i = float(np.nanmean(metrics.rmse))
    if prior is None or nominal is None:
        line, good = (f"no nominal model to compare with: the identified model's mean relative RMSE on {label} data is "
                      f"{_fmt(np.nanmean(metrics.rel_rmse_pct))} %"), False
    elif not prior["comparable"]:
        line, good = (f"the identified model's mean relative RMSE on {label} data is "
                      f"{_fmt(prior['identified_mean_rel_rmse_pct'])} %; the nominal model cannot be compared (efforts "
                      "are motor currents with unit drive gains)"), False
    else:
        mean_n = float(np.nanmean(nominal.rmse))
        absolute = f"mean RMSE {_fmt(mean_i)} vs {_fmt(mean_n)} {unit}, " if unit else ""
        numbers = (f"on {prior['channels_better']} of {prior['n_channels']} channels ({absolute}mean relative RMSE "
                   f"{_fmt(prior['identified_mean_rel_rmse_pct'])} % vs {_fmt(prior['nominal_mean_rel_rmse_pct'])} %)")
        good = bool(prior["beats_nominal"])
        line = (f"the identified model beats the nominal model on {label} data {numbers}" if good else
                f"the identified model TIES with the nominal model on {label} data {numbers}" if prior.get("tie") else
                f"the identified model does NOT beat the nominal model on {label} data {numbers}")
    if label == "in-sample":
        good = False
        line += "; IN-SAMPLE only: the validation motion repeats the training motion, validate on another trajectory"
    if flags is not None:
        k = len(_flagged(flags))
        line += f"; {k} parameter{'s' if k != 1 else ''} flagged" if k else "; no parameter flagged"
    line = line[0].upper() + line[1:] + "."
    return line, good


def _flagged(flags: Mapping[str, Any]) -> dict[str, list[str]]:
    """Parameter name -> reasons, in first-seen order."""
    out: dict[str, list[str]] = {}
    lim = flags.get("rel_std_limit_pct", 15.0)
    for n in flags.get("rel_std_above", ()):
        out.setdefault(n, []).append(f"rel. std >= {lim:g} %")
    for n in flags.get("undetermined", ()):
        out.setdefault(n, []).append("undetermined (rel. std undefined)")
    phys = flags.get("physical") or {}
    for n in phys.get("parameters", ()) if phys.get("checked") else ():
        out.setdefault(n, []).append("physically inconsistent")
    return out


def _params_html(result: IdentificationResult, flags: Mapping[str, Any] | None, alpha: float = 0.05) -> str:
    why = _flagged(flags) if flags is not None else {}
    has_cov = result.cov_params is not None
    pct = int(round(100 * (1 - alpha)))
    head = ("<tr><th>parameter</th><th>value</th>" + (f"<th>std</th><th>rel std %</th><th>{pct}% low</th>"
            f"<th>{pct}% high</th>" if has_cov else "") + "<th>flag</th></tr>")
    rows = []
    ci = result.conf_int(alpha) if has_cov else None
    for i, name in enumerate(result.names):
        cells = f"<td>{html.escape(name)}</td><td>{result.params[i]:.6g}</td>"
        if has_cov:
            cells += (f"<td>{result.bse[i]:.3g}</td><td>{_fmt(result.rel_std[i])}</td><td>{ci[i, 0]:.6g}</td>"
                      f"<td>{ci[i, 1]:.6g}</td>")
        reasons = why.get(name, [])
        cells += f"<td class='why'>{html.escape('; '.join(reasons))}</td>"
        rows.append(f"<tr class='flag' data-param='{html.escape(name)}'>{cells}</tr>" if reasons
                    else f"<tr data-param='{html.escape(name)}'>{cells}</tr>")
    text = ""
    if flags is not None:
        text = f"<p>{html.escape(flags['rule'])}.</p>"
        if not flags.get("assessed", True):
            text += f"<p><b>Relative standard deviations not assessed:</b> {html.escape(flags['reason'])}.</p>"
        phys = flags.get("physical") or {}
        if not phys.get("checked"):
            text += f"<p>Physical consistency not checked: {html.escape(str(phys.get('reason', '')))}.</p>"
        elif phys.get("feasible"):
            text += "<p>Physical consistency: a physically consistent standard parameter vector maps to these base parameters.</p>"
        else:
            text += ("<p><b>Physically inconsistent:</b> no physically consistent standard parameter vector maps to these "
                     f"base parameters; violated: {html.escape(', '.join(phys.get('violated', [])))}.</p>")
        text += (f"<p id='flagged'><b>{len(why)} of {len(result.names)} parameters flagged</b>"
                 + (f": {html.escape(', '.join(why))}" if why else "") + "</p>")
    return f"<h2 id='parameters'>Parameters</h2>{text}<table>{head}{''.join(rows)}</table>"


def _provenance_html(result: IdentificationResult, facts: Mapping[str, str] | None) -> str:
    prov = result.provenance
    rows: list[tuple[str, str]] = [(k, str(v)) for k, v in dict(prov.get("versions", {})).items()]
    rows.append(("configuration", str(prov.get("config_file") or "(none: built in memory)")))
    if prov.get("config_sha256"):
        rows.append(("configuration SHA-256", str(prov["config_sha256"])))
    for key, what in (("training_data", "training log"), ("validation_data", "validation log")):
        for path, digest in dict((prov.get(key) or {}).get("sha256", {})).items():
            rows.append((f"{what}", f"{path}  SHA-256 {digest}"))
    for k, v in (facts or {}).items():
        rows.append((k, v))
    body = "".join(f"<tr><th>{html.escape(k)}</th><td style='text-align:left'><code>{html.escape(v)}</code></td></tr>"
                   for k, v in rows)
    return f"<section id='provenance'><h2>Provenance</h2><table>{body}</table></section>"


def _image_html(path: Path, title: str) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return (f"<figure><img src='data:image/png;base64,{data}' alt='{html.escape(title)}'>"
            f"<figcaption>{html.escape(title)} ({html.escape(Path(path).name)})</figcaption></figure>")


def _several_logs_html(prov: Mapping[str, Any]) -> str:
    """``[[data]]`` / ``[[validation]]`` (:mod:`dynid.pipeline.experiments`): a row per experiment, a held-out
    table per validation log and the pooled one (squared errors summed over every log's rows)."""
    out = ""
    if prov.get("experiments"):
        rows = "".join(f"<tr><td>data[{e['index']}]</td><td>{html.escape(', '.join(Path(f).name for f in e['files']))}"
                       f"</td><td>{e['samples_processed']}</td><td>{e['rate_hz']:.6g}</td><td>{e['rows_used']}</td>"
                       f"<td>{', '.join(f'{x:.4g}' for x in e['noise_std'])}</td></tr>" for e in prov["experiments"])
        out += ("<h2 id='experiments'>Experiments ([[data]])</h2><table><tr><th>experiment</th><th>files</th>"
                f"<th>samples</th><th>rate Hz</th><th>rows used</th><th>noise std (WLS weights)</th></tr>{rows}</table>")
    logs = list(prov.get("validation_logs") or [])
    if logs:
        pooled = prov.get("validation_pooled")
        rows = "".join(f"<tr><td>{html.escape(v['label'])}</td>" + "".join(
            f"<td>{e:.4g} ({100 * r:.1f} %)</td>" for e, r in zip(v["rmse"], v["relative_rmse"])) + "</tr>"
            for v in [*logs, *([pooled] if pooled else [])])
        out += ("<h2 id='validation-logs'>Held-out error per validation log</h2><table><tr><th>log</th>"
                + "".join(f"<th>{html.escape(c)} RMSE (rel.)</th>" for c in logs[0]["channels"]) + f"</tr>{rows}</table>")
    return out


def structure_lines(record: dict[str, Any] | None) -> list[str]:
    """The parameter structure and the evidence of its choice in words (summary.txt, the report):
    ``record`` is result.json's ``"structure"`` (:mod:`dynid.pipeline.structure`)."""
    if record is None:
        return []
    head = f"Parameter structure: {record['chosen']}"
    if "reason" in record:  # forced, or "auto" without a decision to make
        return ["", head + f" ({record['mode']}: {record['reason']})"]
    groups = "; ".join(" = ".join("(" + ", ".join(c) + ")" for c in g) for g in record["chains"])
    lines = ["", head + " (identification.structure = 'auto')",
             f"  identical chains {record['chains_source']}: {groups}",
             f"  base parameters: full {record['n_base_params']['full']}, tied {record['n_base_params']['identical_chains']}"]
    if record["F"] is not None:
        lines.append(f"  F test of the tie: F = {record['F']:.4g} on ({record['df'][0]}, {record['df'][1]}) dof, "
                     f"p = {record['p_value']:.3g} ({'rejected' if record['rejected'] else 'not rejected'} at "
                     f"{100 * record['alpha']:g} %)")
    else:
        lines.append("  F test: the tie removes nothing these data determine")
    lines.append(f"  BIC: full {record['bic']['full']:.6g}, tied {record['bic']['identical_chains']:.6g}")
    cv = record["cv"]
    if cv is not None:
        lines.append(f"  cross-validation over {cv['segments']} time segments, mean held-out weighted RMSE: "
                     f"full {cv['full']:.5g}, tied {cv['identical_chains']:.5g}")
    lines.append(f"  rule: {record['rule']}")
    return lines


def _structure_html(structure: Mapping[str, Any]) -> str:
    """The parameter structure (full or identical chains tied) and, for ``auto``, the F test, BIC
    and cross-validation that chose it (:func:`structure_lines`)."""
    lines = [ln for ln in structure_lines(dict(structure)) if ln]
    return (f"<h2 id='structure'>{html.escape(lines[0])}</h2><ul>"
            + "".join(f"<li>{html.escape(ln.strip())}</li>" for ln in lines[1:]) + "</ul>")


def write_html_report(result: IdentificationResult, metrics: Any, path: str | Path, *,
                      images: Mapping[Any, str] | None = None, nominal: Any = None, prior: dict | None = None,
                      other_view: Any = None, selected: Any = None, units: Any = None,
                      flags: Mapping[str, Any] | None = None, facts: Mapping[str, str] | None = None,
                      structure: Mapping[str, Any] | None = None) -> Path:
    """One HTML file that needs nothing else: the :func:`verdict` first, then the fit, the
    parameters (flagged by ``flags``, :func:`dynid.pipeline.reporting.parameter_flags`), the
    validation table in the channels' ``units`` with the nominal model's errors (``nominal``,
    ``prior``) next to the identified model's, the held-out rows a row selection keeps
    (``selected``), a redundant robot's other view (``other_view``), a parallel robot's parameter
    structure and the evidence of its choice (``structure``, :mod:`dynid.pipeline.structure`), the ``images`` (PNG path ->
    title, embedded as base64 ``data:`` URIs) and the provenance (``facts``: date and machine)."""
    summ = result.summary()
    unit = lambda j: units[j] if units is not None else "N·m or N"  # noqa: E731
    line, good = verdict(metrics, nominal, prior, units, flags)
    rows = "".join(
        f"<tr><td>{html.escape(c)}</td><td>{html.escape(unit(j))}</td><td>{r:.4g}</td><td>{p:.3g}</td><td>{q:.4f}</td>"
        + (f"<td>{nominal.rmse[j]:.4g}</td>" if nominal is not None else "") + "</tr>"
        for j, (c, r, p, q) in enumerate(zip(metrics.channel_names, metrics.rmse, metrics.rel_rmse_pct, metrics.r2))
    )
    info = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in summ.info)
    chan = summ.channel_table
    chan_html = ("<table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in chan[0]) + "</tr>"
                 + "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in chan[1:])
                 + "</table>")
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in summ.notes)
    figs = "".join(_image_html(p, t) for p, t in (images or {}).items())
    nav = " · ".join(f"<a href='#{a}'>{t}</a>" for a, t in (("parameters", "parameters"), ("validation", "validation"),
                                                            ("plots", "plots"), ("provenance", "provenance")))
    body = (
        f"<h1>dynid identification report ({html.escape(result.method)})</h1>"
        f"<p id='verdict' class='verdict{'' if good else ' bad'}'>{html.escape(line)}</p><p>{nav}</p>"
        f"<h2 id='fit'>Fit</h2><table>{info}</table>{chan_html}" + (f"<ul>{notes}</ul>" if notes else "")
        + (_structure_html(structure) if structure is not None else "")
        + _params_html(result, flags)
        + f"<h2 id='validation'>{html.escape(metrics.heading())}</h2>"
        + "<table><tr><th>joint</th><th>unit</th><th>RMSE</th><th>rel RMSE %</th><th>R²</th>"
        + ("<th>RMSE nominal</th>" if nominal is not None else "") + f"</tr>{rows}</table>"
        + _several_logs_html(result.provenance)
        + (_prior_html(metrics, nominal, prior) if nominal is not None and prior is not None else "")
        + (_selected_html(selected) if selected is not None else "")
        + (_other_view_html(other_view) if other_view is not None else "")
        + f"<h2 id='plots'>Plots</h2>{figs or '<p>(no plots)</p>'}"
        + _provenance_html(result, facts)
    )
    path = Path(path)
    path.write_text(f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>dynid report</title>"
                    f"<style>{_STYLE}</style></head><body>{body}</body></html>\n", encoding="utf-8")
    return path
