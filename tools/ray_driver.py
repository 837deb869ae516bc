#!/usr/bin/env python3
"""Runs the jobs of a sharded bimtiles build as Ray tasks, then merges (issue 12).

    bimtiles plan [INPUT... | --manifest campus.json] --out DIR --jobs N [convert options]
    python3 tools/ray_driver.py DIR [--address auto] [--bimtiles PATH] [--max-retries 3] [--threads 1]

Every job with work and without a result yet (DIR/jobs/job-K.bin) becomes one task,
`ray.remote(max_retries=..., retry_exceptions=True)`, that runs `bimtiles build-job DIR --job K` as a
subprocess: a task whose worker dies, or whose build-job fails, is run again (a job writes its tiles
through temporary names and its result last, so a retried job simply starts over). A progress bar on
stderr counts finished jobs; then `bimtiles merge DIR` writes the tileset, byte-identical to
`bimtiles convert` with the same options. DIR and the inputs must be visible to every node (shared
storage) under the same paths, and the bimtiles binary too (`--bimtiles`).

An update (`bimtiles plan ... --out DIR --update`) keeps its plan and results in
DIR/.bimtiles/shard/; its plan marks the jobs whose subtrees did not change ("changed": false),
which become no task: merge takes their tiles from the tile cache.

Fault injection for tests: with BIMTILES_RAY_FAIL_ONCE=K in the driver's environment, job K's first
attempt fails (the marker file DIR/jobs/.ray-fail-once-K, left in place, makes it fail only once).
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import time

import ray


def build_job(bimtiles, build_dir, state_dir, job, threads, fail_once):
    """One sharded job, run on a Ray worker."""
    if fail_once:
        marker = os.path.join(state_dir, "jobs", f".ray-fail-once-{job}")
        if not os.path.exists(marker):
            open(marker, "w").close()
            raise RuntimeError(f"job {job}: failing its first attempt on purpose (BIMTILES_RAY_FAIL_ONCE)")
    t0 = time.time()
    r = subprocess.run([bimtiles, "build-job", build_dir, "--job", str(job), "--quiet",
                        "--threads", str(threads)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"job {job}: {r.stderr.strip()}")
    return job, time.time() - t0


def progress(done, total, started, width=30):
    filled = width * done // max(total, 1)
    sys.stderr.write(f"\r  jobs [{'=' * filled}{' ' * (width - filled)}] {done}/{total} {time.time() - started:6.1f} s")
    sys.stderr.flush()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", help="build folder written by `bimtiles plan`")
    ap.add_argument("--address", default="auto", help="Ray cluster address (default: auto)")
    ap.add_argument("--bimtiles", default=shutil.which("bimtiles") or "bimtiles", help="bimtiles binary")
    ap.add_argument("--max-retries", type=int, default=3, help="attempts after the first, per job")
    ap.add_argument("--threads", type=int, default=1, help="threads per job (one Ray CPU each)")
    a = ap.parse_args()
    build_dir = os.path.abspath(a.dir)
    bimtiles = os.path.abspath(a.bimtiles) if os.path.sep in a.bimtiles else a.bimtiles
    # An update's plan and results sit in the tileset's dot-folder.
    state_dir = os.path.join(build_dir, ".bimtiles", "shard")
    if not os.path.isfile(os.path.join(state_dir, "plan.json")):
        state_dir = build_dir
    with open(os.path.join(state_dir, "plan.json")) as f:
        plan = json.load(f)
    jobs = len(plan["jobs"])
    todo = [j["job"] for j in plan["jobs"] if j.get("changed", True)
            and not os.path.isfile(os.path.join(state_dir, "jobs", f"job-{j['job']}.bin"))]
    fail = os.environ.get("BIMTILES_RAY_FAIL_ONCE")
    ray.init(address=a.address, logging_level="ERROR", log_to_driver=False)
    task = ray.remote(num_cpus=a.threads, max_retries=a.max_retries, retry_exceptions=True)(build_job)
    started = time.time()
    pending = [task.remote(bimtiles, build_dir, state_dir, k, a.threads, fail == str(k)) for k in todo]
    print(f"{len(todo)} of {jobs} jobs to run on {ray.cluster_resources().get('CPU', 0):.0f} CPUs", file=sys.stderr)
    done = 0
    progress(done, len(todo), started)
    failed = []
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        try:
            ray.get(ready[0])
        except Exception as e:  # retries exhausted
            failed.append(str(e).strip().splitlines()[-1])
        done += 1
        progress(done, len(todo), started)
    sys.stderr.write("\n")
    ray.shutdown()
    if failed:
        sys.exit("ray_driver: jobs failed after retries (rerun the driver to run only those):\n  " + "\n  ".join(failed))
    r = subprocess.run([bimtiles, "merge", build_dir])
    sys.exit(r.returncode)


if __name__ == "__main__":
    main()
