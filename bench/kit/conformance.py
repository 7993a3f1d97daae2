"""The conformance suite: what every method plugin must keep, checked on small scenes.

`check_method(name, ctx, settings)` loads a method through the registry (as a run does) and
returns one `Verdict` per check, in this order:

    load           the `gibench.methods` entry point imports and has the protocol's attributes
    declarations   name, summary, stages, needs, flags, cost_terms and frames_identical are well formed
    manual         the docstring names the method, has the generated parameter table (README too),
                   an example `gibench run` line and, with a ladder, says what the ladder is
    parameters     every parameter is a Param with a doc; every number declares a range; values
                   outside it (and outside `choices`) are refused with a one-line ParamError
                   naming the parameter, by resolve_params and by a row rendered with one
    ladder         3-5 distinct rungs with the defaults among them, each valid and rendered
    images         rows render (bench.run.execute.render_outcome, the one row path): images of the
                   view's size, finite, non-negative
    gl_errors      no GL error in a frame, in prepare, or left behind after a row
    determinism    the same seed gives the same images bit for bit (a fresh GpuScene, a fresh
                   instance); a `frames_identical` declaration holds (two error frames compared)
    shared_passes  with the view's shared passes lent, no texture (contents or parameters) changes
                   and the images are those the method gives with passes of its own
    stages         the stages timed are the declared ones (or reported skipped); no readback
                   (texture, buffer or framebuffer read) inside a timed stage
    energy         on `sphere_inside`, the mean indirect radiance of 4 frames does not exceed the
                   analytic one-bounce value rho^2 I / (pi R^2) by more than the method's stated
                   `one_bounce_tolerance` (relative; default DEFAULT_ONE_BOUNCE_TOLERANCE;
                   None: the method makes no one-bounce claim; a zero indirect image claims none)

The checks that render share the rows (bench.kit.rendered_checks), on the first check scene the
method does not decline (SkipRow): a row at the defaults, the same row again from a fresh
GpuScene, one with the passes lent, each other ladder rung; then the defaults on `sphere_inside`.
"""
from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass

from bench.gl import create_context
from bench.gl.passes import expand_needs
from bench.kit import rendered_checks
from bench.kit.rendered_checks import DEFAULT_ONE_BOUNCE_TOLERANCE
from bench.model.scene import check_path_name
from bench.protocol import manual
from bench.protocol.cost import CostFacts
from bench.protocol.method import Param, ParamError, resolve_params
from bench.protocol.registry import MethodLoadError, entry_point_target, load_method
from bench.protocol.vocabulary import SHARED_STAGES, failure_reason

CHECKS = ("load", "declarations", "manual", "parameters", "ladder", "images", "gl_errors", "determinism",
          "shared_passes", "stages", "energy")
# The rendering checks use the first of these a method does not decline (SkipRow): lit_wall_corner
# (336 triangles, every sender on screen) is the cheapest for every method; visibility_gates
# declines open scenes, and takes the closed cornell_spot.
DEFAULT_SCENES = ("lit_wall_corner", "cornell_spot")
DEFAULT_RESOLUTION = (32, 24)
# CostFacts of a small and a large row: cost_terms must give finite, non-negative counts for both
COST_PROBES = (CostFacts(32, 24, 336, 7.0, 1.8), CostFacts(320, 180, 66_434, 1500.0, 20.0))


@dataclass(frozen=True)
class Verdict:
    """One check's outcome: PASS or FAIL and one line saying why."""
    check: str
    ok: bool
    reason: str

    def line(self) -> str:
        return f"{'PASS' if self.ok else 'FAIL'}  {self.check:<13s} {self.reason}"


@dataclass(frozen=True)
class CheckSettings:
    """Where the rendering checks run: the first of `scenes` (corpus names or scene files) the
    method does not decline, at a small size; the energy check adds sphere_inside."""
    scenes: tuple = DEFAULT_SCENES
    width: int = DEFAULT_RESOLUTION[0]
    height: int = DEFAULT_RESOLUTION[1]
    seed: int = 0


def verdict(check: str, problems: list, passed: str) -> Verdict:
    """FAIL with the first problem (and how many more) or PASS with `passed`."""
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        return Verdict(check, False, one_line(problems[0]) + more)
    return Verdict(check, True, passed)


def one_line(text) -> str:
    return " ".join(str(text).split())


# ---------------------------------------------------------------------------- declarations
def declaration_problems(cls) -> list[str]:
    problems = []
    try:
        check_path_name(cls.name, "method name")
    except ValueError as exc:
        problems.append(str(exc))
    if not isinstance(cls.summary, str) or not cls.summary.strip() or "\n" in cls.summary:
        problems.append(f"summary must be one non-empty line, got {cls.summary!r}")
    stages = cls.stages
    if not isinstance(stages, (tuple, list)) or not all(isinstance(s, str) and s.isidentifier() for s in stages):
        problems.append(f"stages must be a tuple of stage names (identifiers), got {stages!r}")
    else:
        if len(set(stages)) != len(stages):
            problems.append(f"stages {list(stages)} name a stage twice")
        shared = sorted(set(stages) & set(SHARED_STAGES))
        if shared:
            problems.append(f"stages {shared} are the shared passes' names; name the method's own stages")
    try:
        expand_needs(cls.needs)
    except (ValueError, TypeError) as exc:
        problems.append(f"needs: {exc}")
    for flag in ("reuses_shared_passes",):
        if not isinstance(getattr(cls, flag, True), bool):
            problems.append(f"{flag} must be True or False, got {getattr(cls, flag)!r}")
    for attr in ("prepare", "render", "release"):
        if not callable(getattr(cls, attr, None)):
            problems.append(f"{attr} is not callable")
    tolerance = getattr(cls, "one_bounce_tolerance", DEFAULT_ONE_BOUNCE_TOLERANCE)
    if tolerance is not None and not (isinstance(tolerance, (int, float)) and 0.0 <= tolerance <= 1.0):
        problems.append(f"one_bounce_tolerance must be None or a relative excess in [0, 1], got {tolerance!r}")
    try:
        defaults = resolve_params(cls, {})
    except Exception as exc:   # reported by the parameters check
        return problems + [f"the default parameters do not resolve ({failure_reason(exc)})"]
    identical = _call(lambda: cls.frames_identical(defaults))
    if not isinstance(identical, bool):
        problems.append(f"frames_identical(defaults) must return True or False, got {identical!r}")
    rungs = cls.ladder if isinstance(getattr(cls, "ladder", ()), (tuple, list)) else ()
    for rung in [{}] + [r for r in rungs if isinstance(r, dict)]:
        try:
            params = resolve_params(cls, rung)
        except Exception:   # an invalid rung: the ladder check says so
            continue
        for size in COST_PROBES:
            problem = _cost_terms_problem(cls, params, size)
            if problem:
                problems.append(f"cost_terms at {rung or 'the defaults'}: {problem}")
                break
    return problems


def _call(function):
    try:
        return function()
    except Exception as exc:
        return f"an exception ({failure_reason(exc)})"


def _cost_terms_problem(cls, params: dict, size: CostFacts) -> str:
    terms = _call(lambda: cls.cost_terms(params, size))
    if terms is None:
        return ""   # the method's guard skips such a row
    if not isinstance(terms, dict):
        return f"must return a dict of work counts or None, got {terms!r}"
    for key, value in terms.items():
        if not isinstance(key, str) or isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value) or value < 0:
            return f"term {key!r} = {value!r} is not a finite, non-negative count"
    return ""


# ---------------------------------------------------------------------------- manual
def manual_problems(cls) -> list[str]:
    doc = (sys.modules[cls.__module__].__doc__ or "").strip()
    if not doc:
        return [f"method.py of '{cls.name}' has no docstring: the docstring is the method's manual"]
    problems = []
    if f"`{cls.name}`" not in doc.splitlines()[0]:
        problems.append(f"the manual's first line does not name the method (`{cls.name}`: what it computes)")
    problems += manual.check(cls)
    if "gibench run" not in doc:
        problems.append("the manual has no example (an indented `gibench run ...` line)")
    if getattr(cls, "ladder", ()) and "ladder" not in doc.lower():
        problems.append("the manual does not say what the quality ladder is")
    return problems


# ---------------------------------------------------------------------------- parameters
def outside_values(p: Param) -> list:
    """Values `p` must refuse: just outside each end of its range, off its choices, a non-bool."""
    if p.choices is not None:
        return ["<not one of the choices>"]
    if isinstance(p.default, bool):
        return [2]
    values = []
    integer = isinstance(p.default, int)
    for bound, sign in ((p.low, -1), (p.high, 1)):
        if bound is not None:
            step = 1 if integer else max(abs(float(bound)), 1.0) * 1e-3
            values.append(bound + sign * step)
    return values


def parameter_problems(cls) -> list[str]:
    problems = []
    if not isinstance(cls.params, dict):
        return [f"params must be a dict of name -> Param, got {type(cls.params).__name__}"]
    for name, p in cls.params.items():
        if not isinstance(p, Param):
            problems.append(f"parameter '{name}' is not declared as a Param (got {type(p).__name__})")
            continue
        if not str(p.doc).strip():
            problems.append(f"parameter '{name}' has no doc: the manual's table is made from it")
        numeric = p.choices is None and isinstance(p.default, (int, float)) and not isinstance(p.default, bool)
        if numeric and (p.low is None or p.high is None):
            problems.append(f"parameter '{name}' declares no range (Param low and high): values outside what the "
                            f"method handles are not refused")
        for value in outside_values(p):
            try:
                resolve_params(cls, {name: value})
            except ParamError as exc:
                if "\n" in str(exc).strip() or f"'{name}'" not in str(exc):
                    problems.append(f"parameter '{name}'={value!r}: the refusal is not one line naming it ({exc!r})")
            except Exception as exc:
                problems.append(f"parameter '{name}'={value!r} raised {type(exc).__name__}, not a ParamError")
            else:
                problems.append(f"parameter '{name}'={value!r} is accepted outside its declared range")
        for value in p.sweep:
            try:
                resolve_params(cls, {name: value})
            except Exception as exc:
                problems.append(f"parameter '{name}': sweep value {value!r} is refused ({failure_reason(exc)})")
    try:
        resolve_params(cls, {})
    except Exception as exc:
        problems.append(f"the defaults are refused: {failure_reason(exc)}")
    return problems


def out_of_range_override(cls) -> dict | None:
    """One parameter set a row must refuse (the first declared range's low end, stepped out), or None."""
    for name, p in (cls.params.items() if isinstance(cls.params, dict) else ()):
        if isinstance(p, Param):
            values = outside_values(p)
            if values:
                return {name: values[0]}
    return None


# ---------------------------------------------------------------------------- ladder (declared)
def ladder_problems(cls) -> list[str]:
    """The ladder as declared: 3-5 distinct valid rungs, fast -> accurate, the defaults among them."""
    ladder = getattr(cls, "ladder", ())
    if not ladder:
        return []
    if not isinstance(ladder, (tuple, list)) or not all(isinstance(r, dict) for r in ladder):
        return [f"ladder must be a tuple of parameter-override dicts, got {ladder!r}"]
    problems = []
    if not 3 <= len(ladder) <= 5:
        problems.append(f"the ladder has {len(ladder)} rungs, not 3-5")
    if {} not in [dict(r) for r in ladder]:
        problems.append("the defaults ({}) are not a rung of the ladder")
    resolved = []
    for rung in ladder:
        try:
            resolved.append(json.dumps(resolve_params(cls, rung), sort_keys=True))
        except Exception as exc:
            problems.append(f"rung {rung} is invalid: {failure_reason(exc)}")
    if len(set(resolved)) != len(resolved):
        problems.append("two rungs resolve to the same parameters")
    return problems


# ---------------------------------------------------------------------------- the suite
def check_method(name: str, ctx=None, settings: CheckSettings | None = None) -> list[Verdict]:
    """Every check of CHECKS on the registered method `name`, one Verdict each."""
    settings = settings or CheckSettings()
    try:
        cls = load_method(name)
    except MethodLoadError as exc:
        return [Verdict("load", False, one_line(exc))] + [
            Verdict(c, False, "not run: the method did not load") for c in CHECKS[1:]]
    verdicts = [Verdict("load", True, f"{entry_point_target(name)}")]
    return verdicts + check_class(cls, ctx, settings)


def check_class(cls, ctx=None, settings: CheckSettings | None = None) -> list[Verdict]:
    """The checks after `load` on a method class (the project's tests call it with classes too)."""
    settings = settings or CheckSettings()
    ctx = ctx or create_context()
    declaration_faults = declaration_problems(cls)
    out = [verdict("declarations", declaration_faults, "" if declaration_faults else
                   f"stages {list(cls.stages)}, needs {sorted(cls.needs)}"),
           verdict("manual", manual_problems(cls), "docstring names the method, tables match the Param "
                   "declarations, an example")]
    rendered = rendered_checks.run(cls, ctx, settings, out_of_range_override(cls))
    row_refusal, _ = rendered.pop("parameters")
    out.append(verdict("parameters", parameter_problems(cls) + row_refusal,
                       f"{len(cls.params)} parameter(s), each refused outside its range in one line"))
    rung_faults, rungs_passed = rendered.pop("ladder")
    out.append(verdict("ladder", ladder_problems(cls) + rung_faults, rungs_passed))
    for check in CHECKS[5:]:
        problems, passed = rendered[check]
        out.append(verdict(check, problems, passed))
    return out
