#!/usr/bin/env python3
"""A sharded `terrain bake` on a Dask cluster: one task per shard running the `terrain` binary
(`terrain bake ... --shard K/N -o PARTS/pK`), then one task for the merge (`terrain bake ...
--merge PARTS -o OUT`), which also bakes the scene tables. The merged store is byte for byte
what a single `terrain bake` of the same DEM and options writes.

Why Dask (distributed): it is pip-installable from PyPI with no native build, its
`LocalCluster` starts worker *processes* on one machine in a second (what the test needs) and
its scheduler is one process that users already run on clusters (`dask scheduler` /
`dask worker`, dask-kubernetes, dask-jobqueue for Slurm/PBS); a task is a plain Python function,
here a subprocess, with per-task retries. Ray would do as well but is a ~100 MB wheel with its
own object store and dashboard processes: heavy for a driver that only runs binaries.

Usage:
    scripts/bake_dask.py [DEM ...] --shards N -o OUT [--scheduler ADDR] [--workers W]
        [--parts DIR] [--retries R] [--terrain BIN] [-- TERRAIN_BAKE_OPTIONS ...]

Everything after `--` goes to every `terrain bake` (shards and merge alike), e.g.
`-- --synthetic 4097 --no-pvs`. Without --scheduler a LocalCluster of W worker processes
(one thread each) is started on 127.0.0.1 and closed at the end. Paths must be readable by
every worker under the same names (one machine, or a shared file system).

A shard whose part is already published in PARTS (from an earlier run) is kept, not baked
again: a run that failed part-way is resumed by running it again. A failing shard task is
retried R times (default 2); its half-written `.pK.part` folder is removed by its re-run. The
merge checks the parts (every shard once, the same DEM checksum and options) and refuses
others by name.
"""

import argparse
import os
import subprocess
import sys
import time


def run_terrain(cmd):
    """Runs one `terrain` command on a worker; raises with its stderr's tail when it fails
    (Dask then retries the task). Returns (wall seconds, CPU seconds of the child, stdout)."""
    t0 = time.monotonic()
    c0 = os.times()
    p = subprocess.run(cmd, capture_output=True, text=True)
    c1 = os.times()
    wall = time.monotonic() - t0
    cpu = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
    if p.returncode != 0:
        raise RuntimeError(
            f"{' '.join(cmd)} exited with {p.returncode}: {p.stderr.strip()[-2000:]}"
        )
    return wall, cpu, p.stdout.strip()


def shard_task(terrain, dem, options, k, n, part):
    return run_terrain(
        [terrain, "bake", *dem, *options, "--shard", f"{k}/{n}", "-o", part, "--overwrite"]
    )


def merge_task(terrain, dem, options, parts_dir, out):
    return run_terrain([terrain, "bake", *dem, *options, "--merge", parts_dir, "-o", out])


def is_part(path):
    try:
        with open(os.path.join(path, "part.tsp"), "rb") as f:
            return f.read(8) == b"TSTRPRT\0"
    except OSError:
        return False


def main(argv):
    own, rest = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dem", nargs="*", help="DEM file(s); none with -- --synthetic SIZE")
    ap.add_argument("--shards", type=int, required=True, help="number of shards N")
    ap.add_argument("-o", "--output", required=True, help="the merged store folder")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://HOST:PORT)")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes")
    ap.add_argument("--parts", help="folder of the parts (default: OUTPUT.parts beside it)")
    ap.add_argument("--retries", type=int, default=2, help="retries of a failed shard task")
    ap.add_argument(
        "--terrain",
        default=os.environ.get("TERRAIN_BIN", "terrain"),
        help="the terrain binary (default $TERRAIN_BIN or terrain on PATH)",
    )
    args = ap.parse_args(own)
    if args.shards < 1:
        ap.error("--shards must be at least 1")
    from dask.distributed import Client, LocalCluster, wait

    terrain = os.path.abspath(args.terrain) if os.sep in args.terrain else args.terrain
    dem = [os.path.abspath(d) for d in args.dem]
    out = os.path.abspath(args.output)
    parts_dir = os.path.abspath(args.parts or out.rstrip(os.sep) + ".parts")
    os.makedirs(parts_dir, exist_ok=True)
    n = args.shards

    cluster = None
    if args.scheduler:
        client = Client(args.scheduler)
    else:
        cluster = LocalCluster(
            n_workers=args.workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
        )
        client = Client(cluster)
    try:
        t0 = time.monotonic()
        futures = {}
        for k in range(n):
            part = os.path.join(parts_dir, f"p{k}")
            if is_part(part):
                print(f"shard {k}/{n}: {part} is already published, kept", file=sys.stderr)
                continue
            futures[k] = client.submit(
                shard_task, terrain, dem, rest, k, n, part,
                key=f"terrain-shard-{k}-of-{n}-{os.getpid()}",
                retries=args.retries, pure=False,
            )
        # Every shard runs to its end (a failed one after its retries) before anything else:
        # the published parts stay for the next run, which bakes only the failed shards.
        wait(list(futures.values()))
        failed = [(k, f.exception()) for k, f in futures.items() if f.status == "error"]
        if failed:
            raise RuntimeError(
                f"{len(failed)} of {n} shards failed after {args.retries} retries (run again "
                "to bake only them):\n" + "\n".join(f"shard {k}/{n}: {e}" for k, e in failed)
            )
        merged = client.submit(
            merge_task, terrain, dem, rest, parts_dir, out,
            key=f"terrain-merge-{os.getpid()}", pure=False,
        )
        wall, cpu, stdout = merged.result()
        shard_results = client.gather(list(futures.values()))
        total = time.monotonic() - t0
        shard_cpu = sum(r[1] for r in shard_results)
        print(stdout)
        print(
            f"dask: {len(futures)} of {n} shards baked ({shard_cpu:.1f} s CPU, "
            f"longest {max((r[0] for r in shard_results), default=0):.1f} s), merge {wall:.1f} s "
            f"({cpu:.1f} s CPU), {total:.1f} s wall in all"
        )
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(1)
