#!/usr/bin/env bash
# lossvo's pure-Python dependencies that a GPU machine with Python, torch, numpy, Lightning, torchmetrics, OpenCV,
# SciPy, matplotlib and joblib lacks, installed into .gpu-deps/ (git-ignored) for such a machine without network:
# carry .gpu-deps/ there and run
#   PYTHONPATH=src:.gpu-deps python benchmarks/gpu_path.py --out gpu.json
#   PYTHONPATH=src:.gpu-deps python benchmarks/gpu_study.py --out OUT
# The first needs roma and Hydra's config packages; the second also runs python -m lossvo.train and
# lossvo.study, whose sweeps use Hydra's joblib launcher. Each is pinned to the version in lossvo's venv; no
# dependencies resolved, no bytecode (the other machine's Python may differ: PyYAML then falls back from its C
# extension to pure Python).
# Run from anywhere: .venv/bin/pip (or $PIP) installs, .venv/bin/python (or $PYTHON) names the versions.
set -euo pipefail
cd "$(dirname "$0")/.."
PIP=${PIP:-.venv/bin/pip}
PYTHON=${PYTHON:-.venv/bin/python}
PACKAGES=(roma hydra-core omegaconf antlr4-python3-runtime PyYAML packaging hydra-joblib-launcher)
pins=()
for name in "${PACKAGES[@]}"; do
    pins+=("$name==$("$PYTHON" -c 'import sys, importlib.metadata as m; print(m.version(sys.argv[1]))' "$name")")
done
rm -rf .gpu-deps
"$PIP" install --quiet --no-deps --no-compile --target .gpu-deps "${pins[@]}"
echo "installed into .gpu-deps ($(du -sh .gpu-deps | cut -f1)): ${pins[*]}"
