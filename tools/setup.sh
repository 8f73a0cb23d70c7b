#!/usr/bin/env bash
# Create .venv at the repository root and install glsynth with its test extra.
# torch 2.13.0 first: on this project's machines it is the CPU build on local disk,
# while any other torch version pulls a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q torch==2.13.0
.venv/bin/python -m pip install -q -e ".[test]"
# anny builds its model data on first use (1-2 minutes, once per machine): do it here,
# not inside the first run's time.
.venv/bin/python -c "from glsynth.assets.bodies import prepare_anny; prepare_anny()"
