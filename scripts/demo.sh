#!/usr/bin/env bash
# Revisit's main job on its embedded default scene: installs what is missing,
# builds, renders a small synthetic reef surveyed three times, reconstructs all
# visits jointly, scores the result against the exact truth and prints where
# the outputs are. Usage: scripts/demo.sh [OUT] (default: demo/).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-demo}
scripts/setup.sh
cargo build --release --locked -p revisit-cli
revisit=target/release/revisit
$revisit synth --out "$out/reef" --sessions 3 --images-per-session 30 --change none --seed 0
sessions=()
for dir in "$out"/reef/sessions/*/; do
  sessions+=(--session "$(basename "$dir")=$dir")
done
$revisit reconstruct "${sessions[@]}" --out "$out/work"
$revisit eval --model "$out/work/model" --points "$out"/reef/truth/evaluation_points_*.csv \
  --truth "$out/reef/truth" --json "$out/work/eval.json" --plots "$out/work/plots"
echo
echo "synthetic reef:  $out/reef (images in sessions/, ground truth in truth/)"
echo "reconstruction:  $out/work (model/, points.ply, poses.csv, report.json)"
echo "evaluation:      $out/work/eval.json, $out/work/plots/"
