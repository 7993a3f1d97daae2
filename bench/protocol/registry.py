"""Method registry over the `gibench.methods` entry-point group.

Listing reads entry-point metadata only (no method is imported); `load_method` imports one on
demand. A method that fails to load raises `MethodLoadError` naming it, so a run can record
the failure and go on with the others.
"""
from __future__ import annotations

from importlib.metadata import entry_points

GROUP = "gibench.methods"
REQUIRED_ATTRIBUTES = ("name", "summary", "stages", "params", "needs", "prepare", "render", "release")


class MethodLoadError(RuntimeError):
    """Unknown method or a method plugin that failed to import or is malformed."""


def _entry_points() -> dict:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def list_methods() -> list[str]:
    """Registered method names, sorted, without importing any of them."""
    return sorted(_entry_points())


def entry_point_target(name: str) -> str:
    ep = _entry_points().get(name)
    return ep.value if ep is not None else ""


def load_method(name: str):
    """The method class registered under `name`."""
    eps = _entry_points()
    ep = eps.get(name)
    if ep is None:
        raise MethodLoadError(f"unknown method '{name}'; registered: {', '.join(sorted(eps)) or 'none'}")
    try:
        cls = ep.load()
    except Exception as exc:  # any import-time failure of a plugin is that plugin's failure
        raise MethodLoadError(f"method '{name}' failed to load ({ep.value}): {type(exc).__name__}: {exc}") from exc
    missing = [a for a in REQUIRED_ATTRIBUTES if not hasattr(cls, a)]
    if missing:
        raise MethodLoadError(f"method '{name}' ({ep.value}) lacks {missing} of the method protocol")
    if cls.name != name:
        raise MethodLoadError(f"method '{name}' ({ep.value}) declares name '{cls.name}'; they must match")
    return cls
