"""`jiggle batch`: a library of clips baked on a Dask cluster, one ordinary bake per job, and an index.

    a folder of clips (BVH, AMC beside its ASF, glTF/GLB: one job per animation) or a manifest TOML
      -> jobs (a name, a BakeRequest: the command line's settings with the job's overrides over them)
      -> each job a Dask task (run_job) on a worker process: prepare (the character, its fitted muscles
         and bound skin taken from the worker's RigCache when an earlier job there had the same ones),
         bake into DIR/<job>/ (chunked, resumable), `jiggle compare` without the video, the job's
         record in DIR/<job>/batch.json; a failure (bad clip, NaN) is recorded, never raised
      -> DIR/index.json and DIR/index.html (one row per job, sortable), rewritten as jobs finish

The cluster: a LocalCluster on this machine (one single-threaded worker process per core) unless a
scheduler address is given. A worker that dies mid-job: Dask runs the task again on another worker
and the bake there goes on from the job's last finished chunk (an unfinished bake with the same
parameters is always continued: the result equals an unbroken bake bit for bit, sim.bake.baker).
With `resume`, a job whose record says it finished, with the same request, is not run again.
"""
from __future__ import annotations

import contextlib
import hashlib
import html
import json
import os
import re
import sys
import time
import traceback
import warnings
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Callable

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError
from jiggle.sim.bake.setup import BakeRequest, file_digest, jsonable, params_key

INDEX_FORMAT = "jiggle.batch/1"
RECORD = "batch.json"
"""Each job's record, in its own folder: status, error, figures, the request's fingerprint."""
CLIP_SUFFIXES = (".bvh", ".amc", ".glb", ".gltf", ".fbx")
JOB_KEYS = {"clip": str, "name": str, "animation": (str, int), "skeleton": str, "character": str, "template": str,
            "fps": float, "start": float, "end": float, "frames": int, "jiggle": float, "blend": float,
            "activation": str}
"""Keys a manifest's [[job]] may hold, and their types; paths are relative to the manifest's folder."""
RIG_CACHE_SIZE = 4
"""Fitted characters kept per worker (a 30k-vertex body's rig is a few hundred MB at most)."""


@dataclass(frozen=True)
class Job:
    """One bake of the library. name : its folder under DIR (letters, digits, ._-). request : the bake.
    source : what it bakes, for people (the clip file, and the animation of a glTF)."""

    name: str
    request: BakeRequest
    source: str


# ---------------------------------------------------------------------------------------- jobs
def find_jobs(source: str, base: BakeRequest, out_root: str | None = None,
              log: Callable[[str], None] = lambda s: None) -> list[Job]:
    """The jobs of a folder of clips or of a manifest TOML, each `base` with the clip (and the job's
    overrides) over it. InputError for a missing source, a bad manifest (file, line, key) or no clip."""
    if os.path.isdir(source):
        jobs = folder_jobs(source, base, out_root, log)
    elif os.path.isfile(source):
        if not source.lower().endswith(".toml"):
            raise InputError("expected a folder of clips or a manifest .toml", source, field="MANIFEST|FOLDER")
        jobs = manifest_jobs(source, base, log)
    else:
        raise InputError("no such folder or manifest", source, field="MANIFEST|FOLDER")
    if not jobs:
        raise InputError(f"no clips here ({', '.join(CLIP_SUFFIXES)}; a glTF with animations)", source,
                         field="MANIFEST|FOLDER")
    return jobs


def folder_jobs(folder: str, base: BakeRequest, out_root: str | None = None,
                log: Callable[[str], None] = lambda s: None) -> list[Job]:
    """Every clip under `folder` (sorted, hidden folders and `out_root` left out): a job per BVH and per
    AMC (its ASF found beside it when the clip is read), a job per animation of a glTF/GLB; a glTF
    without animations is a character, not a clip, and is skipped."""
    skip = os.path.realpath(out_root) if out_root else None
    found = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and os.path.realpath(os.path.join(root, d)) != skip)
        found += [os.path.join(root, f) for f in sorted(files) if f.lower().endswith(CLIP_SUFFIXES)]
    jobs, names = [], set()
    for path in found:
        stem = os.path.splitext(os.path.relpath(path, folder))[0]
        for anim, label in _animations(path, log):
            name = _unique(safe_name(os.path.basename(stem) + ("" if label is None else f"-{label}")), names,
                           safe_name(stem.replace(os.sep, "__")))
            jobs.append(Job(name, replace(base, clip=os.path.abspath(path), animation=anim),
                            path if label is None else f"{path} animation {anim} ({label})"))
    return jobs


def _animations(path: str, log) -> list[tuple[int | None, str | None]]:
    """[(animation, label)] of a clip file: [(None, None)] for BVH and AMC (and for a glTF that cannot be
    read: its job then fails with the reader's error), one per animation of a glTF, none without."""
    if not path.lower().endswith((".glb", ".gltf", ".fbx")):
        return [(None, None)]
    from jiggle.rig.motion.fbx import fbx_to_gltf, is_fbx
    from jiggle.rig.motion.gltf_io import GltfDocument
    try:
        anims = GltfDocument(fbx_to_gltf(path) if is_fbx(path) else path).gltf.animations or []
    except Exception:                  # noqa: BLE001 - the job reports the reader's error
        return [(None, None)]
    if not anims:
        log(f"skipped {path}: a glTF without animations (a character, not a clip)")
        return []
    if len(anims) == 1:
        return [(0, None)]
    return [(k, a.name or f"animation{k}") for k, a in enumerate(anims)]


def safe_name(text: str) -> str:
    """A folder name: runs of anything but letters, digits, '.', '_', '-' become '_'."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "job"
    return name[:120]


def _unique(name: str, taken: set, longer: str) -> str:
    for cand in (name, longer, *(f"{longer}-{k}" for k in range(2, 10_000))):
        if cand not in taken:
            taken.add(cand)
            return cand
    raise AssertionError("unreachable")


def manifest_jobs(path: str, base: BakeRequest, log: Callable[[str], None] = lambda s: None) -> list[Job]:
    """The [[job]] tables of a manifest TOML (see JOB_KEYS and docs/tutorials/library.md), each over `base`. A glTF clip
    without `animation` makes one job per animation. Paths are relative to the manifest's folder."""
    import tomllib
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError("not UTF-8 text", path) from None
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"\(at line (\d+), column \d+\)", str(e))
        why = re.sub(r" \(at line .*", "", str(e))
        raise InputError(f"not valid TOML: {why}", path, line=int(m.group(1)) if m else None) from None
    lines = raw.decode("utf-8").splitlines()
    heads = [i + 1 for i, s in enumerate(lines) if re.match(r"\s*\[\[\s*job\s*\]\]", s)]
    extra = sorted(set(doc) - {"job"})
    if extra:
        raise InputError(f"unknown table or key {extra[0]!r}; a manifest holds [[job]] tables only", path,
                         line=_line(lines, 0, extra[0]), field=extra[0])
    tables = doc.get("job")
    if not isinstance(tables, list) or not tables:
        raise InputError("no [[job]] table; each job is a [[job]] with at least clip = \"FILE\"", path, field="job")
    folder = os.path.dirname(os.path.abspath(path))
    jobs, names = [], set()
    for n, t in enumerate(tables):
        head = heads[n] if n < len(heads) else None

        def bad(msg, key=None, t=t, n=n, head=head):
            line = _line(lines, head, key) if key else head
            return InputError(msg, path, line=line, field=f"job {n + 1}" + (f": {key}" if key else ""))
        for key, value in t.items():
            if key not in JOB_KEYS:
                raise bad(f"unknown key; a job may have {', '.join(JOB_KEYS)}", key)
            kind = JOB_KEYS[key]
            ok = (isinstance(value, kind) and not isinstance(value, bool)) if kind is not float else \
                (isinstance(value, (int, float)) and not isinstance(value, bool))
            if not ok:
                raise bad(f"expected {'a number' if kind is float else 'a whole number' if kind is int else 'text'},"
                          f" got {value!r}", key)
        if "clip" not in t:
            raise bad("no clip; give clip = \"FILE\" (BVH, AMC or glTF)")
        for key, lo, hi, what in (("fps", 0, None, "a positive number"), ("start", 0, None, "zero or more"),
                                  ("end", 0, None, "zero or more"), ("frames", 1, None, "at least 1"),
                                  ("jiggle", 0, 1, "in [0, 1]"), ("blend", 0, 1, "in [0, 1]")):
            if key in t:
                v = float(t[key])
                if not (v >= lo and (hi is None or v <= hi) and v < float("inf")) or (key == "fps" and v <= 0):
                    raise bad(f"must be {what}, got {t[key]!r}", key)
        over = {}
        for key in ("clip", "skeleton", "character", "template"):
            if key in t:
                p = os.path.join(folder, os.path.expanduser(t[key]))
                if key == "template" and not t[key].lower().endswith((".toml", ".xml")):
                    over[key] = t[key]                  # a built-in template's name
                    continue
                if not os.path.isfile(p):
                    raise bad(f"file not found: {p}", key)
                over[key] = os.path.abspath(p)
        for key in ("fps", "start", "end", "jiggle", "blend"):
            if key in t:
                over[key] = float(t[key])
        if "frames" in t:
            over["frames"] = int(t["frames"])
        if "animation" in t:
            over["animation"] = t["animation"]
        if "activation" in t:
            if t["activation"] not in ("on", "off"):
                raise bad(f"must be \"on\" or \"off\", got {t['activation']!r}", "activation")
            over["activation"] = t["activation"]
        req = replace(base, **over)
        stem = t.get("name") or os.path.splitext(os.path.basename(t["clip"]))[0]
        if "name" in t and safe_name(t["name"]) in names:
            raise bad(f"another job is named {t['name']!r}", "name")
        anims = [(req.animation, None)] if "animation" in t else _animations(req.clip, log)
        for anim, label in anims:
            name = _unique(safe_name(stem + ("" if label is None else f"-{label}")), names, safe_name(
                f"{stem}-{n + 1}" + ("" if label is None else f"-{label}")))
            jobs.append(Job(name, replace(req, animation=anim), req.clip if label is None else
                            f"{req.clip} animation {anim} ({label})"))
    return jobs


def _line(lines: list[str], head: int | None, key: str | None) -> int | None:
    """1-based line of `key = ...` in the table whose header is on line `head` (None: the top level),
    else `head`."""
    for i in range(head or 0, len(lines)):
        if re.match(r"\s*\[", lines[i]):           # the next table: not in this one
            break
        if key and re.match(rf"\s*{re.escape(key)}\s*=", lines[i]):
            return i + 1
    return head


def fingerprint(job: Job, report: str) -> str:
    """A hash of what a job's result depends on before it is prepared: its request, the bytes of the files
    it names, and the report asked for (so --resume redoes a job whose clip or settings changed)."""
    req = jsonable(job.request)
    files = {k: file_digest(v) for k in ("clip", "skeleton", "character", "template", "scene", "clip_map",
                                         "character_map")
             if isinstance(v := getattr(job.request, k), str) and os.path.isfile(v)}
    return params_key({"request": req, "files": files, "report": report})


# ---------------------------------------------------------------------------------------- worker side
class RigCache(OrderedDict):
    """The fitted characters of one worker process (sim.bake.setup.FittedRig by fitted_key), the
    `size` most recently used; hits and misses counted."""

    def __init__(self, size: int = RIG_CACHE_SIZE):
        super().__init__()
        self.size, self.hits, self.misses = size, 0, 0

    def get(self, key, default=None):
        if key in self:
            self.hits += 1
            self.move_to_end(key)
            return self[key]
        self.misses += 1
        return default

    def __setitem__(self, key, value):
        super().__setitem__(key, value)
        self.move_to_end(key)
        while len(self) > self.size:
            self.popitem(last=False)


RIGS = RigCache()
"""This process's cache: each Dask worker process has its own."""
_warp_ready = False


def _quiet_warp() -> None:
    """Warp initialised once per worker without its banner, kernel-load lines or the no-CUDA notice
    (written to file descriptor 2): a library's bake would print them once per worker."""
    global _warp_ready
    if _warp_ready:
        return
    import warp
    warp.config.quiet = True
    if hasattr(warp.config, "log_level"):
        warp.config.log_level = warp.LOG_ERROR
    sys.stderr.flush()
    saved = None
    with contextlib.suppress(OSError):
        saved = os.dup(2)
    try:
        if saved is not None:
            with open(os.devnull, "wb") as null:
                os.dup2(null.fileno(), 2)
        warp.init()
    finally:
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
    _warp_ready = True


def run_job(job: Job, out_root: str, report: str = "render", print_fingerprint: str | None = None) -> dict:
    """Bake one job into out_root/<job.name>/ on this worker and return its record (also written to
    RECORD there). Never raises for the job's own failure (a bad clip, a NaN, a bug): the record has
    status "failed" and the error. An unfinished bake there with the same parameters is continued.

    report : "render" (compare without the video: numbers, plots, the peak picture), "numbers" (compare
    without renders), "none".
    """
    _quiet_warp()
    from jiggle.sim.bake.baker import MANIFEST, PARTIAL, bake
    from jiggle.sim.bake.setup import prepare
    out = os.path.join(out_root, job.name)
    t_start = time.perf_counter()
    rec = {"name": job.name, "source": job.source, "status": "failed", "error": None,
           "fingerprint": print_fingerprint, "worker": _worker_name(), "pid": os.getpid()}
    notes = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            hits = RIGS.hits
            t = time.perf_counter()
            setup = prepare(job.request, notes.append, rigs=RIGS)
            rec["setup_s"] = time.perf_counter() - t
            rec["rig_reused"] = RIGS.hits > hits
            manifest = os.path.join(out, PARTIAL, MANIFEST)
            resume = False
            with contextlib.suppress(OSError, ValueError):
                with open(manifest, encoding="utf-8") as fh:
                    resume = json.load(fh).get("key") == setup.key
            t = time.perf_counter()
            summary = bake(setup, out, resume=resume, log=notes.append)
            rec.update(bake_s=time.perf_counter() - t, frames=summary["frames"], fps=summary["fps"],
                       vertices=summary["vertices"], muscles=summary["muscles"], key=summary["key"],
                       resumed_after_chunks=summary["resumed_after_chunks"],
                       frames_per_s=summary["timings"].get("frames_per_s"))
            if report != "none":
                from jiggle.sim.app.report.compare import compare
                t = time.perf_counter()
                res = compare(out, render=report == "render", video=False)
                rec["report_s"] = time.perf_counter() - t
                rec.update(_figures(res["metrics"]))
                rec["files"] = {k: os.path.relpath(v, out_root) for k, v in res["files"].items()
                                if k in ("report", "peak", "metrics")}
            rec["status"], rec["error"] = "ok", None
        except InputError as e:
            rec["error"] = str(e)
        except Exception as e:          # noqa: BLE001 - recorded: the other jobs go on
            rec["error"] = f"{type(e).__name__}: {e}"
            rec["traceback"] = traceback.format_exc(limit=-8)
    rec["time_s"] = time.perf_counter() - t_start
    rec["warnings"] = [str(w.message) for w in caught if not _hidden(w)][:20]
    rec["log"] = notes[-40:]
    rec = jsonable(rec)
    with contextlib.suppress(OSError):
        os.makedirs(out, exist_ok=True)
        with atomic_path(os.path.join(out, RECORD)) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            json.dump(rec, fh, indent=1, allow_nan=False)
    return rec


def _hidden(w) -> bool:
    return issubclass(w.category, RuntimeWarning) and " encountered in " in str(w.message) or \
        issubclass(w.category, DeprecationWarning)


def _worker_name() -> str:
    with contextlib.suppress(Exception):
        from distributed import get_worker
        return get_worker().address
    return "local"


def _figures(metrics: dict) -> dict:
    """From compare's metrics.json: the peak jiggle (skin and muscle) and the skin quality targets."""
    skin, peak = metrics.get("skin") or {}, metrics.get("peak") or {}
    muscles = metrics.get("muscles") or {}
    top = next(iter(muscles.items()), (None, {}))          # listed largest peak first
    limits = metrics.get("limits") or {}
    targets = (metrics.get("skin_quality") or {}).get("targets") or {}
    return {"peak_skin_mm": skin.get("max_mm"), "peak_frame": peak.get("frame"), "peak_time_s": peak.get("time_s"),
            "peak_muscle": top[0], "peak_muscle_mm": top[1].get("peak_mm"),
            "near_limit_pct": None if limits.get("near_limit_fraction_all") is None
            else 100.0 * limits["near_limit_fraction_all"],
            "near_limit_muscle": (limits.get("worst") or {}).get("muscle"),
            "hard_stops": limits.get("hard_stops_total"),
            "quality": {k: {"value": t.get("value"), "limit": t.get("limit"), "pass": t.get("pass")}
                        for k, t in targets.items()}}


# ---------------------------------------------------------------------------------------- client side
@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None):
    """A distributed.Client: on the scheduler at `scheduler` (tcp://host:8786), else on a LocalCluster
    here with `workers` single-threaded worker processes (default: one per core), bound to 127.0.0.1,
    its dashboard on 127.0.0.1:8787 (the next free port when taken) when bokeh is installed."""
    import logging

    from distributed import Client, LocalCluster
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError, TypeError) as e:
            raise InputError(f"cannot reach the Dask scheduler ({type(e).__name__}: {e}); start one with "
                             "`dask scheduler` and workers with `dask worker ADDRESS`", field="--scheduler") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # "Port 8787 is already in use ..." picks another: fine
        # without bokeh the scheduler still serves its health routes: on any free port, dashboard off
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:8787" if has_bokeh() else "127.0.0.1:0",
                               scheduler_kwargs={"dashboard": has_bokeh()}, silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def has_bokeh() -> bool:
    """Whether Dask's dashboard can be served here (it needs bokeh)."""
    import importlib.util
    return importlib.util.find_spec("bokeh") is not None


def dashboard_link(client, local: bool) -> str | None:
    """The Dask dashboard's address: an existing cluster's (it serves its own), a local one's when bokeh is
    installed; None otherwise."""
    if local and not has_bokeh():
        return None
    return getattr(client, "dashboard_link", None)


def run_batch(jobs: list[Job], out_root: str, client, *, resume: bool = False, report: str = "render",
              log: Callable[[str], None] = lambda s: None, bar=None) -> list[dict]:
    """Run every job on `client`'s cluster and return their records in the jobs' order; DIR/index.json
    and index.html are rewritten as each finishes. With `resume`, a job whose record says it finished with
    the same fingerprint (and whose bake.json is there) is kept as it is. `bar` : a tqdm over the jobs."""
    from distributed import as_completed
    out_root = os.path.abspath(out_root)
    prints = {j.name: fingerprint(j, report) for j in jobs}
    records: dict[str, dict] = {}
    todo = []
    for j in jobs:
        old = _read_record(os.path.join(out_root, j.name)) if resume else None
        if old and old.get("status") == "ok" and old.get("fingerprint") == prints[j.name] and \
                os.path.isfile(os.path.join(out_root, j.name, "bake.json")):
            records[j.name] = {**old, "kept": True}
        else:
            todo.append(j)
    if resume:
        log(f"resuming: {len(records)} of {len(jobs)} jobs finished earlier, {len(todo)} to run")
    t0 = time.perf_counter()
    if bar is not None:
        bar.update(len(records))
    write_index(out_root, jobs, records)
    # the longest clips first (their files' sizes tell): the last job to finish is then a short one, not a
    # long one started late while the other workers idle
    futures = {client.submit(run_job, j, out_root, report, prints[j.name], pure=False, priority=_size(j),
                             key=f"jiggle-batch-{j.name}-{hashlib.sha1(os.urandom(8)).hexdigest()[:8]}"): j
               for j in todo}
    frames = 0
    try:
        for fut in as_completed(futures):
            j = futures[fut]
            try:
                rec = fut.result()
            except Exception as e:        # noqa: BLE001 - e.g. KilledWorker: the task killed its workers
                rec = {"name": j.name, "source": j.source, "status": "failed", "fingerprint": prints[j.name],
                       "error": f"{type(e).__name__}: {e}"}
            records[j.name] = rec
            frames += (rec.get("frames") or 0) if rec.get("status") == "ok" else 0
            write_index(out_root, jobs, records)
            if bar is not None:
                wall = time.perf_counter() - t0
                failed = sum(r["status"] != "ok" for r in records.values())
                bar.set_postfix_str(f"{frames / wall:.1f} frames/s, {failed} failed", refresh=False)
                bar.update(1)
    except KeyboardInterrupt:
        for fut in futures:
            fut.cancel()
        raise
    return [records[j.name] for j in jobs]


def _size(job: Job) -> int:
    """A job's rough size for the order of the queue: its clip file's kilobytes."""
    with contextlib.suppress(OSError, TypeError):
        return os.path.getsize(job.request.clip) // 1024
    return 0


def _read_record(folder: str) -> dict | None:
    with contextlib.suppress(OSError, ValueError):
        with open(os.path.join(folder, RECORD), encoding="utf-8") as fh:
            rec = json.load(fh)
        return rec if isinstance(rec, dict) else None
    return None


# ---------------------------------------------------------------------------------------- index
COLUMNS = (("job", "name", "s"), ("status", "status", "s"), ("frames", "frames", "n"), ("time (s)", "time_s", "n"),
           ("set-up (s)", "setup_s", "n"), ("bake (s)", "bake_s", "n"), ("peak skin (mm)", "peak_skin_mm", "n"),
           ("peak muscle (mm)", "peak_muscle_mm", "n"), ("muscle", "peak_muscle", "s"),
           ("near limit (%)", "near_limit_pct", "n"), ("most near limit", "near_limit_muscle", "s"),
           ("hard stops", "hard_stops", "n"))
QUALITY = (("final folds", "final_folded_edges"), ("folds / LBS", "folds_added_over_lbs"),
           ("torn edges", "torn_edges"), ("gradient p99.9", "gradient_p999"))
"""compare's skin quality targets (sim.app.report.skin_quality.check_targets), one column each."""

SORT_JS = """
document.querySelectorAll('th[data-k]').forEach(function (th) {
  th.addEventListener('click', function () {
    var col = th.cellIndex, tb = th.closest('table').tBodies[0], rows = Array.from(tb.rows), up = th.dataset.dir !== 'up';
    th.dataset.dir = up ? 'up' : 'down';
    var key = function (r) { var c = r.cells[col], v = c.dataset.v;
      return th.dataset.k === 'n' ? (v === '' ? -Infinity : parseFloat(v)) : c.textContent.toLowerCase(); };
    rows.sort(function (a, b) { var x = key(a), y = key(b); return (x < y ? -1 : x > y ? 1 : 0) * (up ? 1 : -1); });
    rows.forEach(function (r) { tb.appendChild(r); });
  });
});
"""


def index_doc(out_root: str, jobs: list[Job], records: dict) -> dict:
    """index.json: every job's record (status "pending" for one not finished), and the totals."""
    rows = [records.get(j.name) or {"name": j.name, "source": j.source, "status": "pending"} for j in jobs]
    for r in rows:
        r.pop("log", None)
    ok = [r for r in rows if r["status"] == "ok"]
    return {"format": INDEX_FORMAT, "out": out_root, "jobs": rows,
            "totals": {"jobs": len(rows), "ok": len(ok), "failed": sum(r["status"] == "failed" for r in rows),
                       "pending": sum(r["status"] == "pending" for r in rows),
                       "frames": sum(r.get("frames") or 0 for r in ok)}}


def write_index(out_root: str, jobs: list[Job], records: dict) -> dict:
    """DIR/index.json and DIR/index.html (atomically); returns the index."""
    doc = jsonable(index_doc(out_root, jobs, records))
    with atomic_path(os.path.join(out_root, "index.json")) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1, allow_nan=False)
    with atomic_path(os.path.join(out_root, "index.html")) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(render_index(doc))
    return doc


def render_index(doc: dict) -> str:
    """index.html: a table, one row per job, sortable by any column (click its header); a thumbnail of the
    peak frame and a link to the job's report (compare's report.html), both relative to DIR. The page's
    look is compare's (sim.app.report.CSS)."""
    from jiggle.sim.app.report.page import CSS

    def e(v):
        return "&ndash;" if v is None else html.escape(str(v))

    def num(v, fmt=".1f"):
        return ("", "&ndash;") if not isinstance(v, (int, float)) else (repr(float(v)), format(v, fmt))
    head = [(label, k) for label, _, k in COLUMNS] + [(label, "n") for label, _ in QUALITY] + \
        [("peak frame", None), ("report", None)]
    rows = []
    for r in doc["jobs"]:
        cells = []
        for _, key, kind in COLUMNS:
            v = r.get(key)
            if kind == "n":
                data, text = num(v, "d" if key == "frames" and isinstance(v, int) else ".2f" if key.endswith("_s")
                                 else ".1f")
                cells.append(f'<td class="n" data-v="{data}">{text}</td>')
            elif key == "status":
                colour = {"ok": "#1a7f37", "failed": "#b42318"}.get(v, "#666")
                err = f'<div class="note">{e(r.get("error"))}</div>' if r.get("error") else ""
                cells.append(f'<td><b style="color:{colour}">{e(v)}</b>{err}</td>')
            elif key == "name":
                cells.append(f'<td>{e(v)}<div class="note">{e(r.get("source"))}</div></td>')
            else:
                cells.append(f"<td>{e(v)}</td>")
        q = r.get("quality") or {}
        for _, key in QUALITY:
            t = q.get(key) or {}
            data, text = num(t.get("value"), ".3g")
            mark = "" if t.get("pass") is None else " ok" if t["pass"] else " FAIL"
            style = ' style="color:#b42318"' if t.get("pass") is False else ""
            cells.append(f'<td class="n" data-v="{data}"{style}>{text}{mark}</td>')
        files = r.get("files") or {}
        cells.append(f'<td><img class="thumb" alt="peak frame" loading="lazy" src="{e(files["peak"])}"></td>'
                     if "peak" in files else "<td></td>")
        cells.append(f'<td><a href="{e(files["report"])}">report</a></td>' if "report" in files else "<td></td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    t = doc["totals"]
    ths = "".join(f'<th data-k="{k}">{e(label)}</th>' if k else f"<th>{e(label)}</th>" for label, k in head)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>jiggle batch</title>"
            f"<style>{CSS} body {{ max-width: none; margin: 2em; }} th[data-k] {{ cursor: pointer; }} "
            "th, td { overflow-wrap: normal; } td .note { overflow-wrap: anywhere; } img.thumb { max-width: 220px; }</style></head>\n<body>\n"
            f"<h1>jiggle batch</h1><p class=\"note\">{e(doc['out'])}: {t['jobs']} jobs, {t['ok']} ok, {t['failed']} "
            f"failed, {t['pending']} not finished; {t['frames']} frames. Click a column's header to sort.</p>\n"
            f"<table><thead><tr>{ths}</tr></thead><tbody>\n" + "\n".join(rows) + "\n</tbody></table>\n"
            f"<script>{SORT_JS}</script>\n</body></html>\n")
