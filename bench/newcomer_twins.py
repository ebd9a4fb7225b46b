"""Independent-engine twins (issue 34, item 6): a newcomer's two commands on MuJoCo's logs.

For each of dynid's own MuJoCo twins (examples/mujoco_twins: a 6-UPS Stewart platform with a
ball joint, a redundantly actuated planar 3-RR robot; :mod:`dynid.studies.twin_robots`):

1. MuJoCo simulates the robot (the file's parameters: the truth) under PD + the prior's gravity
   (:mod:`dynid.studies.mujoco_twin`), one training and one validation log (another excitation:
   other base frequency and seed), 1 kHz, seeded noise;
2. ``dynid init PRIOR TRAIN --validation VALID --out CFG`` with the prior (the same file with
   every moving body's mass, second moments and COM 15 % off: the CAD model a user has), then
   ``dynid identify CFG --out OUT``, nothing edited. When this dynid's ``init`` lacks
   ``--validation``, init runs without it and the harness puts the validation log into the
   config as the flag does (:func:`~dynid.studies.mujoco_twin.validation_into_config`); the
   table says which;
3. the true-parameter error: the same two commands with the true file as the robot; its
   ``nominal_validation`` is the file's (the truth's) held-out error through dynid's model, on the
   same processed rows (its identified figures equal the prior run's: WLS does not use the
   nominal model, which the script checks).

Table per robot and channel (held-out relative RMSE, %): identified, true parameters, prior,
identified / true (item 6: <= 1.25) and prior / identified (item 6: >= 2). The redundant robot's
channels are its projected equations (``dynid identify``'s default force model); the
per-actuator minimum-norm view follows as a second table.

Run: ``.venv/bin/python bench/newcomer_twins.py`` (30 s logs; about 5 minutes on 2 cores);
``--quick``: 10 s logs (the tests' size). ``--out DIR`` keeps the logs, configs and results.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "src"))

from dynid.studies.mujoco_twin import simulate, validation_into_config, write_log  # noqa: E402

TWINS = REPO / "examples" / "mujoco_twins"
EXPERIMENTS = {"train": (0.2, 1), "valid": (0.27, 2)}
"""Base frequency [Hz] and seed of each log's excitation (the noise seed is the seed + 1)."""
RATIO_TRUE, RATIO_PRIOR = 1.25, 2.0


def dynid(*args: str, cwd: Path) -> str:
    cmd = [sys.executable, "-m", "dynid.cli", *args]
    env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "OPENBLAS_NUM_THREADS": "1"}
    p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if p.returncode:
        raise SystemExit(f"dynid {' '.join(args)} failed ({p.returncode}):\n{p.stderr}")
    return p.stdout


def init_has_validation(cwd: Path) -> bool:
    return "--validation" in dynid("init", "--help", cwd=cwd)


def init(robot: Path, train: Path, valid: Path, cfg: Path, cwd: Path) -> str:
    """``dynid init ROBOT TRAIN --validation VALID --out CFG`` (or its equivalent, see the docstring)."""
    if init_has_validation(cwd):
        dynid("init", str(robot), train.name, "--validation", valid.name, "--out", cfg.name, cwd=cwd)
        return "dynid init --validation"
    dynid("init", str(robot), train.name, "--out", cfg.name, cwd=cwd)
    validation_into_config(cfg, valid)
    return "dynid init, validation put into the config by the harness (no --validation flag yet)"


def run_robot(kind: str, duration: float, folder: Path, draw: int = 0) -> dict:
    from dynid.studies import draw_seed

    folder.mkdir(parents=True, exist_ok=True)
    truth, prior = TWINS / f"{kind}.xml", TWINS / f"{kind}_prior.xml"
    logs, sim_s = {}, {}
    for name, (f0, seed) in EXPERIMENTS.items():
        t0 = time.perf_counter()
        s = draw_seed(seed, draw)  # draw 0: the recorded experiment; others: other trajectories and noise
        log = simulate(truth, prior, duration, f0, s, noise_seed=draw_seed(seed + 1, draw))
        sim_s[name] = time.perf_counter() - t0
        logs[name] = write_log(log, folder / f"{kind}_{name}.csv")
    out = {}
    for role, robot in (("prior", prior), ("true", truth)):
        cfg = folder / f"{kind}_{role}.toml"
        how = init(robot, logs["train"], logs["valid"], cfg, folder)
        t0 = time.perf_counter()
        dynid("identify", cfg.name, "--out", f"out_{kind}_{role}", "-q", cwd=folder)
        out[role] = (json.loads((folder / f"out_{kind}_{role}" / "result.json").read_text()), time.perf_counter() - t0)
    res, res_true = out["prior"][0], out["true"][0]
    ident = res["validation"]["rel_rmse_pct_per_joint"]
    if max(abs(a - b) for a, b in zip(ident, res_true["validation"]["rel_rmse_pct_per_joint"])) > 1e-6 * max(ident):
        raise SystemExit(f"{kind}: the identified figures depend on the robot file's parameters (WLS should not)")
    row = {"channels": res["validation"]["joints"], "identified": ident,
           "true": res_true["nominal_validation"]["rel_rmse_pct_per_joint"],
           "prior": res["nominal_validation"]["rel_rmse_pct_per_joint"],
           "init": how, "simulate_s": sim_s, "identify_s": out["prior"][1]}
    other, other_true = res.get("validation_other_view"), res_true.get("validation_other_view")
    if other is not None:
        row["other_view"] = {"label": other["label"], "channels": other["identified"]["joints"],
                             "identified": other["identified"]["rel_rmse_pct_per_joint"],
                             "true": other_true["nominal"]["rel_rmse_pct_per_joint"],
                             "prior": other["nominal"]["rel_rmse_pct_per_joint"]}
    return row


def table(channels, ident, true, prior) -> tuple[list[str], bool]:
    lines = [f"  {'channel':<8} {'identified %':>12} {'true %':>8} {'prior %':>8} {'ident/true':>10} {'prior/ident':>11}"]
    ok = True
    for c, a, t, p in zip(channels, ident, true, prior):
        r1, r2 = a / t, p / a
        ok &= r1 <= RATIO_TRUE and r2 >= RATIO_PRIOR
        lines.append(f"  {c:<8} {a:>12.3f} {t:>8.3f} {p:>8.3f} {r1:>10.3f} {r2:>11.2f}"
                     + ("" if r1 <= RATIO_TRUE and r2 >= RATIO_PRIOR else "   <- misses item 6"))
    return lines, ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="10 s logs (the tests' size) instead of 30 s")
    ap.add_argument("--out", default=None, help="keep the logs, configs and results in this folder")
    ap.add_argument("--robots", default="stewart,planar")
    ap.add_argument("--draw", type=int, default=0, help="another draw of the trajectories and noise (0: the recorded one)")
    ap.add_argument("--duration", type=float, default=None, help="log length in s (default 30; --quick 10)")
    args = ap.parse_args(argv)
    duration = args.duration if args.duration else (10.0 if args.quick else 30.0)
    from _util import print_machine

    print_machine()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(args.out) if args.out else Path(tmp)
        every = True
        for kind in args.robots.split(","):
            row = run_robot(kind, duration, base / kind, args.draw)
            print(f"\n{kind}: draw {args.draw}, {duration:g} s logs at 1 kHz (train f0 {EXPERIMENTS['train'][0]} Hz, validation f0 "
                  f"{EXPERIMENTS['valid'][0]} Hz); {row['init']}; simulate {sum(row['simulate_s'].values()):.0f} s, "
                  f"identify {row['identify_s']:.0f} s")
            lines, ok = table(row["channels"], row["identified"], row["true"], row["prior"])
            print("held-out relative RMSE per channel" + (" (projected equations)" if "other_view" in row else ""))
            print("\n".join(lines))
            every &= ok
            if "other_view" in row:
                o = row["other_view"]
                print(f"the same, {o['label'][:60]}...")
                print("\n".join(table(o["channels"], o["identified"], o["true"], o["prior"])[0]))
            print(json.dumps({k: row[k] for k in ("channels", "identified", "true", "prior")}))
        print(f"\nitem 6 ({RATIO_TRUE}x the true-parameter error, {RATIO_PRIOR}x below the prior's, every channel): "
              + ("met" if every else "NOT met"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
