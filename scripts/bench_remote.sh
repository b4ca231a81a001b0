#!/usr/bin/env bash
# Streams one store with `stream_bench realtime` (terrain-stream's example: the real-time
# Streamer alone, paced at the flight's frame rate, no frame ever waiting after the first) from
# local disk, from nginx over HTTP serving the store's folder in place (no copy), and from nginx
# behind scripts/delay_proxy.py (DELAY_MS, default 50, added to every request), the last with
# and without latency-aware Eq. 8 preloading; with S3=1 also from a local SeaweedFS S3 server
# (the store uploaded to it first: needs the store's size free on disk). Each remote run has a
# cold disk cache of its own. Prints one Markdown table, a row per run (bench/remote/README.md).
#
#   scripts/bench_remote.sh STORE_DIR [FLIGHT] [CACHE_MIB] [SETTING...]
#
# STORE_DIR is a baked store folder (e.g. /work/stores/big32k, or `stream_bench bake 4097 8 s4k`
# writes /tmp/terrain-stream-bench/s4k). FLIGHT defaults to flights/fast_pass.json, CACHE_MIB
# to 1024 (the app's stream cache). SETTINGs are `stream_bench realtime`'s key=value settings
# for every run (default `in_flight=2048 lookahead=2`: the app's streamer settings). Environment:
# BIN (default target/release/examples/stream_bench: `cargo build --release -p terrain-stream
# --example stream_bench`), DELAY_MS, S3=1, WEED (default .venv/bin/weed, from
# scripts/requirements-s3.txt), RUNS (a space-separated list of: local nginx delay-aware
# delay-unaware s3-aware s3-unaware, each optionally with settings of its own,
# `delay-aware:threads=32,lookahead=3`; default all but the s3 ones unless S3=1).
#
# Needs nginx (Debian's package), python3 and curl. Servers listen on free ports of 127.0.0.1
# and are stopped on exit; their folders (the uploaded store, the disk caches) are removed.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
store=$(realpath "$1")
flight=${2:-flights/fast_pass.json}
cache_mib=${3:-1024}
shift $(($# < 3 ? $# : 3))
settings=("$@")
[ ${#settings[@]} -gt 0 ] || settings=(in_flight=2048 lookahead=2)
bin=${BIN:-target/release/examples/stream_bench}
delay_ms=${DELAY_MS:-50}
weed=${WEED:-$here/../.venv/bin/weed}
runs=${RUNS:-local nginx delay-aware delay-unaware}
if [ "${S3:-0}" = 1 ] && [ -z "${RUNS:-}" ]; then runs="$runs s3-aware s3-unaware"; fi
[ -x "$bin" ] || { echo "$bin is missing: cargo build --release -p terrain-stream --example stream_bench" >&2; exit 1; }
[ -f "$store/index.tsi" ] || { echo "$store: no index.tsi, not a store folder" >&2; exit 1; }
work=$(mktemp -d /tmp/bench-remote.XXXXXX)
# Free ports below 55536 (weed puts its gRPC listeners at a port + 10000).
ports() { python3 -c '
import socket, sys
held, out = [], []
while len(out) < int(sys.argv[1]):
    s = socket.socket(); s.bind(("127.0.0.1", 0)); held.append(s)
    p = s.getsockname()[1]
    if p < 55536 and p not in out: out.append(p)
print(" ".join(map(str, out)))' "$1"; }
read -r p_nginx p_proxy <<<"$(ports 2)"
mkdir -p "$work/logs"
cat > "$work/nginx.conf" <<EOF
daemon off;
master_process off;
worker_processes 1;
pid $work/nginx.pid;
error_log $work/logs/error.log warn;
events { worker_connections 1024; }
http {
  access_log $work/logs/access.log;
  keepalive_requests 100000;
  client_body_temp_path $work/body;
  proxy_temp_path $work/proxy;
  fastcgi_temp_path $work/fastcgi;
  uwsgi_temp_path $work/uwsgi;
  scgi_temp_path $work/scgi;
  server { listen 127.0.0.1:$p_nginx; root $(dirname "$store"); }
}
EOF
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
    for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
    rm -rf "$work"
}
trap cleanup EXIT
nginx -p "$work" -c "$work/nginx.conf" &
pids+=($!)
python3 "$here/delay_proxy.py" "$p_proxy" "$p_nginx" "$delay_ms" &
pids+=($!)
wait_port() {
    for _ in $(seq 300); do
        if (echo >"/dev/tcp/127.0.0.1/$1") 2>/dev/null; then return 0; fi
        sleep 0.2
    done
    echo "$2 did not listen on 127.0.0.1:$1" >&2
    exit 1
}
wait_port "$p_nginx" nginx
wait_port "$p_proxy" delay_proxy.py
name=$(basename "$store")

s3_env=()
start_s3() {
    [ -x "$weed" ] || { echo "$weed is missing: .venv/bin/pip install -r scripts/requirements-s3.txt" >&2; exit 1; }
    local p
    read -r -a p <<<"$(ports 8)"
    mkdir -p "$work/weed"
    # As terrain-app/tests/remote_store.rs starts it: every port given, Iceberg/Lance off.
    "$weed" server -ip=127.0.0.1 -ip.bind=127.0.0.1 -dir="$work/weed" \
        -master.port="${p[0]}" -master.port.grpc="${p[4]}" -volume.port="${p[1]}" \
        -volume.port.grpc="${p[5]}" -filer.port="${p[2]}" -filer.port.grpc="${p[6]}" -filer \
        -s3 -s3.port="${p[3]}" -s3.port.grpc="${p[7]}" -s3.port.iceberg=0 -s3.port.lance=0 \
        -master.telemetry=false -volume.max=64 -master.volumeSizeLimitMB=1024 \
        >"$work/logs/weed.log" 2>&1 &
    pids+=($!)
    wait_port "${p[3]}" "weed server -s3"
    s3_env=(AWS_ENDPOINT_URL="http://127.0.0.1:${p[3]}" AWS_ACCESS_KEY_ID=bench
        AWS_SECRET_ACCESS_KEY=bench AWS_REGION=us-east-1 AWS_ALLOW_HTTP=true)
    for _ in $(seq 150); do
        curl -sf -X PUT "http://127.0.0.1:${p[3]}/bucket" >/dev/null && break
        sleep 0.2
    done
    echo "uploading $store to s3://bucket/$name (SeaweedFS, $(df -h --output=avail /tmp | tail -1 | tr -d ' ') free)" >&2
    env "${s3_env[@]}" "$bin" upload "$store" "s3://bucket/$name" >&2
}

header_done=0
run() {
    local label=$1 location=$2
    shift 2
    local gets_before gets load out
    gets_before=$(wc -l <"$work/logs/access.log" 2>/dev/null || echo 0)
    load=$(cut -d' ' -f1 /proc/loadavg)
    echo "running: $label ($location ${settings[*]} $*)" >&2
    out=$(env "${s3_env[@]}" TERRAIN_CACHE_DIR="$work/cache-$label" \
        "$bin" realtime "$location" "$flight" "$cache_mib" "${settings[@]}" ground="$store" "$@" | grep -E '^\|')
    case $location in
        http://*) gets=$(($(wc -l <"$work/logs/access.log") - gets_before)) ;;
        *) gets=- ;;
    esac
    if [ "$header_done" = 0 ]; then
        sed -n 1p <<<"$out" | sed 's/^|/| run | load avg 1 min | HTTP GETs (nginx log) |/'
        sed -n 2p <<<"$out" | sed 's/^|/|---|---:|---:|/'
        header_done=1
    fi
    sed -n 3p <<<"$out" | sed "s/^|/| $label | $load | $gets |/"
}

for spec in $runs; do
    # RUN or RUN:key=value,key=value (settings of that run alone, after the others).
    r=${spec%%:*}
    extra=()
    more=""
    if [ "$r" != "$spec" ]; then
        IFS=, read -r -a extra <<<"${spec#*:}"
        more=", ${spec#*:}"
    fi
    case $r in
        local) run "local disk$more" "$store" "${extra[@]}" ;;
        nginx) run "nginx$more" "http://127.0.0.1:$p_nginx/$name" "${extra[@]}" ;;
        delay-aware) run "nginx + $delay_ms ms, latency-aware$more" "http://127.0.0.1:$p_proxy/$name" latency_aware=1 "${extra[@]}" ;;
        delay-unaware) run "nginx + $delay_ms ms, not latency-aware$more" "http://127.0.0.1:$p_proxy/$name" latency_aware=0 "${extra[@]}" ;;
        s3-aware | s3-unaware)
            [ ${#s3_env[@]} -gt 0 ] || start_s3
            aware=1
            [ "$r" = s3-unaware ] && aware=0
            run "SeaweedFS S3$([ $aware = 1 ] && echo ", latency-aware" || echo ", not latency-aware")$more" "s3://bucket/$name" latency_aware=$aware "${extra[@]}"
            ;;
        *) echo "unknown run $r (local nginx delay-aware delay-unaware s3-aware s3-unaware)" >&2; exit 1 ;;
    esac
done
