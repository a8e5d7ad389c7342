#!/usr/bin/env bash
# Create .venv and install scenelabel with its test tools, on a fresh machine, with nothing by hand.
# torch's CPU build is installed first: a bare `torch` requirement with no torch installed pulls a
# multi-GB CUDA build. (On this machine class `torch==2.13.0` is the CPU build on local disk; on
# other Linux machines set TORCH_INDEX=https://download.pytorch.org/whl/cpu.)
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
if ! .venv/bin/python -c "import torch" 2>/dev/null; then
  echo "setup: installing $TORCH_SPEC (CPU build)" >&2
  if [ -n "${TORCH_INDEX:-}" ]; then
    .venv/bin/python -m pip install -q "$TORCH_SPEC" --index-url "$TORCH_INDEX"
  else
    .venv/bin/python -m pip install -q "$TORCH_SPEC"
  fi
fi
echo "setup: installing scenelabel and its dependencies" >&2
if ! .venv/bin/python -m pip install -q -e ".[test]" > .venv/setup.log 2>&1; then
  cat .venv/setup.log >&2
  exit 1
fi
.venv/bin/python -c "import scenelabel, torch; print(f'setup: scenelabel {scenelabel.__version__}, torch {torch.__version__}')" >&2
