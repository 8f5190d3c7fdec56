"""`jiggle batch MANIFEST|FOLDER --out DIR`: a library of clips baked on a Dask cluster, one bake per job
into DIR/<job>/, with DIR/index.html and index.json (sim/app/batch.py).
"""
from __future__ import annotations

import os
import sys

from jiggle.sim.app.args import bake_settings, count, map_options, template_option

EXIT_SOME_FAILED = 1


def run(args) -> int:
    from tqdm import tqdm

    from jiggle.sim.app.batch import dashboard_link, dask_client, find_jobs, run_batch
    from jiggle.sim.app.commands.bake import bake_request
    from jiggle.sim.bake.setup import prepare  # noqa: F401 - fail here, not on a worker, when jiggle is broken
    if args.scheduler is not None and args.workers is not None:
        from jiggle.rig.base.errors import InputError
        raise InputError("--workers sizes the local cluster; an existing cluster (--scheduler) has its own "
                         "workers", field="--workers")
    out = os.path.abspath(args.out)
    base = bake_request(args)
    jobs = find_jobs(args.source, base, out, log=lambda s: print(f"  {s}", file=sys.stderr))
    _writable(out)
    report = "none" if args.no_report else "numbers" if args.no_render else "render"
    with dask_client(args.scheduler, args.workers) as client:
        workers = len(client.scheduler_info().get("workers", {}))
        where = args.scheduler or f"a local cluster of {workers} worker processes"
        print(f"batch: {len(jobs)} jobs on {where} -> {out}", file=sys.stderr)
        link = dashboard_link(client, local=args.scheduler is None)
        if link:
            print(f"  Dask dashboard: {link}", file=sys.stderr)
        with tqdm(total=len(jobs), unit="job", desc="batch", disable=None, file=sys.stderr,
                  dynamic_ncols=True) as bar:
            try:
                records = run_batch(jobs, out, client, resume=args.resume, report=report,
                                    log=lambda s: bar.write(f"  {s}", file=sys.stderr), bar=bar)
            except KeyboardInterrupt:
                bar.close()
                done = _finished(out, jobs)
                raise KeyboardInterrupt(f"after {done} of {len(jobs)} jobs; the finished jobs and the finished chunks "
                                        f"of the others are kept in {out}; to finish, run the same command with "
                                        "--resume") from None
    failed = [r for r in records if r["status"] != "ok"]
    frames = sum(r.get("frames") or 0 for r in records if r["status"] == "ok")
    print(f"{len(records) - len(failed)} of {len(records)} jobs baked ({frames} frames)"
          + (f", {len(failed)} failed:" if failed else ""))
    for r in failed:
        print(f"  {r['name']}: {r.get('error')}")
    print(f"  index {os.path.join(out, 'index.html')}")
    print(f"  json  {os.path.join(out, 'index.json')}")
    return EXIT_SOME_FAILED if failed else 0


def _writable(out: str) -> None:
    from jiggle.rig.base.errors import InputError
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create the output folder: {e.strerror or e}", out, field="--out") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError("the output folder is not writable", out, field="--out")


def _finished(out: str, jobs) -> int:
    from jiggle.sim.app.batch import _read_record
    return sum((_read_record(os.path.join(out, j.name)) or {}).get("status") == "ok" for j in jobs)


def add_parser(sub) -> None:
    """The `jiggle batch` subcommand and its options."""
    p = sub.add_parser("batch", help="bake a library of clips on a Dask cluster, with an index",
                       description="Bake every clip of FOLDER (BVH, AMC with its ASF, glTF/GLB: one job per "
                                   "animation) or every [[job]] of MANIFEST (a TOML: clip and optional name, "
                                   "animation, skeleton, character, template, fps, start, end, frames, jiggle, "
                                   "blend over the command line's) into DIR/<job>/, each an ordinary resumable "
                                   "bake with its compare report (no video), and write DIR/index.html and "
                                   "index.json (one row per job, sortable). Runs on a local Dask cluster (one "
                                   "worker process per core) or on the cluster at --scheduler. A job that fails is "
                                   "recorded and the others go on. Exit codes: 0 all jobs baked, 1 some failed "
                                   "(listed), 2 bad input.")
    p.add_argument("source", metavar="MANIFEST|FOLDER", help="a folder of clips or a manifest TOML")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder: DIR/<job>/ per job, DIR/index.html")
    p.add_argument("--resume", action="store_true", help="run only the jobs not finished in DIR (an unfinished "
                   "bake goes on from its last chunk)")
    g = p.add_argument_group("cluster")
    g.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (tcp://host:8786; start it with "
                   "`dask scheduler`, and `dask worker ADDRESS` on each machine; DIR on a filesystem they all "
                   "share) (default: a local cluster)")
    g.add_argument("--workers", type=count("--workers"), metavar="N", help="worker processes of the local cluster, "
                   "one thread each (default: one per core)")
    g = p.add_argument_group("report")
    g.add_argument("--no-render", action="store_true", help="compare without pictures (no peak-frame thumbnail)")
    g.add_argument("--no-report", action="store_true", help="no compare at all: the index has the bakes' numbers only")
    g = p.add_argument_group("character (every job's, unless its manifest entry says)")
    g.add_argument("--character", metavar="FILE", help="a skinned glTF/GLB or FBX the clips are retargeted onto (default: a "
                   "body generated around each clip's skeleton)")
    template_option(g)
    map_options(g)
    g.add_argument("--skin", type=int, metavar="N", help="which skin of a glTF character (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the character file's unit: auto, m, cm, mm, in, ft or metres per "
                   "unit (default: auto)")
    g = p.add_argument_group("clip reading")
    g.add_argument("--scale", type=float, metavar="M", help="BVH metres per file unit (default: CMU recognised, else "
                   "guessed from height)")
    g.add_argument("--tpose", choices=["auto", "skip", "keep"], default="auto", help="BVH first frame: auto drops a "
                   "T-pose added by converters (CMU), skip always drops it, keep never (default: auto)")
    g = p.add_argument_group("tissue")
    g.add_argument("--activation", choices=("on", "off"), help="every job's muscle activation from its clip's own "
                   "joint torques (jiggle bake --activation; a manifest's job may say its own)")
    bake_settings(p)
    p.set_defaults(func=run)
