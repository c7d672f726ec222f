#!/usr/bin/env bash
# transport_relay.sh F4D_STREAM F4D_CODEC F4D_SCENE DIR: one stream through
# Debian's srt-live-transmit, fanned out to two receivers that both get every
# packet and decode every key.
#
# srt-live-transmit (1.5.1 in Debian 12) takes one input and one output URI,
# and its SRT listener output serves one caller; so the fan-out is a relay
# chain in a private network namespace:
#   f4d-stream send --SRT--> relay0 (listener, passphrase A)
#       --UDP multicast 239.255.42.1 on lo-->  relay1 --SRT--> receiver 1
#                                              relay2 --SRT--> receiver 2
# relay1 / relay2 are listeners with passphrase B that the receivers call;
# relay3 serves a third receiver that joins once receiver 1 has the stream's
# start (the 2 s stream sent over 8 s): it must hand on a suffix of the
# stream (complete packets only) and decode from the next intra key on.
# One SRT message stays one UDP datagram across the chain (our chunks are
# <= 1316 bytes, srt-live-transmit moves up to 1456 per read).
# Needs a network namespace (root, or an unprivileged user namespace) for the
# multicast route on lo: exit 77 (skipped) without one.
set -euo pipefail
source "$(dirname "$0")/../../common/f4d_ports.sh" # f4d_wait_udp
stream=$1 codec=$2 scenebin=$3 dir=$4
if ! command -v srt-live-transmit >/dev/null; then
  echo "[  SKIP    ] transport_relay: srt-live-transmit is absent (Debian package srt-tools)"; exit 77
fi
if [ -z "${F4D_IN_NETNS:-}" ]; then
  for u in "unshare -n" "unshare -rn"; do
    if $u true 2>/dev/null; then
      exec $u env F4D_IN_NETNS=1 bash "$0" "$@"
    fi
  done
  echo "[  SKIP    ] transport_relay: cannot make a private network namespace (unshare -n / -rn failed)"; exit 77
fi
ip link set lo up
ip link set lo multicast on
ip route add 239.0.0.0/8 dev lo

rm -rf "$dir" && mkdir -p "$dir"
"$scenebin" --preset walk --frames 20 --views 1 --size 64x64 --gaussians 3000 -o "$dir/scene" >/dev/null
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/s.f4ds" --key-rate 10 --intra-every 5 >/dev/null

pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap cleanup EXIT
A="passphrase=relay-in-secret&latency=200" B="passphrase=relay-out-secret&latency=200"
# Events, not sleeps (a loaded machine outlasts any sleep): each step waits
# for what the next one needs. The output relays log each caller they accept
# ("Accepted SRT target connection": not -q).
srt-live-transmit -q "srt://:7000?mode=listener&$A" "udp://239.255.42.1:7100" 2>"$dir/relay0.log" & pids+=($!)
for k in 1 2 3; do
  srt-live-transmit "udp://@239.255.42.1:7100" "srt://:700$k?mode=listener&$B" 2>"$dir/relay$k.log" & pids+=($!)
done
for k in 0 1 2 3; do f4d_wait_udp 700$k "${pids[$k]}"; done
# accepted(K PID): relay K logged the caller PID's connection
accepted() {
  local i
  for ((i = 0; i < 1200; i++)); do
    grep -q "Accepted SRT target connection" "$dir/relay$1.log" && return 0
    kill -0 "$2" 2>/dev/null || break
    sleep 0.05
  done
  echo "relay $1 accepted no receiver"; cat "$dir/relay$1.log"; return 1
}
"$stream" recv "srt://127.0.0.1:7001?$B&timeout=30000" -o "$dir/r1.f4ds" --decode --timeout 60000 --quiet \
  > "$dir/r1.json" 2>"$dir/r1.err" & r1=$!
"$stream" recv "srt://127.0.0.1:7002?$B&timeout=30000" -o "$dir/r2.f4ds" --decode --timeout 60000 --quiet \
  > "$dir/r2.json" 2>"$dir/r2.err" & r2=$!
accepted 1 $r1
accepted 2 $r2
# 2 s of stream sent over 8 s (--speed 0.25): the late receiver joins once r1
# has the stream's start, and has seconds to connect before its end
"$stream" send "$dir/s.f4ds" "srt://127.0.0.1:7000?$A&timeout=30000" --speed 0.25 --quiet > "$dir/send.json" &
s=$!
for ((i = 0; i < 1200; i++)); do
  [ -s "$dir/r1.f4ds" ] && break
  kill -0 $s 2>/dev/null || break
  sleep 0.05
done
"$stream" recv "srt://127.0.0.1:7003?$B&timeout=30000" -o "$dir/r3.f4ds" --decode --timeout 60000 --quiet \
  > "$dir/r3.json" 2>"$dir/r3.err" & r3=$!
rc=0
wait $s || rc=1
wait $r1 || rc=1
wait $r2 || rc=1
wait $r3 || rc=1
cat "$dir/send.json" "$dir/r1.json" "$dir/r2.json" "$dir/r3.json" "$dir/r1.err" "$dir/r2.err" "$dir/r3.err"
[ $rc -eq 0 ] || { echo "a receiver failed"; cat "$dir"/relay*.log; exit 1; }
for r in r1 r2; do
  cmp "$dir/s.f4ds" "$dir/$r.f4ds"   # every packet, byte for byte
  grep -q '"ended":"end"' "$dir/$r.json"
  grep -q '"decoded":{"keys":20,' "$dir/$r.json"
done
# the late receiver: a suffix of the stream, some keys but not all
n3=$(stat -c %s "$dir/r3.f4ds")
[ "$n3" -gt 0 ] && [ "$n3" -lt "$(stat -c %s "$dir/s.f4ds")" ]
cmp <(tail -c "$n3" "$dir/s.f4ds") "$dir/r3.f4ds"
grep -q '"ended":"end"' "$dir/r3.json"
keys3=$(sed -n 's/.*"decoded":{"keys":\([0-9]*\),.*/\1/p' "$dir/r3.json")
[ "$keys3" -ge 1 ] && [ "$keys3" -lt 20 ] || { echo "late receiver decoded $keys3 keys"; exit 1; }
echo "transport_relay: two receivers got every packet through srt-live-transmit; one joining late decoded $keys3 keys"
