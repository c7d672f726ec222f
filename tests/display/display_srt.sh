#!/usr/bin/env bash
# display_srt.sh F4D_DISPLAY F4D_STREAM F4D_SCENE F4D_CODEC DIR: f4d-display
# receiving over SRT on loopback (listener, passphrase, 1 s window: ARQ room on a loaded machine) what
# f4d-stream sends in real time: every key decoded, nothing lost or dropped,
# frames shown.
set -euo pipefail
source "$(dirname "$0")/../common/f4d_ports.sh"
disp=$1 stream=$2 scenebin=$3 codec=$4 dir=$5
rm -rf "$dir" && mkdir -p "$dir"
"$scenebin" --preset walk --frames 6 --views 1 --size 96x96 --gaussians 4000 -o "$dir/scene" >/dev/null
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/s.f4ds" --key-rate 10 --intra-every 3 >/dev/null
port=$(f4d_free_ports 26000 2000 1) # this test's own range: see f4d_ports.sh
url="srt://127.0.0.1:$port?mode=listener&latency=1000&passphrase=display-test-secret"
"$disp" --headless --no-status --size 128x96 --fps 30 "$url" > "$dir/disp.json" 2> "$dir/disp.err" &
dpid=$!
trap 'kill $dpid 2>/dev/null || true' EXIT
f4d_wait_udp $port $dpid
"$stream" send "$dir/s.f4ds" "srt://127.0.0.1:$port?latency=1000&passphrase=display-test-secret" --speed 1 --quiet \
  > "$dir/send.json"
wait $dpid || { echo "f4d-display failed"; cat "$dir/disp.err"; exit 1; }
cat "$dir/send.json" "$dir/disp.json"
grep -q '"ok":true' "$dir/send.json"
grep -q '"keys": 6,' "$dir/disp.json"
grep -q '"dropped_packets": 0,' "$dir/disp.json"
grep -q '"lost_packets": 0,' "$dir/disp.json"
frames=$(sed -n 's/.*"frames": \([0-9]*\),.*/\1/p' "$dir/disp.json")
[ "$frames" -ge 6 ] || { echo "only $frames frames shown"; exit 1; }
echo "display_srt: ok"
