"""Paper 003 (Ku, Li & Zhu 2026) on its cobot6r twin: Tables 1, 4, 6, 7, 8 and Fig. 7 in kind.

The paper identifies a JAKA Mini Cobo with a constant-velocity friction pre-identification
(§3.1, Eq. 13-15, Table 4, Fig. 7), a hierarchical iteration between the rigid-body parameters
(LS / WLS, + LMI "FBPE") and the friction curves (§3.3, "Proposed"), and a physics-informed
recurrent network on what is left (§3.4, Table 1); it scores every method on two verification
trajectories (Tables 6 and 8: per-joint RMSE and their Sum, N·m) and the friction families under
Proposed-FBPE (Table 7). Here, in kind, through the product (``dynid simulate`` -> ``dynid
friction`` -> ``dynid identify`` per row -> validation on VT1 and VT2):

* the twin (``examples/twins/cobot6r_paper003_*.toml``): ``builtin:cobot6r``, body parameters 10 %
  off the nominal (CAD) ones, joint friction = paper 003's Eq. 15 with F_c, F_v, alpha, K_v of its
  Table 3 (F_s = 1.3 F_c and the Stribeck velocities ours) as the **steady state** of a friction
  with memory: a first-order lag of 10 ms (Hess & Soom's frictional memory,
  :class:`dynid.model.friction.FrictionMemory`, integrated in the plant). A constant-velocity
  experiment sees exactly Eq. 15; a moving excitation sees friction lagging the curve, which a
  static curve cannot describe and a recurrent network can (the paper's §3.4 argument);
  nominal-model feedforward + joint PID at 1 kHz, logs at 200 Hz, torque noise 0.3 0.3 0.2 0.1
  0.05 0.05 N·m, 17-bit encoders;
* experiments: the friction experiment (``dynid design`` kind ``constant_velocity``,
  ``examples/friction/paper003_twin_design.toml``: 13 speeds 0.003-0.8 rad/s per joint,
  2.5 s windows, 3.85-8 s at the four slowest where Eq. 15's K_v is decided; PID only; ``dynid
  friction`` keeps each window's steady part, after the 1 s skip and its steady-state rule), the
  training excitation (10 s, 5-harmonic rest-to-rest Fourier), VT1 (10 s, another seed) and VT2
  (8 s, another seed, base frequency and speed);
* rows (Tables 6/8): LS = ``ols``, WLS = ``wls``, -FBPE = ``physical_consistency = true`` (LMI),
  all with linear Coulomb + viscous + offset friction; Proposed = ``hierarchical = true``,
  ``friction_model = "arctan"`` (Eq. 15) started from ``dynid friction``'s fit
  (``friction_prior``), with WLS; Proposed-FBPE the same + LMI; +PI-LSTM: Proposed-FBPE with a
  ``[learning]`` section (the network on the hierarchical model's residual); beside them the
  nominal (CAD) model, the truth's static model (true rigid body + Eq. 15: the best any static
  friction curve can do), the truth with its memory state (z integrated from the processed
  velocity: what the plant did, up to the velocity estimate) and the noise floor (the noise std);
* Table 7: Proposed-FBPE with the families Coulomb-viscous (Eq. 2), power law (Eq. 13), Stribeck
  (Eq. 14) and improved Stribeck (Eq. 15), each started from its ``dynid friction`` fit;
* Table 1: PI-RNN / PI-GRU / PI-LSTM on the Proposed-FBPE residual (held-out VT2 RMSE, low-speed
  region |q̇| < 0.5 rad/s, epochs to converge).

Every held-out error is on every processed sample of the verification log (no row selection).
Processing (every row alike): zero-phase 4th-order Butterworth low-pass at 10 Hz of the positions
*and* the torques (parallel filtering), derivatives by central differences; the noise floor is the
noise std times the filter's noise gain (the root of the sum of squares of its impulse response).
Proposed-FBPE and +PI-LSTM come from one ``dynid identify`` run with ``[learning]`` (which reports
the held-out errors without and with the network), Table 1's PI-LSTM is that network, its PI-RNN
and PI-GRU are trained on the same residual with the same settings.
``quick=True``: the first 6 s of VT1, PI-LSTM only in Table 1 (the test's version; VT2 and the
network stay whole: the full run's PI-LSTM gain, 17.9 % against target 2's 20 % (20.3 % before the
steady-state friction points), is closer to the threshold than a smaller network or a shorter VT2
moves it; the friction experiment stays whole: shorter windows bias its low-speed points or, with
the steady-state rule, leave them out, bench/README).

Run: ``python bench/paper003_study.py [--quick]``; figures of the last full run in bench/README.md
("Paper 003 (cobot6r twin)").
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dynid.config import parse_config
from dynid.config.friction import parse_friction_config
from dynid.config.simulate import parse_simulate_config
from dynid.errors import InputError
from dynid.estimation.friction_curves import MODELS, CurveFit
from dynid.model.friction import SmoothStribeck

__all__ = ["EXAMPLES", "FILES", "ROWS", "FAMILIES", "Paper003Study", "paper003_study", "TRUE_FAMILY", "conclusions",
           "plot_fig7", "twin_documents", "identify_document", "friction_design_document", "identifiability"]

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "twins"
FILES = {"train": "cobot6r_paper003_train.toml", "VT1": "cobot6r_paper003_vt1.toml",
         "VT2": "cobot6r_paper003_vt2.toml", "friction": "cobot6r_paper003_friction.toml"}
FRICTION_DESIGN = EXAMPLES.parent / "friction" / "paper003_twin_design.toml"
JOINTS = tuple(f"joint_{j}" for j in range(1, 7))
ROWS = (  # name, method, LMI, hierarchical
    ("LS", "ols", False, False),
    ("WLS", "wls", False, False),
    ("LS-FBPE", "ols", True, False),
    ("WLS-FBPE", "wls", True, False),
    ("Proposed", "wls", False, True),
    ("Proposed-FBPE", "wls", True, True),
)
FAMILIES = (  # Table 7: model number, hierarchical family, dynid friction model
    ("Model 1 (Coulomb-viscous, Eq. 2)", "linear", "coulomb_viscous"),
    ("Model 2 (power law, Eq. 13)", "powerlaw", "power_law"),
    ("Model 3 (Stribeck, Eq. 14)", "stribeck", "stribeck"),
    ("Model 4 (improved Stribeck, Eq. 15)", "arctan", "smooth_stribeck"),
)
TRUE_FAMILY = "smooth_stribeck"
LOWPASS = {"cutoff_hz": 10.0, "order": 4, "filter_effort": True}  # torques filtered like the positions (parallel)
LEARNING = {"model": "lstm", "window": 6, "hidden": 24, "epochs": 150, "lambda": 0.2, "seed": 0, "max_seconds": 300}
LEARNING_QUICK: dict[str, Any] = {}  # the full network: target 2's verdict is 17.9 % against 20 % (bench/README)
NETS = ("rnn", "gru", "lstm")


def _doc(name: str) -> dict[str, Any]:
    return _doc_path(EXAMPLES / FILES[name])


def _doc_path(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InputError(f"paper 003 study: {path} not found (the twin's configs live in the repository's "
                         "examples/twins)")
    with open(path, "rb") as fh:
        return tomllib.load(fh)


def friction_design_document() -> dict[str, Any]:
    """The ``dynid design`` document (``kind = "constant_velocity"``) of the friction experiment."""
    return _doc_path(FRICTION_DESIGN)


def _design_friction(folder: Path) -> Path:
    """``dynid design`` of the friction experiment into ``folder``; its ``design.json``."""
    from dynid.config.design import parse_design_config
    from dynid.pipeline.design import run_design, write_design

    cfg = parse_design_config(friction_design_document(), FRICTION_DESIGN.parent)
    write_design(run_design(cfg), folder)
    return folder / "design.json"


def twin_documents(quick: bool = False, draw: int = 0) -> dict[str, dict[str, Any]]:
    """The ``dynid simulate`` documents of the four experiments (quick: shorter, see module doc);
    ``draw`` > 0: every trajectory and noise seed of another draw (:func:`dynid.studies.draw_seed`),
    the same true robot."""
    from dynid.studies import draw_seed

    docs = {k: _doc(k) for k in FILES}
    for doc in docs.values():
        for table in ("trajectory", "sensors"):
            if "seed" in doc.get(table, {}):
                doc[table]["seed"] = draw_seed(doc[table]["seed"], draw)
    if quick:  # the friction experiment stays whole: shorter windows bias its low-speed points (see docs/guide/friction.md)
        docs["VT1"]["simulation"] = {"duration": 6.0}
    return docs


def _log_spec(path: Path) -> dict[str, Any]:
    return {"file": str(path), "time": {"column": "t", "unit": "s"},
            "position": {"columns": [f"q_{j}" for j in JOINTS], "unit": "rad"},
            "effort": {"columns": [f"tau_{j}" for j in JOINTS], "unit": "N*m", "kind": "torque"}}


def identify_document(train: Path, valid: Path, method: str, lmi: bool, family: str | None,
                      prior: Path | None, learning: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``dynid identify`` document of one row (``family``: None = one-shot with linear friction,
    otherwise ``hierarchical = true`` with that family started from ``prior``)."""
    ident: dict[str, Any] = {"method": method}
    if lmi:
        ident["physical_consistency"] = True
    if family is not None:
        ident.update(hierarchical=True, friction_model=family, friction_prior=str(prior))
    doc = {"robot": {"model": "builtin:cobot6r"}, "data": _log_spec(train), "validation": {"file": str(valid)},
           "processing": {"lowpass": dict(LOWPASS)}, "identification": ident, "output": {"plots": False}}
    if learning is not None:
        doc["learning"] = dict(learning)
    return doc


@dataclasses.dataclass(frozen=True, eq=False)
class Paper003Study:
    """Outcome of :func:`paper003_study`.

    Attributes
    ----------
    vt : dict VT name -> dict row name -> per-joint RMSE list (N·m), rows of Tables 6/8 plus
        "nominal (CAD)", "+PI-LSTM", "truth (static Eq. 15)", "truth (with memory)", "noise floor".
    table7 : dict VT name -> dict model label -> per-joint RMSE list (Proposed-FBPE, families 1-4).
    table4 : dict model -> {"per_joint", "total"} (held-out RMSE of ``dynid friction``'s fits).
    table4_fit : the same for the fitting RMSE on all points.
    table1 : list of rows (model, rmse, low_speed_rmse, epochs_to_converge, seconds, rmse_per_joint) on VT2.
    friction_fit : joint -> {coef: {"value", "std", "truth", "rel_error"}} of the true family in ``dynid friction``.
    hierarchical_fit : joint -> {coef: {"value", "std", "truth", "rel_error"}} of Proposed-FBPE's final curves.
    fig7 : joint -> {"speed", "friction", "sigma", "held_out", "curves": {model: params}} (Fig. 7 data).
    iterations : row -> hierarchical iterations and stop reason.
    timings : stage -> seconds.
    settings : the documents used.
    product_vt1 : row -> per-joint RMSE on VT1 as ``dynid identify`` itself reported it (its
        validation; for +PI-LSTM its ``learning`` validation with the network).
    friction_identifiability : joint -> :func:`identifiability` of the true family on its points.
    """

    vt: dict[str, dict[str, list[float]]]
    table7: dict[str, dict[str, list[float]]]
    table4: dict[str, dict[str, Any]]
    table4_fit: dict[str, dict[str, Any]]
    table1: list[dict[str, Any]]
    friction_fit: dict[str, dict[str, dict[str, float]]]
    hierarchical_fit: dict[str, dict[str, dict[str, float]]]
    fig7: dict[str, dict[str, Any]]
    iterations: dict[str, Any]
    timings: dict[str, float]
    settings: dict[str, Any]
    quick: bool = False
    product_vt1: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    friction_identifiability: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)

    @staticmethod
    def total(per_joint: list[float]) -> float:
        return float(np.sum(per_joint))

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def tables_text(self) -> str:
        """Tables 4, 6/8, 7 and 1 as text (per-joint RMSE and Sum, N·m)."""
        head = f"{'':<30}" + "".join(f"{j:>9}" for j in JOINTS) + f"{'Sum':>9}"
        out = ["Table 4 (in kind): friction-model held-out RMSE of dynid friction (alternate speeds), N*m", head]
        for m, row in self.table4.items():
            out.append(f"{m:<30}" + "".join(f"{row['per_joint'][j]:9.4f}" for j in JOINTS) + f"{row['total']:9.4f}")
        out += ["(fitting RMSE on all points)"]
        for m, row in self.table4_fit.items():
            out.append(f"{m:<30}" + "".join(f"{row['per_joint'][j]:9.4f}" for j in JOINTS) + f"{row['total']:9.4f}")
        for vt, tab in (("VT1", "Table 6"), ("VT2", "Table 8")):
            out += ["", f"{tab} (in kind): held-out RMSE on {vt}, N*m", head]
            for name, per in self.vt[vt].items():
                out.append(f"{name:<30}" + "".join(f"{x:9.4f}" for x in per) + f"{self.total(per):9.4f}")
        out += ["", "Table 7 (in kind): Proposed-FBPE with friction models 1-4, Sum of joint RMSE, N*m",
                f"{'':<40}{'VT1':>9}{'VT2':>9}"]
        for label in self.table7["VT1"]:
            out.append(f"{label:<40}{self.total(self.table7['VT1'][label]):9.4f}"
                       f"{self.total(self.table7['VT2'][label]):9.4f}")
        out += ["", "Table 1 (in kind): networks on the Proposed-FBPE residual, held-out VT2, N*m",
                f"{'model':<30}{'Sum RMSE':>10}{'RMSE all':>10}{'low-speed':>10}{'epochs':>8}{'seconds':>9}"]
        for r in self.table1:
            ep = "" if not np.isfinite(r["epochs_to_converge"]) else f"{r['epochs_to_converge']:.0f}"
            sec = "" if not np.isfinite(r["seconds"]) else f"{r['seconds']:.1f}"
            out.append(f"{r['model']:<30}{sum(r['rmse_per_joint']):10.4f}{r['rmse']:10.4f}{r['low_speed_rmse']:10.4f}"
                       f"{ep:>8}{sec:>9}")
        for title, fit in (("dynid friction (constant-velocity points)", self.friction_fit),
                           ("Proposed-FBPE's final curves (hierarchical)", self.hierarchical_fit)):
            out += ["", f"Eq. 15 coefficients, {title}: value (std) truth, relative error %"]
            for j, coefs in fit.items():
                out.append(f"  {j}: " + ", ".join(
                    f"{n} {c['value']:.4g} ({c['std']:.2g}) {c['truth']:.4g} {100 * c['rel_error']:+.1f}%"
                    for n, c in coefs.items()))
        out += ["", "Eq. 15 identifiability on the constant-velocity points (at the truth): relative std the points "
                "allow, largest correlation, condition number; reduced chi-square of the truth's curve and the fit's"]
        for j, c in self.friction_identifiability.items():
            out.append(f"  {j}: " + ", ".join(f"{n} {100 * x:.1f}%" for n, x in c["rel_std_at_truth"].items())
                       + f"; corr {c['max_corr']:+.3f} ({'/'.join(c['max_corr_pair'])}), cond {c['cond']:.3g}; "
                       f"chi2 truth {c['chi2_red_truth']:.3g}, fit {c['chi2_red_fit']:.3g}")
        return "\n".join(out)

    def targets(self) -> dict[str, Any]:
        """Item 6's four targets, measured (VT2; friction coefficients of the true family)."""
        vt2 = {k: self.total(v) for k, v in self.vt["VT2"].items()}
        prop, wlmi, lstm = vt2["Proposed-FBPE"], vt2["WLS-FBPE"], vt2["+PI-LSTM"]
        worst_fr = max(abs(c["rel_error"]) for cs in self.friction_fit.values() for c in cs.values())
        # a coefficient passes within 10 % of the truth, or, where its reported std exceeds 5 % of the
        # truth (10 % is then below what the method resolves at 2 std), within 2 std
        missed = {f"{j} {n}": round(100 * c["rel_error"], 1) for j, cs in self.friction_fit.items()
                  for n, c in cs.items() if not _coef_ok(c)}
        t7 = {k: {vt: self.total(v) for vt, v in ((vt, self.table7[vt][k]) for vt in self.table7)} for k in
              self.table7["VT1"]}
        lin = FAMILIES[0][0]
        nonlin_beat = {k: all(t7[k][vt] < t7[lin][vt] for vt in ("VT1", "VT2")) for k in t7 if k != lin}
        return {
            "proposed_fbpe_over_wls_fbpe_vt2": prop / wlmi, "target_1_holds": prop <= 0.8 * wlmi,
            "pi_lstm_gain_vt2": 1.0 - lstm / prop, "target_2_holds": lstm <= 0.8 * prop,
            "friction_worst_rel_error": worst_fr, "friction_missed_pct": missed, "target_3_holds": not missed,
            "nonlinear_beat_linear_table7": nonlin_beat, "target_4_holds": all(nonlin_beat.values()),
        }


ONE_SHOT = ("LS", "WLS", "LS-FBPE", "WLS-FBPE")


def conclusions(study: Paper003Study) -> dict[str, Any]:
    """What the study concludes (the quick version must conclude the same as the full one): item 6's
    targets, and the paper's qualitative claims on this twin."""
    t = study.targets()
    sums = {vt: {k: study.total(v) for k, v in rows.items()} for vt, rows in study.vt.items()}
    t7 = {vt: sorted(rows, key=lambda k: study.total(rows[k])) for vt, rows in study.table7.items()}
    t4 = {j: min(study.table4, key=lambda m: study.table4[m]["per_joint"][j]) for j in JOINTS}
    return {
        **{f"target_{k}_holds": bool(t[f"target_{k}_holds"]) for k in (1, 2, 3, 4)},
        "proposed_fbpe_beats_every_one_shot_row": all(
            sums[vt]["Proposed-FBPE"] < min(sums[vt][r] for r in ONE_SHOT) for vt in sums),
        "every_identified_row_beats_nominal": all(
            sums[vt][r] < sums[vt]["nominal (CAD)"] for vt in sums for r in (*ONE_SHOT, "Proposed", "Proposed-FBPE")),
        "pi_lstm_lowers_vt2": sums["VT2"]["+PI-LSTM"] < sums["VT2"]["Proposed-FBPE"],
        "table7_order_vt1": t7["VT1"], "table7_order_vt2": t7["VT2"],
        "table4_true_family_best_on_joints": sorted(j for j, m in t4.items() if m == TRUE_FAMILY),
    }


def _coef_ok(c: dict[str, float]) -> bool:
    """Target 3 for one coefficient: within 10 % of the truth, or within 2 reported std where the
    std is above 5 % of the truth (the method cannot resolve 10 % there)."""
    if abs(c["rel_error"]) <= 0.10:
        return True
    s = c["std"]
    return bool(np.isfinite(s) and s > 0.05 * abs(c["truth"]) and abs(c["value"] - c["truth"]) <= 2 * s)


def identifiability(speed: np.ndarray, sigma: np.ndarray, truth: dict[str, float], fitted: dict[str, float],
                    force: np.ndarray) -> dict[str, Any]:
    """How well the points of one joint decide Eq. 15's six coefficients (paper 003 Eq. 15).

    At the truth, the points' weighted sensitivities ``J = dF(v_i)/d ln(theta) / sigma_i`` give the
    coefficients' relative standard errors ``sqrt(diag (J^T J)^-1)`` (what the noise of the points
    alone allows, locally), their correlation matrix and the condition number of ``J`` (columns
    scaled to unit norm). Beside them, the reduced chi-square of the truth's curve and of the fitted
    one on the same points: where both are alike, the points cannot prefer the truth's coefficients
    to the fitted ones, whatever their distance."""
    from dynid.estimation.friction_curves import curve_force

    names = MODELS[TRUE_FAMILY]
    x0 = np.array([truth[n] for n in names], float)
    J = np.empty((speed.size, len(names)))
    for k in range(len(names)):
        h = 1e-6
        up, dn = x0.copy(), x0.copy()
        up[k] *= np.exp(h)
        dn[k] *= np.exp(-h)
        J[:, k] = (curve_force(TRUE_FAMILY, up, speed) - curve_force(TRUE_FAMILY, dn, speed)) / (2 * h) / sigma
    inv = np.linalg.pinv(J.T @ J)
    rel_std = np.sqrt(np.diag(inv))
    corr = inv / np.outer(rel_std, rel_std)
    off = np.abs(corr - np.diag(np.diag(corr)))
    a, b = np.unravel_index(int(np.argmax(off)), off.shape)
    Jn = J / np.linalg.norm(J, axis=0)
    dof = max(speed.size - len(names), 1)

    def chi2(x):
        return float(np.sum(((curve_force(TRUE_FAMILY, x, speed) - force) / sigma) ** 2) / dof)

    return {"rel_std_at_truth": dict(zip(names, rel_std.tolist())), "max_corr": float(corr[a, b]),
            "max_corr_pair": [names[a], names[b]], "cond": float(np.linalg.cond(Jn)),
            "chi2_red_truth": chi2(x0), "chi2_red_fit": chi2(np.array([fitted[n] for n in names], float))}


def _simulate(doc: dict[str, Any], folder: Path) -> dict[str, Any]:
    from dynid.pipeline.simulate import run_simulation, write_simulation

    sim = run_simulation(parse_simulate_config(doc, folder))
    write_simulation(sim, folder)
    return sim.truth


def _curves_of(result, joints: tuple[str, ...]):
    """The friction curves of a hierarchical result (its ``solver["hierarchical"]``)."""
    from dynid.pipeline.hierarchical import HierarchicalFriction

    info = result.solver["hierarchical"]
    model = info["model"]
    fits = []
    for j in joints:
        c = info["friction"][j]
        p = np.array([c[n]["value"] for n in MODELS[model]])
        s = np.array([np.nan if c[n]["std"] is None else c[n]["std"] for n in MODELS[model]])
        fits.append(CurveFit(model=model, names=MODELS[model], params=p, std=s, at_bound=np.zeros(p.size, bool),
                             cov=np.full((p.size, p.size), np.nan), rmse=float("nan"), chi2_red=float("nan"),
                             n_points=0, success=True, message="hierarchical result"))
    return HierarchicalFriction(info["family"], model, joints, tuple(fits))


def _processed(cfg, system, which: str):
    """A log of ``cfg`` (``"data"`` or ``"validation"``) processed as ``dynid identify`` does."""
    from dynid.pipeline.data import preprocess, read_log, to_actuator_space

    names = tuple(system.actuator_names)
    spec = cfg.data if which == "data" else cfg.validation
    raw = read_log(spec, system.n_actuators, names, which, {})
    act, _ = to_actuator_space(raw, system, which)
    ds, _ = preprocess(act, cfg.processing, which)
    return ds


def _noise_gain(ds) -> float:
    """RMS of the study's low-pass (zero-phase, at the log's rate) applied to unit white noise: the
    root of the sum of squares of its impulse response, away from the ends."""
    from dynid.signals import lowpass

    fs = 1.0 / float(np.median(np.diff(np.asarray(ds.t))))
    x = np.zeros(4001)
    x[2000] = 1.0
    h = lowpass(x, LOWPASS["cutoff_hz"], fs, LOWPASS["order"])
    return float(np.sqrt(np.sum(h ** 2)))


def _lag_state(fss: np.ndarray, t: np.ndarray, tau_m: float) -> np.ndarray:
    """z of dz/dt = (F_ss - z) / T_m along the samples (exact for F_ss linear between samples),
    started at the steady state."""
    z = np.empty_like(fss)
    z[0] = fss[0]
    for k in range(1, len(t)):
        h = t[k] - t[k - 1]
        e = np.exp(-h / tau_m)
        # exact solution for a linear ramp of F_ss over the step
        slope = (fss[k] - fss[k - 1]) / h
        z[k] = fss[k] - tau_m * slope + (z[k - 1] - fss[k - 1] + tau_m * slope) * e
    return z


def paper003_study(*, quick: bool = False, folder: str | Path | None = None,
                   progress: Callable[[str], None] | None = None, draw: int = 0) -> Paper003Study:
    """Simulate the four experiments, run ``dynid friction`` and every row's ``dynid identify``,
    validate on VT1 and VT2; see the module docstring.

    Parameters
    ----------
    quick : bool
        The tests' sizes (module docstring).
    folder : path, optional
        Where logs and results go (kept); default a temporary folder.
    progress : callable(str), optional
        Told what is being done (the bench script prints it with the elapsed time).
    draw : int
        0: the recorded study; another: the same experiments with other trajectory and noise
        seeds (:func:`twin_documents`).
    """
    if folder is None:
        with tempfile.TemporaryDirectory() as tmp:
            return paper003_study(quick=quick, folder=tmp, progress=progress, draw=draw)
    from dynid.pipeline.friction import run_friction, write_friction
    from dynid.pipeline.identification import identify
    from dynid.pipeline.rows import _model_rows

    say = progress or (lambda msg: None)
    d = Path(folder)
    docs = twin_documents(quick, draw)
    timings: dict[str, float] = {}
    truths = {}
    say("dynid design: the friction experiment (kind constant_velocity)")
    t0 = time.perf_counter()
    docs["friction"]["trajectory"] = {"kind": "constant_velocity", "design": str(_design_friction(d / "friction_design"))}
    timings["design friction"] = time.perf_counter() - t0
    settings_design = friction_design_document()
    for k in ("train", "VT1", "VT2", "friction"):
        say(f"dynid simulate: {k}")
        t0 = time.perf_counter()
        truths[k] = _simulate(docs[k], d / k)
        timings[f"simulate {k}"] = time.perf_counter() - t0
    truth = truths["train"]
    gtf = truth["ground_truth_friction"]
    true_static = SmoothStribeck(**{k: np.asarray(gtf[k], float) for k in ("fc", "fs", "fv", "vs", "kv", "alpha")})
    memory = np.broadcast_to(np.asarray(gtf["memory"], float), (6,))

    # --- friction pre-identification (paper 003 Sec. 3.1): Table 4, Fig. 7
    say("dynid friction: the constant-velocity points and the four families")
    t0 = time.perf_counter()
    fdoc = {"robot": {"model": "builtin:cobot6r"}, "data": {k: v for k, v in _log_spec(d / "friction" / "log.csv").items()
                                                            if k in ("file", "time", "position", "effort")},
            "friction": {"models": [f[2] for f in FAMILIES], "skip": settings_design["design"]["skip"],
                         "settle": True, "held_out": "alternate_speeds"},
            "output": {"plots": True}}
    fcfg = parse_friction_config(fdoc, d)
    fout = run_friction(fcfg)
    write_friction(fout, d / "friction_fit")
    prior = d / "friction_fit" / "friction.json"
    timings["dynid friction"] = time.perf_counter() - t0
    table4, table4_fit = fout.table4("held_out"), fout.table4("fit")
    friction_fit = {}
    ident: dict[str, dict[str, Any]] = {}
    fig7 = {}
    for jf in fout.joints:
        j = JOINTS.index(jf.name)
        f = jf.fits[TRUE_FAMILY]
        friction_fit[jf.name] = {n: {"value": float(v), "std": float(s), "truth": float(np.asarray(gtf[n])[j]
                                                                                            if np.ndim(gtf[n]) else gtf[n]),
                                     "rel_error": float(v / (np.asarray(gtf[n])[j] if np.ndim(gtf[n]) else gtf[n]) - 1)}
                                 for n, v, s in zip(f.names, f.params, f.std)}
        p = jf.points
        ident[jf.name] = identifiability(np.asarray(p.speed, float), np.asarray(p.sigma, float),
                                         {n: c["truth"] for n, c in friction_fit[jf.name].items()},
                                         {n: c["value"] for n, c in friction_fit[jf.name].items()},
                                         np.asarray(p.force, float))
        fig7[jf.name] = {"speed": np.asarray(p.speed).tolist(), "friction": np.asarray(p.force).tolist(),
                         "sigma": np.asarray(p.sigma).tolist(), "held_out": np.asarray(jf.held_out).tolist(),
                         "curves": {m: ft.as_dict() for m, ft in jf.fits.items()}}

    # --- identification rows (Tables 6 / 8), Table 7
    train, vt1, vt2 = d / "train" / "log.csv", d / "VT1" / "log.csv", d / "VT2" / "log.csv"
    lcfg = {**LEARNING, **(LEARNING_QUICK if quick else {})}
    plan: list[tuple[str, str, bool, str | None, dict | None]] = [
        (name, method, lmi, "arctan" if hier else None, lcfg if name == "Proposed-FBPE" else None)
        for name, method, lmi, hier in ROWS]
    plan += [(f"T7 {label}", "wls", True, fam, None) for label, fam, _ in FAMILIES if fam != "arctan"]
    vt: dict[str, dict[str, list[float]]] = {"VT1": {}, "VT2": {}}
    table7: dict[str, dict[str, list[float]]] = {"VT1": {}, "VT2": {}}
    iterations: dict[str, Any] = {}
    settings: dict[str, Any] = {"simulate": docs, "design": settings_design, "friction": fdoc, "identify": {}}
    outcomes = {}
    product_vt1: dict[str, list[float]] = {}
    held: dict[str, Any] = {}
    for name, method, lmi, fam, learn in plan:
        say(f"dynid identify: {name}")
        t0 = time.perf_counter()
        doc = identify_document(train, vt1, method, lmi, fam, prior, learn)
        settings["identify"][name] = doc
        cfg = parse_config(doc, d)
        out = identify(cfg)
        timings[f"identify {name}"] = time.perf_counter() - t0
        outcomes[name] = out
        product_vt1[name] = np.asarray(out.validation.rmse, float).tolist()
        if learn is not None:
            product_vt1["+PI-LSTM"] = np.asarray(out.learning.with_network.rmse, float).tolist()
        system = out.system
        key = "rigid" if fam is not None else "full"
        if key not in held:
            cfg2 = parse_config({**doc, "validation": {"file": str(vt2)}}, d)
            held[key] = {"VT1": out.held_out, "VT2": _processed(cfg2, system, "validation")}
        curves = _curves_of(out.result, JOINTS) if fam is not None else None
        if fam is not None:
            h = out.result.solver["hierarchical"]
            iterations[name] = {"iterations": h["iterations"], "stop": h["stop"]}
        for v in ("VT1", "VT2"):
            ds = held[key][v]
            y, p = _model_rows(system, out.base, out.result.params, ds, 20000)
            if curves is not None:
                p = p + curves.force(ds.dq)
            per = np.sqrt(np.mean((y - p) ** 2, axis=0)).tolist()
            if name.startswith("T7 "):
                table7[v][name[3:]] = per
            else:
                vt[v][name] = per
            if name == "Proposed-FBPE":
                table7[v][FAMILIES[3][0]] = per
                p = p + out.learning.networks.predict(ds.dq, ds.ddq)
                vt[v]["+PI-LSTM"] = np.sqrt(np.mean((y - p) ** 2, axis=0)).tolist()
    # nominal (CAD), the truth's static model, the truth with memory, the noise floor
    ls = outcomes["LS"]
    sys_full, base_full = ls.system, ls.base
    if list(sys_full.parameter_names) != list(truth["parameter_names"]):
        raise InputError("paper 003 study: the identified robot's parameters are not those of truth.json")
    nominal = base_full.from_standard(sys_full.nominal_parameters())
    true_base = base_full.from_standard(np.asarray(truth["true_parameters"], float))
    noise = np.broadcast_to(np.asarray(docs["train"]["sensors"]["force_noise_std"], float), (6,)) * _noise_gain(
        held["full"]["VT1"])
    for v in ("VT1", "VT2"):
        ds = held["full"][v]
        y, p_nom = _model_rows(sys_full, base_full, nominal, ds, 20000)
        _, p_rb = _model_rows(sys_full, base_full, true_base, ds, 20000)
        fss = true_static.force(ds.dq)
        z = np.column_stack([_lag_state(fss[:, j], np.asarray(ds.t), memory[j]) for j in range(6)])
        vt[v] = {"nominal (CAD)": np.sqrt(np.mean((y - p_nom) ** 2, axis=0)).tolist(), **vt[v],
                 "truth (static Eq. 15)": np.sqrt(np.mean((y - p_rb - fss) ** 2, axis=0)).tolist(),
                 "truth (with memory)": np.sqrt(np.mean((y - p_rb - z) ** 2, axis=0)).tolist(),
                 "noise floor": noise.tolist()}

    # --- Table 1: the three networks on the Proposed-FBPE residual
    say("Table 1: PI-RNN / PI-GRU / PI-LSTM on the Proposed-FBPE residual")
    from dynid.config.learning import parse_learning
    from dynid.learning import fit_residual
    from dynid.pipeline.learning import LOW_SPEED

    pf = outcomes["Proposed-FBPE"]
    curves = _curves_of(pf.result, JOINTS)
    parts = {}
    for v, ds in (("train", pf.train), ("VT2", held["rigid"]["VT2"])):
        y, p = _model_rows(pf.system, pf.base, pf.result.params, ds, 20000)
        f = curves.force(ds.dq)
        parts[v] = (ds, y - p - f, f)
    ds_v, r_v, _ = parts["VT2"]
    slow = np.abs(ds_v.dq) < LOW_SPEED
    base_cfg = parse_learning(lcfg)
    table1 = [_t1_row("Proposed-FBPE alone", r_v, slow, float("nan"), float("nan"))]
    for kind in (("lstm",) if quick else NETS):
        say(f"Table 1: PI-{kind.upper()}")
        t0 = time.perf_counter()
        ds_t, r_t, f_t = parts["train"]
        if kind == "lstm":  # the product's network ([learning] in the Proposed-FBPE run)
            nets = pf.learning.networks
        else:
            nets = fit_residual(dataclasses.replace(base_cfg, model=kind), ds_t.dq, ds_t.ddq, r_t, None, JOINTS,
                                model_friction=f_t)
        err = r_v - nets.predict(ds_v.dq, ds_v.ddq)
        secs = sum(r.seconds for r in nets.records) if kind == "lstm" else time.perf_counter() - t0
        table1.append(_t1_row(f"PI-{kind.upper()}", err, slow, float(np.mean([r.best_epoch for r in nets.records])),
                              secs))
    timings["table 1"] = sum(r["seconds"] for r in table1 if np.isfinite(r["seconds"]))

    h = pf.result.solver["hierarchical"]["friction"]
    hier_fit = {}
    for j, name in enumerate(JOINTS):
        hier_fit[name] = {}
        for n in MODELS[TRUE_FAMILY]:
            tv = float(np.asarray(gtf[n])[j] if np.ndim(gtf[n]) else gtf[n])
            c = h[name][n]
            hier_fit[name][n] = {"value": c["value"], "std": float("nan") if c["std"] is None else c["std"], "truth": tv,
                                 "rel_error": c["value"] / tv - 1}
    return Paper003Study(vt=vt, table7=table7, table4=table4, table4_fit=table4_fit, table1=table1,
                         friction_fit=friction_fit, hierarchical_fit=hier_fit, fig7=fig7, iterations=iterations,
                         timings=timings, settings=settings, quick=quick, product_vt1=product_vt1,
                         friction_identifiability=ident)


def _t1_row(name: str, err: np.ndarray, slow: np.ndarray, epochs: float, seconds: float) -> dict[str, Any]:
    return {"model": name, "rmse": float(np.sqrt(np.mean(err ** 2))),
            "rmse_per_joint": np.sqrt(np.mean(err ** 2, axis=0)).tolist(),
            "low_speed_rmse": float(np.sqrt(np.mean(err[slow] ** 2))) if slow.any() else float("nan"),
            "epochs_to_converge": epochs, "seconds": seconds}


def plot_fig7(study: Paper003Study, path: str | Path) -> None:
    """Fig. 7 in kind: the extracted friction points (±2 sigma; held-out open) and the four fitted
    curves per joint, with the truth's Eq. 15."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynid.estimation.friction_curves import curve_force

    gtf = study.settings["simulate"]["train"]["robot"]["friction"]
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    for ax, (j, f7) in zip(axes.ravel(), study.fig7.items()):
        k = JOINTS.index(j)
        v, F, s, ho = (np.asarray(f7[x]) for x in ("speed", "friction", "sigma", "held_out"))
        ax.errorbar(v[~ho], F[~ho], yerr=2 * s[~ho], fmt="o", ms=4, color="k", label="points (fit)")
        ax.errorbar(v[ho], F[ho], yerr=2 * s[ho], fmt="o", ms=4, mfc="none", color="k", label="points (held out)")
        vv = np.geomspace(max(v.min() * 0.7, 1e-4), v.max() * 1.1, 300)
        for m, p in f7["curves"].items():
            ax.plot(vv, curve_force(m, p, vv), label=m)
        tr = {n: (gtf[n][k] if isinstance(gtf[n], list) else gtf[n]) for n in ("fc", "fs", "fv", "vs", "kv", "alpha")}
        ax.plot(vv, curve_force("smooth_stribeck", tr, vv), "k:", label="truth (Eq. 15)")
        ax.set_xscale("log")
        ax.set_title(j)
        ax.set_xlabel("speed [rad/s]")
        ax.set_ylabel("friction [N*m]")
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle("Paper 003 Fig. 7 in kind: constant-velocity friction points and the fitted models (cobot6r twin)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
