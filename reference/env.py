"""Importing Mitsuba 3 with the right variant, or a clear message saying what to install.

`llvm_ad_rgb` is preferred (vectorised, JIT-compiled over all pixels); `scalar_rgb` is the
fallback, with a warning (correct but slow: one Python call per sample). The variant can be
forced with GIBENCH_MITSUBA_VARIANT.
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path

PREFERRED_VARIANT = "llvm_ad_rgb"
FALLBACK_VARIANT = "scalar_rgb"
_LLVM_CANDIDATES = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
                    "/usr/lib/llvm-19/lib/libLLVM.so")

INSTALL_HINT = ("install it with `pip install mitsuba` and, for the fast llvm_ad_rgb variant, "
                "apt `libllvm19` with DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so")


class ReferenceUnavailable(Exception):
    """Mitsuba 3 is missing or no usable variant: references (and error columns) cannot be made."""


_state: dict = {}


def _set_llvm_path() -> None:
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return
    for cand in _LLVM_CANDIDATES:
        if Path(cand).is_file():
            os.environ["DRJIT_LIBLLVM_PATH"] = cand
            return


def load_mitsuba():
    """Return the `mitsuba` module with a variant set (llvm_ad_rgb, else scalar_rgb with a warning)."""
    if "mi" in _state:
        return _state["mi"]
    if "error" in _state:
        raise ReferenceUnavailable(_state["error"])
    _set_llvm_path()
    try:
        import mitsuba as mi
    except ImportError as exc:
        _state["error"] = f"Mitsuba 3 is not installed ({exc}): {INSTALL_HINT}"
        raise ReferenceUnavailable(_state["error"]) from None
    forced = os.environ.get("GIBENCH_MITSUBA_VARIANT")
    wanted = [forced] if forced else [PREFERRED_VARIANT, FALLBACK_VARIANT]
    errors = []
    for variant in wanted:
        try:
            mi.set_variant(variant)
        except Exception as exc:  # ImportError / RuntimeError when LLVM cannot be loaded
            errors.append(f"{variant}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
            continue
        if variant != PREFERRED_VARIANT and not forced:
            warnings.warn(f"Mitsuba variant {PREFERRED_VARIANT} unavailable ({errors[0]}); falling back to "
                          f"{variant} (slow). For {PREFERRED_VARIANT}: apt `libllvm19` and "
                          f"DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so", RuntimeWarning)
        from reference import integrators
        integrators.register(mi)
        _state["mi"] = mi
        return mi
    _state["error"] = f"no usable Mitsuba variant ({'; '.join(errors)}): {INSTALL_HINT}"
    raise ReferenceUnavailable(_state["error"])


def mitsuba_version() -> tuple[str, str]:
    """(Mitsuba version, active variant), loading Mitsuba if needed."""
    mi = load_mitsuba()
    return mi.__version__, mi.variant()


def is_jit(mi) -> bool:
    return mi.variant().startswith(("llvm_", "cuda_"))
