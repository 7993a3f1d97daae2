"""HDR-FLIP compiled from NVIDIA's FLIP.h on first use, the pip wheel `flip-evaluator` as fallback.

The same FLIP.h the wheel is built from, compiled here without FMA contraction, gives the wheel's
map bit for bit at about a quarter of its cost, and splits into a reference half (computed once per
reference and exposure range: `reference_features`) and a test half (`map_against_reference`);
README.md beside this file says where the sources come from and why the flags.

The shared library is built into `<cache>/flip_native/` ($GIBENCH_CACHE_DIR, else ~/.cache/gibench)
under a name keyed by the sources' hash, the flags, the compiler's version and the CPU, written to a
temporary file and renamed into place, so processes building at once (Dask workers) never load a
half-written library. Without a compiler, or when the build fails, `library()` is None and the
callers use the wheel (same values, slower), after one line on stderr saying why.
`GIBENCH_FLIP_WHEEL=1` forces the wheel.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

SOURCES = (Path(__file__).with_name("FLIP.h"), Path(__file__).with_name("flip_native.cpp"))
# -ffp-contract=off: no fused multiply-add, whose single rounding changes FLIP's bits wherever the
# target has FMA (with -march=native on most CPUs of the last decade); -O3 without -ffast-math
# vectorises the filters across pixels and keeps each pixel's float operations and their order;
# -march=native: the widest vectors of this CPU (the library is keyed by it, see library_path).
FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fopenmp", "-shared", "-fPIC", "-std=c++17")
ABI = 2
FORCE_WHEEL_ENV = "GIBENCH_FLIP_WHEEL"

_state: dict = {}   # "lib": the loaded library or None, once decided


def _cache_dir() -> Path:
    return Path(os.environ.get("GIBENCH_CACHE_DIR", Path.home() / ".cache" / "gibench")) / "flip_native"


def _compiler() -> tuple[str, str] | None:
    """(path, version line) of the C++ compiler ($CXX, else g++, else c++), or None."""
    for name in (os.environ.get("CXX"), "g++", "c++"):
        path = shutil.which(name) if name else None
        if path:
            try:
                out = subprocess.run([path, "--version"], capture_output=True, text=True, timeout=30)
            except (OSError, subprocess.SubprocessError):
                continue
            if out.returncode == 0 and out.stdout.strip():
                return path, out.stdout.splitlines()[0].strip()
    return None


def _cpu_signature() -> str:
    """This CPU's model and instruction-set flags: a library built with -march=native is only
    loaded on a CPU like the one it was built on (a cache shared between machines)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    keys = ("model name", "flags", "Features", "CPU implementer", "CPU part")
    picked = {ln.split(":", 1)[0].strip(): ln.split(":", 1)[1].strip() for ln in lines if ":" in ln
              and ln.split(":", 1)[0].strip() in keys}
    return "|".join(f"{k}={picked[k]}" for k in sorted(picked)) or f"{platform.machine()}|{platform.processor()}"


def library_path(compiler_version: str) -> Path:
    h = hashlib.sha256(f"{ABI}|{' '.join(FLAGS)}|{compiler_version}|{_cpu_signature()}".encode())
    for src in SOURCES:
        h.update(src.read_bytes())
    return _cache_dir() / f"flip_native-{h.hexdigest()[:20]}.so"


def _build(compiler: str, target: Path) -> None:
    """Compile into a temporary file beside `target`, then rename it into place (atomic)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".so.tmp", dir=target.parent)
    os.close(fd)
    try:
        out = subprocess.run([compiler, *FLAGS, "-o", tmp, str(SOURCES[1])], capture_output=True, text=True,
                             timeout=600)
        if out.returncode != 0:
            lines = [ln for ln in (out.stderr or out.stdout).splitlines() if ln.strip()]
            raise RuntimeError(f"compiler failed: {lines[0] if lines else f'exit status {out.returncode}'}")
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _load(path: Path):
    lib = ctypes.CDLL(str(path))
    if lib.flip_native_abi() != ABI:
        raise RuntimeError(f"{path.name} has ABI {lib.flip_native_abi()}, expected {ABI}")
    ptr, i, f = ctypes.c_void_p, ctypes.c_int, ctypes.c_float
    lib.flip_hdr.argtypes = [ptr, ptr, i, i, f, f, f, i, ptr]
    lib.flip_reference_features.argtypes = [ptr, i, i, f, f, f, i, ptr, i]
    lib.flip_against_reference.argtypes = [ptr, i, i, ptr, i, i, i, i, f, f, f, i, ptr, i]
    for fn in (lib.flip_hdr, lib.flip_reference_features, lib.flip_against_reference):
        fn.restype = None
    return lib


def library():
    """The compiled FLIP library, building it if needed; None when the wheel must be used."""
    if "lib" in _state:
        return _state["lib"]
    lib, why = None, None
    if os.environ.get(FORCE_WHEEL_ENV, "").strip() not in ("", "0"):
        why = f"{FORCE_WHEEL_ENV} is set"
    else:
        compiler = _compiler()
        if compiler is None:
            why = "no C++ compiler found (g++ or c++; $CXX)"
        else:
            try:
                path = library_path(compiler[1])
                if not path.is_file():
                    _build(compiler[0], path)
                lib = _load(path)
            except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
                why = f"building FLIP.h failed ({' '.join(str(exc).split())})"
    if lib is None and os.environ.get(FORCE_WHEEL_ENV, "").strip() in ("", "0"):
        print(f"gibench: HDR-FLIP runs on the pip wheel: {why}; metrics are slower, values the same", file=sys.stderr)
    _state["lib"] = lib
    return lib


def _floats(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def flip_map(ref32: np.ndarray, img32: np.ndarray, ppd: float, start: float, stop: float, exposures: int) -> np.ndarray:
    """The HDR map (HxW float32) of two HxWx3 images, from the two halves: the wheel's values."""
    features = reference_features(ref32, ppd, start, stop, exposures)
    return map_against_reference(features, img32, 0, 0, ppd, start, stop)


def flip_evaluate(ref32: np.ndarray, img32: np.ndarray, ppd: float, start: float, stop: float,
                  exposures: int) -> np.ndarray:
    """FLIP.h's own FLIP::evaluate (HDR), compiled here: what the tests hold the halves and the wheel to."""
    lib = library()
    ref32, img32 = _floats(ref32), _floats(img32)
    h, w = ref32.shape[:2]
    out = np.empty((h, w), np.float32)
    lib.flip_hdr(ref32.ctypes.data, img32.ctypes.data, w, h, ppd, start, stop, int(exposures), out.ctypes.data)
    return out


def reference_features(ref32: np.ndarray, ppd: float, start: float, stop: float, exposures: int,
                       threads: int = 0) -> np.ndarray:
    """The reference's half of the map: (exposures, H, W, 5) float32 (filtered Lab-Hunt colour, edge, point).
    `threads`: OpenMP threads (0: OpenMP's default), here and below."""
    lib = library()
    ref32 = _floats(ref32)
    h, w = ref32.shape[:2]
    out = np.empty((int(exposures), h, w, lib.flip_native_features_per_pixel()), np.float32)
    lib.flip_reference_features(ref32.ctypes.data, w, h, ppd, start, stop, int(exposures), out.ctypes.data, int(threads))
    return out


def map_against_reference(features: np.ndarray, test_crop: np.ndarray, y0: int, x0: int, ppd: float, start: float,
                          stop: float, threads: int = 0) -> np.ndarray:
    """The map (crop's HxW float32) of a crop of the test image, top-left at (y0, x0), against the
    reference's `features` (of the same ppd and exposures). Its values are the whole image's map
    wherever FLIP's filter windows stay inside the crop or reach the image's edge with it."""
    lib = library()
    test_crop = _floats(test_crop)
    exposures, h, w = features.shape[:3]
    ch, cw = test_crop.shape[:2]
    if not (0 <= y0 and y0 + ch <= h and 0 <= x0 and x0 + cw <= w):
        raise ValueError(f"crop {cw}x{ch} at ({x0}, {y0}) is outside the {w}x{h} reference")
    features = np.ascontiguousarray(features, dtype=np.float32)
    out = np.empty((ch, cw), np.float32)
    lib.flip_against_reference(features.ctypes.data, w, h, test_crop.ctypes.data, x0, y0, cw, ch, ppd, start, stop,
                               exposures, out.ctypes.data, int(threads))
    return out
