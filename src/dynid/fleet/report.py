"""The fleet's figures (matplotlib, headless) and its self-contained HTML report."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np

from dynid.fleet.analysis import DAYS_PER_YEAR, FleetResult

__all__ = ["plot_spread", "plot_drift", "write_fleet_html"]

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px}
table{border-collapse:collapse;margin:1em 0;font-size:13px}
td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}
th{background:#f3f3f3} td:first-child,th:first-child{text-align:left}
img{max-width:100%} tr.flag td{background:#fff3d6} .err{color:#a40;text-align:left}
"""
_MAX_PANELS = 6


def _pyplot():
    from dynid.report.plots import _pyplot as pyplot

    return pyplot()


def plot_spread(result: FleetResult, path: Path) -> Path:
    """Per model, each robot's pooled estimate standardized by the fleet: ``(theta - median) / s``
    with ``s^2`` = the fleet's robust spread squared + the median of the robots' variances; error
    bars: the robot's own standard deviation on that scale; outliers in red."""
    plt = _pyplot()
    models = [m for m in result.models if m.robots] or result.models[:1]
    fig, axes = plt.subplots(len(models), 1, figsize=(11, 3.6 * len(models)), squeeze=False)
    for ax, m in zip(axes[:, 0], models):
        if not m.robots:
            ax.text(0.5, 0.5, f"{m.model}: no robot identified", ha="center", va="center")
            ax.set_axis_off()
            continue
        robots = [result.robot(r) for r in m.robots]
        est = np.array([r.params for r in robots])
        std = np.array([np.sqrt(np.diag(r.cov)) for r in robots])
        scale = np.sqrt(m.spread["std"] ** 2 + np.median(std**2, axis=0))
        scale = np.where(scale > 0, scale, 1.0)
        x = np.arange(len(m.names))
        width = 0.8 / max(1, len(robots))
        for i, r in enumerate(robots):
            bad = r.outlier is not None and r.outlier.outlier
            ax.errorbar(x - 0.4 + (i + 0.5) * width, (est[i] - m.spread["median"]) / scale, yerr=std[i] / scale,
                        fmt="o", ms=3, lw=0.8, color="#c33" if bad else f"C{i % 10}",
                        label=r.robot + (" (outlier)" if bad else ""))
        for y in (-3, 3):
            ax.axhline(y, color="0.6", lw=0.6, ls="--")
        ax.axhline(0, color="0.3", lw=0.6)
        ax.set_xticks(x)
        ax.set_xticklabels(m.names, rotation=90, fontsize=7)
        ax.set_ylabel("(estimate - fleet median) / spread")
        ax.set_title(f"{m.model}: {len(robots)} robots, pooled estimates against the fleet", fontsize=10)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def _drift_panels(result: FleetResult) -> list[tuple[Any, int]]:
    panels = []
    for r in result.robots:
        if r.drift is None:
            continue
        for j, d in enumerate(r.drift):
            if d["drift"] or d["change"]:
                panels.append((r, j))
    return panels[:_MAX_PANELS]


def plot_drift(result: FleetResult, path: Path) -> Path:
    """The parameters that drift or change (up to six panels): each dated log's estimate with its
    (scaled) standard deviation against the date, the weighted trend and its interval."""
    plt = _pyplot()
    panels = _drift_panels(result)
    if not panels:
        fig, ax = plt.subplots(figsize=(8, 2))
        dated = sum(r.drift is not None for r in result.robots)
        ax.text(0.5, 0.5, f"no drift or change flagged ({dated} robot(s) with 3 or more dated logs tested)",
                ha="center", va="center")
        ax.set_axis_off()
        fig.savefig(path, dpi=90)
        plt.close(fig)
        return Path(path)
    cols = min(3, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    models = {m.model: m for m in result.models}
    for ax, (r, j) in zip(axes.flat, panels):
        d = r.drift[j]
        logs = [result.logs[i] for i in r.ok_logs if result.logs[i].days is not None]
        f = models[r.model].factors[j] if models[r.model].factors.size else 1.0
        t = np.array([log.days for log in logs])
        x = np.array([log.params[j] for log in logs])
        s = np.array([np.sqrt(log.cov[j, j]) * f for log in logs])
        ax.errorbar(t, x, yerr=s, fmt="o", ms=4, color="C0", label="per log")
        tt = np.linspace(t.min(), t.max(), 50)
        line = d["intercept"] + d["slope_per_day"] * (tt - d["t0_days"])
        ax.plot(tt, line, color="C3", lw=1, label=f"trend {d['slope_per_year']:+.3g}/yr")
        lo, hi = d["slope_interval"]
        ax.fill_between(tt, d["intercept"] + lo * (tt - d["t0_days"]), d["intercept"] + hi * (tt - d["t0_days"]),
                        color="C3", alpha=0.15, lw=0, label="slope interval")
        flags = [w for w, on in (("drift", d["drift"]), ("change", d["change"])) if on]
        ax.set_title(f"{r.robot} {d['name']} ({', '.join(flags)})", fontsize=9)
        ax.set_xlabel(f"days since {result.first_date}")
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def _img(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(Path(path).name)}">'


def _f(v: Any, fmt: str = ".4g") -> str:
    return "-" if v is None else format(v, fmt)


def write_fleet_html(result: FleetResult, doc: dict[str, Any], path: Path, images: list[Path]) -> Path:
    """One self-contained file: the robots' table (verdict against the prior, outlier, drift), the
    failed logs, the spread and drift figures, the per-parameter table of each model, the methods."""
    e = html.escape
    rows = []
    for r in doc["robots"]:
        if "error" in r:
            rows.append(f"<tr class='flag'><td>{e(r['robot'])}</td><td>{e(r['model'])}</td><td>0/{len(r['logs'])}</td>"
                        f"<td colspan='5' class='err'>{e(r['error'])}</td></tr>")
            continue
        pr, o = r["prior_comparison"], r["outlier"]
        vs = "beats" if pr["beats_nominal"] else ("ties" if pr["tie"] else "loses")
        flag = (o is not None and o["outlier"]) or r["drifting_parameters"] or r["changed_parameters"]
        rows.append(
            f"<tr{' class=flag' if flag else ''}><td>{e(r['robot'])}</td><td>{e(r['model'])}</td>"
            f"<td>{len(r['identified_logs'])}/{len(r['logs'])}</td>"
            f"<td>{_f(pr['identified_mean_rel_rmse_pct'], '.3g')} % vs {_f(pr['nominal_mean_rel_rmse_pct'], '.3g')} % ({vs})</td>"
            f"<td>{'-' if o is None else _f(o['d2'], '.1f') + ' / ' + _f(o['threshold'], '.1f') + (' <b>outlier</b>' if o['outlier'] else '')}</td>"
            f"<td>{'-' if r['drift'] is None else e(', '.join(r['drifting_parameters']) or 'none')}</td>"
            f"<td>{'-' if r['drift'] is None else e(', '.join(r['changed_parameters']) or 'none')}</td></tr>")
    failed = "".join(f"<tr><td>{log['index']}</td><td>{e(log['robot'])}</td><td><code>{e(log['file'])}</code></td>"
                     f"<td class='err'>{e(log['error'])}</td></tr>" for log in doc["logs"] if not log["ok"])
    params = []
    for m in doc["models"]:
        if not m["robots"]:
            continue
        head = "".join(f"<th>{e(r)}</th>" for r in m["robots"])
        by = {r["robot"]: r for r in doc["robots"]}
        body = "".join(
            f"<tr><td>{e(n)}</td><td>{_f(m['spread']['median'][j])}</td><td>{_f(m['spread']['std'][j], '.3g')}</td>"
            f"<td>{_f(m['scatter_factors'][j], '.3g')}</td>"
            + "".join(f"<td>{_f(by[r]['params'][j])} &plusmn; {_f(by[r]['std'][j], '.2g')}</td>" for r in m["robots"])
            + "</tr>" for j, n in enumerate(m["names"]))
        params.append(f"<h3>{e(m['model'])}</h3><table><tr><th>parameter</th><th>fleet median</th><th>spread</th>"
                      f"<th>scatter factor</th>{head}</tr>{body}</table>")
    methods = "".join(f"<li><b>{e(k)}</b>: {e(v)}</li>" for k, v in doc["methods"].items())
    text = (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>dynid fleet report</title>"
        f"<style>{_STYLE}</style></head><body><h1>Fleet report</h1>"
        f"<p>{len(doc['robots'])} robots, {doc['n_logs']} logs ({doc['n_failed']} failed); alpha = {doc['alpha']:g}; "
        f"dates from {e(str(doc['first_date']))}; dynid {e(doc['dynid_version'])}</p>"
        "<h2>Robots</h2><table><tr><th>robot</th><th>model</th><th>logs identified</th>"
        "<th>held-out mean rel. RMSE, pooled estimate vs nominal</th><th>outlier d&sup2; / threshold</th>"
        f"<th>drift</th><th>change</th></tr>{''.join(rows)}</table>"
        + (f"<h2>Failed logs</h2><table><tr><th>#</th><th>robot</th><th>file</th><th>error</th></tr>{failed}</table>"
           if failed else "")
        + "<h2>Spread over the fleet</h2>" + _img(images[0])
        + "<h2>Drift over time</h2>" + _img(images[1])
        + f"<h2>Parameters</h2>{''.join(params)}<h2>Methods</h2><ul>{methods}</ul>"
        + f"<p>Slopes per year use {DAYS_PER_YEAR} days.</p></body></html>\n")
    Path(path).write_text(text)
    return Path(path)
