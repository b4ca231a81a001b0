#!/usr/bin/env bash
# Our greedy Delaunay mesher against fogleman/hmm, delatin and @mapbox/martini, side by side
# (issue 16's per-tile meshing target): triangles, measured max error, build time (median).
#
#   bench/mesh/compare.sh [DEM VERTICAL_SCALE SPACING_M] [RUNS] [BOUNDS...]
#   bench/mesh/compare.sh                  # Puget Sound 1k, 0.1, 160 m, 3 runs, 1 4 16 m
#
# Peers live in bench/mesh/peers (git-ignored; their code is never committed):
# - hmm: its source in bench/mesh/peers/hmm (`git clone https://github.com/fogleman/hmm`
#   there; needs Debian's libglm-dev), its triangulator compiled with hmm's own flags (-O3
#   -flto -march=native) and our timing driver bench/mesh/hmm_time.cpp (thread CPU time
#   around Run + Points + Triangles, as hmm's "triangulating" step). Without the source it
#   is skipped with a message. Ours is built with `-C target-cpu=native` to match (in
#   target/native).
# - delatin 0.2.0 and @mapbox/martini 0.2.0: installed here from the npm registry; if npm
#   cannot reach it they are skipped with a message.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
peers="$root/bench/mesh/peers"
data="${TERRAIN_DATA:-$root/../shared/data}"
dem="${1:-$data/puget_sound/ps_height_1k.png}"
scale="${2:-0.1}"
spacing="${3:-160}"
runs="${4:-3}"
shift $(( $# < 4 ? $# : 4 ))
bounds=("$@")
[ ${#bounds[@]} -gt 0 ] || bounds=(1 4 16)
mkdir -p "$peers"

if [ -f "$peers/hmm/src/triangulator.cpp" ]; then
  if [ ! -x "$peers/hmm_time" ]; then
    echo "building hmm's triangulator with bench/mesh/hmm_time.cpp into $peers/hmm_time" >&2
    (cd "$peers/hmm" && g++ -std=c++11 -O3 -flto -march=native -DNDEBUG -Isrc -w \
      -o "$peers/hmm_time" "$root/bench/mesh/hmm_time.cpp" src/heightmap.cpp \
      src/triangulator.cpp src/base.cpp src/blur.cpp) \
      || echo "hmm: build failed (libglm-dev installed?); skipped" >&2
  fi
else
  echo "hmm: no source in $peers/hmm (git clone https://github.com/fogleman/hmm there); skipped" >&2
fi
if [ ! -d "$peers/node_modules/delatin" ] || [ ! -d "$peers/node_modules/@mapbox/martini" ]; then
  if command -v npm >/dev/null; then
    [ -f "$peers/package.json" ] || echo '{"private": true}' > "$peers/package.json"
    (cd "$peers" && npm install --no-audit --no-fund delatin@0.2.0 @mapbox/martini@0.2.0 >/dev/null) \
      || echo "delatin, martini: npm install failed; skipped" >&2
  else
    echo "delatin, martini: no npm; skipped" >&2
  fi
fi

cd "$root"
# Ours compiled for this CPU too, as hmm is (`-march=native`): like for like. Its own target
# folder, so the portable release build in target/release is left as it is.
RUSTFLAGS="${RUSTFLAGS:-} -C target-cpu=native" CARGO_TARGET_DIR="$root/target/native" \
  cargo build --release -p terrain-core --example mesh_compare >&2
"$root/target/native/release/examples/mesh_compare" "$dem" "$scale" "$spacing" "$peers" "$runs" "${bounds[@]}"
