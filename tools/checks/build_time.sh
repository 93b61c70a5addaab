#!/usr/bin/env bash
# Clean-build time of `cargo test --no-run` (issue 33), this tree against an older commit, in
# interleaved rounds on the same machine: each build from an empty target folder, dependencies
# included, `--timings` reports kept beside.
#
#   tools/checks/build_time.sh [BEFORE_REV=574dfde] [ROUNDS=2] [WORK=/tmp/build_time]
# Prints one line per build: round, tree, wall s, user s, sys s.
set -euo pipefail
cd "$(dirname "$0")/../.."
before=${1:-574dfde}; rounds=${2:-2}; work=${3:-/tmp/build_time}
mkdir -p "$work"
if [ ! -d "$work/before" ]; then
  git worktree add --detach "$work/before" "$before" >/dev/null
fi
here=$(pwd)
for round in $(seq 1 "$rounds"); do
  for tree in before after; do
    dir=$here; [ "$tree" = before ] && dir=$work/before
    rm -rf "$work/target_$tree"
    (cd "$dir" && CARGO_TARGET_DIR="$work/target_$tree" /usr/bin/time -f "%e %U %S" -o "$work/$tree.time" \
      cargo test --no-run --offline --timings > "$work/${tree}_$round.log" 2>&1)
    echo "$round $tree $(cat "$work/$tree.time")"
  done
done
