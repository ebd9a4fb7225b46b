"""Human-facing output: plots (matplotlib, optional extra ``plot``) and an HTML report."""

from dynid.report.html import write_html_report
from dynid.report.plots import plot_tracking, plot_validation

__all__ = ["plot_tracking", "plot_validation", "write_html_report"]
