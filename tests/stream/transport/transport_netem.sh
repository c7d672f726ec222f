#!/usr/bin/env bash
# transport_netem.sh F4D_STREAM F4D_CODEC F4D_SCENE DIR: f4d-stream through
# kernel-made loss: a private network namespace whose lo has `tc qdisc netem
# loss 5% delay 5ms` (every datagram, both ways; 10 ms RTT), a 1 s window:
# SRT's ARQ recovers every packet. The same check as the loss proxy's in
# transport_cli.sh, with the kernel's netem instead of the user-space relay.
# Exit 77 (skipped) without a network namespace or without sch_netem (this
# development VM's kernel has none: "Specified qdisc kind is unknown"), so it
# is labelled machine-dependent; not exercised here.
set -euo pipefail
source "$(dirname "$0")/../../common/f4d_ports.sh" # f4d_wait_udp
stream=$1 codec=$2 scenebin=$3 dir=$4
if [ -z "${F4D_IN_NETNS:-}" ]; then
  for u in "unshare -n" "unshare -rn"; do
    if $u true 2>/dev/null; then
      exec $u env F4D_IN_NETNS=1 bash "$0" "$@"
    fi
  done
  echo "[  SKIP    ] transport_netem: cannot make a private network namespace (unshare -n / -rn failed)"; exit 77
fi
ip link set lo up
if ! why=$(tc qdisc add dev lo root netem loss 5% delay 5ms 2>&1); then
  echo "[  SKIP    ] transport_netem: tc netem is not available (kernel without sch_netem?): $why"; exit 77
fi
rm -rf "$dir" && mkdir -p "$dir"
"$scenebin" --preset walk --frames 20 --views 1 --size 64x64 --gaussians 3000 -o "$dir/scene" >/dev/null
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/s.f4ds" --key-rate 10 --intra-every 5 >/dev/null
P="passphrase=netem-test-secret&latency=1000&timeout=5000"
"$stream" recv "srt://127.0.0.1:7200?mode=listener&$P" -o "$dir/r.f4ds" --decode --timeout 60000 --quiet \
  > "$dir/r.json" & r=$!
f4d_wait_udp 7200 $r
"$stream" send "$dir/s.f4ds" "srt://127.0.0.1:7200?$P" --quiet > "$dir/send.json"
wait $r
cat "$dir/send.json" "$dir/r.json"
cmp "$dir/s.f4ds" "$dir/r.f4ds"
grep -q '"decoded":{"keys":20,' "$dir/r.json"
if grep -q '"retrans":0,' "$dir/send.json"; then echo "no retransmission through 5 % netem loss"; exit 1; fi
echo "transport_netem: every packet through netem loss"
