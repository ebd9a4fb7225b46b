"""What a payload identification computed (:class:`PayloadOutcome`: payload.json, its summary) and its files
(:func:`write_payload_files`: payload.json, payload.urdf, payload.xml), shared by ``dynid payload``
(:mod:`dynid.pipeline.payload`) and the joint mode of ``dynid identify`` (:mod:`dynid.pipeline.joint_payload`)."""

from __future__ import annotations

import dataclasses
import datetime
import json
from pathlib import Path
from typing import Any

import numpy as np

from dynid import __version__
from dynid.config._payload import PayloadConfig
from dynid.errors import ConfigError
from dynid.estimation.payload import PAYLOAD_NAMES, PayloadFit, derived_covariance, describe_payload
from dynid.io.payload_export import payload_mjcf, payload_urdf, rpy_matrix

__all__ = ["PayloadOutcome", "write_payload_files", "Z95"]

Z95 = 1.959963984540054  # the normal 97.5 % quantile: 95 % two-sided intervals


@dataclasses.dataclass(frozen=True, eq=False)
class PayloadOutcome:
    """What ``dynid payload`` computed."""

    cfg: PayloadConfig
    fit: PayloadFit
    robot: str
    body: str  # the mount joint's name
    parent_link: str  # the link (pinocchio BODY frame) of the mount joint the URDF snippet attaches to
    parent_placement: Any  # pinocchio.SE3 of that link in the mount joint's frame
    arm_result: str
    arm_method: str
    arm_sha256: str
    log_meta: dict[str, Any]
    n_rows: list[int]
    notes: tuple[str, ...]

    # ---------------------------------------------------------------- values
    def values(self) -> np.ndarray:
        """The 10 payload parameters in the mount frame: the estimate where identified (the known mass), the
        physically consistent vector elsewhere."""
        out = np.array(self.fit.standard, dtype=float)
        res = self.fit.result
        for name in self.fit.identified:
            k = PAYLOAD_NAMES.index(name)
            out[k] = self.fit.mass_known if (k == 0 and self.fit.mass_known is not None) else \
                float(res.params[list(res.names).index(name)])
        return out

    def in_payload_frame(self) -> dict[str, Any]:
        """Mass, centre of mass and inertia about it in the payload's frame (``[payload] origin``)."""
        d = describe_payload(self.values())
        R, p = rpy_matrix(self.cfg.origin_rpy), np.asarray(self.cfg.origin_xyz, dtype=float)
        return {"mass": d["mass"], "com": R.T @ (d["com"] - p), "inertia_com": R.T @ d["inertia_com"] @ R}

    def to_dict(self) -> dict[str, Any]:
        fit, res = self.fit, self.fit.result
        vals = self.values()
        std = fit.std_of()
        params = []
        for k, name in enumerate(PAYLOAD_NAMES):
            s = std.get(name)
            params.append({"name": name, "value": float(vals[k]), "std": s,
                           "ci95": None if s is None else [float(vals[k] - Z95 * s), float(vals[k] + Z95 * s)],
                           "identified": name in fit.identified})
        d = describe_payload(vals)
        cov10 = fit.standard_covariance()
        derived = None if cov10 is None else derived_covariance(vals, cov10)
        frame = self.in_payload_frame()
        bse = [None] * len(res.names) if res.cov_params is None else [float(b) for b in res.bse]
        base = [{"name": n, "expression": e, "value": float(v), "std": b}
                for n, e, v, b in zip(res.names, fit.base.expressions(), res.params, bse)]
        mass_std = std.get(PAYLOAD_NAMES[0])
        return {
            "format": "dynid-payload-1",
            "body": self.body,
            "frame": "the mount joint's frame (pinocchio's joint frame; inertia about its origin)",
            "parameters": params,
            "identifiable_combinations": base,
            "unidentifiable": list(fit.unidentifiable),
            "mass": {"value": d["mass"], "std": mass_std, "known": fit.mass_known is not None,
                     "ci95": None if mass_std is None else [d["mass"] - Z95 * mass_std, d["mass"] + Z95 * mass_std]},
            "com": {"value": d["com"].tolist(),
                    "std": None if derived is None else np.sqrt(np.diag(derived["com"])).tolist()},
            "inertia_com": {"value": d["inertia_com"].tolist(),
                            "std_xx_xy_yy_xz_yz_zz": None if derived is None else
                            np.sqrt(np.maximum(np.diag(derived["inertia_com"]), 0.0)).tolist()},
            "principal_moments": d["principal_moments"].tolist(),
            "principal_axes": d["principal_axes"].tolist(),
            "payload_frame": {"xyz": list(self.cfg.origin_xyz), "rpy": list(self.cfg.origin_rpy),
                              "mass": frame["mass"], "com": frame["com"].tolist(),
                              "inertia_com": frame["inertia_com"].tolist()},
            "consistency": {"min_pseudo_inertia_eigenvalue": d["min_pseudo_inertia_eigenvalue"],
                            "consistent": d["violation"] == "", "violation": d["violation"],
                            "constrained": self.cfg.physical,
                            "active_constraints": list(res.solver.get("active_constraints", []))},
            "covariance": {"parameters": list(res.names),
                           "total": None if res.cov_params is None else np.asarray(res.cov_params).tolist(),
                           "noise": None if fit.cov_noise is None else fit.cov_noise.tolist(),
                           "arm": None if fit.cov_arm is None else fit.cov_arm.tolist()},
            "method": res.method,
            "noise_std": dict(zip(res.channel_names, np.asarray(res.noise_std, float).tolist())),
            "rows": dict(zip(res.channel_names, [int(n) for n in self.n_rows])),
            "notes": list(self.notes) + list(res.notes),
            "provenance": {"dynid": __version__, "config": None if self.cfg.source is None else str(self.cfg.source),
                           "arm_result": self.arm_result, "arm_result_sha256": self.arm_sha256,
                           "arm_method": self.arm_method, "robot": self.robot, "log": _log_files(self.log_meta),
                           "log_sha256": self.log_meta.get("sha256"),
                           "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")},
        }

    def summary_text(self) -> str:
        fit, res = self.fit, self.fit.result
        vals, std = self.values(), self.fit.std_of()
        d = describe_payload(vals)
        lines = [f"Payload on {self.body} of {self.robot} (arm: {self.arm_result}, {self.arm_method})",
                 f"method: {res.method}; rows per channel: {', '.join(str(int(n)) for n in self.n_rows)}", "",
                 f"{'parameter':<14}{'value':>13}{'std':>11}{'95% low':>13}{'95% high':>13}", "-" * 64]
        for k, name in enumerate(PAYLOAD_NAMES):
            s = std.get(name)
            if s is None:
                why = "(not identified)" if name not in fit.identified else "(constraint active)"
                lines.append(f"{name:<14}{vals[k]:>13.6g}{'-':>11}{why:>26}")
            else:
                lines.append(f"{name:<14}{vals[k]:>13.6g}{s:>11.3g}{vals[k] - Z95 * s:>13.6g}{vals[k] + Z95 * s:>13.6g}")
        lines += ["", f"mass {d['mass']:.6g} kg" + ("" if PAYLOAD_NAMES[0] not in std else
                                                    (" (known)" if fit.mass_known is not None else
                                                     f" +- {Z95 * std[PAYLOAD_NAMES[0]]:.3g} (95 %)")),
                  f"centre of mass {np.array2string(d['com'], precision=5)} m (mount frame)",
                  f"principal moments {np.array2string(d['principal_moments'], precision=5)} kg*m^2",
                  "physically consistent: " + ("yes" if d["violation"] == "" else f"NO ({d['violation']})")
                  + f" (smallest pseudo-inertia eigenvalue {d['min_pseudo_inertia_eigenvalue']:.3g})"]
        if fit.unidentifiable:
            lines += ["", "not identified by this log (no interval; the values are a consistent choice):"]
            lines += [f"  {u}" for u in fit.unidentifiable]
        lines += [""] + [f"note: {n}" for n in (*self.notes, *res.notes)]
        return "\n".join(lines) + "\n"


def _mount(system, body: str | None) -> tuple[str, np.ndarray, str, Any]:
    """(joint name, the body's 10 standard-parameter indices, parent link name, its placement in the joint frame)."""
    model = system.model
    pin_model = model.pin_model if hasattr(model, "pin_model") else model.model
    names = list(system.parameter_names)
    blocks = system.body_blocks()
    by_joint = {}
    if system.kind == "serial":
        for k, blk in enumerate(blocks):
            by_joint[model.joint_names[k]] = blk
    else:
        for blk in blocks:
            by_joint[names[blk[0]][1:].lstrip("_")] = blk
    if body is None:
        if system.kind != "serial":
            raise ConfigError(f"payload.body: name the joint whose body carries the payload, one of {sorted(by_joint)}")
        body = model.joint_names[-1]
    if body not in by_joint:
        raise ConfigError(f"payload.body = {body!r} is no body of {system.name!r}; one of {list(by_joint)}")
    if getattr(system, "structure", "full") != "full":
        raise ConfigError(f"payload.body: the arm was identified with structure {system.structure!r} (bodies tied); "
                          "the payload's body needs its own parameters: identify the arm with structure = 'full'")
    import pinocchio as pin

    jid = pin_model.getJointId(body)
    parent, placement = body, pin.SE3.Identity()
    frames = [f for f in pin_model.frames if f.type == pin.FrameType.BODY and f.parentJoint == jid]
    if frames:
        exact = [f for f in frames if f.placement.isIdentity()]
        f = exact[0] if exact else frames[0]
        parent, placement = f.name, f.placement
    return body, np.asarray(by_joint[body], dtype=int), parent, placement


def write_payload_files(outcome: PayloadOutcome, stage: Path, summary: str = "summary.txt") -> None:
    """payload.json, payload.urdf, payload.xml and the summary (named ``summary``) into an existing folder."""
    cfg = outcome.cfg
    fr = outcome.in_payload_frame()
    R, p = rpy_matrix(cfg.origin_rpy), np.asarray(cfg.origin_xyz, dtype=float)
    P = outcome.parent_placement  # the payload frame in the parent link's frame: placement^-1 * (R, p)
    Rp, pp = P.rotation.T @ R, P.rotation.T @ (p - P.translation)
    import pinocchio as pin

    rpy_parent = pin.rpy.matrixToRpy(Rp)
    comment = f"identified by dynid {__version__} payload from {', '.join(_log_files(outcome.log_meta))}"
    urdf = payload_urdf(cfg.name, outcome.parent_link, pp, rpy_parent, fr["mass"], fr["com"], fr["inertia_com"], comment)
    mjcf = payload_mjcf(cfg.name, outcome.body, p, R, fr["mass"], fr["com"], fr["inertia_com"], comment)
    (stage / "payload.json").write_text(json.dumps(_finite(outcome.to_dict()), indent=2) + "\n")
    (stage / "payload.urdf").write_text(urdf)
    (stage / "payload.xml").write_text(mjcf)
    (stage / summary).write_text(outcome.summary_text())


def _log_files(meta: dict[str, Any]) -> list[str]:
    """The files of a log's ``source`` (a path, or a path per signal)."""
    src = meta.get("source")
    if isinstance(src, dict):
        return list(dict.fromkeys(str(v) for v in src.values()))
    return [] if src is None else [str(src)]


def _finite(x: Any) -> Any:
    if isinstance(x, float):
        return x if np.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x
