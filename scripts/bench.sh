#!/usr/bin/env bash
# Set up everything (apt packages, .venv), run the default benchmark and build its HTML report.
# Extra arguments go to `gibench run` (e.g. --res 256x192 --scenes cornell_spot).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-$(ls /usr/lib/x86_64-linux-gnu/libLLVM-19.so* /usr/lib/*/libLLVM-19.so* 2>/dev/null | head -n 1)}"
# manylights with both VPL lobes: the report then shows, per scene, how far the flc lobe (what FLC
# estimates without bias) is from the Lambertian bounce that Mitsuba computes.
# The IR baselines also run at val_clustered's VPL count (1024), so VAL is compared at equal VPLs.
.venv/bin/gibench run --param manylights.emission=lambert,flc \
    --param ir_unshadowed.vpl_count=256,1024 --param ir_shadowed.vpl_count=256,1024 "$@"
.venv/bin/gibench report runs/latest
