#!/usr/bin/env bash
# Installs what Revisit needs on a fresh machine, unattended and idempotently:
# the project's Python environment (.venv) with pinned packages, and Debian's
# Chromium (the comparison page's browser test). A second run takes seconds.
# Rust comes with the machine (rustup's stable toolchain).
set -euo pipefail
cd "$(dirname "$0")/.."

command -v cargo >/dev/null || { echo "setup: cargo not found; install Rust (rustup) first" >&2; exit 1; }
PYTHON=${PYTHON:-python3}
command -v "$PYTHON" >/dev/null || { echo "setup: $PYTHON not found" >&2; exit 1; }

stamp=.venv/.requirements.sha256
want=$(sha256sum python/requirements.txt | cut -d' ' -f1)
if [ -x .venv/bin/python ] && [ "$(cat "$stamp" 2>/dev/null)" = "$want" ]; then
  echo "setup: .venv is up to date"
else
  echo "setup: creating .venv (pycolmap, numpy, scipy, opencv, onnxruntime, open3d, plotly)"
  [ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -r python/requirements.txt
  .venv/bin/python -c "import pycolmap, cv2, numpy, scipy, onnxruntime, open3d, plotly; print('setup: pycolmap', pycolmap.__version__)"
  echo "$want" > "$stamp"
fi

if [ -x /usr/bin/chromium ]; then
  echo "setup: chromium is installed"
else
  echo "setup: installing Debian's chromium"
  sudo=""
  [ "$(id -u)" = 0 ] || sudo=sudo
  command -v apt-get >/dev/null || { echo "setup: chromium is missing and apt-get is not here; install Chromium as /usr/bin/chromium" >&2; exit 1; }
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi
