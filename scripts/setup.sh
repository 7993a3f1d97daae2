#!/usr/bin/env bash
# Sets up everything gibench needs on a fresh Debian machine: apt packages for headless
# Mesa EGL and libLLVM 19 (Mitsuba's LLVM variant), a venv in .venv, and the package itself.
# Idempotent: a second call only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libllvm19 g++"   # g++: the native HDR-FLIP build (bench/analysis/flip_native)
if [ "${GIBENCH_BROWSER:-0}" = "1" ]; then APT_PACKAGES="$APT_PACKAGES chromium"; fi
missing=""
for p in $APT_PACKAGES; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
  SUDO=""; [ "$(id -u)" = "0" ] || SUDO="sudo"
  echo "setup: installing apt packages:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.gibench-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing Python packages into .venv"
  .venv/bin/pip install -q --upgrade pip
  .venv/bin/pip install -q -e '.[test]'
  touch "$stamp"
fi
