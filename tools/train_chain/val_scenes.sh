# The rendered validation scenes of validate.sh (SPEC.md §3a), shared by the tools that use them:
# classic renders 200000-200005 and realistic renders 200050-200052, 40 frames at 320x240, in
# runs/val/{s,r}SEED. Source this file, then
#
#   val_scenes BIN        # renders the missing ones with BIN and sets VAL_SCENES=(runs/val/s200000 ...)
#
# (the real validation scene, SUN3D f0935, is added by each tool with its own keyframes).
val_scenes() {
  local bin=$1 seed d style
  VAL_SCENES=()
  for seed in 200000 200001 200002 200003 200004 200005 200050 200051 200052; do
    if [ "$seed" -lt 200050 ]; then d=runs/val/s$seed; style=classic; else d=runs/val/r$seed; style=real; fi
    [ -f "$d/.done" ] || { nice -n 19 "$bin" synth --seed "$seed" --frames 40 --size 320x240 --style $style --out "$d" --quiet && touch "$d/.done"; }
    VAL_SCENES+=("$d")
  done
}
