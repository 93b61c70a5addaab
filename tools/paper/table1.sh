#!/usr/bin/env bash
# The paper's Table 1 on this project's test scenes (issue 32 item 4; SPEC.md §3a, §10.2): the four
# mapping variants P.E.+S (rgb-tv), L.F.E.+S (learned-tv), P.E.+normals (rgb-normals) and
# L.F.E.+normals (learned-normals) with the built-in predictor's normals, and the two normal-prior
# rows again with ground-truth normals (the bound). Every flag at its default (λ per variant as
# chosen on validation, SPEC §10.1a; the shipped feature and normal weights). Test scenes are run
# once per issue, at the end: this script is that run.
#
#   tools/paper/table1.sh TAG
#
# Writes runs/test/TAG_builtin/ and runs/test/TAG_gt/ (test_scenes.sh's folders: eval's outputs
# per scene, all.csv) and prints the table (tools/paper/table1.py).
set -euo pipefail
cd "$(dirname "$0")/../.."

tag=${1:-table1}
weights=fixtures/weights/featurenet_trained_mf8sow.safetensors  # the default (b1s2 until 2026-12-04, mf4l until 2026-12-05, mf4sc and mf4so until 2026-12-06, mf8so until 2026-12-07)
# The built-in run also carries the winner-take-all rows, so that it is issue 30's test table too
# (tools/train_chain/test_table.py on its all.csv): one run of the test scenes serves both issues.
tools/train_chain/test_scenes.sh "${tag}_builtin" "$weights" \
  --methods rgb-wta,rgb-tv,learned-wta,learned-tv,rgb-normals,learned-normals --normals learned
tools/train_chain/test_scenes.sh "${tag}_gt" "$weights" \
  --methods rgb-normals,learned-normals --normals gt
python3 tools/paper/table1.py "runs/test/${tag}_builtin" "runs/test/${tag}_gt"
echo
python3 tools/train_chain/test_table.py "runs/test/${tag}_builtin/all.csv"
