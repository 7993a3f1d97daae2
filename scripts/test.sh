#!/usr/bin/env bash
# Set up everything (apt packages, .venv) and run the test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
GIBENCH_BROWSER=1 bash scripts/setup.sh
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-$(ls /usr/lib/x86_64-linux-gnu/libLLVM-19.so* /usr/lib/*/libLLVM-19.so* 2>/dev/null | head -n 1)}"
export GIBENCH_CACHE_DIR="${GIBENCH_CACHE_DIR:-$PWD/.cache/gibench-tests}"
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
