#!/usr/bin/env bash
# Streams one store with `stream_bench realtime` (terrain-stream's example: the real-time
# Streamer alone, paced at the flight's frame rate) from local disk, from nginx over HTTP, and
# from nginx behind scripts/delay_proxy.py (50 ms added to every request), the last with and
# without latency-aware Eq. 8 preloading; each remote run with a cold disk cache of its own.
#
#   scripts/bench_remote.sh STORE_DIR [FLIGHT] [CACHE_MIB] [STREAM_BENCH_BINARY]
#
# STORE_DIR is a baked store folder (e.g. `stream_bench bake 4097 8 s4k` writes
# /tmp/terrain-stream-bench/s4k). Needs nginx (Debian's package) and python3. Servers are on
# free ports of 127.0.0.1 and stopped on exit.
set -euo pipefail
store=$(realpath "$1")
flight=${2:-flights/fast_pass.json}
cache_mib=${3:-256}
bin=${4:-target/release/examples/stream_bench}
work=$(mktemp -d /tmp/bench-remote.XXXXXX)
port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
p_nginx=$(port)
p_proxy=$(port)
mkdir -p "$work/logs"
cat > "$work/nginx.conf" <<EOF
daemon off;
master_process off;
worker_processes 1;
pid $work/nginx.pid;
error_log $work/logs/error.log warn;
events { worker_connections 1024; }
http {
  access_log off;
  client_body_temp_path $work/body;
  proxy_temp_path $work/proxy;
  fastcgi_temp_path $work/fastcgi;
  uwsgi_temp_path $work/uwsgi;
  scgi_temp_path $work/scgi;
  server { listen 127.0.0.1:$p_nginx; root $(dirname "$store"); }
}
EOF
nginx -p "$work" -c "$work/nginx.conf" &
ngx=$!
python3 "$(dirname "$0")/delay_proxy.py" "$p_proxy" "$p_nginx" 50 &
proxy=$!
trap 'kill -TERM $ngx $proxy 2>/dev/null; wait $ngx $proxy 2>/dev/null; rm -rf "$work"' EXIT
sleep 1
name=$(basename "$store")
run() {
    echo "### $1"
    shift
    TERRAIN_CACHE_DIR="$work/cache-$RANDOM" "$bin" realtime "$@" | grep -E '^\|'
}
run "local disk" "$store" "$flight" "$cache_mib"
run "nginx" "http://127.0.0.1:$p_nginx/$name" "$flight" "$cache_mib"
run "nginx + 50 ms, latency-aware" "http://127.0.0.1:$p_proxy/$name" "$flight" "$cache_mib"
run "nginx + 50 ms, not latency-aware" "http://127.0.0.1:$p_proxy/$name" "$flight" "$cache_mib" latency_aware=0
