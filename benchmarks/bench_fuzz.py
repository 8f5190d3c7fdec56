"""The long fuzz run: tests/test_fuzz.py's seeded mutations of every input format jiggle reads, with
thousands of inputs, each format in its own child process under a memory limit.

    .venv/bin/python benchmarks/bench_fuzz.py [--seed N] [--count N] [--keep DIR] [--memory-gb G]

--count is the number of inputs over all formats (default 2,400), shared among them in the test's
proportions. An input fails when it ends other than with exit 0, or exit 2 and one "jiggle: error:"
line, when it prints a traceback, takes longer than 10 s, or raises the child's peak memory by over
1 GB; the child itself runs under RLIMIT_AS (default 8 GB), so a runaway allocation ends as a
failure rather than a swap storm. Prints one row per format: inputs, exit 0, exit 2, failures,
time; the first few failing inputs of each format are saved under --keep (default /tmp/jiggle_fuzz)
with the reason beside them (NAME.why.txt), to rerun with `jiggle inspect FILE` or the reader.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import test_fuzz  # noqa: E402  the mutations and the rules (tests/test_fuzz.py)

KEEP_PER_FORMAT = 5


def child(fmt: str, count: int, seed: int, keep: Path) -> None:
    """Run one format's share and print its tally as JSON on the last stdout line."""
    with tempfile.TemporaryDirectory(prefix=f"jiggle_fuzz_{fmt}_") as work:
        res = test_fuzz.fuzz(seed, {fmt: count}, Path(work), keep=keep / fmt)
    t = res.get(fmt, test_fuzz.Tally())
    for i, (path, why) in enumerate(t.failures):
        if i >= KEEP_PER_FORMAT:
            Path(path).unlink(missing_ok=True)
        else:
            Path(path + ".why.txt").write_text(why)
    sys.stdout.flush()
    print("\n" + json.dumps({"inputs": t.inputs, "ok": t.ok, "user_error": t.user_error,
                             "failures": [f[0] for f in t.failures[:KEEP_PER_FORMAT]],
                             "n_failures": len(t.failures), "why": [f[1].strip().splitlines()[-1][:160]
                                                                    for f in t.failures[:KEEP_PER_FORMAT]],
                             "seconds": t.seconds}))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--count", type=int, default=2400, help="inputs over all formats (default 2400)")
    ap.add_argument("--keep", type=Path, default=Path(tempfile.gettempdir()) / "jiggle_fuzz")
    ap.add_argument("--memory-gb", type=float, default=8.0, help="address-space limit of each child")
    ap.add_argument("--formats", default=",".join(test_fuzz.COUNTS), help="comma-separated (default: all)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.child, a.count, a.seed, a.keep)
        return 0
    formats = [f for f in a.formats.split(",") if f]
    total = sum(test_fuzz.COUNTS[f] for f in formats)
    limit = int(a.memory_gb * 2 ** 30)

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    rows, t_all = [], time.perf_counter()
    print(f"fuzz: seed {a.seed}, {a.count} inputs, failing inputs under {a.keep}", flush=True)
    for k, fmt in enumerate(formats):
        n = max(1, round(a.count * test_fuzz.COUNTS[fmt] / total))
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, __file__, "--child", fmt, "--count", str(n), "--seed",
                               str(a.seed * 1000 + k), "--keep", str(a.keep)], capture_output=True, text=True,
                              preexec_fn=limited, cwd=ROOT, env={**os.environ, "PYTHONHASHSEED": "0"})
        wall = time.perf_counter() - t0
        try:
            r = json.loads(proc.stdout.strip().splitlines()[-1])
        except (IndexError, ValueError):
            r = {"inputs": n, "ok": 0, "user_error": 0, "n_failures": n, "failures": [],
                 "why": [f"the child died (exit {proc.returncode}): {proc.stderr.strip()[-300:]}"], "seconds": wall}
        rows.append((fmt, r, wall))
    print()
    print(f"| {'format':<10} | {'inputs':>6} | {'exit 0':>6} | {'exit 2':>6} | {'failures':>8} | {'time s':>7} |")
    print(f"|{'-' * 12}|{'-' * 8}|{'-' * 8}|{'-' * 8}|{'-' * 10}|{'-' * 9}|")
    tot = [0, 0, 0, 0, 0.0]
    for fmt, r, wall in rows:
        print(f"| {fmt:<10} | {r['inputs']:>6} | {r['ok']:>6} | {r['user_error']:>6} | {r['n_failures']:>8} | "
              f"{wall:>7.1f} |")
        for i, v in enumerate((r["inputs"], r["ok"], r["user_error"], r["n_failures"], wall)):
            tot[i] += v
    print(f"| {'total':<10} | {tot[0]:>6} | {tot[1]:>6} | {tot[2]:>6} | {tot[3]:>8} | {tot[4]:>7.1f} |")
    print(f"\n(wall {time.perf_counter() - t_all:.1f} s; time per format includes the child's start-up)")
    bad = [(fmt, r) for fmt, r, _ in rows if r["n_failures"]]
    for fmt, r in bad:
        print(f"\n{fmt}: {r['n_failures']} failing inputs; the first:")
        for path, why in zip(r["failures"] or ["-"] * len(r["why"]), r["why"]):
            print(f"  {path}\n    {why}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
