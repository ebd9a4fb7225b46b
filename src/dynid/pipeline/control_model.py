"""The controller's model of ``dynid simulate`` (``control.model``): nominal, true, or identified.

An identified model is the ``result.json`` of ``dynid identify``: its base parameters
:math:`\\beta` are mapped to the standard vector closest to the nominal one with the same base
parameters, :math:`\\pi = \\pi_0 + B^+(\\beta - B\\pi_0)`
(:meth:`~dynid.model.base_parameters.BaseParameters.to_standard`). Every standard vector
with these base parameters gives the same joint or actuator forces, so computed torque and the
feedforward of paper 002, Section 5.4 (Figs. 10–12) and paper 004, Fig. 6 use exactly the
identified model. The base parameters are those of the identification: the same robot, the
same sampling (seed, number of samples, rank tolerance, from the result's provenance) and, for
redundant actuation, the same force model (``identification.force_model``, ``"projected"``
when none was recorded). With redundant actuation the base parameters of the projected
equations fix :math:`G^T(\\ldots)` and hence the ``"min_norm"`` distribution exactly; the
``"min_norm_local_friction"`` distribution also needs the actuators' own friction terms
separately, which a projected identification may group with others (the nominal values then
fill the ungrouped part).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from dynid.errors import ConfigError, InputError, read_file_text
from dynid.estimation.results import _FORMAT as RESULT_FORMAT
from dynid.model.closed_loop import DISTRIBUTIONS
from dynid.model.system import as_system

__all__ = ["controller_parameters", "identified_parameters"]


def controller_parameters(model: str, base_dir: Path, robot, nominal: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, dict]:
    """The standard parameters of the controller's model and what to record about them.

    Parameters
    ----------
    model : str
        ``control.model``: ``"nominal"``, ``"true"`` or the path of a result (relative to
        ``base_dir``, the configuration's folder).
    robot : RobotModel or Mechanism
        As loaded from the configuration (a mechanism with its own independent coordinates,
        as ``dynid identify`` builds it).
    nominal, true : array, shape (n_params,)

    Returns
    -------
    params : array, shape (n_params,)
    record : dict
        For metadata.json: ``kind`` and, for a result, its path relative to ``base_dir``,
        method, robot, force model and number of base parameters.
    """
    if model == "nominal":
        return nominal, {"kind": "nominal"}
    if model == "true":
        return true, {"kind": "true", "note": "the robot's true parameters (a payload stays unknown to the controller)"}
    return identified_parameters(model, base_dir, robot, nominal)


def identified_parameters(model: str, base_dir: Path, robot, nominal: np.ndarray) -> tuple[np.ndarray, dict]:
    """The standard vector of an identification result (see the module docstring)."""
    path = Path(model).expanduser()
    path = path if path.is_absolute() else base_dir / path
    if path.is_dir():
        path = path / "result.json"
    try:
        text = read_file_text(path, "control.model: identification result")
    except InputError as exc:
        raise ConfigError(f"{exc} (control.model is 'nominal', 'true' or the result.json of dynid identify)") from None
    try:
        doc = json.loads(text)
        if not isinstance(doc, dict) or doc.get("format") != RESULT_FORMAT:
            raise ValueError(f"format {doc.get('format') if isinstance(doc, dict) else None!r}")
        names = [str(p["name"]) for p in doc["params"]]
        beta = np.array([float(p["value"]) for p in doc["params"]], dtype=float)
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"control.model: {path} is not a result.json of dynid identify ({exc})") from None
    method = str(doc.get("method", ""))
    solver = doc.get("solver") if isinstance(doc.get("solver"), dict) else {}
    if "stribeck" in solver or "stribeck" in method.lower():
        raise ConfigError(f"control.model: {path} is a Stribeck result ({method}): its friction is nonlinear in the "
                          "parameters, so it is no linear model the controller can use; identify with a linear friction model")
    prov = doc.get("provenance") if isinstance(doc.get("provenance"), dict) else {}
    sampling = prov.get("base_parameters") if isinstance(prov.get("base_parameters"), dict) else {}
    kw = {k: sampling[k] for k in ("seed", "n_samples", "rank_tol") if isinstance(sampling.get(k), (int, float))}
    rec_robot = prov.get("robot") if isinstance(prov.get("robot"), dict) else {}
    system = as_system(robot)
    structure = rec_robot.get("parameter_structure")
    if isinstance(structure, dict) and isinstance(structure.get("structure"), str):  # identification.structure
        chains = structure.get("identical_chains") or None
        system = system.with_structure(structure["structure"],
                                       tuple(tuple(tuple(c) for c in g) for g in chains) if chains else None)
    recorded = rec_robot.get("force_model")
    force_model = (recorded if recorded in DISTRIBUTIONS else "projected") if system.redundant else None
    base = system.base_parameters(force_model, n_samples=kw.get("n_samples"), seed=kw.get("seed", 0),
                                  rank_tol=kw.get("rank_tol", 1e-8))
    if names != list(base.names):
        of = f" (a result of {rec_robot['name']!r})" if isinstance(rec_robot.get("name"), str) else ""
        missing = [n for n in base.names if n not in names]
        extra = [n for n in names if n not in base.names]
        parts = ([f"{len(extra)} names it should not have (first {extra[0]!r})"] if extra else []) + \
                ([f"{len(missing)} missing (first {missing[0]!r})"] if missing else [])
        detail = ", ".join(parts) or "the same names in another order"
        raise ConfigError(f"control.model: {path}{of} does not identify the base parameters of {robot.name!r}: "
                          f"{len(names)} parameters for {base.n_base}, {detail}")
    record = {
        "kind": "identified",
        "result": Path(os.path.relpath(path.resolve(), Path(base_dir).resolve())).as_posix(),
        "method": method,
        "robot": rec_robot.get("name"),
        "force_model": force_model,
        "n_base": base.n_base,
        "standard_parameters": "closest to the nominal ones with the identified base parameters",
    }
    if system.structure != "full":
        record["structure"] = system.structure
    psi = base.to_standard(beta, reference=system.reduce_parameters(nominal))
    return system.expand_parameters(psi), record
