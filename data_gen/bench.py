"""``chpf-gen-data bench``: pool build time and samples/s of whole ``pairs``/``ae`` commands.

Every figure is the wall time of a separate ``chpf-gen-data`` process (start-up, pool loading,
composition and shard writing included); the pools are built first (timed separately) and
then reused from the cache by every timed run.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from chpf.errors import ChpfError

REPO_ROOT = Path(__file__).resolve().parent.parent


def _run(args: list[str]) -> float:
    """Run ``python -m data_gen.cli ARGS``; wall seconds. ChpfError with its stderr on failure."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-m", "data_gen.cli", *args], env=env, capture_output=True, text=True
    )
    dt = time.perf_counter() - t0
    if res.returncode != 0:
        last = (res.stderr.strip().splitlines() or ["?"])[-1]
        raise ChpfError(f"bench: chpf-gen-data {' '.join(args[:1])} failed: {last}")
    return dt


def run_bench(
    obj: str,
    n: int,
    size: int,
    workers: list[int],
    cache_dir: Path | None = None,
    config: Path | None = None,
    sets: list[str] | None = None,
) -> list[dict]:
    """Time the pool build and pairs/ae generation; print a table; return its rows."""
    tmp = Path(tempfile.mkdtemp(prefix="chpf-gen-bench-"))
    cache = Path(cache_dir) if cache_dir else tmp / "cache"
    common = ["--object", obj, "--size", str(size), "--cache-dir", str(cache), "--no-progress"]
    if config:
        common += ["--config", str(config)]
    for s in sets or []:
        common += ["--set", s]
    rows = []
    try:
        t_pool = _run(["pool", *common, "--kind", "pairs", "--workers", str(max(workers))])
        builds = {}
        for meta in cache.glob("*/meta.json"):
            m = json.loads(meta.read_text())
            builds[m["kind"]] = builds.get(m["kind"], 0.0) + m.get("build_seconds", 0.0)
        print(
            f"pool build ({obj}, S={size}, {max(workers)} workers): {t_pool:.1f} s wall "
            f"(codebook {builds.get('codebook', 0):.1f} s, obs {builds.get('obs', 0):.1f} s, "
            f"occluders {builds.get('occluders', 0):.1f} s; 0 if already cached)"
        )
        for kind in ("pairs", "ae"):
            for w in workers:
                out = tmp / f"{kind}_{w}"
                dt = _run([kind, *common, "--out", str(out), "--n", str(n), "--workers", str(w)])
                rows.append(
                    {
                        "kind": kind,
                        "workers": w,
                        "n": n,
                        "seconds": round(dt, 2),
                        "samples_per_s": round(n / dt, 1),
                    }
                )
                shutil.rmtree(out, ignore_errors=True)
        print(f"{'kind':<6} {'workers':>7} {'samples':>8} {'wall s':>8} {'samples/s':>10}")
        for r in rows:
            print(
                f"{r['kind']:<6} {r['workers']:>7} {r['n']:>8} {r['seconds']:>8.2f} "
                f"{r['samples_per_s']:>10.1f}"
            )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows
