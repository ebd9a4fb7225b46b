"""What ``dynid identify``'s report states besides the numbers of the fit: the units of each
output channel, which parameters are badly identified, and where and when the run happened.

* :func:`effort_units`: the unit of each regression equation, from the log (N·m for a revolute
  actuator, N for a prismatic one, A when the efforts are motor currents without drive gains,
  whose parameters then absorb the unknown current-to-torque gains);
* :func:`parameter_flags`: the base parameters a reader must not trust, by the two criteria of
  paper 000 §6.2 (a parameter is properly identified when its relative standard deviation,
  paper 001 Eq. 20, is below 15 % *and* the parameter set is physically feasible), plus the
  parameters whose relative standard deviation is undefined (a zero estimate, or no finite
  standard error: the data do not determine them);
* :func:`git_commit`, :func:`run_facts`: provenance not in the result itself.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

from dynid.errors import DynidError, InputError
from dynid.estimation.results import IdentificationResult

__all__ = ["REL_STD_LIMIT_PCT", "effort_units", "file_sha256", "git_commit", "parameter_flags", "run_facts"]

REL_STD_LIMIT_PCT = 15.0
"""A base parameter whose relative standard deviation :math:`100\\,\\sigma_i/|\\hat\\beta_i|` (paper 001
Eq. 20) is at or above this many percent is flagged as badly identified (paper 000 §6.2: 15 %)."""


def effort_units(system: Any, force_model: str | None, effort_kind: str) -> tuple[str, ...]:
    """Unit of each output channel (regression equation) of ``system``.

    Motor currents read with unit drive gains (or without a transmission) stay currents: ``"A"``
    (through the coupling matrix, :math:`\\tau_a = C^T K i` with :math:`K = 1`). Otherwise the
    efforts are joint torques or forces: ``"N·m"`` for a revolute actuator, ``"N"`` for a
    prismatic one; the projected equations :math:`G_a^T\\tau_a` of a redundant mechanism are
    generalized forces of its independent coordinates (N along a point coordinate, the joint's
    unit along a joint coordinate)."""
    tr = getattr(system, "transmission", None)
    channels = system.channel_names(force_model)
    if effort_kind == "current" and (tr is None or np.all(np.asarray(tr.drive_gains) == 1.0)):
        return ("A",) * len(channels)
    unit = {"revolute": "N·m", "prismatic": "N"}
    if system.channels_are_actuators(force_model):
        return tuple(unit.get(k, "N·m or N") for k in system.actuator_kinds())
    from dynid.model.closures import JointCoordinates
    from dynid.model.robot import joint_kinds

    ind = system.model.independent
    if isinstance(ind, JointCoordinates):
        pm = system.model.pin_model
        kinds = joint_kinds(pm, [pm.joints[j + 1].idx_v for j in ind.joints])
        return tuple(unit.get(k, "N·m or N") for k in kinds)
    return ("N",) * len(channels)  # point coordinates: forces along x, y, z


def parameter_flags(result: IdentificationResult, base: Any, system: Any, *, physical: bool = True,
                    limit_pct: float = REL_STD_LIMIT_PCT) -> dict[str, Any]:
    """The parameters of ``result`` a reader must not trust (written to result.json and the report).

    - ``rel_std_above``: relative standard deviation (paper 001 Eq. 20) at or above ``limit_pct``
      (paper 000 §6.2: 15 %), in the result's order;
    - ``undetermined``: relative standard deviation undefined (zero estimate, or no finite
      standard error): the data do not determine them;
    - ``physical``: with ``physical``, :func:`~dynid.estimation.identifiability.is_feasible` on the
      base parameters (paper 000 §6.2, after Yoshida et al. 1996: is there a physically consistent
      standard parameter vector behind them?) and the parameters whose grouping touches a violated
      constraint; ``{"checked": False, "reason": ...}`` when not checked, with the reason.
    """
    out: dict[str, Any] = {
        "rel_std_limit_pct": limit_pct,
        "rule": (f"flagged: relative standard deviation >= {limit_pct:g} % (paper 000 Sec. 6.2), undefined relative "
                 "standard deviation (zero estimate or no finite standard error), or a grouping that touches a "
                 "physical-consistency constraint the base parameters violate"),
    }
    if result.cov_params is None:
        out.update(assessed=False, reason=f"{result.method} gives no covariance: no relative standard deviation",
                   rel_std_above=[], undetermined=[])
    else:
        rel = np.asarray(result.rel_std, dtype=float)
        out.update(assessed=True,
                   rel_std_above=[n for n, r in zip(result.names, rel) if np.isfinite(r) and r >= limit_pct],
                   undetermined=[n for n, r in zip(result.names, rel) if not np.isfinite(r)])
    out["physical"] = _physical(result, base, system) if physical else {
        "checked": False, "reason": "checked when the report is written (output.plots = true)"}
    return out


def _physical(result: IdentificationResult, base: Any, system: Any) -> dict[str, Any]:
    if tuple(result.names) != tuple(base.names):
        return {"checked": False, "reason": "the result's parameters are not the base parameters of the robot "
                                            "description (reduced or extended parameter set)"}
    from dynid.estimation.feasibility import is_feasible, violating_parameters

    try:
        smap = system.standard_map(base)
        feas = is_feasible(np.asarray(result.params, dtype=float), smap)
    except (DynidError, InputError) as exc:  # cvxpy missing, NaN estimates, solver failure: said, not hidden
        return {"checked": False, "reason": str(exc)}
    return {"checked": True, "feasible": bool(feas.feasible), "violated": list(feas.violated),
            "parameters": list(violating_parameters(result.names, feas, base.names, smap)), "solver_status": feas.status}


def file_sha256(path: str | Path | None) -> str | None:
    """SHA-256 of a file's bytes (None when there is no such file)."""
    if path is None or not Path(path).is_file():
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def git_commit() -> str | None:
    """The git commit of the dynid source tree (``-dirty`` with uncommitted changes), None when
    dynid is not run from a git checkout or git is not available."""
    here = Path(__file__).resolve().parent.parent  # the dynid package
    try:  # the package's own files must be tracked: an installed copy inside another repository is not it
        tracked = subprocess.run(["git", "-C", str(here), "ls-files", "--error-unmatch", "__init__.py"],
                                 capture_output=True, text=True, timeout=10)
        if tracked.returncode != 0:
            return None
        r = subprocess.run(["git", "-C", str(here), "describe", "--always", "--dirty", "--abbrev=40"],
                           capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return (r.stdout.strip() or None) if r.returncode == 0 else None


def run_facts() -> dict[str, str]:
    """The date (UTC, to the day: two equal runs on one day write equal reports; ``SOURCE_DATE_EPOCH``
    sets it, the reproducible-builds convention) and the machine of this run."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    try:
        now = _dt.datetime.fromtimestamp(int(epoch), _dt.timezone.utc) if epoch else _dt.datetime.now(_dt.timezone.utc)
    except (ValueError, OverflowError, OSError):
        raise InputError(f"SOURCE_DATE_EPOCH = {epoch!r} is not a number of seconds since 1970") from None
    return {"date": now.strftime("%Y-%m-%d (UTC)"),
            "machine": f"{platform.node() or 'unknown host'} ({platform.system()} {platform.release()}, "
                       f"{platform.machine()})"}
