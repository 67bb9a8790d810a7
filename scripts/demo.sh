#!/usr/bin/env bash
# Revisit's main job on its embedded default scene: installs what is missing,
# builds, renders a small synthetic reef surveyed three times under strong
# change (each visit at another heading), reconstructs all visits jointly
# (place recognition + ALIKED/LightGlue with roll search across visits),
# scores the result against the exact truth and prints where the outputs are.
# Usage: scripts/demo.sh [OUT] (default: demo/). The learned models come from
# $REVISIT_MODELS, else models/ (scripts/get-models.sh), else ../shared/models.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-demo}
scripts/setup.sh
cargo build --release --locked -p revisit-cli
revisit=target/release/revisit
if [ -z "${REVISIT_MODELS:-}" ] && [ ! -d models ] && [ -d ../shared/models ]; then
  export REVISIT_MODELS=../shared/models
fi
$revisit synth --out "$out/reef" --sessions 3 --images-per-session 16 --change strong --seed 0
# The survey camera is calibrated: its intrinsics come with the truth.
camera=$(.venv/bin/python -c 'import json, sys; c = json.load(open(sys.argv[1]))[0]; print(c["model"] + ":" + ",".join(map(str, c["params"])))' "$out/reef/truth/intrinsics.json")
sessions=()
for dir in "$out"/reef/sessions/*/; do
  sessions+=(--session "$(basename "$dir")=$dir")
done
# LightGlue on the 384 keypoints of each image likeliest to match across (README): the
# demo's survey maps in a third of the learned matching's time, with fewer wrong pairs.
$revisit reconstruct "${sessions[@]}" --out "$out/work" --camera "$camera" --cross-keypoints 384
$revisit eval --model "$out/work/model" --points "$out"/reef/truth/evaluation_points_*.csv \
  --truth "$out/reef/truth" --at-click-depth --radius-px 8 --json "$out/work/eval.json" --plots "$out/work/plots"
echo
echo "synthetic reef:  $out/reef (images in sessions/, ground truth in truth/)"
echo "reconstruction:  $out/work (model/, points.ply, poses.csv, report.json)"
echo "evaluation:      $out/work/eval.json, $out/work/plots/"
