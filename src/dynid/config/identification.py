"""``[identification]`` of the identify configuration: the method, physical consistency (bodies),
covariance, friction model, hierarchical fit, structure, the control-loop methods' keys, streaming
and the Dask cluster."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid.config._schema import _bool, _int, _num, _path, _str, _table, parse_scheduler, parse_workers
from dynid.errors import ConfigError

_METHODS = ("ols", "wls", "gm", "irls", "tls", "ml", "iv", "didim", "cloe", "ekf", "ukf")
_FORCE_MODELS = ("projected", "min_norm", "min_norm_local_friction")


@dataclasses.dataclass(frozen=True)
class CovarianceConfig:
    """``[identification] covariance`` and its keys: which covariance of the estimates is reported
    (:mod:`dynid.estimation.block_covariance`). ``blocks`` None: the default number."""

    kind: str = "model"  # covariance: "model" (white residuals) | "hac" (block-robust sandwich) | "block_bootstrap"
    blocks: int | None = None  # covariance_blocks (hac, block_bootstrap): contiguous blocks of the training rows
    lags: int = 1  # covariance_lags (hac): neighbouring blocks in the Bartlett kernel (0: blocks independent)
    replicates: int = 500  # bootstrap_replicates (block_bootstrap): the bootstrap replicates
    seed: int = 0  # bootstrap_seed (block_bootstrap): seed of the draws


_COVARIANCE_KINDS = ("model", "hac", "block_bootstrap")  # dynid.estimation.block_covariance.COVARIANCE_KINDS
_COVARIANCE_KEYS = ("covariance", "covariance_blocks", "covariance_lags", "bootstrap_replicates", "bootstrap_seed")


def _parse_covariance(t: Mapping[str, Any], method: str, physical: bool, friction_model: str) -> CovarianceConfig:
    """The covariance keys of ``[identification]``; each only where it applies."""
    where = "identification"
    kind = _str(t.get("covariance", "model"), f"{where}.covariance", _COVARIANCE_KINDS)
    for key, kinds in (("covariance_blocks", ("hac", "block_bootstrap")), ("covariance_lags", ("hac",)),
                       ("bootstrap_replicates", ("block_bootstrap",)), ("bootstrap_seed", ("block_bootstrap",))):
        if key in t and kind not in kinds:
            raise ConfigError(f"{where}.{key} is for covariance = {' or '.join(repr(k) for k in kinds)}, not {kind!r}")
    if kind != "model":
        if method not in ("ols", "wls") or physical or friction_model != "linear":
            what = ("physical_consistency = true" if physical else "friction_model = 'stribeck'" if friction_model != "linear"
                    else f"method = {method!r}")
            raise ConfigError(f"{where}.covariance = {kind!r} is for the linear least-squares methods 'ols' and 'wls' "
                              f"(an estimate that is a sum over blocks), not {what}")
    return CovarianceConfig(
        kind=kind,
        blocks=_int(t["covariance_blocks"], f"{where}.covariance_blocks", 2) if "covariance_blocks" in t else None,
        lags=_int(t.get("covariance_lags", 1), f"{where}.covariance_lags", 0),
        replicates=_int(t.get("bootstrap_replicates", 500), f"{where}.bootstrap_replicates", 2),
        seed=_int(t.get("bootstrap_seed", 0), f"{where}.bootstrap_seed", 0),
    )


@dataclasses.dataclass(frozen=True)
class IdentificationConfig:
    method: str = "wls"  # the estimator of the base parameters (docs/guide/computes.md: what each one computes)
    # true: LMI constraints (pseudo-inertia >= 0, Ia, fv, fc >= 0), cvxpy + Clarabel; methods ols | wls | gm | didim
    physical_consistency: bool = False
    chunk_size: int = 20000  # at most this many samples per chunk when compressing (fewer past 8 MiB of regressor rows)
    # "auto": a long log (at least dynid.pipeline.streaming.AUTO_ROWS rows) read, processed and compressed
    # chunk by chunk when the configuration allows it; "on": streamed or a ConfigError saying why not;
    # "off": held in memory (dynid.pipeline.streaming)
    streaming: str = "auto"
    # the streamed path's chunks on a Dask cluster (dynid.pipeline.cluster_qr): "off", "local" (a LocalCluster
    # of `workers` processes; 0: the cores this process may use) or a scheduler address (montecarlo.scheduler's
    # syntax; its workers are the cluster's)
    cluster: str = "off"
    workers: int = 0  # cluster = "local": its worker processes (0: the cores this process may use)
    base_seed: int = 0  # seed of the random states that find the base parameters (deterministic)
    base_samples: int | None = None  # how many random states (default: from the numbers of parameters and joints)
    min_joint_motion: float = 1e-3  # rad (or m): a joint of the training log moving less is an error (unidentifiable)
    # parallel robots with redundant actuation only: "projected" | "min_norm" | "min_norm_local_friction"
    force_model: str | None = None
    # gm | ml: the noise covariance across joints: "residuals" (feasible GLS) | "periodic" (period averaging) |
    # a matrix [[...], ...]; ml: "periodic" by default
    noise_covariance: str | tuple[tuple[float, ...], ...] = "residuals"
    iterations: int = 1  # gm with noise_covariance = "residuals": rounds of covariance re-estimation
    nominal_weighting: bool = False  # wls: weight the observation matrix by the nominal values (Shang Eq. 17)
    # ml only: Sigma_dd of the actuator positions, "periodic" (from the period averaging) or a matrix [[...], ...]
    position_covariance: str | tuple[tuple[float, ...], ...] = "periodic"
    # ml only: the cut-offs searched, [low, high] in Hz; None: 0.5-2 x the configured cut-off
    cutoff_range_hz: tuple[float, float] | None = None
    # physically consistent identification (physical_consistency = true; issue 8)
    margin: float = 0.0  # physical: every pseudo-inertia >= margin * I
    # physical: towards the nominal values, "none" | "euclidean" (paper 003 Eq. 22) | "logdet" (Lee-Wensing-Park)
    regularization: str = "none"
    # physical: lambda, in units of the residual chi^2 (default 1 with a regularization named, else 0)
    regularization_weight: float = 0.0
    solver: str = "CLARABEL"  # physical: any installed cvxpy solver
    # physical: bounds per body, [identification.bodies.<name>] (named as its mass parameter: m3 -> "3"):
    # mass = [lo, hi] kg, com_box = [[x, y, z], [x, y, z]] m, com_ellipsoid = { center, semi_axes } m
    bodies: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    # physical, ols | wls: "linear" or "stribeck" (nonlinear friction, paper 000 Eq. 32);
    # hierarchical = true: the friction family, "linear" | "stribeck" | "powerlaw" | "arctan"
    friction_model: str = "linear"
    max_samples: int = 4000  # friction_model = "stribeck": samples used by the nonlinear fit
    # structural reduction (dynid.model.reduction): "auto" (parallel robots: "full" or "identical_chains"
    # chosen from the training data, dynid.pipeline.structure; serial robots: "full"), "full",
    # "identical_chains" or "paper"
    structure: str = "auto"
    # parallel robots: the chains' joints in corresponding order, [["a1", "b1"], ["a2", "b2"]], or groups of
    # such lists; None: the mechanism's own chains
    identical_chains: tuple[tuple[tuple[str, ...], ...], ...] | None = None
    # ols | wls: the covariance the intervals use (issue 17), "model" (white residuals) | "hac" | "block_bootstrap"
    covariance: CovarianceConfig = CovarianceConfig()
    # methods "iv", "didim" and "cloe" (issue 17): the experiment replayed on the model under its controller
    experiment: Path | None = None  # the dynid simulate config of the training experiment
    start: str = "wls"  # "wls" (IDIM-WLS estimate) or "nominal" (the robot description's values)
    max_iterations: int = 10  # the most iterations (replays of the experiment)
    tolerance: float = 0.5  # stop when no parameter moves by more than this many standard deviations
    # the replays' regularized Coulomb law: tanh(v / v_b), v_b this fraction of the largest measured
    # actuator speed; 0: the discontinuous law (dynid.pipeline.control_loop). Default 0.05 for "iv", 0 for "didim" and "cloe"
    replay_coulomb_band: float = 0.05
    # the directions estimated (fixed at the start's replay): singular values of the scaled step matrix
    # (IV: Z^T W; DIDIM, CLOE: W_s^T W_s) above this fraction of the largest. Default 1e-3 for "iv", 1e-6 for "didim"/"cloe"
    directions_rtol: float = 1e-3
    # the Coulomb terms' sign: "none" (the sign), "auto" (erf of the data's velocity-noise std), or widths per actuator
    coulomb_smoothing: str | tuple[float, ...] = "none"
    # hierarchical iterative identification (paper 003 Sec. 3.3, Algorithm 1; dynid.pipeline.hierarchical):
    # friction_model then names a paper-003 family ("linear", "stribeck", "powerlaw", "arctan")
    hierarchical: bool = False
    friction_prior: Path | None = None  # a dynid friction result (friction.json): the starting friction


HIERARCHICAL_FAMILIES = ("linear", "stribeck", "powerlaw", "arctan")
"""``friction_model`` with ``hierarchical = true``: paper 003 Eq. 2, 14, 13 and 15 (the improved Stribeck
model); see :data:`dynid.pipeline.hierarchical.FAMILIES`."""


_PHYSICAL_KEYS = ("margin", "regularization", "regularization_weight", "solver", "bodies", "friction_model", "max_samples")
_BODY_KEYS = {"mass", "com_box", "com_ellipsoid"}


def _parse_bodies(t: Any, where: str) -> dict[str, dict[str, Any]]:
    """``[identification.bodies.<name>]``: mass = [lo, hi], com_box = [[x,y,z], [x,y,z]],
    com_ellipsoid = {center = [x,y,z], semi_axes = [a,b,c]}."""
    if not isinstance(t, dict):
        raise ConfigError(f"{where}: expected a table of bodies")

    def vec(v, w, n):
        if not (isinstance(v, list) and len(v) == n):
            raise ConfigError(f"{w} must be a list of {n} numbers")
        return tuple(_num(x, w) for x in v)

    out: dict[str, dict[str, Any]] = {}
    for name, b in t.items():
        w = f"{where}.{name}"
        b = _table(b, w, _BODY_KEYS)
        entry: dict[str, Any] = {}
        if "mass" in b:
            entry["mass"] = vec(b["mass"], f"{w}.mass", 2)
        if "com_box" in b:
            v = b["com_box"]
            if not (isinstance(v, list) and len(v) == 2):
                raise ConfigError(f"{w}.com_box must be [[x, y, z] low, [x, y, z] high] in m")
            entry["com_box"] = (vec(v[0], f"{w}.com_box", 3), vec(v[1], f"{w}.com_box", 3))
        if "com_ellipsoid" in b:
            e = _table(b["com_ellipsoid"], f"{w}.com_ellipsoid", {"center", "semi_axes"}, {"center", "semi_axes"})
            entry["com_ellipsoid"] = (vec(e["center"], f"{w}.com_ellipsoid.center", 3),
                                      vec(e["semi_axes"], f"{w}.com_ellipsoid.semi_axes", 3))
        out[str(name)] = entry
    return out



_STRUCTURES = ("auto", "full", "identical_chains", "paper")  # "auto" + dynid.model.reduction.STRUCTURES (config sits above model)


def _chain_groups(spec: Any, where: str) -> tuple[tuple[tuple[str, ...], ...], ...]:
    """``identical_chains``: one group of chains ``[["a1", "b1", "P1"], ["a2", "b2", "P2"], ...]`` (each chain
    its joint names in corresponding order) or several groups ``[[["a1", "b1"], ["a2", "b2"]], [...]]``."""
    if not isinstance(spec, list) or not spec:
        raise ConfigError(f"{where} must be a non-empty list of chains (lists of joint names)")
    nested = all(isinstance(c, list) and c and isinstance(c[0], list) for c in spec)
    out = []
    for g in spec if nested else [spec]:
        if not isinstance(g, list) or len(g) < 2:
            raise ConfigError(f"{where}: a group needs at least two chains, got {g!r}")
        for c in g:
            if not isinstance(c, list) or not c or not all(isinstance(j, str) for j in c):
                raise ConfigError(f"{where}: a chain is a list of joint names, got {c!r}")
        out.append(tuple(tuple(c) for c in g))
    return tuple(out)


_LOOP_KEYS = ("experiment", "start", "max_iterations", "tolerance", "replay_coulomb_band", "directions_rtol")


IDENTIFICATION_KEYS = ("method", "physical_consistency", "chunk_size", "streaming", "cluster", "workers", "base_seed", "base_samples", "min_joint_motion",
                       "force_model", "noise_covariance", "iterations", "nominal_weighting", "position_covariance",
                       "cutoff_range_hz", "structure", "identical_chains", "coulomb_smoothing", "hierarchical",
                       "friction_prior", *_PHYSICAL_KEYS, *_COVARIANCE_KEYS, *_LOOP_KEYS)
"""The keys of ``[identification]``."""


def _parse_cluster(t: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``cluster`` ("off", "local" or a Dask scheduler address) and ``workers`` (with "local" only)."""
    cluster = t.get("cluster", "off")
    if cluster not in ("off", "local"):
        if not (isinstance(cluster, str) and "://" in cluster):  # a bare word is a typo of a choice, not a host
            raise ConfigError(f"{where}.cluster: expected 'off', 'local' or a Dask scheduler address with its scheme "
                              f"(tcp://host:8786), got {cluster!r}")
        cluster = parse_scheduler(cluster, f"{where}.cluster")
    if "workers" in t and cluster != "local":
        raise ConfigError(f"{where}.workers is the size of the local cluster (cluster = 'local'); with cluster = "
                          f"{cluster!r} " + ("nothing runs on workers" if cluster == "off" else "the scheduler's workers run it"))
    return {"cluster": cluster, "workers": parse_workers(t.get("workers", 0), f"{where}.workers")}


def _parse_identification(t: Any, base: Path = Path(".")) -> IdentificationConfig:
    where = "identification"
    t = _table(t, where, set(IDENTIFICATION_KEYS))
    method = _str(t.get("method", "wls"), f"{where}.method", _METHODS)
    physical = _bool(t.get("physical_consistency", False), f"{where}.physical_consistency")
    hierarchical = _bool(t.get("hierarchical", False), f"{where}.hierarchical")
    if not hierarchical and t.get("friction_model") in ("powerlaw", "arctan"):
        raise ConfigError(f"{where}.friction_model = {t['friction_model']!r} is a family of the hierarchical "
                          f"identification (paper 003 Sec. 3.3): set {where}.hierarchical = true")
    given = [k for k in _PHYSICAL_KEYS if k in t and not (hierarchical and k == "friction_model")]
    if given and not physical:
        raise ConfigError(f"{where}.{given[0]} is for physically consistent identification: set "
                          f"{where}.physical_consistency = true")
    if physical and method not in ("ols", "wls", "gm", "didim"):
        raise ConfigError(f"{where}.physical_consistency = true is available with methods 'ols', 'wls', 'gm' and "
                          f"'didim', not {method!r}")
    loop = method in ("iv", "didim", "cloe")
    extra = [k for k in _LOOP_KEYS if k in t]
    if extra and not loop:
        raise ConfigError(f"{where}.{extra[0]} is for method = 'iv', 'didim' or 'cloe' (the experiment replayed on the model)")
    if loop and "experiment" not in t:
        raise ConfigError(f"{where}.method = {method!r} simulates the experiment with the current estimate under its "
                          f"controller: set {where}.experiment to the dynid simulate config of the training experiment "
                          "(controller, gains, reference, rates)")
    reg = _str(t.get("regularization", "none"), f"{where}.regularization", ("none", "euclidean", "logdet"))
    # a named regularization weighs 1 by default: lambda is in units of the residual chi^2 (PhysicalLS), so at 1 a
    # unit divergence from the nominal model costs as much as one noise variance of extra residual; "none" has none
    reg_w = _num(t.get("regularization_weight", 0.0 if reg == "none" else 1.0), f"{where}.regularization_weight")
    if reg == "none" and reg_w != 0.0:
        raise ConfigError(f"{where}.regularization_weight = {reg_w:g} needs a regularization: set "
                          f"{where}.regularization = 'euclidean' or 'logdet'")
    if reg != "none" and not reg_w > 0:
        raise ConfigError(f"{where}.regularization = {reg!r} needs regularization_weight > 0 (default 1), got {reg_w:g}")
    margin = _num(t.get("margin", 0.0), f"{where}.margin")
    if margin < 0:
        raise ConfigError(f"{where}.margin must be >= 0, got {margin}")
    if hierarchical:
        if "friction_model" not in t:
            raise ConfigError(f"{where}.hierarchical = true alternates rigid-body and friction fits: name the friction "
                              f"family, {where}.friction_model = 'stribeck', 'powerlaw', 'arctan' or 'linear' "
                              "(paper 003 Eq. 14, 13, 15, 2)")
        friction_model = _str(t["friction_model"], f"{where}.friction_model", HIERARCHICAL_FAMILIES)
        if method not in ("ols", "wls"):
            raise ConfigError(f"{where}.hierarchical = true fits the rigid-body part by 'ols' or 'wls' (+ LMI with "
                              f"physical_consistency), not method {method!r}")
        if "max_samples" in t:
            raise ConfigError(f"{where}.max_samples is for the paper-000 Stribeck fit; hierarchical = true uses every "
                              "processed training sample")
        if "covariance" in t and t["covariance"] != "model":
            raise ConfigError(f"{where}.covariance = {t['covariance']!r} is not available with hierarchical = true "
                              "(the rigid-body fit is repeated on friction-corrected torques; only the model covariance)")
        if "coulomb_smoothing" in t:
            raise ConfigError(f"{where}.coulomb_smoothing is for the linear friction columns; hierarchical = true fits "
                              "the friction curve itself (friction_model = 'arctan' smooths with arctan, Eq. 15)")
    else:
        friction_model = _str(t.get("friction_model", "linear"), f"{where}.friction_model", ("linear", "stribeck"))
        if "friction_prior" in t:
            raise ConfigError(f"{where}.friction_prior is the starting friction of hierarchical = true; set "
                              f"{where}.hierarchical = true or remove it")
    if "max_samples" in t and friction_model != "stribeck":
        raise ConfigError(f"{where}.max_samples is for friction_model = 'stribeck' (the rows of the nonlinear fit)")
    for key, need in (("noise_covariance", ("gm", "ml")), ("iterations", ("gm",)), ("nominal_weighting", ("wls",)),
                      ("position_covariance", ("ml",)), ("cutoff_range_hz", ("ml",))):
        if key in t and method not in need:
            raise ConfigError(f"{where}.{key} is for method = {' or '.join(repr(m) for m in need)}, not {method!r}")

    def matrix(key: str, words: tuple[str, ...]) -> Any:
        v = t[key]
        if isinstance(v, str):
            return _str(v, f"{where}.{key}", words)
        if isinstance(v, list) and v and all(isinstance(r, list) and len(r) == len(v) for r in v):
            return tuple(tuple(_num(x, f"{where}.{key}") for x in r) for r in v)
        raise ConfigError(f"{where}.{key} must be {' or '.join(repr(w) for w in words)} or a square matrix (list of rows)")

    ncov: Any = "periodic" if method == "ml" else "residuals"
    if "noise_covariance" in t:
        ncov = matrix("noise_covariance", ("periodic",) if method == "ml" else ("residuals", "periodic"))
    pcov = matrix("position_covariance", ("periodic",)) if "position_covariance" in t else "periodic"
    crange = None
    if "cutoff_range_hz" in t:
        v = t["cutoff_range_hz"]
        if not (isinstance(v, list) and len(v) == 2):
            raise ConfigError(f"{where}.cutoff_range_hz must be [low, high] in Hz")
        crange = (_num(v[0], f"{where}.cutoff_range_hz"), _num(v[1], f"{where}.cutoff_range_hz"))
        if not 0 < crange[0] < crange[1]:
            raise ConfigError(f"{where}.cutoff_range_hz must satisfy 0 < low < high, got {list(crange)}")
    smoothing: str | tuple[float, ...] = "none"
    if "coulomb_smoothing" in t:
        v = t["coulomb_smoothing"]
        if isinstance(v, str):
            smoothing = _str(v, f"{where}.coulomb_smoothing", ("none", "auto"))
        elif isinstance(v, list) and v:
            smoothing = tuple(_num(x, f"{where}.coulomb_smoothing", minimum=0.0) for x in v)
        else:
            raise ConfigError(f"{where}.coulomb_smoothing must be 'none', 'auto' or a list of velocity widths per actuator "
                              "[rad/s or m/s]")
        if smoothing != "none" and (method not in ("ols", "wls", "gm", "ml") or friction_model != "linear"):
            raise ConfigError(f"{where}.coulomb_smoothing is available with methods 'ols', 'wls', 'gm' and 'ml' and the linear "
                              f"friction model, not method {method!r}" + (" with friction_model = 'stribeck'"
                                                                            if friction_model != "linear" else ""))
    chains = _chain_groups(t["identical_chains"], f"{where}.identical_chains") if "identical_chains" in t else None
    # chains named by hand tie them unless the structure says otherwise ("auto": tied or full, from the data)
    structure = _str(t.get("structure", "identical_chains" if chains else "auto"), f"{where}.structure", _STRUCTURES)
    if chains and structure == "full":
        raise ConfigError(f"{where}.identical_chains needs {where}.structure = 'identical_chains', 'paper' or 'auto', "
                          "not 'full'")
    return IdentificationConfig(
        structure=structure,
        identical_chains=chains,
        coulomb_smoothing=smoothing,
        hierarchical=hierarchical,
        friction_prior=_path(t["friction_prior"], f"{where}.friction_prior", base) if "friction_prior" in t else None,
        experiment=_path(t["experiment"], f"{where}.experiment", base) if loop else None,
        start=_str(t.get("start", "wls" if method == "iv" else "nominal"), f"{where}.start", ("wls", "nominal")),
        max_iterations=_int(t.get("max_iterations", 10), f"{where}.max_iterations", 1),
        tolerance=_num(t.get("tolerance", 0.5), f"{where}.tolerance", minimum=0.0),
        replay_coulomb_band=_num(t.get("replay_coulomb_band", 0.05 if method == "iv" else 0.0), f"{where}.replay_coulomb_band",
                                 minimum=0.0),
        directions_rtol=_num(t.get("directions_rtol", 1e-3 if method == "iv" else 1e-6), f"{where}.directions_rtol",
                             positive=True),
        noise_covariance=ncov,
        position_covariance=pcov,
        cutoff_range_hz=crange,
        iterations=_int(t.get("iterations", 1), f"{where}.iterations", 1),
        nominal_weighting=_bool(t.get("nominal_weighting", False), f"{where}.nominal_weighting"),
        method=method,
        physical_consistency=physical,
        margin=margin,
        regularization=reg,
        regularization_weight=reg_w,
        solver=_str(t.get("solver", "CLARABEL"), f"{where}.solver"),
        bodies=_parse_bodies(t["bodies"], f"{where}.bodies") if "bodies" in t else {},
        friction_model=friction_model,
        covariance=_parse_covariance(t, method, physical, "linear" if hierarchical else friction_model),
        max_samples=_int(t.get("max_samples", 4000), f"{where}.max_samples", 100),
        chunk_size=_int(t.get("chunk_size", 20000), f"{where}.chunk_size", 1),
        streaming=_str(t.get("streaming", "auto"), f"{where}.streaming", ("auto", "on", "off")),
        **_parse_cluster(t, where),
        base_seed=_int(t.get("base_seed", 0), f"{where}.base_seed", 0),
        base_samples=_int(t["base_samples"], f"{where}.base_samples", 1) if "base_samples" in t else None,
        min_joint_motion=_num(t.get("min_joint_motion", 1e-3), f"{where}.min_joint_motion", minimum=0.0),
        force_model=_str(t["force_model"], f"{where}.force_model", _FORCE_MODELS) if "force_model" in t else None,
    )
