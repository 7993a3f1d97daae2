#!/usr/bin/env bash
# Set up everything (apt packages, .venv), run the default benchmark and build its HTML report.
# The default run: procedural and real scenes (sponza, sibenik, conference, cornell_box) at
# 320x180, every method's quality ladder (one time-vs-error curve per method and view), Mitsuba
# references (cached), calibrated timing. Extra arguments go to `gibench run` (e.g. --quick for
# a first report in minutes, --res 640x360, --scenes cornell_spot).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-$(ls /usr/lib/x86_64-linux-gnu/libLLVM-19.so* /usr/lib/*/libLLVM-19.so* 2>/dev/null | head -n 1)}"
# manylights with both VPL lobes: the report then shows, per scene, how far the flc lobe (what FLC
# estimates without bias) is from the Lambertian bounce that Mitsuba computes. It sums every
# triangle at every pixel, so it runs on the scenes of up to 20k triangles (the others: skipped, said so).
.venv/bin/gibench run --param manylights.emission=lambert,flc --param manylights.max_triangles=20000 "$@"
.venv/bin/gibench report runs/latest
