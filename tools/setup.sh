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
# open3d (a test dependency: the tests read exported PLY files with it) needs libusb-1.0 at import.
if ! { ldconfig -p || /sbin/ldconfig -p; } 2>/dev/null | grep -q "libusb-1.0.so.0"; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing libusb-1.0-0 (Debian) for open3d" >&2
    DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "setup: warning: libusb-1.0 is missing and open3d (tests) needs it: run 'sudo apt-get install libusb-1.0-0'" >&2
  fi
fi
# The web viewer's browser test and tools/screenshots.py drive a headless Chromium (Debian: chromium);
# without one that test is skipped. Setup never fails for it.
if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1 \
    && ! command -v google-chrome >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing chromium (Debian) for the viewer's browser test" >&2
    if ! { DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null \
        && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }; then
      echo "setup: warning: could not install chromium: the viewer's browser test will be skipped" >&2
    fi
  else
    echo "setup: warning: no chromium: the viewer's browser test is skipped (run 'sudo apt-get install chromium')" >&2
  fi
fi
echo "setup: installing scenelabel and its dependencies" >&2
if ! .venv/bin/python -m pip install -q -e ".[test]" > .venv/setup.log 2>&1; then
  cat .venv/setup.log >&2
  exit 1
fi
.venv/bin/python -c "import scenelabel, torch; print(f'setup: scenelabel {scenelabel.__version__}, torch {torch.__version__}')" >&2
