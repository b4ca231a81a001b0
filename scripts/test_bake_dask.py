#!/usr/bin/env python3
"""The Dask driver end to end: a LocalCluster of 3 worker processes on 127.0.0.1 (started by
the test), a 4-shard bake of a real DEM with voids through `scripts/bake_dask.py`, and the
merged store compared file by file, byte for byte, with a single-process `terrain bake` of the
same DEM and options (a negative control shows the comparison sees one changed byte). Then a
failing shard: a part folder blocked by a file makes the shard fail, the driver's retries fail
too and it exits non-zero naming the shard, and a second run (after the block is removed)
bakes that shard alone, keeping the others.

Run by .ci/run with the virtualenv's Python (`python -m unittest scripts/test_bake_dask.py`);
the `terrain` binary is $TERRAIN_BIN (default target/debug/terrain, built by cargo test), the
DEMs are in $TERRAIN_DATA (default ../shared/data).
"""

import os
import shutil
import subprocess
import sys
import tempfile
import unittest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TERRAIN = os.environ.get("TERRAIN_BIN", os.path.join(ROOT, "target", "debug", "terrain"))
DATA = os.environ.get("TERRAIN_DATA", os.path.join(ROOT, "..", "shared", "data"))
DEM = os.path.join(DATA, "crater_lake", "craterlake-elev-16bit-30m.tif")
# 429 x 279 samples in blocks of 64 cells: 7 x 5 blocks. Every table, the PVS at a small size.
OPTIONS = ["--nodata", "-32767", "--block-k", "6", "--pvs-cells", "4", "--pvs-floors", "1"]


def files(d):
    out = {}
    for root, _, names in os.walk(d):
        for n in names:
            p = os.path.join(root, n)
            with open(p, "rb") as f:
                out[os.path.relpath(p, d)] = f.read()
    return out


def first_difference(a, b):
    fa, fb = files(a), files(b)
    if sorted(fa) != sorted(fb):
        return f"file names differ: {sorted(set(fa) ^ set(fb))}"
    return next((n for n in sorted(fa) if fa[n] != fb[n]), None)


class DaskBake(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        assert os.path.exists(TERRAIN), f"no terrain binary at {TERRAIN} (set TERRAIN_BIN)"
        assert os.path.exists(DEM), f"test data {DEM} is missing (set TERRAIN_DATA)"
        cls.tmp = tempfile.mkdtemp(prefix="terrain-dask-")
        cls.single = os.path.join(cls.tmp, "single")
        subprocess.run([TERRAIN, "bake", DEM, *OPTIONS, "-o", cls.single], check=True,
                       capture_output=True)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def driver(self, out, parts, extra=()):
        cmd = [sys.executable, os.path.join(ROOT, "scripts", "bake_dask.py"), DEM,
               "--shards", "4", "--workers", "3", "--retries", "1", "--terrain", TERRAIN,
               "-o", out, "--parts", parts, *extra, "--", *OPTIONS]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=900)

    def test_a_4_shard_dask_bake_is_the_single_bake_byte_for_byte(self):
        out, parts = os.path.join(self.tmp, "dask"), os.path.join(self.tmp, "dask.parts")
        r = self.driver(out, parts)
        self.assertEqual(r.returncode, 0, r.stderr[-3000:])
        self.assertIn("4 of 4 shards baked", r.stdout)
        self.assertEqual(sorted(os.listdir(parts)), ["p0", "p1", "p2", "p3"])
        names = files(out)
        for table in ["index.tsi", "roughness.bin", "geomip.bin", "dss_errors.bin", "pvs.bin"]:
            self.assertIn(table, names)
        self.assertGreater(len([n for n in names if n.startswith("blocks")]), 30)
        self.assertIsNone(first_difference(self.single, out))
        # Negative control: one byte of one block file changed shows.
        copy = os.path.join(self.tmp, "control")
        shutil.copytree(out, copy)
        block = os.path.join(copy, "blocks", sorted(os.listdir(os.path.join(copy, "blocks")))[7])
        with open(block, "r+b") as f:
            f.seek(40)
            b = f.read(1)
            f.seek(40)
            f.write(bytes([b[0] ^ 1]))
        self.assertIsNotNone(first_difference(self.single, copy))

    def test_a_failing_shard_fails_the_run_and_is_baked_alone_by_the_next(self):
        out, parts = os.path.join(self.tmp, "retry"), os.path.join(self.tmp, "retry.parts")
        os.makedirs(parts)
        # Shard 2's part path is a file: `terrain` refuses to replace it, on every retry.
        blocker = os.path.join(parts, "p2")
        with open(blocker, "w") as f:
            f.write("not a part")
        r = self.driver(out, parts)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn("--shard 2/4", r.stderr)
        self.assertFalse(os.path.exists(out))
        published = sorted(p for p in os.listdir(parts) if p != "p2")
        self.assertEqual(published, ["p0", "p1", "p3"])
        before = {p: os.stat(os.path.join(parts, p, "part.tsp")).st_mtime_ns for p in published}
        os.remove(blocker)
        r = self.driver(out, parts)
        self.assertEqual(r.returncode, 0, r.stderr[-3000:])
        self.assertIn("1 of 4 shards baked", r.stdout)
        after = {p: os.stat(os.path.join(parts, p, "part.tsp")).st_mtime_ns for p in published}
        self.assertEqual(before, after, "the published parts were kept as they were")
        self.assertIsNone(first_difference(self.single, out))


if __name__ == "__main__":
    unittest.main()
