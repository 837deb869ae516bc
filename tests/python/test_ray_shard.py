"""Sharded builds on a local Ray cluster: tools/ray_driver.py runs the jobs of `bimtiles plan` as Ray
tasks, then merges.
- A build, one job made to fail once (retried): the tileset must be byte-identical to `bimtiles
  convert` with the same options (every tile, tileset.json, schema.json).
- An update (`plan --update`) after one building moved: only the jobs the plan marks changed become
  tasks, and the tileset and its tile cache equal a full build of the new manifest.

The cluster (a head and a second node, one CPU each) runs inside a private network namespace
(`unshare -n`, loopback only: ../shared/notes/ray.md), so no Ray traffic leaves the machine. Skipped,
with a message, only where `unshare -n` is not permitted.
"""
import shutil
import json
import os
import pathlib
import shlex
import subprocess
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = pathlib.Path(os.environ.get("BIMTILES_BIN", REPO / "target/release/bimtiles"))
SAMPLE = REPO / "samples/sample_building.glb"


def unshare_permitted():
    try:
        return subprocess.run(["unshare", "-n", "true"], capture_output=True).returncode == 0
    except FileNotFoundError:
        return False


def tileset_files(d):
    out = {}
    for p in sorted(d.rglob("*")):
        rel = p.relative_to(d).as_posix()
        if p.is_file() and rel not in ("report.json", "plan.json") and not rel.startswith("jobs/"):
            out[rel] = p.read_bytes()
    return out


def run(*args):
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    assert r.returncode == 0, f"{args}: {r.stderr}"
    return r


def shared_model(name):
    """A model of ../shared/data: missing, the test fails under BIMTILES_REQUIRE_TOOLS=1 and is
    skipped otherwise."""
    for c in [os.environ.get("BIMTILES_SHARED", ""), str(REPO.parent / "shared"), "/work/shared"]:
        p = pathlib.Path(c) / "data" / name
        if c and p.is_file():
            return p
    if os.environ.get("BIMTILES_REQUIRE_TOOLS") == "1":
        pytest.fail(f"shared model {name} not found (set BIMTILES_SHARED)")
    pytest.skip(f"shared model {name} not found (set BIMTILES_SHARED)")


def on_local_ray(commands, env=None):
    """Runs the shell `commands` with a local Ray cluster up (a head and a second node, one CPU
    each, in a private network namespace); returns the finished process."""
    bindir = pathlib.Path(sys.executable).parent
    ray_cli = shlex.quote(str(bindir / "ray"))
    script = f"""set -e
ip link set lo up
export RAY_USAGE_STATS_ENABLED=0
trap '{ray_cli} stop --force >/dev/null 2>&1 || true' EXIT
{ray_cli} start --head --port=6399 --num-cpus=1 --include-dashboard=false --node-ip-address=127.0.0.1 >/dev/null
{ray_cli} start --address=127.0.0.1:6399 --num-cpus=1 --node-ip-address=127.0.0.1 >/dev/null
{commands}
"""
    return subprocess.run(["unshare", "-n", "bash", "-c", script], capture_output=True, text=True, timeout=600,
                          env={**os.environ, **(env or {}), "PATH": f"{bindir}:{os.environ.get('PATH', '')}"})


def driver(build):
    """The shell command that runs tools/ray_driver.py on the build folder `build`."""
    return (f"{shlex.quote(sys.executable)} {shlex.quote(str(REPO / 'tools/ray_driver.py'))} "
            f"{shlex.quote(str(build))} --bimtiles {shlex.quote(str(BIN))} --max-retries 2 --threads 1")


needs_unshare = pytest.mark.skipif(
    not unshare_permitted(), reason="`unshare -n` is not permitted here: a Ray cluster cannot be kept on "
    "loopback, so the Ray driver tests are skipped")


@needs_unshare
def test_ray_driver_retries_and_matches_convert(tmp_path):
    assert BIN.is_file(), f"{BIN} missing: build with `cargo build --release` first"
    # A copy, not a symlink: manifest entries leading out of their folder are refused.
    shutil.copyfile(SAMPLE, tmp_path / "sample.glb")
    models = [{"name": f"b{i}", "path": "sample.glb", "east_m": 45.0 * (i % 2), "north_m": 45.0 * (i // 2),
               "heading_deg": 20.0 * i} for i in range(4)]
    (tmp_path / "campus.json").write_text(json.dumps({"models": models}))
    opts = ["--max-tile-triangles", "3000", "--quiet"]
    run(BIN, "convert", "--manifest", tmp_path / "campus.json", "--out", tmp_path / "convert", *opts)
    build = tmp_path / "ray"
    run(BIN, "plan", "--manifest", tmp_path / "campus.json", "--out", build, "--jobs", "4", *opts)

    r = on_local_ray(driver(build), env={"BIMTILES_RAY_FAIL_ONCE": "2"})
    assert r.returncode == 0, f"driver failed:\n{r.stdout}\n{r.stderr}"
    assert "4 of 4 jobs to run on 2 CPUs" in r.stderr, r.stderr
    assert "4/4" in r.stderr, r.stderr

    a, b = tileset_files(tmp_path / "convert"), tileset_files(build)
    assert sorted(a) == sorted(b)
    assert len([k for k in a if k.startswith("tiles/")]) > 4
    for name in a:
        assert a[name] == b[name], f"{name} differs from convert's"
    # Job 2's first attempt ran and failed (its marker), and the retry built it (its result).
    assert (build / "jobs/.ray-fail-once-2").exists() and (build / "jobs/job-2.bin").exists()


@needs_unshare
def test_ray_update_runs_only_changed_jobs_and_equals_a_full_build(tmp_path):
    assert BIN.is_file(), f"{BIN} missing: build with `cargo build --release` first"
    # Untextured models: a textured tileset takes no tile from the tile cache.
    for name, model in [("a.glb", "duplex.glb"), ("b.glb", "AC20-FZK-Haus.glb")]:
        shutil.copyfile(shared_model(model), tmp_path / name)
    # 200 m apart: a building moved changes the jobs of its own cells and the top, not all of them.
    models = [{"name": f"b{i}", "path": ["a.glb", "b.glb"][i % 2], "east_m": 200.0 * (i % 3),
               "north_m": 200.0 * (i // 3)} for i in range(6)]
    manifest = tmp_path / "campus.json"
    manifest.write_text(json.dumps({"models": models}))
    out = tmp_path / "out"
    plan = [BIN, "plan", "--manifest", manifest, "--out", out, "--jobs", "4", "--update",
            "--max-tile-triangles", "4000", "--quiet"]
    run(*plan)
    first = on_local_ray(driver(out))
    assert first.returncode == 0, f"driver failed:\n{first.stdout}\n{first.stderr}"
    assert "4 of 4 jobs to run on 2 CPUs" in first.stderr, first.stderr

    # One building moved inside the campus's extent: the plan marks the jobs it touches.
    models[4]["east_m"] += 1.0
    manifest.write_text(json.dumps({"models": models}))
    run(*plan)
    jobs = json.loads((out / ".bimtiles/shard/plan.json").read_text())["jobs"]
    changed = sum(1 for j in jobs if j["changed"])
    assert 0 < changed < len(jobs), jobs
    second = on_local_ray(driver(out))
    assert second.returncode == 0, f"driver failed:\n{second.stdout}\n{second.stderr}"
    assert f"{changed} of 4 jobs to run on 2 CPUs" in second.stderr, second.stderr
    assert not (out / ".bimtiles/shard").exists(), "the build folder stays after the merge"

    full = tmp_path / "full"
    run(BIN, "convert", "--manifest", manifest, "--out", full, "--update", "--max-tile-triangles", "4000",
        "--quiet")
    a, b = tileset_files(full), tileset_files(out)
    assert sorted(a) == sorted(b)
    assert ".bimtiles/tile-cache.bin" in a
    for name in a:
        assert a[name] == b[name], f"{name} differs from a full build's"
