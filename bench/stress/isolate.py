"""A stress case in a child process, with a timeout and a memory cap: a parameter extreme (a count
at its maximum) may exhaust the machine or run for hours, and must cost one failed row only.

    python -m bench.stress.isolate SPEC.json

SPEC: {"scene": corpus name or scene file, "variant": a scene perturbation's name or null,
"method", "params", "view", "width", "height", "seed", "out": the .npz the images go to}. The
child writes SPEC.json.out ({"status"}) and, for a rendered case, the images.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.gl import create_context
from bench.model.corpus import load_scene
from bench.protocol.registry import load_method
from bench.protocol.vocabulary import Status
from bench.stress.case import CaseResult, run_case
from bench.stress.variants import scene_variant

CASE_TIMEOUT_S = 300.0
WORKER_MEMORY_BYTES = 6 << 30


def run_case_isolated(spec: dict, timeout: float) -> CaseResult:
    """`run_case` in a child process (python -m bench.stress.isolate SPEC.json) with a timeout and a memory cap."""
    with tempfile.TemporaryDirectory(prefix="gibench-stress-") as tmp:
        spec = dict(spec, out=str(Path(tmp) / "case.npz"))
        spec_path = Path(tmp) / "case.json"
        spec_path.write_text(json.dumps(spec))
        try:
            proc = subprocess.run([sys.executable, "-m", "bench.stress.isolate", str(spec_path)], capture_output=True,
                                  text=True, timeout=timeout, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        except subprocess.TimeoutExpired:
            return CaseResult(Status.failed(f"timeout after {timeout:g} s"))
        if proc.returncode < 0:
            return CaseResult(Status.failed(f"crashed (signal {-proc.returncode})"))
        if proc.returncode != 0:
            lines = [l for l in proc.stderr.strip().splitlines() if l.strip()]
            return CaseResult(Status.failed(f"worker exit {proc.returncode}: {lines[-1] if lines else '?'}"[:300]))
        result = json.loads((Path(tmp) / "case.json.out").read_text())
        if result["status"] != Status.OK:
            return CaseResult(result["status"])
        with np.load(spec["out"]) as z:
            return CaseResult(Status.OK, {"direct": z["direct"], "indirect": z["indirect"]})


def main(spec_path: str) -> int:
    try:
        resource.setrlimit(resource.RLIMIT_DATA, (WORKER_MEMORY_BYTES, WORKER_MEMORY_BYTES))
    except (ValueError, OSError):
        pass
    spec = json.loads(Path(spec_path).read_text())
    scene = load_scene(spec["scene"])
    if spec.get("variant"):
        scene = scene_variant(spec["variant"]).build(scene, spec["view"])
    res = run_case(create_context(), load_method(spec["method"]), scene, spec["view"], spec["width"],
                   spec["height"], spec["params"], spec["seed"])
    if res.images is not None:
        np.savez(spec["out"], **res.images)
    Path(spec_path + ".out").write_text(json.dumps({"status": res.status}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
