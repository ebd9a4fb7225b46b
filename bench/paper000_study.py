"""Study (issue 17, item 5): paper 000's Tables 4–6 on the 3-RPS twin ``builtin:rps3``.

Simulates a training experiment and six test trajectories (one at low speed) with
``dynid simulate``, runs ``dynid identifiability`` (WLS, model-structure search by relative
standard deviation < 15 %, feasibility of models 1–4) and prints Table 4 (condition number of
each test trajectory's regressor, ε_RA of models 1–4 and of the nominal model), Table 5
(parameters of models 1–4 with relative std, infeasible ones marked ``*``, truth alongside) and
Table 6 (per model: parameters, identified, ε_RA, ε_AV). The set-up is in the docstring of
:mod:`dynid.studies.paper000`.

Run: ``.venv/bin/python bench/paper000_study.py`` (a few minutes on 2 cores; ``--quick``: the
small version the tests run; ``--json PATH``: everything as JSON; ``--keep DIR``: keep the logs).
The figures of the last full run are in bench/README.md ("Paper 000, Tables 4–6").
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from dynid.studies.paper000 import paper000_study


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small logs (the tests' size)")
    ap.add_argument("--json", default=None, metavar="PATH", help="write the outcome as JSON")
    ap.add_argument("--keep", default=None, metavar="DIR", help="write the simulated logs here (kept)")
    ap.add_argument("--draw", type=int, default=0, help="another draw of every trajectory and noise (0: the recorded study)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    study = paper000_study(quick=args.quick, folder=args.keep, draw=args.draw,
                           progress=lambda msg: print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", flush=True))
    print()
    print(study.outcome.summary_text())
    print()
    print("trajectories (true motion): duration [s], logged samples, largest leg speed [m/s]")
    for name, info in study.trajectories.items():
        print(f"  {name:<10} {info['duration_s']:6.1f} {info['samples']:7d} {info['max_leg_speed']:8.4f}")
    if args.json:
        doc = {"outcome": study.outcome.to_dict(), "trajectories": study.trajectories, "settings": study.settings}
        with open(args.json, "w") as fh:
            json.dump(doc, fh, indent=2, default=str)
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
