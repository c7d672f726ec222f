# f4d_ports.sh: loopback UDP ports for the test scripts that ctest runs side
# by side (ctest -j), sourced by them. Every test that listens on loopback owns
# a range of its own, below the kernel's ephemeral ports (32768 and up, where
# SRT callers bind their sockets), so no two tests ever pick the same port:
#
#   20000..23999  stream/transport   (test_transport.c, f4d_test_udp_ports)
#   24000..25999  stream/transport_cli
#   26000..27999  display/srt
#   28000..29999  app/run_srt        (test_run.c, f4d_test_udp_ports)
#
# (stream/transport_relay and stream/transport_netem run in network
# namespaces of their own: fixed ports there.)
#
#   base=$(f4d_free_ports FIRST COUNT N)   # N consecutive ports free now
#   f4d_wait_udp PORT PID [SECONDS]        # until PORT is bound (PID alive)

# The UDP ports bound on this machine now, one per line (decimal).
f4d_bound_udp() {
  local sl local rest
  cat /proc/net/udp /proc/net/udp6 2>/dev/null | while read -r sl local rest; do
    [ "$sl" = sl ] && continue
    echo $((16#${local##*:}))
  done
}

# Prints a base b in [FIRST, FIRST + COUNT) with b .. b+N-1 all unbound, the
# search starting at an offset from this shell's pid (two runs of one test
# start apart); fails when the range is full.
f4d_free_ports() {
  local first=$1 count=$2 n=$3 slots i k base busy bound
  slots=$((count / n))
  bound=" $(f4d_bound_udp | tr '\n' ' ') "
  for ((i = 0; i < slots; i++)); do
    base=$((first + (($$ + i) % slots) * n))
    busy=0
    for ((k = 0; k < n; k++)); do
      case $bound in *" $((base + k)) "*) busy=1; break ;; esac
    done
    [ $busy -eq 0 ] && { echo $base; return 0; }
  done
  echo "f4d_free_ports: no $n free ports in $first..$((first + count - 1))" >&2
  return 1
}

# Waits until something binds UDP PORT: the event a caller needs before it
# dials a listener another process opens (rather than a sleep that a loaded
# machine outlasts). Fails when PID exits first or after SECONDS (default 60).
f4d_wait_udp() {
  local port=$1 pid=$2 secs=${3:-60} i
  for ((i = 0; i < secs * 20; i++)); do
    f4d_bound_udp | grep -qx "$port" && return 0
    kill -0 "$pid" 2>/dev/null || { echo "f4d_wait_udp: process $pid exited before port $port was bound" >&2; return 1; }
    sleep 0.05
  done
  echo "f4d_wait_udp: nothing bound port $port within $secs s" >&2
  return 1
}
