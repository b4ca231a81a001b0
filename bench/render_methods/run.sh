#!/usr/bin/env bash
# Frame time and triangles of every LOD method on Puget Sound 1k from five fixed cameras, six
# frames each (frame 1 tessellates and JIT-compiles shaders; frames 2-6 reuse the tessellation),
# on Vulkan (lavapipe here) and GL (llvmpipe), 1280x720. Writes per-run JSON to $OUT and prints
# the Markdown table kept in results.md. Run from the workspace root after
# `cargo build --release -p terrain-app`; needs ../shared/data.
set -eu
OUT=${OUT:-target/bench-render-methods}
mkdir -p "$OUT"
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/terrain-xdg-$UID}
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
T=./target/release/terrain
DEM=(../shared/data/puget_sound/ps_height_1k.png --vertical-scale 0.1 --spacing 160)
# x,y,z (metres from the south-west sample), yaw, pitch: low oblique, low north, high oblique,
# straight down from 40 km, grazing.
CAMS=("20000,20000,3000,45,-15" "80000,30000,2500,0,-10" "120000,120000,6000,225,-25" "82000,82000,40000,0,-90" "10000,150000,1500,135,-5")
METHODS=(uniform pvps-a pvps-b pvps-c dss-1 dss-2)
for backend in vulkan gl; do
  for m in "${METHODS[@]}"; do
    for k in "${!CAMS[@]}"; do
      TERRAIN_GPU_BACKEND=$backend $T render "${DEM[@]}" --method "$m" --camera "${CAMS[$k]}" \
        --frames 6 --size 1280x720 --stats-json "$OUT/${backend}_${m}_$k.json" \
        -o "$OUT/${backend}_${m}_$k.png" > /dev/null
    done
  done
done
python3 - "$OUT" <<'PY'
import json, os, statistics as st, sys
out = sys.argv[1]
print("| backend | method | triangles, median (min-max) | selection ms | first frame ms | frame ms (2-6) | draw pass ms |")
print("|---|---|---|---|---|---|---|")
for backend in ["vulkan", "gl"]:
    for m in ["uniform", "pvps-a", "pvps-b", "pvps-c", "dss-1", "dss-2"]:
        tri, sel, first, wall, draw = [], [], [], [], []
        for k in range(5):
            fr = json.load(open(os.path.join(out, f"{backend}_{m}_{k}.json")))["frames"]
            tri.append(fr[0]["triangles"]); sel.append(st.median(f["selection_ms"] for f in fr))
            first.append(fr[0]["wall_ms"]); wall.append(st.median(f["wall_ms"] for f in fr[1:]))
            if fr[1]["draw_pass_ms"] is not None:
                draw.append(st.median(f["draw_pass_ms"] for f in fr[1:]))
        d = f"{st.median(draw):.0f}" if draw else "n/a"
        print(f"| {backend} | {m} | {st.median(tri):,.0f} ({min(tri):,}-{max(tri):,}) | {st.median(sel):.2f} "
              f"| {st.median(first):.0f} | {st.median(wall):.0f} | {d} |")
PY
