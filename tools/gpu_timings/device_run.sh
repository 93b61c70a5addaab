#!/usr/bin/env bash
# One call on a machine with a real GPU (issue 11 item 5, SPEC §15.4): the GPU backend's timings at
# the sizes the README and SPEC report, next to the same commands on the CPU backend, in one run.
# Expects (carried, see tools/gpu_timings/README.md): .gpu/densefeat-gpu, an x86-64 release binary
# built with `--features gpu` and stripped. Writes $OUT/gpu_timings.md and $OUT/device.log.
# Env: RUNS (timed runs per bench, default 20), FRAMES640 (live frames of the 640x480 keyframe, 60),
#      BACKENDS (default "gpu cpu"), SIZES (default "320x240 640x480"), B (the binary).
# A dry run on the build machine: B=target/release/densefeat BACKENDS=cpu SIZES=320x240 FRAMES640=4 OUT=/tmp/dry bash tools/gpu_timings/device_run.sh
set -u
RUNS=${RUNS:-20}; FRAMES640=${FRAMES640:-60}; BACKENDS=${BACKENDS:-gpu cpu}; SIZES=${SIZES:-320x240 640x480}
OUTD=${OUT:-/tmp/out}; mkdir -p "$OUTD"
exec > >(tee "$OUTD/device.log") 2>&1
B=${B:-.gpu/densefeat-gpu}; chmod +x "$B"
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg}; mkdir -p "$XDG_RUNTIME_DIR"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null || echo "no Vulkan ICD folder: wgpu may find no Vulkan adapter"
md="$OUTD/gpu_timings.md"
{ echo "# GPU timings ($(date -u +%F), $(nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null | head -1))"; echo; } > "$md"
section() { echo; echo "## $*"; echo; echo '```'; }
run() {  # label, command...
  echo "== $1"; shift
  { echo "\$ densefeat $*"; timeout 300 "$B" "$@" 2>&1 | grep -v XDG_RUNTIME_DIR | tail -n 12; } | tee -a "$md"
}
{ section "Network forward"; } >> "$md"
for size in $SIZES; do for s in 2 1; do for be in $BACKENDS; do
  run "forward $size s$s $be" bench forward --size "$size" --b1-stride "$s" --threads 16 --runs "$RUNS" --backend "$be"
done; done; done
echo '```' >> "$md"
{ section "Cost volume, one live frame"; } >> "$md"
for size in $SIZES; do for k in 64 128; do for c in 3 32; do for be in $BACKENDS; do
  run "costvolume $size K$k C$c $be" bench costvolume --size "$size" --bins "$k" --channels "$c" --threads 16 --runs "$RUNS" --backend "$be"
done; done; done; done
echo '```' >> "$md"
{ section "DTAM"; } >> "$md"
for size in $SIZES; do for be in $BACKENDS; do
  run "tv $size $be" bench tv --size "$size" --bins 128 --threads 16 --runs 10 --backend "$be"
done; done
echo '```' >> "$md"
# A whole keyframe: rendered sequences made by the carried binary (no data leaves the repository).
"$B" synth --seed 200000 --frames 31 --size 320x240 --out /tmp/seq320 --quiet
"$B" synth --seed 200000 --frames $((FRAMES640 + 1)) --size 640x480 --out /tmp/seq640 --quiet
{ section "Whole keyframe (reconstruct, wall time with every stage)"; } >> "$md"
for be in $BACKENDS; do
  run "keyframe 320 learned L1 $be" reconstruct --sequence /tmp/seq320 --keyframe 15 --window 15,15 --bins 64 \
    --features learned --level 1 --backend "$be" --out "/tmp/k320_$be"
  run "keyframe 640 rgb L0 $be" reconstruct --sequence /tmp/seq640 --keyframe $((FRAMES640 / 2)) --bins 128 \
    --features rgb --level 0 --backend "$be" --out "/tmp/k640rgb_$be"
  run "keyframe 640 learned L0 $be" reconstruct --sequence /tmp/seq640 --keyframe $((FRAMES640 / 2)) --bins 128 \
    --features learned --level 0 --backend "$be" --out "/tmp/k640l_$be"
done
echo '```' >> "$md"
for d in /tmp/k320_gpu /tmp/k640rgb_gpu /tmp/k640l_gpu; do
  [ -f "$d/metrics.json" ] && cp "$d/metrics.json" "$OUTD/$(basename "$d")_metrics.json"
done
echo "done: $md"
