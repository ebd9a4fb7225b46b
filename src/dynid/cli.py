"""The ``dynid`` command line: the only place that prints. Exit codes: 0 ok, 2 bad input."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path

from dynid import __version__
from dynid.errors import ConfigError, DynidError, InputError

EXIT_OK = 0
EXIT_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse with dynid's error format: one line ``dynid: error: ...``, status 2 (no usage
    block; ``--help`` still prints it)."""

    def error(self, message: str):  # type: ignore[override]
        command = self.prog.split(" ", 1)[1] if " " in self.prog else ""
        hint = f" (see dynid {command + ' ' if command else ''}--help)"
        self.exit(EXIT_INPUT, f"dynid: error: {' '.join(message.split())}{hint}\n")


@contextmanager
def _progress_bar(enabled: bool):
    """A rich progress bar on stderr, fed through ``progress(task, done, total)``.

    Only drawn on a terminal: redirected stderr gets nothing but error lines.
    """
    if not enabled or not sys.stderr.isatty():
        yield lambda task, done, total: None
        return
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn
    from rich.console import Console

    bar = Progress(TextColumn("{task.description:>16}"), BarColumn(), TaskProgressColumn(), TimeRemainingColumn(),
                   console=Console(stderr=True), transient=True)
    tasks: dict[str, int] = {}

    def progress(task: str, done: int, total: int) -> None:
        if task not in tasks:
            tasks[task] = bar.add_task(task, total=total)
        bar.update(tasks[task], completed=done, total=total)

    with bar:
        yield progress


def _cmd_info(args: argparse.Namespace) -> int:
    from dynid.model import load_model, robot_base_parameters
    from dynid.model.mechanism import Mechanism

    extras = tuple(e for e in args.extras.split(",") if e) if args.extras is not None else ("Ia", "fv", "fc", "offset")
    def joints(value: str | None, flag: str) -> list[str] | None:
        if value is None:
            return None
        names = [n.strip() for n in value.split(",") if n.strip()]
        if not names:
            raise ConfigError(f"{flag}: no joint names (a comma-separated list, e.g. {flag} j1,j2)")
        return names

    robot = load_model(args.robot, extras=extras, closures=args.closures,
                       actuated=joints(args.actuated, "--actuated"), independent=joints(args.independent, "--independent"))
    if isinstance(robot, Mechanism):
        return _info_mechanism(robot, args.json)
    base = robot_base_parameters(robot)
    info = {
        "robot": robot.name,
        "source": robot.source,
        "kind": "serial",
        "dof": robot.dof,
        "n_actuators": robot.n_actuators,
        "extras": list(robot.extras),
        "n_standard_params": robot.n_standard_params,
        "n_base_params": base.n_base,
        "base_param_names": list(base.names),
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return EXIT_OK
    print(f"robot            : {robot.name} ({robot.source})")
    print(f"joints           : {robot.dof} ({', '.join(robot.joint_names)})")
    print(f"actuators        : {robot.n_actuators}")
    print(f"extras           : {', '.join(robot.extras) or 'none'}")
    print(f"standard params  : {robot.n_standard_params}")
    print(f"base params      : {base.n_base}")
    for name, expr in zip(base.names, base.expressions()):
        print(f"  {name:<8} = {expr}")
    return EXIT_OK


def _identical_chains(mech) -> tuple[tuple, str]:
    """The mechanism's identical chains: declared by the description (a built-in's symmetry) or
    found in it (:func:`dynid.model.reduction.detect_identical_chains`), and which."""
    from dynid.model.reduction import CHAIN_TOL, detect_identical_chains

    if mech.identical_chains:
        return tuple(mech.identical_chains), "declared by the description"
    return detect_identical_chains(mech), f"found in the description (joints and bodies equal to {CHAIN_TOL:g})"


def _structures(mech, chains: tuple) -> dict:
    """Base-parameter counts of the reduced structures of a mechanism's identical chains (and the
    papers' symmetric bodies where the description declares them; :mod:`dynid.model.reduction`)."""
    from dynid.model.closed_loop import mechanism_base_parameters
    from dynid.model.reduction import reduce_mechanism

    out = {}
    for st in ("identical_chains", "paper") if chains else ():
        if st == "paper" and not mech.symmetric_zero:
            continue
        red = reduce_mechanism(mech, st, chains)
        base = mechanism_base_parameters(mech, reduction=red)
        out[st] = {"n_params": red.n_params, "n_base_params": base.n_base,
                   "n_base_rigid_body": int(sum(1 for i in base.independent if i < red.n_body_params)),
                   "base_param_names": list(base.names)}
    return out


def _info_mechanism(mech, as_json: bool) -> int:
    from dynid.model.closed_loop import mechanism_base_parameters

    base = mechanism_base_parameters(mech)
    n_rb = int(sum(1 for i in base.independent if i < mech.n_body_params))
    ind = mech.independent
    coords = (
        [mech.pin_model.names[j + 1] for j in ind.joints]
        if hasattr(ind, "joints")
        else [f"{'xyz'[a]}@{mech.pin_model.names[ind.joint]}" for a in ind.axes]
    )
    chains, chains_source = _identical_chains(mech)
    info = {
        "robot": mech.name,
        "source": mech.source,
        "kind": "closed-loop",
        "dof": mech.dof,
        "n_actuators": mech.n_actuators,
        "redundant_actuation": mech.redundant,
        "n_joints": mech.nv,
        "n_bodies": len(mech.bodies),
        "closures": [{"name": c.name, "type": c.kind} for c in mech.closures],
        "actuated": mech.actuated_names,
        "independent_coordinates": coords,
        "independent_choice": mech.independent_choice or "given (or the actuated joints)",
        "force_model": "projected (default for redundant actuation)" if mech.redundant else "actuator forces",
        "n_standard_params": mech.n_standard_params,
        "n_base_params": base.n_base,
        "n_base_rigid_body": n_rb,
        "n_base_joint_terms": base.n_base - n_rb,
        "base_param_names": list(base.names),
        "identical_chains": [[list(c) for c in g] for g in chains],
        "identical_chains_source": chains_source if chains else "none declared by the description, none found in it",
        "structures": _structures(mech, chains),
        "notes": list(mech.notes),
    }
    if as_json:
        print(json.dumps(info, indent=2))
        return EXIT_OK
    print(f"mechanism        : {mech.name} ({mech.source})")
    print(f"degrees of freedom: {mech.dof}")
    print(f"actuators        : {mech.n_actuators} ({', '.join(mech.actuated_names)})"
          + ("  [redundant actuation]" if mech.redundant else ""))
    print(f"joints, bodies   : {mech.nv} joints (active and passive), {len(mech.bodies)} bodies with mass")
    print(f"loop closures    : {len(mech.closures)} ({', '.join(f'{c.name}:{c.kind}' for c in mech.closures)})")
    print(f"independent u    : {', '.join(coords)}" + (f" ({mech.independent_choice}; --independent overrides)"
                                                           if mech.independent_choice else ""))
    if chains:
        for g in chains:
            print(f"identical chains : {' = '.join('(' + ', '.join(c) + ')' for c in g)}  [{chains_source}]")
    else:
        print("identical chains : none (none declared by the description, none found in it)")
    print(f"standard params  : {mech.n_standard_params}")
    print(f"base params      : {base.n_base} ({n_rb} rigid-body + {base.n_base - n_rb} joint terms)")
    for name, expr in zip(base.names, base.expressions()):
        print(f"  {name:<12} = {expr}")
    for st, d in info["structures"].items():
        print(f"structure {st:<16}: {d['n_params']} parameters, {d['n_base_params']} base "
              f"({d['n_base_rigid_body']} rigid-body + {d['n_base_params'] - d['n_base_rigid_body']} joint terms)")
    for note in mech.notes:
        print(f"note: {note}")
    return EXIT_OK


def _check_out(out: str) -> None:
    """Refuse an --out that cannot be a folder before any long computation."""
    if not out.strip():
        raise InputError("--out: empty folder name")
    path = Path(out)
    for p in (path, *path.parents):
        if p.exists():
            if not p.is_dir():
                raise InputError(f"--out {out}: {p} exists and is not a folder")
            break


def _cmd_identify(args: argparse.Namespace) -> int:
    from dynid.config import load_config

    _check_out(args.out)
    started = None
    if len(args.config) == 1:
        if args.validation is not None:
            raise InputError("--validation: only with `dynid identify ROBOT LOG` (a config names its validation in "
                             "[validation])")
        cfg = load_config(args.config[0])  # config errors come before the heavy imports below
    elif len(args.config) == 2:
        # no config: what `dynid init ROBOT LOG` would write, saved beside the results (issue 34, item 9)
        import tomllib

        from dynid.config import parse_config
        from dynid.pipeline.starter import starting_config

        target = Path(args.out) / "identify.toml"
        started = starting_config(args.config[0], args.config[1], target, validation=args.validation)
        if started.unmatched:
            raise InputError(f"{args.config[1]}: no column for {', '.join(started.unmatched)}; run `dynid init "
                             f"{args.config[0]} {args.config[1]} --out identify.toml`, name them there, then identify it")
        cfg = parse_config(tomllib.loads(started.text), target.resolve().parent)
    else:
        raise InputError(f"identify takes CONFIG.toml or ROBOT LOG, got {len(args.config)} arguments")
    from dynid.pipeline import identify, write_outputs

    with _progress_bar(not args.quiet) as progress:
        outcome = identify(cfg, progress, plot_worker=True)
    written = write_outputs(outcome, args.out)
    if started is not None:
        (Path(args.out) / "identify.toml").write_text(started.text)
        written = [*written, "identify.toml"]
    if not args.quiet:
        print(outcome.summary_text())
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(sorted(written))}")
    return EXIT_OK


def _threshold(value: str) -> float:
    try:
        t = float(value)
    except ValueError:
        t = float("nan")
    if not (t > 0 and t < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive number of percent, got {value!r}")
    return t


def _cmd_identifiability(args: argparse.Namespace) -> int:
    from dynid.config import load_config

    _check_out(args.out)
    cfg = load_config(args.config)  # config errors come before the heavy imports below
    from dynid.pipeline.identifiability import load_truth, run_identifiability, write_identifiability

    truth = load_truth(args.truth) if args.truth is not None else None
    with _progress_bar(not args.quiet) as progress:
        outcome = run_identifiability(cfg, truth=truth, threshold_pct=args.threshold, progress=progress)
    written = write_identifiability(outcome, args.out)
    if not args.quiet:
        print(outcome.summary_text())
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    return EXIT_OK


def _cmd_simulate(args: argparse.Namespace) -> int:
    from dynid.config.simulate import load_simulate_config

    _check_out(args.out)
    cfg = load_simulate_config(args.config)  # config errors come before the heavy imports below
    from dynid.pipeline.simulate import run_simulation, write_simulation

    outcome = run_simulation(cfg)
    written = write_simulation(outcome, args.out)
    if not args.quiet:
        print(outcome.summary_text())
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    for w in outcome.metadata["warnings"]:  # also in metadata.json; printed even with -q
        print(f"dynid: warning: {w['message']}", file=sys.stderr)
    return EXIT_OK


def _cmd_design(args: argparse.Namespace) -> int:
    from dynid.config.design import load_design_config

    _check_out(args.out)
    cfg = load_design_config(args.config)
    from dynid.pipeline.design import DesignOutcome, run_design, simulate_snippet, write_design

    with _progress_bar(not args.quiet) as progress:
        outcome = run_design(cfg, progress)
    if isinstance(outcome, DesignOutcome) and not outcome.design.success:
        # an excitation that violates a limit is not an output: nothing is written
        print(f"dynid: error: no design within the limits: the best one found violates {outcome.design.violation} "
              f"(criterion {outcome.design.criterion}; widen the limits or lower harmonics)", file=sys.stderr)
        return EXIT_INPUT
    written = write_design(outcome, args.out)
    if not args.quiet:
        print(outcome.summary_text())
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    if args.quiet and not isinstance(outcome, DesignOutcome):  # the summary lists them otherwise
        for line in outcome.design.dropped:
            print(line)
    print()
    print(simulate_snippet(outcome, args.out))
    return EXIT_OK


def _cmd_friction(args: argparse.Namespace) -> int:
    from dynid.config.friction import load_friction_config

    _check_out(args.out)
    cfg = load_friction_config(args.config)  # config errors come before the heavy imports below
    from dynid.pipeline.friction import run_friction, write_friction

    with _progress_bar(not args.quiet) as progress:
        outcome = run_friction(cfg, progress)
    written = write_friction(outcome, args.out)
    if not args.quiet:
        print(outcome.summary_text())
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    return EXIT_OK


def _workers(value: str) -> int | str:
    if value == "auto":
        return value
    try:
        n = int(value)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0 or 'auto', got {value!r}")
    return n


def _trials(value: str) -> int:
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value!r}")
    return n


def _seed_arg(value: str) -> int:
    try:
        n = int(value)
    except ValueError:
        n = -1
    if not 0 <= n < 2**31:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2**31), got {value!r}")
    return n


def _cmd_montecarlo(args: argparse.Namespace) -> int:
    import dataclasses

    from dynid.config.montecarlo import load_montecarlo_config, parse_scheduler, parse_workers

    _check_out(args.out)
    scheduler = parse_scheduler(args.scheduler, "--scheduler") if args.scheduler is not None else None
    cfg = load_montecarlo_config(args.config)  # config errors come before the heavy imports below
    if args.trials is not None:
        cfg = dataclasses.replace(cfg, trials=args.trials)
    if args.workers is not None:
        cfg = dataclasses.replace(cfg, workers=parse_workers(args.workers, "--workers"))
    if scheduler is not None:
        cfg = dataclasses.replace(cfg, scheduler=scheduler)
    from dynid.pipeline.montecarlo import run_montecarlo, write_montecarlo

    with _progress_bar(not args.no_progress) as progress:
        result = run_montecarlo(cfg, progress)
    written = write_montecarlo(result, args.out, source=cfg.source)
    print(result.summary_text())
    print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    return EXIT_OK


def _cmd_fleet(args: argparse.Namespace) -> int:
    import dataclasses

    from dynid.config.fleet import load_fleet_config
    from dynid.config.montecarlo import parse_scheduler, parse_workers

    _check_out(args.out)
    cfg = load_fleet_config(args.config)  # config errors come before the heavy imports below
    if args.workers is not None:
        cfg = dataclasses.replace(cfg, workers=parse_workers(args.workers, "--workers"))
    if args.scheduler is not None:
        cfg = dataclasses.replace(cfg, scheduler=parse_scheduler(args.scheduler, "--scheduler"))
    from dynid.fleet.output import summary_text, write_fleet
    from dynid.fleet.run import run_fleet

    with _progress_bar(not args.quiet) as progress:
        result = run_fleet(cfg, progress)
    written = write_fleet(result, args.out, source=cfg.source)
    if not args.quiet:
        print(summary_text(result))
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from dynid.pipeline.demo import run_demo

    _check_out(args.out)
    with _progress_bar(not args.quiet) as progress:
        demo = run_demo(args.out, progress, seed=args.seed)
    print(demo.outcome.summary_text())
    print()
    print(demo.truth_table())
    print()
    print(demo.tracking_table())
    print()
    out = Path(args.out)
    print(f"outputs in {out}/:")
    for name, what in (
        ("summary.txt", "this summary"),
        ("result.json", "DIDIM: method, parameters (value, std, rel. std %, 95 % CI), validation, iterations"),
        ("params.csv", "identified base parameters with grouping expressions"),
        ("validation.png", "held-out projected forces, measured vs predicted"),
        ("report.html", "HTML report"),
        ("tracking.png", "rectangle tracked with the nominal, identified and true models"),
        ("tracking.json", "P-RSME and errors of the three tracking runs"),
        ("config.toml", "the identification config (rerun: dynid identify config.toml --out DIR)"),
        ("wls/", "the same rows identified with WLS (the errors in the variables DIDIM avoids)"),
        ("data/", "simulated logs (train: circle, validation: rectangle), each with truth.json, metadata.json and "
                  "the config of the experiment (config.toml)"),
    ):
        if (out / name.rstrip("/")).exists():
            print(f"  {out / name}  - {what}")
    return EXIT_OK


def _cmd_init(args: argparse.Namespace) -> int:
    from dynid.pipeline.starter import write_starting_config

    def names(value: str | None, flag: str) -> list[str] | None:
        if value is None:
            return None
        out = [n.strip() for n in value.split(",") if n.strip()]
        if not out:
            raise InputError(f"{flag}: no joint names (a comma-separated list, e.g. {flag} j1,j2)")
        return out

    if args.rate is not None and not (0 < args.rate < float("inf")):
        raise InputError(f"--rate: must be a positive number of Hz, got {args.rate!r}")
    cfg = write_starting_config(args.robot, args.log, args.out, force=args.force, actuated=names(args.actuated, "--actuated"),
                                independent=names(args.independent, "--independent"), sample_rate_hz=args.rate,
                                validation=args.validation, effort_log=args.effort_log, drive=args.drive)
    print(f"wrote {args.out}: {len(cfg.joints)} actuators, sampling rate {cfg.sample_rate_hz:.6g} Hz, "
          f"low-pass {cfg.cutoff_hz:g} Hz, method wls")
    guessed = [f"{w} of {j} ({m.column})" for j, p, e in zip(cfg.joints, cfg.position, cfg.effort)
               for w, m in (("position", p), ("effort", e)) if m.how == "index"]
    if guessed:
        print(f"guessed by index (check): {', '.join(guessed)}")
    if cfg.unmatched:
        print(f"UNMATCHED (edit the config before dynid identify): {', '.join(cfg.unmatched)}")
    return EXIT_OK


def _cmd_predict(args: argparse.Namespace) -> int:
    _check_out(args.out)
    from dynid.pipeline.predict import load_saved, log_count, predict, predict_logs, write_prediction, write_predictions

    load_saved(args.result)  # a missing or older result is refused before the log is read
    if args.processing_from is not None:
        load_saved(args.processing_from)
    if log_count(args.log_config) > 1:  # [[data]]: each log scored on its own, and the pooled table
        if args.processing_from is not None:
            raise InputError("--processing-from with several [[data]] logs: score them one log config at a time")
        with _progress_bar(not args.quiet) as progress:
            outcomes, per_log, pooled = predict_logs(args.result, args.log_config, progress)
        written = write_predictions(outcomes, per_log, pooled, args.out, plots=not args.no_plots)
        if not args.quiet:
            print((Path(args.out) / "summary.txt").read_text())
        print(f"outputs in {Path(args.out)}: {', '.join(written)}")
        return EXIT_OK
    with _progress_bar(not args.quiet) as progress:
        outcome = predict(args.result, args.log_config, progress, processing_from=args.processing_from)
    written = write_prediction(outcome, args.out, plots=not args.no_plots)
    if not args.quiet:
        print(outcome.summary_text())
        print()
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    return EXIT_OK


def _cmd_payload(args: argparse.Namespace) -> int:
    _check_out(args.out)
    from dynid.pipeline.payload import identify_payload, payload_config_of, write_payload

    cfg = payload_config_of(args.config)
    with _progress_bar(not args.quiet) as progress:
        outcome = identify_payload(cfg, progress)
    written = write_payload(outcome, args.out)
    if not args.quiet:
        print(outcome.summary_text())
    print(f"outputs in {Path(args.out)}: {', '.join(written)}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="dynid", description="Identify the dynamic parameters of robot manipulators.")
    p.add_argument("--version", action="version", version=f"dynid {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    pi = sub.add_parser("info", help="describe a robot model: joints, standard and base parameters")
    pi.add_argument("robot", help="builtin:<name>, or a .urdf (+ closure YAML) / .xml (MJCF) / DH .toml file")
    pi.add_argument("--json", action="store_true", help="print JSON")
    pi.add_argument("--extras", default=None, help="comma-separated joint extras (default Ia,fv,fc,offset; '' for none)")
    pi.add_argument("--closures", default=None, help="loop-closure YAML for a URDF parallel robot (default: robot.yaml beside it)")
    pi.add_argument("--actuated", default=None, metavar="J1,J2,...",
                    help="parallel robots: the actuated joints in actuator order (default: the file's actuators)")
    pi.add_argument("--independent", default=None, metavar="J1,J2,...",
                    help="parallel robots: joints whose positions are the independent coordinates (default: the actuated "
                         "joints; a redundantly actuated robot needs as many as its mobility)")
    pi.set_defaults(func=_cmd_info)

    pn = sub.add_parser("init", help="write a commented starting config for dynid identify: the robot's joints, the "
                                      "log's columns matched to them, safe processing defaults for its rate")
    pn.add_argument("robot", help="builtin:<name>, or a .urdf (+ robot.yaml closures beside it) / .xml (MJCF) / DH .toml file")
    pn.add_argument("log", help="the log: .csv/.tsv, .npz or .parquet with a header (column names)")
    pn.add_argument("--out", required=True, help="the config file to write (refused when it exists, unless --force)")
    pn.add_argument("--force", action="store_true", help="replace an existing --out file")
    pn.add_argument("--validation", default=None, metavar="OTHER_LOG",
                    help="a second run of the robot (the same columns) to validate on: better than the last quarter of LOG")
    pn.add_argument("--rate", type=float, default=None, metavar="HZ", help="sampling rate of a log without a time column")
    pn.add_argument("--effort-log", default=None, metavar="EFFORT_LOG",
                    help="the efforts (torques or currents) in a second file with the same rows as LOG")
    pn.add_argument("--drive", default=None, metavar="DRIVE.toml",
                    help="the drive train the description lacks: a [robot] table with gear_ratios, couplings, "
                         "drive_gains, position_offset, rotor_inertia (docs/guide/configuration.md)")
    pn.add_argument("--actuated", default=None, metavar="J1,J2,...", help="parallel robots: the actuated joints, as for info")
    pn.add_argument("--independent", default=None, metavar="J1,J2,...", help="parallel robots: the independent coordinates' joints")
    pn.set_defaults(func=_cmd_init)

    pid = sub.add_parser("identify", help="identify base parameters from logs as CONFIG.toml says")
    pid.add_argument("config", nargs="+", metavar="CONFIG | ROBOT LOG",
                     help="TOML configuration (schema: docs/guide/configuration.md), or a robot and a log: then the config `dynid init "
                          "ROBOT LOG` would write is run and saved as OUT/identify.toml")
    pid.add_argument("--validation", default=None, metavar="LOG",
                     help="with ROBOT LOG: a second run to validate on (else the last quarter of LOG)")
    pid.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pid.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    pid.set_defaults(func=_cmd_identify)

    pp = sub.add_parser("predict", help="score a saved identification on a new log, beside the nominal model: "
                                        "per-joint RMSE, relative error, R2, plot")
    pp.add_argument("result", help="the --out folder of dynid identify (or its result.json)")
    pp.add_argument("log_config", help="TOML with a [data] table naming the new log (identify's [data] keys) and "
                                       "optionally [robot] (checked against the result's)")
    pp.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pp.add_argument("--processing-from", default=None, metavar="OTHER_RESULT",
                    help="score on the rows another identification of the same robot processed (its filters, "
                         "derivatives, decimation): two models compared like for like")
    pp.add_argument("--no-plots", action="store_true", help="no predict.png")
    pp.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    pp.set_defaults(func=_cmd_predict)

    pl = sub.add_parser("payload", help="a payload's 10 inertial parameters from a log with it mounted, given the "
                                         "arm's dynid identify result: payload.json, payload.urdf, payload.xml")
    pl.add_argument("config", help="TOML with [payload] (arm = the arm's result.json, body, mass, origin) and [data] "
                                   "(the log with the payload mounted)")
    pl.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pl.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    pl.set_defaults(func=_cmd_payload)

    pf = sub.add_parser("identifiability", help="model-structure search of paper 000 on CONFIG.toml's logs: models "
                                                "1-4, parameters identified (rel. std < 15 %% and feasible), eps_RA, eps_AV")
    pf.add_argument("config", help="TOML configuration of dynid identify (method 'ols' or 'wls')")
    pf.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pf.add_argument("--truth", default=None, metavar="TRUTH.json",
                    help="truth.json of dynid simulate: the true parameters beside the estimates, and eps_AV")
    pf.add_argument("--threshold", type=_threshold, default=15.0, metavar="PCT",
                    help="relative standard deviation counted as identified, %% (default 15, paper 000)")
    pf.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no tables")
    pf.set_defaults(func=_cmd_identifiability)

    ps = sub.add_parser("simulate", help="run a virtual experiment as CONFIG.toml says; write the log and the truth")
    ps.add_argument("config", help="TOML configuration (schema: docs/guide/simulation.md)")
    ps.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    ps.add_argument("-q", "--quiet", action="store_true", help="no summary")
    ps.set_defaults(func=_cmd_simulate)

    pg = sub.add_parser("design", help="optimize an excitation trajectory under actuator and workspace limits")
    pg.add_argument("config", help="TOML configuration (schema: docs/guide/excitation.md)")
    pg.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pg.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    pg.set_defaults(func=_cmd_design)

    pr = sub.add_parser("friction", help="friction curves from a constant-velocity log (paper 003): extracted points, "
                                         "four models fitted with uncertainties, held-out comparison, plot")
    pr.add_argument("config", help="TOML configuration (schema: docs/guide/friction.md)")
    pr.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pr.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no tables")
    pr.set_defaults(func=_cmd_friction)

    pm = sub.add_parser("montecarlo", help="repeat a virtual experiment and its identification: coverage of the "
                                           "intervals, chi2 against the confidence ellipsoid")
    pm.add_argument("config", help="TOML configuration (schema: docs/guide/montecarlo.md)")
    pm.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pm.add_argument("--trials", type=_trials, default=None, metavar="N", help="number of trials (default: the config's, 100)")
    pm.add_argument("--workers", type=_workers, default=None, metavar="K",
                    help="local worker processes; 0 or 'auto': all cores (default: the config's, 1)")
    pm.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the trials on a Dask cluster, e.g. tcp://host:8786 (default: local processes)")
    pm.add_argument("--no-progress", action="store_true", help="no progress bar")
    pm.set_defaults(func=_cmd_montecarlo)

    pl = sub.add_parser("fleet", help="many robots x many logs on Dask: per robot the pooled estimate and its verdict "
                                      "against the prior; over the fleet the spread, outliers and drift")
    pl.add_argument("config", help="TOML configuration (schema: docs/guide/fleets.md)")
    pl.add_argument("--out", required=True, help="output folder (created; files replaced only when all succeed)")
    pl.add_argument("--workers", type=_workers, default=None, metavar="K",
                    help="process workers of the local Dask cluster; 0 or 'auto': all cores (default: the config's, 2)")
    pl.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run on an existing Dask cluster, e.g. tcp://host:8786 (default: a local cluster)")
    pl.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    pl.set_defaults(func=_cmd_fleet)

    pd = sub.add_parser("demo", help="simulate builtin:shang2dof under control, identify it, validate, track again (needs nothing else)")
    pd.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    pd.add_argument("--seed", type=_seed_arg, default=None,
                    help="seed of the sensor noise (default 2026, the figures of docs/guide/demo.md); the true robot stays the same")
    pd.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    pd.set_defaults(func=_cmd_demo)
    return p


@contextmanager
def _warnings_as_lines():
    """dynid's own warnings (:class:`dynid.errors.DynidWarning`, e.g. a vendor URDF's impossible
    inertia) as one line each on stderr, ``dynid: warning: ...``, once per distinct message;
    other warnings as Python shows them."""
    import warnings

    from dynid.errors import DynidWarning

    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, DynidWarning):
                print(f"dynid: warning: {' '.join(str(message).split())}", file=sys.stderr)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.simplefilter("default", DynidWarning)
        warnings.showwarning = show
        yield


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a usage error (2, one line already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_INPUT
    try:
        with _warnings_as_lines():
            return args.func(args)
    except DynidError as exc:
        print(f"dynid: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("dynid: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # stdout piped into a program that stopped reading (`| head`)
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
