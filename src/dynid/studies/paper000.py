"""Paper 000 (Mata / Farhat et al., §6.2, Tables 4–6) on the 3-RPS twin ``builtin:rps3``.

The paper identifies a simulated 3-RPS (ADAMS; inertial parameters from CAD, friction from an
earlier identification; noise on the forces and on the coordinates) with symmetric linear
friction, keeps a parameter when its relative standard deviation is below 15 % and the set
is physically feasible, and compares models of 37, 24, 18 and 12 parameters (Table 6: ε_RA,
ε_AV, parameters identified); Table 5 lists some parameters of model 1 with the exact values,
infeasible ones marked ``*``; Table 4 scores identified models on six trajectories with
condition numbers 563–718 and one at low velocity. Here, in kind, through the product:

* the twin: ``builtin:rps3``, identified with the joint terms ``Ia, fv, fc, offset`` on the
  legs: 25 + 12 = 37 base parameters, the paper's model 1 with Jr + Js, Fv, Fc+ and Fc- of
  Table 5 (on moving legs F_C+ = fc + offset and F_C- = fc - offset span the same forces; the
  builtin keeps its symmetric ``fc``, so ``fc+`` / ``fc-`` would only regroup with it). The
  truth is 10 % away from the nominal model body by body (``perturbation_seed = 3``) with the
  twin's own linear friction (so that ``truth.json`` holds the plant's friction, offsets 0);
  computed torque with the nominal model at 500 Hz, logged at 100 Hz (the paper's rate), 1 µm
  encoders and 5 N of force noise (``dynid simulate``);
* the training experiment: a 5-harmonic Fourier excitation of the leg lengths (the paper's
  optimized trajectory lasts 7.5 s; here 3 periods of 5 s, ``quick``: 1 period of 4 s);
* six test trajectories: five other Fourier excitations (other seeds and base frequencies, the
  same limits) and one at low speed (a quarter of the velocity limit, the paper's "LowVel");
* the analysis: ``dynid identifiability``
  (:func:`dynid.pipeline.identifiability.run_identifiability`: WLS,
  :func:`dynid.estimation.identifiability.structure_search`, feasibility of models 1–4), on the
  equations of the legs moving faster than 5 mm/s (``processing.min_velocity``; at reversals
  the simulated legs chatter under discontinuous Coulomb friction, see
  :mod:`dynid.simulation.control`), in training and in every test log alike.

Run: ``python bench/paper000_study.py [--quick]``; the figures of the last full run are in
bench/README.md ("Paper 000, Tables 4–6").
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dynid.config import DataConfig, parse_config
from dynid.config.simulate import parse_simulate_config
from dynid.pipeline.identifiability import IdentifiabilityOutcome, run_identifiability
from dynid.pipeline.simulate import run_simulation, write_simulation

__all__ = ["ROBOT", "Paper000Study", "simulate_config", "identify_config", "paper000_study"]

ROBOT = {"model": "builtin:rps3", "perturbation": 0.1, "perturbation_seed": 3}
EXTRAS = ["Ia", "fv", "fc", "offset"]
CONTROL = {"rate_hz": 500, "kp": 400, "kd": 40, "substeps": 2}
SENSORS = {"log_rate_hz": 100, "encoder_resolution": 1e-6, "force_noise_std": 5.0}
MAX_VELOCITY = 0.1  # m/s, every leg
MAX_ACCELERATION = 1.0  # m/s^2
MIN_VELOCITY = 0.005  # m/s: rows slower than this are left out (Coulomb friction undefined there)
TRAIN = {"kind": "fourier", "base_frequency_hz": 0.2, "harmonics": 5, "fill": 0.5, "max_velocity": MAX_VELOCITY,
         "max_acceleration": MAX_ACCELERATION, "periods": 3, "seed": 11}
TESTS = (  # name, base frequency [Hz], seed, velocity limit as a fraction of MAX_VELOCITY
    ("test 1", 0.2, 21, 1.0),
    ("test 2", 0.25, 22, 1.0),
    ("test 3", 0.15, 23, 1.0),
    ("test 4", 0.2, 24, 1.0),
    ("test 5", 0.3, 25, 1.0),
    ("low speed", 0.2, 26, 0.25),
)
LOW_SPEED = "low speed"


def simulate_config(trajectory: dict[str, Any], seed: int, *, rate_hz: float | None = None) -> dict[str, Any]:
    """The ``dynid simulate`` document of one experiment on the twin."""
    control = {**CONTROL, **({"rate_hz": rate_hz} if rate_hz else {})}
    return {"robot": ROBOT, "trajectory": trajectory, "control": control, "sensors": {**SENSORS, "seed": seed},
            "output": {"format": "npz"}}


def identify_config(train: Path, valid: Path, *, min_velocity: float = MIN_VELOCITY) -> dict[str, Any]:
    """The ``dynid identify`` document (WLS, linear friction, 10 Hz low-pass of the positions)."""
    act = ("P1", "P2", "P3")
    return {
        "robot": {"model": "builtin:rps3", "extras": EXTRAS},
        "data": {"file": str(train), "time": {"column": "t", "unit": "s"},
                 "position": {"columns": [f"q_{a}" for a in act], "unit": "m"},
                 "effort": {"columns": [f"tau_{a}" for a in act], "kind": "torque", "unit": "N"}},
        "validation": {"file": str(valid)},
        "processing": {"lowpass": {"cutoff_hz": 10.0, "order": 4, "filter_effort": False},
                       "min_velocity": [min_velocity]},
        "identification": {"method": "wls"},
        "output": {"plots": False},
    }


@dataclasses.dataclass(frozen=True, eq=False)
class Paper000Study:
    """Outcome of :func:`paper000_study`.

    Attributes
    ----------
    outcome : IdentifiabilityOutcome
        Tables 4–6 (``outcome.summary_text()``), the model sequence and the evaluations.
    trajectories : dict name -> dict
        Per log: duration [s], samples and the largest leg speed [m/s] of the true motion.
    settings : dict
        The simulate and identify documents used.
    """

    outcome: IdentifiabilityOutcome
    trajectories: dict[str, dict[str, float]]
    settings: dict[str, Any]


def _simulate(doc: dict[str, Any], folder: Path) -> dict[str, float]:
    sim = run_simulation(parse_simulate_config(doc, folder))
    write_simulation(sim, folder)
    ds = sim.dataset
    t = np.asarray(ds.t)
    v = np.gradient(np.asarray(ds.q), t, axis=0)
    return {"duration_s": float(t[-1] - t[0]), "samples": int(t.size), "max_leg_speed": float(np.max(np.abs(v))),
            "truth": sim.truth}


def paper000_study(*, quick: bool = False, folder: str | Path | None = None,
                   progress: Callable[[str], None] | None = None, draw: int = 0) -> Paper000Study:
    """Simulate the training and the six test experiments, run the identifiability procedure.

    Parameters
    ----------
    quick : bool
        Small sizes for the tests (a 4 s training log, 2 s test logs, control at 200 Hz: a few
        seconds); otherwise the set-up of the module docstring.
    folder : path, optional
        Where the logs are written (kept); default a temporary folder.
    progress : callable(str), optional
        Told what is being done (the bench script prints it).
    draw : int
        0: the recorded study; another: the same experiments with other trajectory and noise
        seeds (:func:`dynid.studies.draw_seed`), the same true robot.
    """
    from dynid.studies import draw_seed

    say = progress or (lambda msg: None)
    if folder is None:
        with tempfile.TemporaryDirectory() as tmp:
            return paper000_study(quick=quick, folder=tmp, progress=progress, draw=draw)
    d = Path(folder)
    rate = 200 if quick else None
    train_traj = {**TRAIN, **({"base_frequency_hz": 0.25, "periods": 1} if quick else {}),
                  "seed": draw_seed(TRAIN["seed"], draw)}
    say("simulating the training experiment")
    info = {"training": _simulate(simulate_config(train_traj, draw_seed(1, draw), rate_hz=rate), d / "train")}
    truth = info["training"].pop("truth")
    docs = {"training": simulate_config(train_traj, draw_seed(1, draw), rate_hz=rate)}
    for k, (name, f0, seed, speed) in enumerate(TESTS):
        traj = {**TRAIN, "base_frequency_hz": 0.5 if quick else f0, "seed": draw_seed(seed, draw), "periods": 1,
                "max_velocity": MAX_VELOCITY * speed}
        doc = simulate_config(traj, draw_seed(100 + k, draw), rate_hz=rate)
        say(f"simulating {name}")
        info[name] = _simulate(doc, d / f"test{k + 1}")
        info[name].pop("truth")
        docs[name] = doc
    base_doc = identify_config(d / "train" / "log.npz", d / "test1" / "log.npz")
    cfg = parse_config(base_doc, d)
    tests: list[tuple[str, DataConfig]] = []
    for k, (name, *_) in enumerate(TESTS[1:], start=2):
        other = parse_config(identify_config(d / "train" / "log.npz", d / f"test{k}" / "log.npz"), d)
        tests.append((name, other.validation))
    say("structure search and evaluation (dynid identifiability)")
    outcome = run_identifiability(cfg, tests=tests, truth=truth, validation_name=TESTS[0][0])
    return Paper000Study(outcome, info, {"simulate": docs, "identify": base_doc})
