#!/usr/bin/env bash
# The main job on the simulated board: installs what is missing, builds, then
# runs the appliance (`forge4d run`) on the simulated 4-camera rig
# (board/sim-4cam.json, the synthetic 'walk' scene): capture -> take on disk,
# key-frame inference through the Forge4D sequence (state, motion) -> scene
# budget -> stream file, with f4d-display attached live (headless, following
# the stream file as it is written, paced at 30 fps, timing every key from its
# trigger to the refresh that shows it); then shows the stream from a camera
# the rig does not have beside the ground-truth render of the same view and
# time.
# Outputs land in out/ (override with OUT=DIR):
#   take/          the recorded take (verified)
#   stream.f4ds    the 4D Gaussian stream
#   novel.gif      left: the stream from the novel camera, right: ground truth
#   novel.png      the last pair; novel.json per-key PSNR
#   run.json       forge4d run's stats (with the live display's fps and
#                  trigger-to-display latency); summary.txt the run in a few lines
#   display.json   the live display's summary; stream.keys the keys' trigger times
#   display/       the stream's first 30 frames as PNG (a second, offline play)
#   model-cameras.json  the model's cameras at the last key (aligns the novel view)
# Weights: WEIGHTS=FILE, else the shipped default, else a random-weight model
# (labelled UNTRAINED everywhere it shows). SECONDS_RUN (default 20) sets the
# length, DISPLAY_SIZE (default 640x360) the live display's; extra arguments
# go to `forge4d run`. Latency first (README, the appliance section): MOTION
# (default off: the shipped model's motion is no better than none, and a key
# with motion leaves one set late) and KEY_HZ (default 6 keys a second, 0:
# as fast as inference goes; the spare CPU keeps the stages and the display
# from queueing on 2 cores) and INFER_THREADS (default 1: the model's second
# thread costs more CPU than it saves wall time when every core is busy).
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup-debian.sh
cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)"
bin=build/release

out=${OUT:-out}
rm -rf "$out/take" "$out/stream.f4ds" "$out/display.json" "$out/stream.keys"
mkdir -p "$out"
weights=${WEIGHTS:-}
label=trained
for w in "$weights" "${F4D_WEIGHTS:-}" firmware/infer/weights/forge4d_small.gguf; do
  if [ -n "$w" ] && [ -f "$w" ]; then weights=$w; break; fi
  weights=
done
if [ -z "$weights" ]; then
  weights=$out/untrained-random.gguf
  label="UNTRAINED (random weights: the reconstruction is noise; no shipped weights in this tree)"
  echo "main: no trained weights found; writing a random-weight model to $weights -- UNTRAINED"
  "$bin/tools/f4d-bench/f4d-bench" model --write-random "$weights" --preset tiny >/dev/null
fi

load0=$(cut -d' ' -f1-3 /proc/loadavg)
display=$bin/tools/f4d-display/f4d-display
size=${DISPLAY_SIZE:-640x360}
attach=()
if [ -x "$display" ]; then
  # live: the daemon spawns the display on the stream file it writes; the CPU
  # rasterizer (llvmpipe's GLES is 5-12x slower here, and auto's probe of both
  # costs seconds before the first key)
  attach=(--display "$display" --display-json "$out/display.json" --key-times "$out/stream.keys"
          --display-args "--renderer cpu --size $size")
  echo "main: forge4d run, ${SECONDS_RUN:-20} s of the simulated rig, weights $weights ($label), f4d-display live at $size"
else
  echo "main: forge4d run, ${SECONDS_RUN:-20} s of the simulated rig, weights $weights ($label); f4d-display is not in this tree: nothing displayed"
fi
motion=${MOTION:-off}
key_hz=${KEY_HZ:-6}
infer_threads=${INFER_THREADS:-1}
"$bin/firmware/app/forge4d" run --no-config --board board/sim-4cam.json --weights "$weights" \
  --seconds "${SECONDS_RUN:-20}" --record "$out/take" --stream "file:$out/stream.f4ds" \
  --motion "$motion" --key-hz "$key_hz" --threads "$infer_threads" \
  --stats-json "$out/run.json" --rig-json "$out/model-cameras.json" "${attach[@]}" "$@"
"$bin/firmware/app/forge4d" verify "$out/take"

if [ -x "$display" ]; then
  # the first second again, every frame archived as PNG (out/display/): encoding a PNG
  # costs more than drawing the frame, so it stays out of the live, measured run
  rm -rf "$out/display"
  "$display" --headless --renderer cpu --png-dir "$out/display" --frames 30 --no-status "$out/stream.f4ds" >/dev/null ||
    echo "main: f4d-display (PNG archive) failed (see above)"
fi

echo "main: the stream from a camera the rig lacks, beside ground truth"
rigarg=()
[ -f "$out/model-cameras.json" ] && rigarg=(--rig "$out/model-cameras.json")
"$bin/tools/f4d-novel/f4d-novel" "$out/stream.f4ds" -o "$out" "${rigarg[@]}" --scene walk --seed 1 --views 4 --size 518

field() { sed -n "s/.*\"$1\":[[:space:]]*\([-0-9.eE+]*\|null\).*/\1/p" "$2" | head -1; }
# a number of the stats JSON to 2 decimals (null stays null)
num() { local v; v=$(field "$1" "$2"); case "$v" in ''|null) echo "${v:-null}" ;; *) printf '%.2f' "$v" ;; esac; }
# the same inside one object of the stats ("latency_breakdown_ms", "cpu_ms_per_key"), to 0 decimals
sub() { local v; v=$(sed -n "/\"$1\"/,/}/p" "$3" | sed -n "s/.*\"$2\":[[:space:]]*\([-0-9.eE+]*\|null\).*/\1/p" | head -1)
        case "$v" in ''|null) echo "${v:-null}" ;; *) printf '%.0f' "$v" ;; esac; }
lb() { sub latency_breakdown_ms "$1" "$out/run.json"; }
cpu() { sub cpu_ms_per_key "$1" "$out/run.json"; }
{
  echo "weights:           $weights ($label)"
  echo "key frames:        $(field key_frames "$out/run.json") at $(num key_hz "$out/run.json") Hz"
  echo "sets captured:     $(field sets_captured "$out/run.json") (skipped by inference: $(field sets_skipped_by_inference "$out/run.json"))"
  echo "latency p50 / p95: $(num latency_ms_p50 "$out/run.json") / $(num latency_ms_p95 "$out/run.json") ms from the trigger to the $(sed -n 's/.*"latency_to":[[:space:]]*"\([a-z]*\)".*/\1/p' "$out/run.json" | head -1) (to the stream sink: $(num latency_sink_ms_p50 "$out/run.json") / $(num latency_sink_ms_p95 "$out/run.json") ms)"
  echo "latency parts:     delivery $(lb delivery), to inference $(lb infer_wait), inference $(lb inference), key queue $(lb key_queue_wait), encode $(lb encode), sink $(lb sink_write) = $(lb to_sink) ms to the sink; then display read $(lb display_read), shown $(lb display_show) = $(lb to_display) ms (means)"
  echo "key stages (ms):   preprocess $(num preprocess "$out/run.json"), model $(num model "$out/run.json"), budget $(num budget "$out/run.json"), encode $(num encode "$out/run.json") (mean wall time a key)"
  echo "CPU a key (ms):    simulated cameras $(cpu capture), inference $(cpu inference), stream $(cpu stream), recorder $(cpu record), display $(cpu display): $(cpu total) (motion $motion, keys paced at ${key_hz} Hz, inference threads $infer_threads)"
  echo "bitrate:           $(num bitrate_mbps "$out/run.json") Mbit/s"
  if [ -x "$display" ]; then
    echo "displayed fps:     $(num displayed_fps "$out/run.json") (live, $size, paced at 30; $(field keys_displayed "$out/run.json") keys shown)"
  else
    echo "displayed fps:     null (f4d-display is not in this tree)"
  fi
  echo "novel-view PSNR:   $(field psnr_db_mean "$out/novel.json") dB (mean over keys, vs ground truth)"
  echo "files:             $out/take $out/stream.f4ds $out/novel.gif $out/run.json $out/display.json $out/display/"
  echo "machine:           $(nproc) cores, load average $load0 at the start, $(cut -d' ' -f1-3 /proc/loadavg) at the end (other jobs slow every figure above)"
} | tee "$out/summary.txt"
