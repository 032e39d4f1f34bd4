#!/usr/bin/env bash
# Sets up a fresh Debian machine for IPM-Bench: system libraries, a virtual
# environment in .venv with the project installed. Idempotent; safe to re-run.
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian packages: libLLVM 19 for Dr.Jit's LLVM backend (14/15 crash), libusb for open3d,
# libgl/libgomp for open3d's and pycolmap's shared objects.
# Node.js and npm run the Khronos glTF validator in the tests (tests/gltf) and install the report's
# 3D viewer (reports/js); Chromium (headless) opens the report in its browser test; rsync
# moves files for the storage plugin (jobs without a shared working directory); SLURM's daemons,
# clients and munge run the single-node cluster of scripts/slurm_local.sh (tests/test_slurm.py).
pkgs="libllvm19 libusb-1.0-0 libgomp1 libgl1 libegl1 chromium rsync slurmctld slurmd slurm-client munge"
command -v npm >/dev/null 2>&1 || pkgs="$pkgs nodejs npm"
missing=""
for p in $pkgs; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]" -c requirements.lock
npm ci --prefix tests/gltf --no-audit --no-fund --silent
npm ci --prefix reports/js --no-audit --no-fund --silent
echo "setup done: activate with 'source .venv/bin/activate'"
