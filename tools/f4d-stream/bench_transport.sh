#!/usr/bin/env bash
# bench_transport.sh F4D_STREAM UDP_LOSS_PROXY STREAM.f4ds [LATENCY_MS...]:
# measures f4d-stream over loopback on this machine (not a test: numbers).
#  1. throughput: the file sent at 2, 4 and 8 times real time and unpaced
#     (--speed 0), with and without AES (passphrase, 16-byte key); Mbit/s
#     until the last ACK (sender) and between the first and last packet handed
#     on (receiver), and whether every packet arrived
#  2. loss: paced in real time through udp_loss_proxy at 1, 5 and 10 % loss
#     (both directions) for each latency window (default 120 and 1000 ms):
#     SRT's retransmissions and drops, our incomplete / missing packets and the
#     decoder's lost / skipped keys. One JSON line per run on stdout.
set -euo pipefail
stream=$1 proxy=$2 file=$3
shift 3
lat=("$@")
[ ${#lat[@]} -gt 0 ] || lat=(120 1000)
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
base=$((40000 + ($$ % 1000) * 16))
port=$base
run() { # run LABEL RX_PARAMS TX_PARAMS SPEED [LOSS]
  local label=$1 rxp=$2 txp=$3 speed=$4 loss=${5:-} rp=$port
  port=$((port + 2))
  "$stream" recv "srt://127.0.0.1:$rp?mode=listener&$rxp" -o "$dir/r.f4ds" --decode --timeout 5000 --quiet \
    > "$dir/r.json" & local r=$!
  local tp=$rp px=
  if [ -n "$loss" ]; then
    tp=$((rp + 1))
    "$proxy" $tp $rp "$loss" 11 > "$dir/p.json" & px=$!
  fi
  sleep 0.3
  "$stream" send "$file" "srt://127.0.0.1:$tp?$txp" --speed "$speed" --quiet > "$dir/s.json" || true
  wait $r || true
  [ -z "$px" ] || { kill $px; wait $px || true; }
  printf '{"run":"%s","send":%s,"recv":%s%s}\n' "$label" "$(cat "$dir/s.json")" "$(cat "$dir/r.json")" \
    "$([ -z "$loss" ] || printf ',"proxy":%s' "$(cat "$dir/p.json")")"
}
for speed in 2 4 8 0; do
  run "speed-$speed-plain" "latency=1000" "latency=1000" $speed
  run "speed-$speed-aes128" "latency=1000&passphrase=bench-passphrase" "latency=1000&passphrase=bench-passphrase" $speed
done
run "realtime-aes128" "passphrase=bench-passphrase" "passphrase=bench-passphrase" 1
for l in "${lat[@]}"; do
  for loss in 0.01 0.05 0.10; do
    run "loss-$loss-latency-$l" "latency=$l&passphrase=bench-passphrase" "latency=$l&passphrase=bench-passphrase" 1 $loss
  done
done
