"""Issue 19, item 6, target 1 over other verification draws: how much of Proposed-FBPE / WLS-FBPE on
VT2 is the one trajectory.

Target 1 (Proposed-FBPE held-out Sum at most 0.8 x WLS-FBPE on VT2) is judged by
``bench/paper003_study.py`` on one VT2 draw (``examples/twins/cobot6r_paper003_vt2.toml``, seed 22).
This script keeps the study's training log, friction experiment and both identified models and
scores them on VT2 *and on other draws of the same kind of motion*: the VT2 document with only
``trajectory.seed`` and ``sensors.seed`` changed (same plant, base frequency, harmonics, fill,
speed and acceleration limits, controller, sensors). Each row: the Sum of per-joint held-out RMSE
of WLS-FBPE and of Proposed-FBPE, processed and scored as the study does
(:func:`dynid.studies.paper003._processed`, every processed sample), and their ratio.

It needs the logs of a study run: ``bench/paper003_study.py --keep DIR`` first (about 6 minutes), then
``.venv/bin/python bench/paper003_vt2_draws.py DIR [--seeds 22,101,...]`` (about 10 s per draw).
Prints the table and the median and range of the ratios; the seeds are listed, the study's own first.
Nothing here changes the study's verdict: it says how far one draw decides it (bench/README,
"Paper 003", target 1).
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
from pathlib import Path

import numpy as np

from dynid.config import parse_config
from dynid.pipeline.identification import _model_rows, identify
from dynid.studies import paper003 as P

SEEDS = (22, 101, 102, 103, 104, 105, 106, 107, 108)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("keep", help="the --keep folder of a bench/paper003_study.py run")
    ap.add_argument("--seeds", default=",".join(map(str, SEEDS)), help="VT2 draws (trajectory and sensor seed)")
    args = ap.parse_args(argv)
    d = Path(args.keep)
    prior = d / "friction_fit" / "friction.json"
    for need in (d / "train" / "log.csv", d / "VT1" / "log.csv", prior):
        if not need.is_file():
            print(f"paper003_vt2_draws: error: {need} not found (run bench/paper003_study.py --keep {d} first)")
            return 2
    models = {}
    for name, fam in (("WLS-FBPE", None), ("Proposed-FBPE", "arctan")):
        doc = P.identify_document(d / "train" / "log.csv", d / "VT1" / "log.csv", "wls", True, fam, prior, None)
        models[name] = (doc, identify(parse_config(doc, d)))

    def score(name: str, log: Path) -> float:
        doc, o = models[name]
        ds = P._processed(parse_config({**doc, "validation": {"file": str(log)}}, d), o.system, "validation")
        y, p = _model_rows(o.system, o.base, o.result.params, ds, 20000)
        if name != "WLS-FBPE":
            p = p + P._curves_of(o.result, P.JOINTS).force(ds.dq)
        return float(np.sqrt(np.mean((y - p) ** 2, axis=0)).sum())

    base = P._doc("VT2")
    ratios = []
    print(f"{'seed':>6} {'WLS-FBPE':>9} {'Proposed-FBPE':>14} {'ratio':>7}  (held-out Sum of joint RMSE, N*m)")
    for s in (int(x) for x in args.seeds.split(",")):
        doc = copy.deepcopy(base)
        doc["trajectory"]["seed"] = s
        doc["sensors"]["seed"] = s
        folder = d / "vt2_draws" / str(s)
        folder.mkdir(parents=True, exist_ok=True)
        P._simulate(doc, folder)
        a, b = score("WLS-FBPE", folder / "log.csv"), score("Proposed-FBPE", folder / "log.csv")
        ratios.append(b / a)
        print(f"{s:>6} {a:9.3f} {b:14.3f} {b / a:7.3f}" + ("  <- the study's VT2" if s == 22 else ""), flush=True)
    print(f"ratio over {len(ratios)} draws: median {statistics.median(ratios):.3f}, range "
          f"{min(ratios):.3f}-{max(ratios):.3f}, at most 0.8 in {sum(r <= 0.8 for r in ratios)} of {len(ratios)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
