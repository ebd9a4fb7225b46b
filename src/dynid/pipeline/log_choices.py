"""What ``dynid identify`` chooses from the training log itself (issue 38: the pipeline split by
concern): a redundantly actuated mechanism's independent coordinates (:func:`_chart_from_log`) and,
with ``identification.structure = "auto"``, the parameter structure (:func:`_decide_structure`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynid.config import Config
from dynid.dataset import Dataset
from dynid.model.system import System
from dynid.pipeline.rows import Progress, _compress

def _chart_from_log(cfg0: Config, cfg: Config, system: System, train: Dataset,
                    max_samples: int = 200) -> tuple[System, Config, Config]:
    """The independent coordinates of a redundantly actuated mechanism that were chosen over its
    workspace, chosen again over the training log (:meth:`~dynid.model.mechanism.Mechanism.choose_independent`
    on up to ``max_samples`` evenly spread samples, all joints solved through the workspace chart);
    both configs then name them in ``[robot] independent`` (what the hierarchical prior and
    ``dynid predict`` rebuild)."""
    mech = system.model
    act = list(mech.actuated)
    cols = [act.index(j) for j in mech.independent.joints]
    pick = np.unique(np.linspace(0, train.n_samples - 1, min(max_samples, train.n_samples)).astype(int))
    q = mech.solve_positions(np.asarray(train.q)[pick][:, cols])
    chosen = mech.choose_independent(q, "samples of the training log")
    names = tuple(chosen.pin_model.names[j + 1] for j in chosen.independent.joints)

    def named(c: Config) -> Config:
        return dataclasses.replace(c, robot=dataclasses.replace(c.robot, independent=names))

    return dataclasses.replace(system, model=chosen), named(cfg0), named(cfg)


def _decide_structure(cfg0: Config, cfg: Config, system: System, train: Dataset, force_model: str | None,
                      auto: tuple, progress: Progress) -> tuple[System, dict[str, Any], Config, Config]:
    """``identification.structure = "auto"``: the full and the tied model compared on the training
    log (:func:`dynid.pipeline.structure.decide_structure`); returns the chosen system, the decision's
    record and both configs with the structure made explicit (what the rest of the run, the
    hierarchical prior and ``dynid predict`` rebuild)."""
    from dynid.pipeline.structure import N_SEGMENTS, decide_structure

    groups, source = auto
    icfg, pcfg = cfg.identification, cfg.processing
    tied = system.with_structure("identical_chains", groups)
    base_full = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    base_tied = tied.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    pose = pcfg.periodic is not None and pcfg.periodic.domain == "pose"  # one averaged period: no time segments
    k = 1 if pose else N_SEGMENTS
    edges = np.linspace(0, train.n_samples, k + 1).astype(int)
    segments = []
    for a, b in zip(edges[:-1], edges[1:]):
        part = train if k == 1 else train.rows(int(a), int(b))
        segments.append(_compress(system, base_full, part, force_model=force_model, min_velocity=pcfg.min_velocity,
                                  parallel_decimate=parallel, chunk_size=icfg.chunk_size, progress=progress,
                                  meta={}, cross=False, periodic=pcfg.periodic if pose else None,
                                  min_velocity_passive=pcfg.min_velocity_passive,
                                  reversal_guard=pcfg.reversal_guard_s(), check=False)[0])
    decision = decide_structure(segments, base_full, base_tied, tied.reduction.T, groups, source)
    chosen = tied if decision.chosen == "identical_chains" else system
    chains = groups if decision.chosen == "identical_chains" else None

    return (chosen, decision.record, _explicit_structure(cfg0, decision.chosen, chains),
            _explicit_structure(cfg, decision.chosen, chains))


def _explicit_structure(cfg: Config, structure: str, chains) -> Config:
    """``cfg`` with the structure ``"auto"`` chose (what the hierarchical prior rebuilds)."""
    ic = dataclasses.replace(cfg.identification, structure=structure, identical_chains=chains)
    return dataclasses.replace(cfg, identification=ic)
