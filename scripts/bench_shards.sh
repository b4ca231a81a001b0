#!/usr/bin/env bash
# Sharded bake against the single-process bake, wall and CPU (user+sys, children included):
#   single      terrain bake SRC OPTS -o single
#   4 seq.      terrain bake SRC OPTS --shard K/4 -o parts/pK, K = 0..3 one after the other,
#               then terrain bake SRC OPTS --merge parts -o merged
#   dask        scripts/bake_dask.py SRC --shards 4 --workers 2 (a LocalCluster on this machine)
#   the merge's join of the parts (its blocks-and-index time, from its summary line)
# and checks each result is byte-identical to the single bake.
# Usage: scripts/bench_shards.sh NAME SCRATCH_DIR -- SOURCE_AND_OPTIONS...
# e.g.   scripts/bench_shards.sh synth4k /tmp/x -- --synthetic 4097 --no-pvs
set -euo pipefail
name=$1 dir=$2; shift 3
root="$(cd "$(dirname "$0")/.." && pwd)"
terrain=${TERRAIN_BIN:-$root/target/release/terrain}
py=${PYTHON:-$root/.venv/bin/python}
rm -rf "$dir" && mkdir -p "$dir"
t() { # label, command...: prints "label wall cpu"
    local label=$1; shift
    /usr/bin/time -f "%e %U %S" -o "$dir/time" "$@" >"$dir/$label.log" 2>&1
    awk -v l="$label" '{printf "%-12s wall %7.1f s  cpu %7.1f s\n", l, $1, $2 + $3}' "$dir/time"
}
echo "$name: $* ($(uptime | sed 's/.*load/load/'))"
t single "$terrain" bake "$@" -o "$dir/single"
t shards-seq bash -c 'for k in 0 1 2 3; do "$0" bake "${@:2}" --shard $k/4 -o "$1/parts/p$k" || exit 1; done' \
    "$terrain" "$dir" "$@"
t merge "$terrain" bake "$@" --merge "$dir/parts" -o "$dir/merged"
# The merge's own summary line: its blocks-and-index time (the join), before the tables.
grep -o "[0-9.]* s, [0-9.]* MiB/s" "$dir/merge.log" | sed 's/^/merge: joining the parts (blocks + index) /; s/, .*//'
t dask "$py" "$root/scripts/bake_dask.py" --shards 4 --workers 2 --terrain "$terrain" \
    -o "$dir/dask" --parts "$dir/dask.parts" -- "$@"
diff -r "$dir/single" "$dir/merged" >/dev/null && echo "4 seq. + merge: byte-identical" || echo "4 seq. + merge: DIFFERS"
diff -r "$dir/single" "$dir/dask" >/dev/null && echo "dask: byte-identical" || echo "dask: DIFFERS"
grep -h "^dask:" "$dir/dask.log" || true
echo "($(uptime | sed 's/.*load/load/'))"
