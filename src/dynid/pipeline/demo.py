"""``dynid demo``: the main job on a built-in default, needing nothing outside the package.

The parallel-robot study of paper 001 (Shang, Cong & Kong 2009) as a virtual experiment on
``builtin:shang2dof`` (2 DOF, 3 actuators):

1. the true robot (Table 3 / Table 2 values perturbed by 10 %, seeded) follows paper 001's
   excitation circle (centre (0.29, 0.25) m, radius 0.04 m, 0.2 m/s, 15 turns) under the
   augmented PD of Eq. 22 at 500 Hz with the nominal model; encoders and motor-torque noise
   (correlated across the drives) make the training log; the rectangle-with-diagonals path
   makes the validation log (``dynid simulate``);
2. the logs are identified with DIDIM (the experiment replayed on the estimate under its own
   controller, :mod:`dynid.pipeline.control_loop`; physically consistent: every iterate a robot,
   the fixed point projected onto the consistent set in the metric of its covariance, so no
   friction coefficient has the wrong sign) and, for comparison, with WLS on the same
   processed rows, exactly as ``dynid identify`` would: actuator positions through the closed
   loops, projected equations, Gautier's parallel decimation;
3. the identified model replaces the nominal one in the controller, and the rectangle is
   tracked again (paper 001, Table 5: P-RSME of the nominal and the identified model).

Because the truth is known, the demo also reports how many true base parameters fall inside
their 95 % intervals. The training experiment's own configuration is delivered with its log
(``data/train/config.toml``): DIDIM replays it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

from dynid._files import write_timing
from dynid.config import load_config
from dynid.config.simulate import parse_simulate_config
from dynid.io.output import staged_output
from dynid.model.robots import build_mechanism
from dynid.pipeline.identification import identify
from dynid.pipeline.outcome import IdentifyOutcome
from dynid.pipeline.outputs import write_files
from dynid.pipeline.rows import Progress, _no_progress
from dynid.pipeline.simulate import run_simulation, write_simulation
from dynid.simulation.closed_loop import AugmentedPD, ConstrainedSimulator, simulate_mechanism_control
from dynid.trajectories import PolylinePath
from dynid.stats import tracking_errors

__all__ = ["DemoOutcome", "run_demo", "DEMO_SEED"]

DEMO_SEED = 2026

_SIM = {
    "robot": {"model": "builtin:shang2dof", "perturbation": 0.1, "perturbation_seed": DEMO_SEED},
    "control": {"rate_hz": 500.0, "kp": 35000.0, "kd": 300.0, "distribution": "min_norm_local_friction"},
    "sensors": {"encoder_resolution": 5.992e-6, "force_noise_std": 0.02, "force_correlation": 0.3},
}
_CIRCLE = {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.04, "speed": 0.2, "turns": 15, "clockwise": True, "ramp": 0.2}
_RECTANGLE = [[0.244, 0.286], [0.343, 0.21], [0.343, 0.286], [0.244, 0.21], [0.244, 0.286],
              [0.343, 0.286], [0.343, 0.21], [0.244, 0.21], [0.244, 0.286]]
_POLYLINE = {"kind": "polyline", "vertices": _RECTANGLE, "speed": 0.1, "ramp": 0.1}

_CONFIG = """\
# dynid demo: identification of builtin:shang2dof (paper 001) from simulated logs (see docs/guide/demo.md)
[robot]
model = "builtin:shang2dof"

[data]
file = "data/train/log.csv"
time = {{ column = "t", unit = "s" }}
position = {{ columns = ["q_qa1", "q_qa2", "q_qa3"], unit = "rad" }}
effort = {{ columns = ["tau_qa1", "tau_qa2", "tau_qa3"], kind = "torque", unit = "N*m" }}

[validation]
file = "data/validation/log.csv"

[processing]
lowpass = {{ cutoff_hz = 20.0, order = 4, filter_effort = false }}
derivatives = "central"
decimate = 5
decimate_method = "parallel"

[identification]
method = "{method}"
force_model = "projected"
structure = "full"   # paper 001 identifies each chain; the simulated robot's chains differ (perturbation)
"""
_DIDIM = ('experiment = "data/train/config.toml"   # the training experiment, replayed on the estimate\n'
          "physical_consistency = true   # every iterate a robot; the result projected onto the consistent set, "
          "with its covariance\n")


def _toml(doc: dict) -> str:
    """A simulate configuration of flat tables (numbers, strings, booleans, lists) as TOML."""
    lines = []
    for section, table in doc.items():
        lines += ["", f"[{section}]"] + [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    return "\n".join(lines[1:]) + "\n"



@dataclasses.dataclass(frozen=True, eq=False)
class DemoOutcome:
    outcome: IdentifyOutcome
    wls: IdentifyOutcome
    true_base: np.ndarray
    tracking: dict
    out_dir: Path

    @property
    def z_scores(self) -> np.ndarray:
        r = self.outcome.result
        return (r.params - self.true_base) / r.bse

    def truth_table(self) -> str:
        lines = []
        for label, o in (("DIDIM", self.outcome), ("WLS", self.wls)):
            r = o.result
            ci = r.conf_int()
            inside = (ci[:, 0] <= self.true_base) & (self.true_base <= ci[:, 1])
            z = (r.params - self.true_base) / r.bse
            lines.append(
                f"Ground truth check ({label}): {int(inside.sum())} of {inside.size} true base parameters lie inside "
                f"their 95 % intervals; largest |z| = {np.max(np.abs(z)):.2f}"
            )
        v_w, v_o = self.outcome.validation, self.wls.validation
        lines.append(
            "Held-out RMSE of the projected forces (DIDIM / WLS): "
            + ", ".join(f"{c} {a:.3g} / {b:.3g}" for c, a, b in zip(v_w.channel_names, v_w.rmse, v_o.rmse))
        )
        return "\n".join(lines)

    def tracking_table(self) -> str:
        rows = [("controller model", "P-RSME [m]", "max error [m]")]
        for label, m in self.tracking.items():
            rows.append((label, f"{m['p_rsme']:.3e}", f"{max(m['max_abs_per_axis']):.3e}"))
        w = [max(len(r[i]) for r in rows) for i in range(3)]
        lines = ["Rectangle tracking under the augmented PD (paper 001, Table 5)"]
        lines += ["  ".join([r[0].ljust(w[0])] + [c.rjust(x) for c, x in zip(r[1:], w[1:])]) for r in rows]
        lines.insert(2, "-" * len(lines[1]))
        return "\n".join(lines)


def _relocate(obj, stage: str, folder: str):
    """Paths under ``stage`` made relative to ``folder`` (both in the staging tree), in every
    string of a nested structure: the record then names the delivered files wherever the output
    folder is, and two equal runs into different folders write equal files."""
    if isinstance(obj, str):
        return os.path.relpath(obj, folder) if obj == stage or obj.startswith(stage + os.sep) else obj
    if isinstance(obj, dict):
        return {(_relocate(k, stage, folder)): _relocate(v, stage, folder) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_relocate(v, stage, folder) for v in obj]
    return obj


def _track(mech, true_params, model_params, path):
    """The rectangle tracked under the augmented PD with ``model_params`` in the controller."""
    sim = ConstrainedSimulator(mech, true_params)
    ctrl = AugmentedPD(mech, model_params, np.full(2, 35000.0), np.full(2, 300.0), "min_norm_local_friction")
    return simulate_mechanism_control(sim, ctrl, path.sample, duration=path.duration, dt=1.0 / 500.0)


def _tracking(mech, motion, path) -> tuple[np.ndarray, dict]:
    """End-effector path and tracking errors (paper 001 Eq. 23) of a simulated motion."""
    xy = mech.coordinates(motion.q)
    return xy, {k: (np.asarray(v).tolist() if not isinstance(v, float) else v)
                for k, v in tracking_errors(path.sample(motion.t)[0], xy).items()}


def run_demo(out_dir: str | Path, progress: Progress = _no_progress, seed: int | None = DEMO_SEED) -> DemoOutcome:
    """Simulate, identify, validate, track again; write everything into ``out_dir``.

    ``seed``: of the sensor noise of the training and validation experiments (``seed`` and
    ``seed + 1``; None: :data:`DEMO_SEED`, the figures of docs/guide/demo.md). The true robot (the nominal
    values perturbed with :data:`DEMO_SEED`) is the same for every seed: another seed is another
    experiment on the same robot."""
    seed = DEMO_SEED if seed is None else int(seed)
    out = Path(out_dir)
    t0 = time.perf_counter()
    with staged_output(out) as stage:
        sims = {}
        for k, (name, traj) in enumerate((("train", _CIRCLE), ("validation", _POLYLINE))):
            progress("simulate", k, 2)
            doc = {**_SIM, "trajectory": traj, "sensors": {**_SIM["sensors"], "seed": seed + k}}
            source = stage / f"_{name}.toml"  # delivered as data/<name>/config.toml
            source.write_text(_toml(doc))
            sims[name] = run_simulation(parse_simulate_config(doc, stage, source=source))
            write_simulation(sims[name], stage / "data" / name)
            source.unlink()
        progress("simulate", 2, 2)
        outcomes = {}
        for method in ("didim", "wls"):
            folder = stage if method == "didim" else stage / "wls"
            folder.mkdir(exist_ok=True)
            (folder / "config.toml").write_text(_CONFIG.format(method=method).replace(
                'file = "data/', 'file = "' + ("" if method == "didim" else "../") + "data/")
                + (_DIDIM if method == "didim" else ""))
            o = identify(load_config(folder / "config.toml"), progress)
            # the inputs were read from the staging folder: the record names them relative to the
            # folder of its result.json
            where = (str(stage.resolve()), str(folder.resolve()))
            relocated = _relocate(dict(o.result.provenance), *where)
            outcomes[method] = dataclasses.replace(
                o, result=o.result.with_provenance(**relocated),
                validation=dataclasses.replace(o.validation, source=_relocate(o.validation.source, *where)),
                prediction=_relocate(o.prediction, *where))
            write_files(outcomes[method], folder)
        main = outcomes["didim"]
        truth = sims["train"].truth
        true_std = np.array(truth["true_parameters"])
        true_base = main.base.from_standard(true_std)
        # paper 001, Table 5: track the rectangle with the nominal and with the identified model
        mech = build_mechanism("shang2dof")
        nominal = np.array(truth["nominal_parameters"])
        identified = main.base.to_standard(main.result.params, reference=nominal)
        path = PolylinePath(np.array(_RECTANGLE), 0.1, ramp=0.1)
        progress("track", 0, 3)
        paths, tracking = {}, {}
        for k, (label, params) in enumerate((("nominal", nominal), ("identified (DIDIM)", identified), ("true", true_std))):
            # the validation log is that very experiment with the nominal model (the controller
            # never sees the sensors): its true motion is the nominal row
            motion = sims["validation"].motion if label == "nominal" else _track(mech, true_std, params, path)
            paths[label], tracking[label] = _tracking(mech, motion, path)
            progress("track", k + 1, 3)
        demo = DemoOutcome(main, outcomes["wls"], true_base, tracking, out)
        (stage / "tracking.json").write_text(json.dumps(tracking, indent=2) + "\n")
        from dynid.report import plot_tracking

        reference = path.sample(np.arange(paths["true"].shape[0]) / 500.0)[0]
        plot_tracking(reference, paths, stage / "tracking.png",
                      title="shang2dof: rectangle with diagonals, augmented PD at 500 Hz")
        with open(stage / "summary.txt", "a") as fh:
            fh.write("\n" + demo.truth_table() + "\n\n" + demo.tracking_table() + "\n")
        write_timing(stage, {"demo_s": time.perf_counter() - t0,
                             "identify_s": {m: o.elapsed_s for m, o in outcomes.items()},
                             "simulation_s": {k: s.elapsed_s for k, s in sims.items()}})
    return demo
