#!/usr/bin/env bash
# transport_cli.sh F4D_STREAM F4D_CODEC F4D_SCENE UDP_LOSS_PROXY DIR: f4d-stream
# over loopback: send -> recv with a passphrase (the received file equals the
# sent one), the same through 5 % loss with a 1 s window (all recovered), a
# wrong passphrase, an unreachable peer and a bad URL fail with a clear
# message, file: URLs copy, and the JSON summaries carry the counters.
set -euo pipefail
source "$(dirname "$0")/../../common/f4d_ports.sh"
stream=$1 codec=$2 scenebin=$3 proxy=$4 dir=$5
rm -rf "$dir" && mkdir -p "$dir"
"$scenebin" --preset walk --frames 20 --views 1 --size 64x64 --gaussians 3000 -o "$dir/scene" >/dev/null
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/s.f4ds" --key-rate 10 --intra-every 5 >/dev/null
base=$(f4d_free_ports 24000 2000 5) # this test's own range: see f4d_ports.sh
P="passphrase=cli-test-secret"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap cleanup EXIT

# 1. listener receiver, caller sender, passphrase; live status lines on stderr
"$stream" recv "srt://127.0.0.1:$base?mode=listener&$P" -o "$dir/r.f4ds" --decode --timeout 60000 --status-ms 300 \
  > "$dir/r.json" 2>"$dir/r.err" & r=$!
pids+=($r)
f4d_wait_udp $base $r
"$stream" send "$dir/s.f4ds" "srt://127.0.0.1:$base?$P" --speed 2 --status-ms 300 > "$dir/send.json" 2>"$dir/send.err"
wait $r
cat "$dir/send.json" "$dir/r.json"
cmp "$dir/s.f4ds" "$dir/r.f4ds"
grep -q '"decoded":{"keys":20,' "$dir/r.json"
grep -q '"ok":true' "$dir/send.json"
grep -q 'Mbit/s  srt: sent' "$dir/send.err"
grep -q 'Mbit/s  srt: sent' "$dir/r.err"

# 2. through the loss proxy: 5 % of the datagrams both ways, 1 s window
"$stream" recv "srt://127.0.0.1:$((base + 1))?mode=listener&$P&latency=1000" -o "$dir/l.f4ds" --decode \
  --timeout 60000 --quiet > "$dir/l.json" & r=$!
pids+=($r)
"$proxy" $((base + 2)) $((base + 1)) 0.05 7 > "$dir/proxy.json" & px=$!
pids+=($px)
f4d_wait_udp $((base + 1)) $r
f4d_wait_udp $((base + 2)) $px
"$stream" send "$dir/s.f4ds" "srt://127.0.0.1:$((base + 2))?$P&latency=1000" --speed 2 --quiet > "$dir/lsend.json"
wait $r
kill $px && wait $px || true
cat "$dir/lsend.json" "$dir/l.json" "$dir/proxy.json"
cmp "$dir/s.f4ds" "$dir/l.f4ds"
grep -q '"decoded":{"keys":20,' "$dir/l.json"
if grep -q '"dropped_fwd":0,' "$dir/proxy.json"; then echo "the proxy dropped nothing"; exit 1; fi
if grep -q '"retrans":0,' "$dir/lsend.json"; then echo "no retransmission through 5 % loss"; exit 1; fi

# 3. clear errors
# (the receiver's timeout only bounds a hang: it is stopped once the sender failed)
"$stream" recv "srt://127.0.0.1:$((base + 3))?mode=listener&$P" -o "$dir/w.f4ds" --timeout 60000 --quiet \
  > /dev/null 2>&1 & r=$!
pids+=($r)
f4d_wait_udp $((base + 3)) $r
if "$stream" send "$dir/s.f4ds" "srt://127.0.0.1:$((base + 3))?passphrase=not-the-secret" 2>"$dir/e1.txt"; then
  echo "wrong passphrase accepted"; exit 1; fi
grep -q "wrong passphrase" "$dir/e1.txt"
kill $r 2>/dev/null || true
wait $r || true
if "$stream" send "$dir/s.f4ds" "srt://127.0.0.1:$((base + 4))?timeout=300" 2>"$dir/e2.txt"; then exit 1; fi
grep -q "no SRT peer answered within 300 ms" "$dir/e2.txt"
if "$stream" recv "srt://127.0.0.1:$((base + 4))?latency=fast" -o "$dir/x.f4ds" 2>"$dir/e3.txt"; then exit 1; fi
grep -q "latency 'fast'" "$dir/e3.txt"
if "$stream" send "$dir/nonexistent.f4ds" "file:$dir/x.f4ds" 2>"$dir/e4.txt"; then exit 1; fi
grep -q "nonexistent.f4ds" "$dir/e4.txt"

# 4. file: URLs
"$stream" send "$dir/s.f4ds" "file:$dir/copy.f4ds" --speed 0 --quiet > /dev/null
cmp "$dir/s.f4ds" "$dir/copy.f4ds"
"$stream" recv "file:$dir/copy.f4ds" -o "$dir/copy2.f4ds" --decode --quiet > "$dir/f.json"
cmp "$dir/s.f4ds" "$dir/copy2.f4ds"
grep -q '"ended":"end"' "$dir/f.json"
echo "transport_cli: ok"
