"""Study (issue 19, items 5-6): paper 003's Tables 1, 4, 6, 7, 8 and Fig. 7 on its cobot6r twin.

Simulates the friction experiment, the training excitation and the verification trajectories VT1
and VT2 (``examples/twins/cobot6r_paper003_*.toml``: Eq. 15 friction with a 10 ms memory), runs
``dynid friction`` (Table 4, Fig. 7) and ``dynid identify`` for the rows LS, WLS, LS-FBPE,
WLS-FBPE, Proposed, Proposed-FBPE and +PI-LSTM (Tables 6 and 8, beside the nominal model, the
truth and the noise floor), Proposed-FBPE with friction models 1-4 (Table 7) and the network
ablation on the Proposed-FBPE residual (Table 1); then checks item 6's four targets. The set-up
is in the docstring of :mod:`dynid.studies.paper003`.

Run: ``.venv/bin/python bench/paper003_study.py`` (``--quick``: the tests' version; ``--json
PATH``: everything as JSON; ``--keep DIR``: keep logs and results; ``--fig PATH``: Fig. 7 as PNG).
The figures of the last full run are in bench/README.md ("Paper 003 (cobot6r twin)").
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from dynid.studies.paper003 import conclusions, paper003_study, plot_fig7


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a shorter VT1 and only the PI-LSTM in Table 1 (the tests' size)")
    ap.add_argument("--json", default=None, metavar="PATH", help="write the outcome as JSON")
    ap.add_argument("--keep", default=None, metavar="DIR", help="write the logs and results here (kept)")
    ap.add_argument("--fig", default=None, metavar="PATH", help="write Fig. 7 (in kind) here")
    ap.add_argument("--record", default=None, metavar="PATH",
                    help="write the conclusions and Sums as JSON (bench/data/paper003_full.json: what the quick test "
                         "must conclude alike)")
    ap.add_argument("--draw", type=int, default=0,
                    help="another draw of every trajectory and noise seed (0: the recorded study; --record needs 0)")
    args = ap.parse_args(argv)
    if args.record and args.draw:
        ap.error("--record writes the recorded study (draw 0)")
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    t0 = time.perf_counter()
    study = paper003_study(quick=args.quick, folder=args.keep, draw=args.draw,
                           progress=lambda msg: print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", flush=True))
    print()
    print(study.tables_text())
    print()
    print("hierarchical iterations:", ", ".join(f"{k} {v['iterations']} ({v['stop']})" for k, v in study.iterations.items()))
    print("timings [s]:", ", ".join(f"{k} {v:.0f}" for k, v in study.timings.items()))
    print()
    print("targets (dynid issue 19, item 6):")
    for k, v in study.targets().items():
        print(f"  {k}: {v}")
    con = conclusions(study)
    print("conclusions:")
    for k, v in con.items():
        print(f"  {k}: {v}")
    if args.record:
        rec = {"quick": study.quick, "conclusions": con, "targets": study.targets(),
               "sums": {vt: {k: study.total(v) for k, v in rows.items()} for vt, rows in study.vt.items()},
               "table7_sums": {vt: {k: study.total(v) for k, v in rows.items()} for vt, rows in study.table7.items()}}
        with open(args.record, "w") as fh:
            json.dump(rec, fh, indent=1, default=str)
    if args.fig:
        plot_fig7(study, args.fig)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(study.to_dict(), fh, indent=1, default=str)
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
