#!/usr/bin/env bash
# One bake, side by side for two `terrain` binaries, alternated (before, after, before, after):
# wall, CPU (user + sys) and peak RSS from /usr/bin/time, the bake's own blocks line (MiB/s of
# f32 input) and its stage summary (wall / CPU seconds per stage, when the binary prints it).
# Then, with SHARDS=1, the same bake as 4 shards run 2 at a time (two cores) and the merge,
# for each binary, with the merged store compared byte for byte with that binary's single bake.
# Usage: scripts/bench_bake.sh BEFORE AFTER SCRATCH_DIR REPS -- SOURCE_AND_OPTIONS...
# e.g.   scripts/bench_bake.sh /tmp/terrain.main target/release/terrain /tmp/bb 2 -- --synthetic 4097 --no-pvs
set -euo pipefail
before=$1 after=$2 dir=$3 reps=$4; shift 5
mkdir -p "$dir"
t() { # label, command...: prints "label wall cpu rss"
    local label=$1; shift
    /usr/bin/time -f "%e %U %S %M" -o "$dir/time" "$@" >"$dir/$label.log" 2>&1
    awk -v l="$label" '{printf "%-22s wall %7.1f s  cpu %7.1f s  peak RSS %5.0f MB\n", l, $1, $2 + $3, $4 / 1024}' "$dir/time"
    grep -h "MiB/s of f32 input\|^stages\|by bands of rows\|with the blocks" "$dir/$label.log" | sed 's/^/    /' | cut -c1-220 || true
}
echo "$* ($(uptime | sed 's/.*load/load/'))"
for r in $(seq 1 "$reps"); do
    for b in before after; do
        bin=$before; [ "$b" = after ] && bin=$after
        rm -rf "$dir/$b-single"
        t "$b-single-$r" "$bin" bake "$@" -o "$dir/$b-single"
    done
done
if [ "${SHARDS:-0}" = 1 ]; then
    for b in before after; do
        bin=$before; [ "$b" = after ] && bin=$after
        rm -rf "$dir/$b-parts" "$dir/$b-merged"
        t "$b-4-shards-2-at-a-time" bash -c '
            "$0" bake "${@:3}" --shard 0/4 -o "$1/p0" >"$1.0.log" 2>&1 & a=$!
            "$0" bake "${@:3}" --shard 1/4 -o "$1/p1" >"$1.1.log" 2>&1 & b=$!
            wait $a && wait $b || exit 1
            "$0" bake "${@:3}" --shard 2/4 -o "$1/p2" >"$1.2.log" 2>&1 & a=$!
            "$0" bake "${@:3}" --shard 3/4 -o "$1/p3" >"$1.3.log" 2>&1 & b=$!
            wait $a && wait $b' "$bin" "$dir/$b-parts" "$dir/$b-parts" "$@"
        t "$b-merge" "$bin" bake "$@" --merge "$dir/$b-parts" -o "$dir/$b-merged"
        diff -r "$dir/$b-single" "$dir/$b-merged" >/dev/null && echo "    $b: merged = single, byte for byte" || echo "    $b: merged DIFFERS from single"
    done
fi
echo "($(uptime | sed 's/.*load/load/'))"
