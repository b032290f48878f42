"""``kartpilot study``: the thesis's study, and sweeps of any stack setting, on Ray (see ``kartpilot.study``)."""

from __future__ import annotations

import argparse
import sys

from kartpilot.study.report import write_report
from kartpilot.study.run import run_study
from kartpilot.study.spec import BUILT_IN, expand_cells, load_spec
from kartpilot.study.tune import tune_study

__all__ = ["study_list", "study_report", "study_run", "study_tune"]


def study_list(args: argparse.Namespace) -> int:
    for name in BUILT_IN:
        spec = load_spec(name)
        full, quick = ({c.key for c in expand_cells(spec, q)} for q in (False, True))
        print(f"{name:12s} {len(full):4d} cells ({len(quick):3d} with --quick)  {spec.title}"
              + ("  [tune]" if spec.tune else ""))
    return 0


def study_run(args: argparse.Namespace) -> int:
    spec = load_spec(args.spec)
    run = run_study(spec, args.out, args.data, quick=args.quick, address=args.address, cpus=args.cpus,
                    cache_dir=args.cache, progress=not args.no_progress and sys.stderr.isatty())
    where = f"in {run.wall_s:.0f} s on {run.cpus:g} CPUs" if run.computed else "nothing to compute"
    print(f"{spec.name}: {len(run.rows)} cells, {run.computed} computed, {run.cached} from the cache, "
          f"{run.failed} failed, {where}")
    files = write_report(args.out)
    print(f"report: {files[0]}  rows: {files[1]}")
    return 1 if run.failed and run.failed == len({r['config_hash'] for r in run.rows}) else 0


def study_report(args: argparse.Namespace) -> int:
    files = write_report(args.folder)
    print("\n".join(str(f) for f in files))
    return 0


def study_tune(args: argparse.Namespace) -> int:
    spec = load_spec(args.spec)
    result = tune_study(spec, args.out, args.data, quick=args.quick, address=args.address, cpus=args.cpus,
                        trials=args.trials, progress=not args.no_progress and sys.stderr.isatty())
    best = ", ".join(f"{k.split('.')[-1]} {v:.3g}" for k, v in result.best_params.items())
    print(f"{spec.name}: {result.trials} trials in {result.wall_s:.0f} s; best {best}")
    for name, summary in result.held_out.items():
        if name == "change":
            continue
        print(f"  held out, {name:8s} " + ", ".join(f"{k} {v:.4g}" for k, v in summary.items()))
    print(f"settings for --config: {args.out}/best.yaml  report: {args.out}/tune.md")
    return 0
