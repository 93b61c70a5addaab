#!/usr/bin/env bash
# Resumable background training of the built-in normal predictor (SPEC.md §13.11, issue 32 item 3c),
# chunked across sessions as the feature chains are (chain.sh):
#
#   tools/train_chain/normals_chain.sh start NAME   # resume NAME from its committed checkpoint (or begin),
#                                                  # in the background, under nice; log in runs/normals_NAME/train.out
#   tools/train_chain/normals_chain.sh save NAME    # copy the latest checkpoint, best weights and log to
#                                                  # docs/normals/chain_NAME/ (then commit that folder)
#   tools/train_chain/normals_chain.sh status NAME  # last log line
#
# One fixed configuration per name (`densefeat train-normals --resume` refuses a changed one).
set -euo pipefail
cd "$(dirname "$0")/../.."

name=${2:-v4}
run=runs/normals_$name
kept=docs/normals/chain_$name
D=../shared/data

# v2's recipe (fixtures/weights/MODEL_CARD_normalnet.md: 8 000 steps, best at 7 400, still improving),
# run five times longer: 40 000 steps = 160 000 frames, one cosine schedule over the whole chain.
args_v4=(
  --data $D/hololens_000 --data $D/tartanair_hospital --data $D/tsdffusion_desk_box
  --val-data $D/sun3d_studyroom_f0935 --val-fraction 0
  --synthetic-scenes 256 --synthetic-style mixed --synthetic-val-scenes 8
  --crop 256x192 --batch 4 --steps 40000 --lr 1e-4 --warmup 200 --val-every 500
  --val-per-source 8 --ckpt-every 100
)

case "${1:-}" in
  start)
    var="args_${name}[@]"
    args=("${!var}")
    mkdir -p "$run"
    resume=()
    if [ -f "$run/checkpoint.safetensors" ]; then
      resume=(--resume "$run/checkpoint.safetensors")
    elif [ -f "$kept/checkpoint.safetensors" ]; then
      cp "$kept"/* "$run/"
      resume=(--resume "$run/checkpoint.safetensors")
    fi
    bin=${BIN:-target/release/densefeat}
    [ -x "$bin" ] || cargo build --release
    cp "$bin" "$run/densefeat"
    echo "$(date -u +%FT%TZ) start: $run/densefeat train-normals --out $run ${args[*]} ${resume[*]} --threads 2 --quiet" >> "$run/chunks.txt"
    nohup nice -n 19 "$run/densefeat" train-normals --out "$run" "${args[@]}" "${resume[@]}" --threads 2 --quiet \
      > "$run/train.out" 2>&1 &
    echo "started pid $! (log $run/train.out)"
    ;;
  save)
    mkdir -p "$kept"
    for f in checkpoint.safetensors best_normalnet.safetensors log.csv chunks.txt; do
      [ -f "$run/$f" ] && cp "$run/$f" "$kept/"
    done
    tail -1 "$kept/log.csv"
    ;;
  status)
    tail -1 "$run/log.csv" 2>/dev/null || echo "no log yet"
    tail -3 "$run/train.out" 2>/dev/null || true
    ;;
  *)
    echo "usage: $0 start|save|status NAME" >&2
    exit 2
    ;;
esac
