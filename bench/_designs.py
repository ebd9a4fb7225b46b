"""Helpers shared by the bench studies: an excitation design written as the ``design.json``
that ``dynid simulate`` follows (``trajectory.design``), and the hexapod's D-optimal design of
paper 002 (task-space harmonics, actuator limits of :mod:`dynid.studies.excitation`)."""

from __future__ import annotations

import json
from pathlib import Path

from dynid.excitation import ExcitationProblem
from dynid.model.robots import build_mechanism
from dynid.studies.excitation import HEXAPOD_BOX, HEXAPOD_LIMITS


def design_file(folder: Path, design) -> Path:
    """``folder/design.json`` with the coordinates and Fourier coefficients of ``design``."""
    tr = design.trajectory
    path = folder / "design.json"
    folder.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"coordinates": list(design.coordinates), "trajectory": {
        "kind": "fourier", "base_frequency_hz": tr.base_frequency_hz, "a": tr.a.tolist(), "b": tr.b.tolist(),
        "q0": tr.q0.tolist()}}))
    return path


def hexapod_design(folder: Path, quick: bool, base_frequency_hz: float, harmonics: int) -> Path:
    """The hexapod's D-optimal task-space excitation (2 N force noise per actuator), written to
    ``folder/design.json``; a short search with ``quick``."""
    pb = ExcitationProblem(build_mechanism("hexapod"), coordinates="task", harmonics=harmonics,
                           base_frequency_hz=base_frequency_hz, samples=24 if quick else 40, criterion="d_opt",
                           limits=HEXAPOD_LIMITS, box=HEXAPOD_BOX, noise_std=[2.0] * 6)
    return design_file(folder, pb.optimize(starts=1, seed=0, max_iter=15 if quick else 100))
