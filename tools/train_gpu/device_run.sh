#!/usr/bin/env bash
# One call on the GPU machine (SPEC §13.9): render synthetic training scenes with the carried
# densefeat binary, then train B1 stride 2 and B1 stride 1 concurrently with train_gpu.py, and
# pack logs, snapshots and final checkpoints into $OUT/runs.tgz.
# Expects (carried, see tools/train_gpu/README.md): .gpu/densefeat (x86-64 release binary),
# .gpu/init_b1s{1,2}.safetensors, .gpu/pack/{hololens_000,tartanair_hospital}.
# Env: BUDGET (s per training process, default 400), SCENES (synthetic scenes, default 96),
#      STYLE (renderer style flag, default "--style real"), B2/B1 (batches, default 16 / 8).
set -u
BUDGET=${BUDGET:-400}; SCENES=${SCENES:-96}; STYLE=${STYLE:---style real}; B2=${B2:-16}; B1=${B1:-8}
OUTD=${OUT:-/tmp/out}; mkdir -p "$OUTD"
exec > >(tee "$OUTD/device.log") 2>&1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
chmod +x .gpu/densefeat
t0=$(date +%s)
mkdir -p /tmp/synth
seq 100000 $((100000 + SCENES - 1)) | xargs -P 16 -I{} sh -c \
  ".gpu/densefeat synth $STYLE --seed {} --frames 40 --size 320x240 --out /tmp/synth/s{} >/dev/null 2>>/tmp/synth_err.log"
if [ "$(ls /tmp/synth | wc -l)" -eq 0 ]; then  # the binary has no such style: classic renderer
  echo "no scene rendered with '$STYLE'; using the classic style"
  seq 100000 $((100000 + SCENES - 1)) | xargs -P 16 -I{} sh -c \
    ".gpu/densefeat synth --seed {} --frames 40 --size 320x240 --out /tmp/synth/s{} >/dev/null 2>>/tmp/synth_err.log"
fi
echo "rendered $(ls /tmp/synth | wc -l) scenes in $(( $(date +%s) - t0 )) s"; head -3 /tmp/synth_err.log 2>/dev/null
run() {  # name init batch
  PYTHONUNBUFFERED=1 python3 tools/train_gpu/train_gpu.py --init "$2" --training-init \
    --pack .gpu/pack/hololens_000 .gpu/pack/tartanair_hospital --synth /tmp/synth/s* \
    --out "/tmp/runs/$1" --budget-s "$BUDGET" --batch "$3" > "/tmp/runs/$1.log" 2>&1
}
mkdir -p /tmp/runs
export PYTORCH_CUDA_ALLOC_CONF=expandable_segments:True
( while sleep 60; do tar czf /tmp/partial.tgz -C /tmp runs 2>/dev/null && mv /tmp/partial.tgz "$OUTD/runs.tgz"; done ) & TARLOOP=$!
run b1s2 .gpu/init_b1s2.safetensors "$B2" & P2=$!
run b1s1 .gpu/init_b1s1.safetensors "$B1" & P1=$!
n=0
while kill -0 $P2 2>/dev/null || kill -0 $P1 2>/dev/null; do
  sleep 5; n=$((n + 1)); [ $((n % 12)) -eq 0 ] || continue; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
  tail -n 1 /tmp/runs/b1s2.log; tail -n 1 /tmp/runs/b1s1.log
done
wait $P2; echo "b1s2 exit $?"; wait $P1; echo "b1s1 exit $?"
tail -n 5 /tmp/runs/b1s2.log /tmp/runs/b1s1.log
kill $TARLOOP 2>/dev/null; wait $TARLOOP 2>/dev/null
tar czf "$OUTD/runs.tgz" -C /tmp runs
ls -la "$OUTD"
