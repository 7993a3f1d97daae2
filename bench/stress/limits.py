"""Documented limits: the stress failures a target's manual owns up to (bench.stress.suite).

A method's manual is its module's docstring (and the class's own docstring, and a
`stress_limits` ClassVar {pattern: reason}); the references' manual is the docstring of the
`reference` package and of reference.integrators. A "Stress limit PATTERN: reason" line
documents every perturbation whose name matches the fnmatch PATTERN; its one parser is
bench.protocol.manual.stress_limits.
"""
from __future__ import annotations

import fnmatch
import importlib
import sys

from bench.protocol.manual import stress_limits

REFERENCE_MANUALS = ("reference", "reference.integrators")


def documented_limits(target) -> dict:
    """{fnmatch pattern: reason} from a method class (docstring lines and `stress_limits`), or for
    the string "reference" from the reference package's docstrings."""
    texts, limits = [], {}
    if target == "reference":
        for mod in REFERENCE_MANUALS:
            try:
                texts.append(importlib.import_module(mod).__doc__ or "")
            except Exception:  # a reference package that fails to import documents nothing
                pass
    else:
        module = sys.modules.get(getattr(target, "__module__", ""), None)
        texts.append(getattr(module, "__doc__", "") or "")
        texts.append(getattr(target, "__doc__", "") or "")
        limits.update(dict(getattr(target, "stress_limits", {}) or {}))
    for text in texts:
        for pattern, reason in stress_limits(text).items():
            limits.setdefault(pattern, reason)
    return limits


def match_limit(limits: dict, perturbation: str) -> str | None:
    """The reason of the first pattern of `limits` that `perturbation` matches, else None."""
    for pattern, reason in limits.items():
        if fnmatch.fnmatchcase(perturbation, pattern):
            return reason
    return None
