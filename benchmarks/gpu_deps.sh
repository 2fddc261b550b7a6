#!/usr/bin/env bash
# lossvo's pure-Python dependencies of benchmarks/gpu_path.py, installed into .gpu-deps/ (git-ignored) for a
# GPU machine that has Python, torch and numpy and nothing else, and no network: carry .gpu-deps/ there and run
#   PYTHONPATH=src:.gpu-deps python benchmarks/gpu_path.py --out gpu.json
# Importing lossvo.models and lossvo.losses (and reading the shipped configs) needs these beyond torch and
# numpy. Each is pinned to the version in lossvo's venv; no dependencies resolved, no bytecode
# (the other machine's Python may differ: PyYAML then falls back from its C extension to pure Python).
# Run from anywhere: .venv/bin/pip (or $PIP) installs, .venv/bin/python (or $PYTHON) names the versions.
set -euo pipefail
cd "$(dirname "$0")/.."
PIP=${PIP:-.venv/bin/pip}
PYTHON=${PYTHON:-.venv/bin/python}
PACKAGES=(roma hydra-core omegaconf antlr4-python3-runtime PyYAML packaging)
pins=()
for name in "${PACKAGES[@]}"; do
    pins+=("$name==$("$PYTHON" -c 'import sys, importlib.metadata as m; print(m.version(sys.argv[1]))' "$name")")
done
rm -rf .gpu-deps
"$PIP" install --quiet --no-deps --no-compile --target .gpu-deps "${pins[@]}"
echo "installed into .gpu-deps ($(du -sh .gpu-deps | cut -f1)): ${pins[*]}"
