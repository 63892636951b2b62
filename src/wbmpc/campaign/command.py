"""`wbmpc campaign`: spec file and/or grid flags -> Dask run -> Parquet table -> report."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict

from wbmpc.errors import ConfigError


def add_parser(sub) -> None:
    p = sub.add_parser("campaign", help="robustness campaign on Dask: scenario x grid/random samples x seeds "
                                        "-> Parquet rows, push map, curves, summary.md")
    p.add_argument("spec", nargs="?", help="campaign spec (.yaml, .json or .toml); flags below override it")
    p.add_argument("--scenario", help="scenario of every case (default push)")
    p.add_argument("--robot", help="robot preset (default b1_z1)")
    p.add_argument("--duration", type=float, help="simulated seconds per case (default 4)")
    p.add_argument("--nodes", type=int, help="horizon nodes (default 15)")
    p.add_argument("--compiled", action="store_true", default=None, help="compiled solver (C, cached)")
    p.add_argument("--delay-mode", choices=("none", "fixed", "realtime"),
                   help="none (default) | fixed (--delay-ms) | realtime (one case at a time beside its solver process, "
                   "wall-clock paced; the summary lists each case's MPC rate and late share)")
    p.add_argument("--delay-ms", type=float, metavar="MS", help="a fixed solver delay of every case (ms)")
    p.add_argument("--delay", help="deprecated, the old form of --delay-mode / --delay-ms: none | MS | realtime")
    p.add_argument("--solver", help="solver of every case (default fatrop; with --delay-mode realtime: the run's default)")
    p.add_argument("--grid", action="append", metavar="AXIS=V1,V2|START:STOP:STEP",
                   help="add a grid axis (repeatable); `--list-axes` shows the axes")
    p.add_argument("--set", action="append", metavar="AXIS=VALUE", help="fixed axis value for every case (repeatable)")
    p.add_argument("--randomize", action="store_true", default=None,
                   help="the reality gap: each case a plant drawn around the robot's model (link masses and inertias "
                   "+-10 %%, base CoM +-2 cm, floor friction 0.4-1.0, rotor inertia, joint damping and dry friction "
                   "0-2x the robot's, a delay of 0-10 ms, IMU and encoder noise 0-2x, the estimator's state), seeded "
                   "and recorded in its row; --grid/--set override single axes")
    p.add_argument("--samples", type=int, metavar="N", help="random draws per grid point (with --randomize: default "
                   "100)")
    p.add_argument("--seeds", help="comma-separated seeds (default 0)")
    p.add_argument("--out", default="runs/campaign", help="output directory: rows/, results.parquet, report")
    p.add_argument("--workers", type=int, help="LocalCluster worker processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="use an existing Dask scheduler instead of a LocalCluster")
    p.add_argument("--resume", action="store_true", help="skip the cases already in --out")
    p.add_argument("--overwrite", action="store_true", help="delete the rows already in --out first")
    p.add_argument("--report-only", action="store_true", help="only (re)write the report from --out's table")
    p.add_argument("--kill-workers", type=int, default=0, metavar="N",
                   help="fault injection: SIGKILL the worker mid-case in the first N cases, once each")
    p.add_argument("--dry-run", action="store_true", help="list the cases and exit")
    p.add_argument("--list-axes", action="store_true", help="list the campaign axes and exit")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=cmd_campaign)


def _pairs(items, label):
    from wbmpc.campaign.spec import parse_grid_flag

    out = {}
    for item in items or []:
        name, values = parse_grid_flag(item)
        if label == "set":
            if len(values) != 1:
                raise ConfigError(f"--set {name} takes one value, got {values}")
            values = values[0]
        out[name] = values
    return out


def _random(spec_path, samples: int | None):
    """--samples on top of the spec file's random draws (None: the file's)."""
    if samples is None:
        return None
    if samples < 1:
        raise ConfigError(f"--samples must be >= 1, got {samples}")
    from wbmpc.campaign.spec import load_spec

    random = load_spec(spec_path).random if spec_path else None
    return {"samples": samples, "ranges": dict(random.ranges) if random else {}, "seed": random.seed if random else 0}


def cmd_campaign(args: argparse.Namespace) -> int:
    from pathlib import Path

    from wbmpc.campaign.cases import AXES, expand
    from wbmpc.campaign.report import write_report
    from wbmpc.campaign.spec import load_spec

    if args.list_axes:
        print("\n".join(f"{name:28s} {text}" for name, text in AXES.items()))
        return 0
    out_dir = Path(args.out)
    info = None
    if not args.report_only:
        seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else None
        spec = load_spec(args.spec, scenario=args.scenario, robot=args.robot, duration_s=args.duration,
                         nodes=args.nodes, compiled=args.compiled, seeds=seeds, delay=delay_from_args(args), solver=args.solver,
                         grid=_pairs(args.grid, "grid"), fixed=_pairs(args.set, "set"), randomize=args.randomize,
                         random=_random(args.spec, args.samples))
        cases = expand(spec)
        if args.dry_run:
            for case in cases:
                print(f"{case.id}  {case.label()}")
            print(f"{len(cases)} cases", file=sys.stderr)
            return 0
        from wbmpc.campaign.execution import run_campaign

        runner = None
        if args.kill_workers:
            from wbmpc.campaign.faults import KillWorkerOnce

            runner = KillWorkerOnce(str(out_dir / "faults"), frozenset(c.id for c in cases[: args.kill_workers]),
                                    after_s=2.0)
        print(f"wbmpc campaign {spec.name}: {len(cases)} cases of {spec.scenario} ({spec.robot}, "
              f"{spec.duration_s:g} s each) -> {out_dir}", file=sys.stderr)
        run = run_campaign(spec, out_dir, workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                           overwrite=args.overwrite, **({"runner": runner} if runner else {}))
        info = {k: v for k, v in asdict(run).items() if k != "out_dir"}
        info["throughput_cases_per_min"] = run.throughput_cases_per_min
        if runner is not None:
            info["workers_killed"] = len(runner.killed())
        (out_dir / "run.json").write_text(json.dumps(info, indent=2))
    elif (out_dir / "run.json").is_file():
        info = json.loads((out_dir / "run.json").read_text())
    paths = write_report(out_dir, info)
    summary = json.loads((out_dir / "summary.json").read_text())
    lines = [f"{summary['cases']} cases in {out_dir}: {summary['recovered']} recovered, {summary['fell']} fell, "
             f"{summary['errors']} errors"]
    if info:
        lines.append(f"  this run: {info['recorded']} recorded, {info['skipped']} skipped, {len(info['unfinished'])} "
                     f"unfinished, {info['workers']} workers, {info['wall_time_s']:.0f} s"
                     + (f", {info['throughput_cases_per_min']:.2f} cases/min" if info.get("throughput_cases_per_min") else "")
                     + (f", {info['workers_killed']} workers killed" if info.get("workers_killed") is not None else ""))
    if summary.get("push_map"):
        lines.append("  largest push speed recovered per direction: " + ", ".join(
            f"{float(d):g} deg {v['largest_recovered_m_s']:g}" for d, v in summary["push_map"].items()))
    lines.append(f"  wrote {', '.join(p.name for p in paths)}")
    text = "\n".join(lines)
    if args.json:
        print(json.dumps({"summary": summary, "run": info}, default=str))
        print(text, file=sys.stderr)
    else:
        print(text)
    return 0


def delay_from_args(args) -> str | None:
    """The spec's delay text from --delay-mode/--delay-ms (or the deprecated --delay); None: the spec's own."""
    import sys

    from wbmpc.control.delay import delay_text
    from wbmpc.errors import ConfigError

    if args.delay is not None:
        if args.delay_mode is not None or args.delay_ms is not None:
            raise ConfigError("--delay is the old form of --delay-mode / --delay-ms: give one or the other")
        print("wbmpc: warning: --delay is deprecated; use --delay-mode none|fixed|realtime or --delay-ms MS",
              file=sys.stderr)
        return args.delay
    if args.delay_ms is not None:
        if args.delay_mode not in (None, "fixed"):
            raise ConfigError(f"--delay-ms is a fixed delay: drop it or use --delay-mode fixed (got {args.delay_mode})")
        return delay_text("fixed", args.delay_ms)
    if args.delay_mode == "fixed":
        raise ConfigError("--delay-mode fixed needs --delay-ms MS")
    return args.delay_mode
