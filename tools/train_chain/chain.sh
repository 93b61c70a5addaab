#!/usr/bin/env bash
# The long CPU training chain of issue 30 (SPEC.md §13.10): one fixed configuration per chain,
# run as resumable chunks across sessions.
#
#   tools/train_chain/chain.sh start NAME   # resume NAME from its committed checkpoint (or begin),
#                                          # in the background, under nice; log in runs/NAME.out
#   tools/train_chain/chain.sh save NAME    # copy the run's latest checkpoint, log and curves to
#                                          # docs/training/chain_NAME/ (then commit that folder)
#   tools/train_chain/chain.sh status NAME  # last log line and steps done
#   tools/train_chain/chain.sh finish NAME  # wait for the run to end; save it with its final weights,
#                                          # run the 101-scene validation of the learned rows and
#                                          # compare it with the chains named in COMPARE (default
#                                          # "mf8so"); then commit docs/training/ by hand
#
# The configuration of each chain is below; changing it starts a new chain (the checkpoint's
# fingerprint would no longer match, and `densefeat train --resume` refuses it).
set -euo pipefail
cd "$(dirname "$0")/../.."

name=${2:-b1s2}
run=runs/chain_$name
kept=docs/training/chain_$name
D=../shared/data

# derive NEW BASE FLAG VALUE ...: the array NEW is BASE's arguments with each FLAG's value replaced.
derive() {
  local -n _new=$1 _base=$2
  shift 2
  _new=("${_base[@]}")
  while [ $# -ge 2 ]; do
    for i in "${!_new[@]}"; do [ "${_new[$i]}" = "$1" ] && _new[$((i + 1))]=$2; done
    shift 2
  done
}

args_b1s2=(
  --data $D/hololens_000 --data $D/tartanair_hospital --data $D/tsdffusion_desk_box
  --val-data $D/sun3d_studyroom_f0935 --val-fraction 0
  --synthetic-scenes 64 --synthetic-style real --synthetic-fraction 0.5 --synthetic-val-scenes 4
  --b1-stride 2 --crop 256x192 --bins 256
  --steps 37500 --batch 4 --lr 1e-3 --warmup 500 --weight-decay 1e-4 --clip-norm 5000
  --loss-sample-stride 2 --seed 0 --init-seed 0
  --val-every 250 --val-per-source 4 --ckpt-every 100
)

# Block-1 stride 1 (issue 30: the other stride, >= 60 000 pairs). The same data, crops, bins and
# optimiser; the finest supervised level is 0 here, so --loss-sample-stride 4 evaluates as many
# pixels per scale as b1s2's 2 does at level 1 (SPEC.md §13.1a). 15 000 steps x 4 = 60 000 pairs.
# Start it once b1s2 has finished (the two would share the two cores).
args_b1s1=(
  --data $D/hololens_000 --data $D/tartanair_hospital --data $D/tsdffusion_desk_box
  --val-data $D/sun3d_studyroom_f0935 --val-fraction 0
  --synthetic-scenes 64 --synthetic-style real --synthetic-fraction 0.5 --synthetic-val-scenes 4
  --b1-stride 1 --crop 256x192 --bins 256
  --steps 15000 --batch 4 --lr 1e-3 --warmup 500 --weight-decay 1e-4 --clip-norm 5000
  --loss-sample-stride 4 --seed 0 --init-seed 0
  --val-every 250 --val-per-source 4 --ckpt-every 100
)

# Issue 30 item 5, the multi-frame objective (SPEC.md §13.1b) on validation: two fine-tunes of the
# shipped b1s2 weights that differ only in --live-frames (4 against the pair loss's 1), with the
# chain's data, crops and loss sampling, fresh data draws (--seed 1) and a short schedule of their own.
# tools/train_chain/validate.sh mf4 / mf1 then compares them with the mapper on the validation scenes.
args_mf4=(
  --data $D/hololens_000 --data $D/tartanair_hospital --data $D/tsdffusion_desk_box
  --val-data $D/sun3d_studyroom_f0935 --val-fraction 0
  --synthetic-scenes 64 --synthetic-style real --synthetic-fraction 0.5 --synthetic-val-scenes 4
  --b1-stride 2 --crop 256x192 --bins 256
  --init-weights fixtures/weights/featurenet_trained_b1s2.safetensors --live-frames 4
  --steps 2500 --batch 4 --lr 1e-4 --warmup 100 --weight-decay 1e-4 --clip-norm 5000
  --loss-sample-stride 2 --seed 1 --init-seed 0
  --val-every 250 --val-per-source 4 --ckpt-every 100
)
derive args_mf1 args_mf4 --live-frames 1

# The multi-frame objective's long run (issue 30 item 5): mf4 beat its 1-frame control mf1 on
# validation (learned-TV 0.887 vs 0.882, WTA 0.842 vs 0.839; docs/training/README.md), so the same
# fine-tune of the shipped b1s2 weights runs 4x longer (40 000 tuples of 1 reference + 4 live frames),
# with its own data draws (--seed 2).
derive args_mf4l args_mf4 --steps 10000 --seed 2

# Issue 30 items 3 and 5 on validation: the chain's synthetic scenes were all realistic-style, while
# half of the validation and test renders are classic-style (procedural textures, large white walls),
# where the wide validation (tools/train_chain/wide_validation.sh) puts learned-TV's weakest scenes.
# mx4 continues mf4l's multi-frame fine-tune from its final weights with both renderer styles
# (--synthetic-style mixed: even seeds classic, odd seeds real; SPEC.md §13.5), 5 000 steps = 20 000
# tuples, its own data draws (--seed 3).
derive args_mx4 args_mf4 --synthetic-style mixed \
  --init-weights docs/training/chain_mf4l/best_weights.safetensors --steps 5000 --seed 3

# mx4 did not beat mf4l on the wide validation (docs/training/wide_validation/README.md), so the
# multi-frame objective is pushed further instead: mf8 continues mf4l's fine-tune from its final
# weights with 8 live frames per reference (the mapper sums over up to 60), realistic-style renders
# as in mf4l, 5 000 steps = 20 000 tuples, its own data draws (--seed 4).
derive args_mf8 args_mf4 --live-frames 8 \
  --init-weights docs/training/chain_mf4l/best_weights.safetensors --steps 5000 --seed 4

# The control of mf8: the same fine-tune from mf4l's final weights, the same 5 000 steps and data seed,
# with 4 live frames (as mf4l), so mf8 - mf4c is the effect of 8 frames, not of 5 000 more steps.
derive args_mf4c args_mf4 \
  --init-weights docs/training/chain_mf4l/best_weights.safetensors --steps 5000 --seed 4

# The multi-frame objective for the other stride (issue 30 item 2's stride-1 weights): mf4l's recipe
# (+0.012 learned-TV on the 101 validation scenes for stride 2) applied to the shipped b1s1 weights,
# with b1s1's loss sampling (stride 4 at level 0), 5 000 steps = 20 000 tuples, its own data draws
# (--seed 5). About 4x mf4l's cost per step: a chain over sessions.
derive args_mf4s1 args_mf4 --b1-stride 1 --loss-sample-stride 4 \
  --init-weights fixtures/weights/featurenet_trained_b1s1.safetensors --steps 5000 --seed 5

# The position code (2026-12-05): on a constant image the network's features vary by up to an L1 of
# 7.6 within ~80 level-1 pixels of the image border (its zero padding), as large as the learned cost's
# spread. Training cut each live crop at the reference window shifted by the mean flow, so that code
# pointed at the true match on average; the mapper compares full frames at the same coordinates,
# where it points at zero motion, i.e. far depth: the far-biased valleys on textureless walls
# (issue 30). mf4sc is mf4c (its control: mf4l's final weights, 5 000 steps, data seed 4) with the live
# crops cut at the reference window itself (--live-crop same, SPEC.md §13.5).
args_mf4sc=("${args_mf4c[@]}" --live-crop same)

# mf4sc beat its control mf4c on the 101 validation scenes (learned-TV +0.011, learned-normals +0.008,
# learned-WTA +0.009; docs/training/README.md), so the same-crop fine-tune continues from mf4sc's final
# weights for 10 000 steps = 40 000 tuples, its own schedule and data draws (--seed 6): a chain over
# sessions.
derive args_mf4sc2 args_mf4sc --init-weights docs/training/chain_mf4sc/weights.safetensors \
  --steps 10000 --seed 6

# mf4sc2 ended +0.0012 over mf4sc on validation (docs/training/wide_validation/mf4sc2.csv) with the
# position code still shrinking. A 256x192 crop is mostly border zone (the code reaches ~80 level-1
# px in), while the mapper matches 640x480 frames; mf4sc3 continues the same-window fine-tune from
# mf4sc2's final weights on 320x240 crops (the largest every training sequence holds:
# tsdffusion_desk_box is 320x240), 6 000 steps = 24 000 tuples, its own data draws (--seed 7).
derive args_mf4sc3 args_mf4sc --init-weights docs/training/chain_mf4sc2/weights.safetensors \
  --crop 320x240 --steps 6000 --seed 7

# mf4sc3 (320x240 crops) gained on the 100 validation renders (learned-TV +0.003, learned-normals
# +0.004 over mf4sc) and lost on the one real validation room (SUN3D f0935: -0.019 / -0.018), as
# mf4sc2 had stayed flat there: the synthetic half of every batch may be what the extra steps fit.
# mf4sr continues mf4sc2's same-window fine-tune (256x192) with a quarter of the tuples synthetic
# instead of half (more of the real and photo-realistic training sequences), 5 000 steps = 20 000
# tuples, its own data draws (--seed 8). Judged, like every chain, on all 101 validation scenes and
# on the real one separately.
derive args_mf4sr args_mf4sc --init-weights docs/training/chain_mf4sc2/weights.safetensors \
  --synthetic-fraction 0.25 --steps 5000 --seed 8

# mf4sc4 continues mf4sc3's 320x240 same-window fine-tune from its end, 6 000 steps = 24 000 tuples,
# its own data draws (--seed 9): does the render gain keep growing? Started before the nine-keyframe
# check of the real room (docs/training/wide_validation/README.md), which found mf4sc3 worse there on
# every keyframe: not a default candidate unless the real room recovers.
derive args_mf4sc4 args_mf4sc3 --init-weights docs/training/chain_mf4sc3/weights.safetensors --seed 9

# Occlusion masking (2026-12-06, SPEC.md §13.1c): the loss took a reference pixel hidden behind a
# nearer surface in a live frame as matching the occluder's feature there, teaching wall pixels beside
# a box to look like the box (the learned features' blank-wall failure of issue 32, s200001 / s2).
# 4-5 % of the chain's reference pixels are hidden in at least one of the 4 live frames (τ 0.02-0.1
# gives 5.0-4.0 %). mf4so is mf4sc (mf4l's final weights, 5 000 steps, data seed 4, same-window
# crops) with --occlusion-mask 0.05, so mf4so - mf4sc is the mask's effect alone.
args_mf4so=("${args_mf4sc[@]}" --occlusion-mask 0.05)

# mf4so beat mf4sc on the 101 validation scenes (learned-normals +0.0012, learned-WTA +0.0022 on 74 of
# 101 scenes, the real room +0.009; docs/training/README.md) and became the default. mf8so continues it
# with 8 live frames per reference (mf8 - mf4c was +0.004 learned-TV at equal steps, with flow crops),
# the mask kept, 5 000 steps = 20 000 tuples of 1 + 8 frames, its own data draws (--seed 10): about
# 1.5 h, a chain over sessions.
derive args_mf8so args_mf4so --live-frames 8 \
  --init-weights docs/training/chain_mf4so/weights.safetensors --seed 10
# (mf8so was started on 2026-12-06 and stopped before its first step, for mxso below; started again
# at 17:43 that evening, after mxso.)

# mxso is mf4so (mf4l's final weights, 5 000 steps, data seed 4, same-window crops, the mask) with both
# renderer styles (--synthetic-style mixed: even seeds classic, odd seeds realistic; SPEC.md §13.5), so
# mxso - mf4so is the style alone. The classic renders are the ones with large blank walls beside boxes
# (issue 32's s200001 / s2); mx4 tried the mix before the mask and the same-window crops, with no gain
# on the classic validation renders, when occluded pixels could still teach a wall to look like the box.
derive args_mxso args_mf4so --synthetic-style mixed
# mxso lost to mf4so on validation (learned-WTA worse on 66 of 101 scenes, the real room -0.004
# learned-TV; docs/training/README.md): not adopted.

# mf4soce is mf4so (mf4l's final weights, 5 000 steps, data seed 4, same-window crops, the mask) with the
# cross-entropy alone (--regression-weight 0, SPEC.md §13.1 step 5), so mf4soce - mf4so is the
# regression term's effect: on a blank wall beside a box the learned cost's single valley lies between
# the wall's and the box's depths (docs/table1/README.md, "The blank wall's cost curves"), where the
# regression term puts the expected depth under ambiguity.
args_mf4soce=("${args_mf4so[@]}" --regression-weight 0)
# mf4soce: learned-WTA +0.0035 on validation, the regularised rows flat, the real room -0.007: not
# adopted, and the blank wall's minima did not move (docs/training/README.md).

# mf4sos is mf4so (mf4l's final weights, 5 000 steps, data seed 4, same-window crops, the mask) with the
# mapper's rule for live frames that do not all see a hypothesis (--multi-cost seen, SPEC.md §13.1d):
# each hypothesis averaged over the frames that see it, and pixels whose true match leaves some frame
# trained too. Those pixels, blank, are the learned features' worst at run time (δ<1.25 0.38 against
# 0.80, docs/table1/README.md, "The blank wall on the training scenes"). mf4sos - mf4so is the rule's
# effect.
args_mf4sos=("${args_mf4so[@]}" --multi-cost seen)
# mf4sos lost to mf4so on validation (learned-normals -0.0038, worse on 69 of 101 scenes; the real room
# -0.005) and barely moved its target pixels: not adopted (docs/training/README.md).

# mf4sof is mf4so (mf4l's final weights, 5 000 steps, data seed 4, same-window crops, the mask) with the
# loss on the aggregated features alone (--supervision final, SPEC.md §13.2), so mf4sof - mf4so is deep
# supervision's effect. On a blank wall beside a box the wall's features follow the box's parallax
# through the coarse blocks (docs/table1/README.md, "The blank wall's cost curves"), and deep
# supervision asks each coarse block's output to be a matching feature of its own, which at that scale
# means encoding the box; without it the blocks are free to serve only the features the mapper matches.
args_mf4sof=("${args_mf4so[@]}" --supervision final)

# mf4sof on validation: learned-WTA +0.0070 (better on 72 of 101 scenes, the real room +0.009), the
# regularised rows flat (learned-normals -0.0007, learned-TV -0.0021; the real room +0.007): not adopted
# (docs/training/README.md). mf8so (defined above) was adopted instead. mf8sof continues the
# new default, mf8so's final weights, with the loss on L alone and mf8so's 8 live frames, 5 000 steps,
# its own data draws (--seed 12): does the WTA gain of final supervision carry to the regularised rows
# from the better start?
derive args_mf8sof args_mf8so --init-weights docs/training/chain_mf8so/weights.safetensors --seed 12
args_mf8sof+=(--supervision final)
# mf8sof on validation against mf8so: learned-WTA +0.0055 (71 of 101), the real room +0.014 / +0.012
# (normals / TV), the renders' regularised rows lower (learned-normals -0.0011 on the 101): as mf4sof.
# mf8sod is its control at equal steps: the same start (mf8so's final weights), schedule and data
# draws (--seed 12) with deep supervision, so mf8sof - mf8sod is the supervision alone, and mf8sod -
# mf8so is 5 000 more steps.
derive args_mf8sod args_mf8so --init-weights docs/training/chain_mf8so/weights.safetensors --seed 12
# mf8sod on validation (2026-12-07): flat against mf8so (learned-normals +0.0004, the real room -0.002),
# not adopted; mf8sof - mf8sod: WTA +0.0051, the real room +0.016, the realistic renders -0.003.
# mf8soa: mf8sod with the sensor augmentation of SPEC.md §13.5 (a motion blur of up to 3 px in any
# direction and a gamma curve, ln γ within ±0.25, on every training crop, drawn per crop): the same
# start, schedule, pairs and crops, so mf8soa - mf8sod is the augmentation alone. Every fine-tune
# trained on sharp renders gained on them and not on the real room; real cameras blur and bend tones.
derive args_mf8soa args_mf8sod
args_mf8soa+=(--augment-blur 3 --augment-gamma 0.25)
# mf8soa on validation (2026-12-07): flat against mf8sod (learned-normals -0.0005, learned-TV -0.0012
# on the 101 scenes; the real room +0.005 / +0.002, inside one chain's spread there): not adopted.
# mf8sohs: mf8sod with the mapper's rule for partially seen hypotheses (SPEC.md §13.1d) and the
# ranking term (§13.1e, weight 1, margin 1): on one training room (docs/table1/README.md, "The ranking
# term on one room") the two together fitted the room's blank pixels best of every fine-tune (mapper
# WTA 0.687 against 0.640 with the paper's loss; the rule alone 0.667, the term alone 0.606), while its
# regularised depth did not move; a long run on the full mix is the test that remains (weak evidence).
# Not started yet: after mf8soa.
derive args_mf8sohs args_mf8sod
args_mf8sohs+=(--multi-cost seen --hinge-weight 1 --hinge-margin 1)

# mf8sow: mf8sod with the block scales weighted 0.2 against L (--deep-weight 0.2, SPEC.md §13.2): the
# same start, schedule, pairs and crops, so it sits between mf8sod (weight 1, the paper's) and mf8sof
# (weight 0, L alone). Those two trade the renders' regularised rows (deep) against the data term and
# the real room (final); 0.2 = 1/5 gives the five block scales together the weight of L (set a priori,
# not chosen on any scene). Does one objective keep both?
derive args_mf8sow args_mf8sod
args_mf8sow+=(--deep-weight 0.2)
# mf8sow on validation (2026-12-07, session 44): learned-normals +0.0002, the real room +0.0045, WTA
# +0.0037 (74 of 101) against mf8so; by the rule (the default regulariser's mean and the real room) it
# became the default (fixtures/weights/featurenet_trained_mf8sow.safetensors). mf8sohs started next.

# mf4rp is mf4sr (the same init, mix, steps and data seed) with the two real training sequences'
# poses refined to agree with their own depth first (tools/train_chain/refine_poses.py; they were
# about 2 px off, docs/training/README.md): does cleaner real supervision help the real room, where
# mf4sr lost? The refined copies live in runs/refined/ (made on `start` when missing; the data are
# never committed).
R=runs/refined
args_mf4rp=("${args_mf4sr[@]/#$D\/hololens_000/$R/hololens_000}")
args_mf4rp=("${args_mf4rp[@]/#$D\/tsdffusion_desk_box/$R/tsdffusion_desk_box}")
prepare_mf4rp() {
  for s in hololens_000 tsdffusion_desk_box; do
    [ -f "$R/$s/poses.txt" ] || python3 tools/train_chain/refine_poses.py "$D/$s" "$R/$s"
  done
}

case "${1:-}" in
  start)
    if declare -F "prepare_$name" > /dev/null; then "prepare_$name"; fi
    var="args_${name}[@]"
    args=("${!var}")
    mkdir -p "$run"
    resume=()
    if [ -f "$run/checkpoint.safetensors" ]; then
      resume=(--resume "$run/checkpoint.safetensors")
    elif [ -f "$kept/checkpoint.safetensors" ]; then
      cp "$kept/checkpoint.safetensors" "$kept/log.csv" "$run/"
      # The chunk history too, so that `save` on a fresh machine keeps the earlier chunks.
      if [ -f "$kept/chunks.txt" ]; then cp "$kept/chunks.txt" "$run/"; fi
      resume=(--resume "$run/checkpoint.safetensors")
    fi
    bin=${BIN:-target/release/densefeat}
    [ -x "$bin" ] || cargo build --release
    # A copy of the binary, so rebuilding the project does not touch the running trainer.
    cp "$bin" "$run/densefeat"
    echo "$(date -u +%FT%TZ) start: $run/densefeat train --out $run ${args[*]} ${resume[*]} --threads 2 --quiet" >> "$run/chunks.txt"
    nohup nice -n 19 "$run/densefeat" train --out "$run" "${args[@]}" "${resume[@]}" --threads 2 --quiet \
      > "$run/train.out" 2>&1 &
    echo "started pid $! (log $run/train.out)"
    ;;
  save)
    mkdir -p "$kept"
    cp "$run/checkpoint.safetensors" "$run/log.csv" "$run/curves.png" "$kept/"
    cp "$run/chunks.txt" "$kept/chunks.txt"
    tail -1 "$kept/log.csv" | cut -d, -f1,3,15,16
    ;;
  status)
    tail -1 "$run/log.csv" 2>/dev/null || echo "no log yet"
    tail -3 "$run/train.out" 2>/dev/null || true
    ;;
  finish)
    var="args_${name}[@]"
    args=("${!var}")
    steps=""
    for i in "${!args[@]}"; do [ "${args[$i]}" = "--steps" ] && steps=${args[$((i + 1))]}; done
    while pgrep -f "$run/densefeat train" > /dev/null; do sleep 60; done
    last=$(tail -1 "$run/log.csv" | cut -d, -f1)
    if [ "$last" != "$steps" ]; then
      echo "chain.sh finish: $run has reached step $last of $steps; start it again first" >&2
      exit 1
    fi
    "$0" save "$name"
    cp "$run/weights.safetensors" "$kept/"
    METHODS=learned-wta,learned-tv,learned-normals tools/train_chain/wide_validation.sh "$name" "$kept/weights.safetensors"
    cp "runs/valwide/$name/all.csv" "docs/training/wide_validation/$name.csv"
    for other in ${COMPARE:-mf8so}; do
      echo "== $other -> $name"
      python3 tools/train_chain/compare_pair.py "docs/training/wide_validation/$other.csv" \
        "docs/training/wide_validation/$name.csv" --scene s200001 --scene sun3d_studyroom_f0935
    done
    ;;
  *)
    echo "usage: $0 start|save|status|finish NAME" >&2
    exit 2
    ;;
esac
