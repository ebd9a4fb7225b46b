"""Study (issue 7, item 6): the estimator comparisons of the papers, as tables.

A. Paper 001, Tables 1–2 on the shang2dof twin (``builtin:shang2dof``, 10 % perturbed truth,
   motor torques with 0.02 N·m noise correlated 0.3, 2^20-count encoders, 20 Hz zero-phase
   low-pass, projected equations, WLS). Four identifications:

   * the paper's circle (centre (0.29, 0.25), radius 0.04 m, 0.2 m/s), WLS;
   * the same log, WLS with the observation matrix weighted by the nominal values (Eq. 17):
     the column scaling changes cond(Z_ww), not the estimate or its relative standard
     deviations (the least-squares solution is invariant to column scaling);
   * a periodic excitation designed for the smallest cond(Z_w) (the criterion *without*
     weighting) and one designed for the smallest cond(Z_ww) (*with* weighting), both of 4
     harmonics of 0.5 Hz under the same actuator limits, each simulated and identified the
     same way. This is where the paper's two columns differ: the weighted criterion spreads the
     information so that small parameters get a better relative accuracy.

B. Paper 004, Table II on the hexapod twin (``builtin:hexapod`` with the nominal model as the
   truth, whose friction is the paper's Gauss–Markov column): a D-optimal periodic excitation
   in task space, strut encoders of 1 µm with 5 µm of position noise, drive forces with 2 N of
   noise correlated 0.2; period averaging, the platform pose filtered in the frequency domain.
   Gauss–Markov with the period covariance at the excited band against maximum likelihood with
   the cut-off estimated (Eq. 24). Both identify the papers' model (``identification.structure =
   "paper"``: six identical struts, symmetric bodies): the 10 rigid-body parameters p1..p10 of
   paper 002's Table 1 and the 14 friction terms, all 24 rows of Table II.

C. Coverage of the 95 % intervals over Monte Carlo trials (``dynid montecarlo``): 100 trials of
   a serial 6R arm with exact positions and 2 N·m of torque noise for OLS, WLS, GM.

Run: ``.venv/bin/python bench/estimator_study.py`` (``--quick``: a small version, used by the
tests). The figures of the last full run are in ``bench/README.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from dynid._files import save_npz
from dynid.config import parse_config
from dynid.config.montecarlo import parse_montecarlo_config
from dynid.config.simulate import parse_simulate_config
from dynid.excitation import DesignLimits, ExcitationProblem
from dynid.model.robots import build_mechanism, hexapod
from dynid.pipeline import identify
from dynid.pipeline.montecarlo import run_montecarlo
from dynid.pipeline.simulate import run_simulation, write_simulation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _designs import design_file, hexapod_design  # noqa: E402


# ---------------------------------------------------------------------- A: paper 001
SHANG_SIM = {
    "robot": {"model": "builtin:shang2dof", "perturbation": 0.1, "perturbation_seed": 1},
    "control": {"rate_hz": 500, "kp": 35000, "kd": 300},
    "sensors": {"encoder_resolution": 5.992e-6, "force_noise_std": 0.02, "force_correlation": 0.3, "seed": 1},
}


def _shang_identify(folder: Path, nominal_weighting: bool = False):
    acts = ["qa1", "qa2", "qa3"]
    ident = {"method": "wls", "structure": "full"}  # paper 001 identifies each chain (the simulated robot's differ)
    if nominal_weighting:
        ident["nominal_weighting"] = True
    doc = {
        "robot": {"model": "builtin:shang2dof"},
        "data": {"file": str(folder / "log.csv"), "time": {"column": "t", "unit": "s"},
                 "position": {"columns": [f"q_{a}" for a in acts], "unit": "rad"},
                 "effort": {"columns": [f"tau_{a}" for a in acts], "kind": "torque", "unit": "N*m"},
                 "rows": [0, None]},
        "processing": {"lowpass": {"cutoff_hz": 20.0, "order": 4, "filter_effort": False}},
        "identification": ident,
        "output": {"plots": False},
    }
    n = len((folder / "log.csv").read_text().splitlines()) - 1
    split = int(0.8 * n)
    doc["data"]["rows"] = [0, split]
    doc["validation"] = {"rows": [split, n]}
    return identify(parse_config(doc, folder))


def shang_tables(quick: bool = False) -> dict:
    mech = build_mechanism("shang2dof")
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        turns, periods, iters = (3, 3, 10) if quick else (15, 15, 60)
        circle = {"kind": "circle", "centre": [0.29, 0.25], "radius": 0.04, "speed": 0.2, "turns": turns,
                  "clockwise": True, "ramp": 0.2}
        sim = run_simulation(parse_simulate_config({**SHANG_SIM, "trajectory": circle}, d / "circle"))
        write_simulation(sim, d / "circle")
        truth = np.asarray(sim.truth["true_parameters"])
        runs = {"circle": _shang_identify(d / "circle"), "circle, nominal weighting": _shang_identify(d / "circle", True)}
        lim = DesignLimits(velocity=np.full(3, 6.0), acceleration=np.full(3, 60.0))
        for label, criterion in (("design cond(Z_w)", "cond"), ("design cond(Z_ww)", "weighted_cond")):
            pb = ExcitationProblem(mech, harmonics=4, base_frequency_hz=0.5, samples=48, criterion=criterion, limits=lim)
            design = pb.optimize(starts=1, seed=0, max_iter=iters)
            folder = d / criterion
            traj = {"kind": "fourier", "design": str(design_file(folder, design)), "periods": periods}
            write_simulation(run_simulation(parse_simulate_config({**SHANG_SIM, "trajectory": traj}, folder)), folder)
            runs[label] = _shang_identify(folder)
            out.setdefault("design_criteria", {})[label] = {k: float(v) for k, v in design.criteria.items()}
            out.setdefault("design_search", {})[label] = {"criterion": criterion, "initial": float(design.initial_value),
                                                          "reached": float(design.value), "feasible": bool(design.success)}
        base = runs["circle"].base
        true_base = base.from_standard(truth)
        nominal_base = base.from_standard(mech.nominal_parameters())
        out["names"] = list(base.names)
        out["expressions"] = list(base.expressions())
        out["truth"] = true_base.tolist()
        out["nominal"] = nominal_base.tolist()
        out["runs"] = {}
        for label, o in runs.items():
            r = o.result
            out["runs"][label] = {
                "params": r.params.tolist(), "rel_std_pct": r.rel_std.tolist(), "bse": r.bse.tolist(),
                "cond_Zw": float(r.solver.get("cond_Zw", r.condition_number)),
                "cond_Zww": float(r.solver["cond_Zww"]) if "cond_Zww" in r.solver else None,
                "validation_rel_rmse_pct": [float(x) for x in o.validation.rel_rmse_pct],
            }
    return out


def shang_table(res: dict) -> str:
    labels = list(res["runs"])
    lines = ["A. shang2dof (paper 001, Tables 1-2): WLS estimates and relative standard deviations [%]",
             f"{'parameter':<10}{'truth':>10}" + "".join(f"{lab:>28}" for lab in labels)]
    for i, name in enumerate(res["names"]):
        cells = "".join(f"{res['runs'][lab]['params'][i]:>18.4g}{res['runs'][lab]['rel_std_pct'][i]:>9.2f}%" for lab in labels)
        lines.append(f"{name:<10}{res['truth'][i]:>10.4g}{cells}")
    lines.append("")
    for lab in labels:
        r = res["runs"][lab]
        rel = np.asarray(r["rel_std_pct"])
        err = np.abs(np.asarray(r["params"]) - np.asarray(res["truth"])) / np.maximum(np.abs(res["truth"]), 1e-12) * 100
        cz = f", cond(Z_ww) {r['cond_Zww']:.1f}" if r["cond_Zww"] is not None else ""
        lines.append(f"{lab:<28} median rel std {np.median(rel):6.2f} %, max {rel.max():7.2f} %, "
                     f"median |error| {np.median(err):6.2f} %; cond(Z_w) {r['cond_Zw']:.3g}{cz}; "
                     f"held-out rel RMSE {', '.join(f'{x:.1f}' for x in r['validation_rel_rmse_pct'])} %")
    for lab, c in res.get("design_criteria", {}).items():
        lines.append(f"{lab:<28} design criteria: cond {c['cond']:.3g}, weighted cond {c['weighted_cond']:.3g}")
    return "\n".join(lines)


# ---------------------------------------------------------------------- B: paper 004
PAPER_TABLE2 = {  # name: (GM, ML) of paper 004 Table II; p1..p10 are the base parameters hexapod.TABLE1_NAMES
    "p1": (-0.0447, -0.0444), "p2": (1.0892, 1.0915), "p3": (1.0077, 1.0106), "p4": (0.5995, 0.6029),
    "p5": (-1.2885, -1.2898), "p6": (0.3078, 0.3084), "p7": (0.3021, 0.3018), "p8": (0.1176, 0.1173),
    "p9": (1.8896, 1.8874), "p10": (16.3081, 16.2966),
    "fc_alpha": (0.5756, 0.5593), "fc_beta": (0.9195, 0.9339),
    "fc_P1": (11.9772, 12.1195), "fc_P2": (4.8071, 5.1917), "fc_P3": (20.1528, 20.1773),
    "fc_P4": (5.1518, 5.4981), "fc_P5": (1.5857, 1.7191), "fc_P6": (5.0057, 4.9622),
    "fv_P1": (16.8771, 16.7115), "fv_P2": (16.7406, 16.1764), "fv_P3": (6.3408, 6.2864),
    "fv_P4": (23.1662, 22.6607), "fv_P5": (26.4675, 26.3370), "fv_P6": (22.8053, 22.8194),
}
PAPER_FC = (1.6182, 1.6195)
TABLE2_PARAMS = {**{f"p{k + 1}": n for k, n in enumerate(hexapod.TABLE1_NAMES)}, **{n: n for n in list(PAPER_TABLE2)[10:]}}
"""Row of paper 004 Table II -> dynid's base parameter under identification.structure = "paper"."""


def hexapod_table2(quick: bool = False) -> dict:
    f0, harmonics = (1.0, 3) if quick else (0.2, 5)
    periods = 4 if quick else 8
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        traj = {"kind": "fourier", "coordinates": "task", "design": str(hexapod_design(d, quick, f0, harmonics)),
                "periods": periods + 1}
        sim = run_simulation(parse_simulate_config({
            "robot": {"model": "builtin:hexapod"},
            "trajectory": traj,
            "control": {"rate_hz": 500, "kp": 2500, "kd": 100, "model": "true", "substeps": 2},
            "sensors": {"encoder_resolution": 1e-6, "position_noise_std": 5e-6, "force_noise_std": 2.0,
                        "force_correlation": 0.2, "seed": 1},
        }, d))
        # the first period (start-up) is dropped; the rest is whole periods
        n_per = int(round(500 / f0))
        cols = {k: v[n_per:] for k, v in sim.columns.items()}
        cols["t"] = cols["t"] - cols["t"][0]
        save_npz(d / "log.npz", cols)
        q = [f"q_P{j}" for j in range(1, 7)]
        base_doc = {
            "robot": {"model": "builtin:hexapod"},
            "data": {"file": str(d / "log.npz"), "time": {"column": "t", "unit": "s"},
                     "position": {"columns": q, "unit": "m"},
                     "effort": {"columns": [c.replace("q_", "tau_") for c in q], "kind": "torque", "unit": "N"},
                     "rows": [0, (periods - 1) * n_per]},
            "validation": {"rows": [(periods - 1) * n_per, periods * n_per]},
            "processing": {"periodic": {"period_s": 1.0 / f0, "cutoff_hz": (harmonics + 0.5) * f0, "domain": "pose"}},
            "output": {"plots": False},
        }
        # the papers' model: six identical struts, symmetric bodies (p1..p10 of Table 1) + 14 friction terms
        gm = identify(parse_config({**base_doc, "identification": {"method": "gm", "noise_covariance": "periodic",
                                                                   "structure": "paper"}}, d))
        ml = identify(parse_config({**base_doc, "identification": {
            "method": "ml", "cutoff_range_hz": [(harmonics - 0.5) * f0, (40.0 if quick else 60.0) * f0],
            "structure": "paper"}}, d))
        # the truth (the nominal model) satisfies both assumptions: T T^+ pi = pi
        truth = gm.base.from_standard(gm.system.reduce_parameters(np.asarray(sim.truth["true_parameters"])))
    names = list(gm.result.names)
    rows = []
    for name, (p_gm, p_ml) in PAPER_TABLE2.items():
        i = names.index(TABLE2_PARAMS[name])
        rows.append({"name": name, "param": names[i], "paper_gm": p_gm, "paper_ml": p_ml, "truth": float(truth[i]),
                     "gm": float(gm.result.params[i]), "gm_std": float(gm.result.bse[i]),
                     "ml": float(ml.result.params[i]), "ml_std": float(ml.result.bse[i])})

    def summary(o):
        z = (o.result.params - truth) / o.result.bse
        return {"max_abs_z": float(np.abs(z).max()), "median_abs_z": float(np.median(np.abs(z))),
                "validation_rel_rmse_pct": [float(x) for x in o.validation.rel_rmse_pct]}

    within = {m: int(sum(abs(r[m] - r["truth"]) <= 3 * r[f"{m}_std"] for r in rows)) for m in ("gm", "ml")}
    grid = [r["cutoff_hz"] for r in ml.result.solver["profile"]]
    return {"rows": rows, "within_3_std": within, "n_base": len(names), "f0_hz": f0, "harmonics": harmonics, "periods": periods,
            "gm_cutoff_hz": (harmonics + 0.5) * f0, "ml_cutoff_hz": ml.result.solver["cutoff_hz"],
            "ml_cutoff_interval_hz": ml.result.solver["cutoff_interval_hz"],
            "ml_profile": ml.result.solver["profile"],
            "ml_cutoff_interior": bool(grid[0] < ml.result.solver["cutoff_hz"] < grid[-1]), "gm": summary(gm), "ml": summary(ml),
            "max_abs_param_difference_in_std": float(np.max(np.abs(ml.result.params - gm.result.params) / gm.result.bse))}


def hexapod_table(res: dict) -> str:
    lines = ["B. hexapod (paper 004, Table II): the papers' 24 parameters (structure 'paper'), Gauss-Markov vs "
             "maximum likelihood",
             f"{'param':<10}{'paper GM':>10}{'paper ML':>10}{'truth':>10}{'dynid GM':>12}{'+-':>8}{'dynid ML':>12}{'+-':>8}"]
    for r in res["rows"]:
        lines.append(f"{r['name']:<10}{r['paper_gm']:>10.4f}{r['paper_ml']:>10.4f}{r['truth']:>10.4f}"
                     f"{r['gm']:>12.4f}{r['gm_std']:>8.3f}{r['ml']:>12.4f}{r['ml_std']:>8.3f}")
    lo, hi = res["ml_cutoff_interval_hz"]
    lines += [f"{'f_c [Hz]':<10}{PAPER_FC[0]:>10.4f}{PAPER_FC[1]:>10.4f}{'':>10}{res['gm_cutoff_hz']:>12.4f}{'(set)':>8}"
              f"{res['ml_cutoff_hz']:>12.4f}  (any in [{lo:.3f}, {hi:.3f}) Hz; "
              f"{'interior to' if res['ml_cutoff_interior'] else 'at an end of'} the searched range)",
              f"excitation: {res['harmonics']} harmonics of {res['f0_hz']} Hz, {res['periods']} periods averaged",
              f"truth within 3 std: GM {res['within_3_std']['gm']}/{len(res['rows'])}, "
              f"ML {res['within_3_std']['ml']}/{len(res['rows'])}",
              f"all {res['n_base']} base parameters, |estimate - truth| / std: "
              f"GM max {res['gm']['max_abs_z']:.2f} (median {res['gm']['median_abs_z']:.2f}), "
              f"ML max {res['ml']['max_abs_z']:.2f} (median {res['ml']['median_abs_z']:.2f}); "
              f"largest |ML - GM| = {res['max_abs_param_difference_in_std']:.2f} GM std",
              "cost profile of ML (f_c: position part + force part = total):"]
    for r in res["ml_profile"]:
        if r["cost"] is None:
            lines.append(f"  {r['cutoff_hz']:7.3f} Hz: not identifiable")
        else:
            lines.append(f"  {r['cutoff_hz']:7.3f} Hz: {r['position_cost']:12.1f} + {r['force_cost']:10.1f} = {r['cost']:12.1f}")
    return "\n".join(lines)


# ---------------------------------------------------------------------- C: Monte Carlo coverage
MC_DOC = {
    "simulate": {
        "robot": {"model": "builtin:cobot6r", "perturbation": 0.1},
        "trajectory": {"kind": "fourier", "base_frequency_hz": 0.5, "harmonics": 4, "fill": 0.6, "periods": 2, "seed": 1,
                       "max_velocity": 1.5, "max_acceleration": 6.0},
        "control": {"rate_hz": 500, "kp": 400, "kd": 40, "substeps": 2},
        "sensors": {"force_noise_std": 2.0, "seed": 0},
    },
    "identify": {"processing": {"min_velocity": 0.05}},
    "montecarlo": {"trials": 100, "workers": 2},
}


def coverage(quick: bool = False, draw: int = 0) -> dict:
    """Part C; ``draw`` > 0: the trials' trajectory and noise from other seeds (:func:`dynid.studies.draw_seed`)."""
    from dynid.studies import draw_seed

    out = {}
    for method in ("ols", "wls", "gm"):
        doc = json.loads(json.dumps(MC_DOC))
        sim = doc["simulate"]
        sim["trajectory"]["seed"] = draw_seed(sim["trajectory"]["seed"], draw)
        sim["sensors"]["seed"] = draw_seed(sim["sensors"]["seed"], draw)
        doc["identify"]["identification"] = {"method": method}
        doc["montecarlo"]["trials"] = 10 if quick else 100
        r = run_montecarlo(parse_montecarlo_config(doc, Path(".")))
        out[method] = {"trials": int(r.trial.size), "coverage_pct": r.overall_coverage, "ellipsoid_pct": r.ellipsoid_share,
                       "mean_chi2": r.mean_chi2, "p": r.n_params, "min_param_coverage_pct": float(np.nanmin(r.coverage))}
    return out


def coverage_table(res: dict) -> str:
    lines = ["C. Coverage of the 95 % intervals over Monte Carlo trials (builtin:cobot6r, exact positions, 2 N*m noise)",
             f"{'method':<8}{'trials':>8}{'coverage %':>12}{'worst param %':>15}{'in ellipsoid %':>16}{'mean chi2':>11}{'p':>5}"]
    for m, r in res.items():
        lines.append(f"{m:<8}{r['trials']:>8}{r['coverage_pct']:>12.1f}{r['min_param_coverage_pct']:>15.0f}"
                     f"{r['ellipsoid_pct']:>16.1f}{r['mean_chi2']:>11.1f}{r['p']:>5}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--part", choices=["A", "B", "C"], action="append")
    ap.add_argument("--draw", type=int, default=0, help="part C on another draw of its trajectory and noise (0: the recorded one)")
    args = ap.parse_args(argv)
    parts = args.part or ["A", "B", "C"]
    if "A" in parts:
        print(shang_table(shang_tables(args.quick)), "\n", flush=True)
    if "B" in parts:
        print(hexapod_table(hexapod_table2(args.quick)), "\n", flush=True)
    if "C" in parts:
        print(coverage_table(coverage(args.quick, args.draw)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
