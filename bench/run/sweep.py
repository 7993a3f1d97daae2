"""`gibench sweep`: a run over each method's quality knobs (time-vs-error curves, Pareto fronts).

A method marks the knobs a sweep turns with `Param(quality=True, sweep=(v1, v2, ...))`.
`sweep_param_sets` expands them into parameter sets: the grid of values when the method has
one knob, otherwise one knob at a time with the others at their defaults (a full grid over
several knobs grows as the product of their value counts, and mostly repeats the default
axis). The runner renders every set, reusing its row cache, so a repeated sweep only renders
what changed; bench.analysis.curves turns the rows into the sweep and Pareto tables.
"""
from __future__ import annotations

import pandas as pd

from bench.analysis.curves import write_sweep
from bench.protocol import results as store
from bench.protocol.registry import MethodLoadError, load_method
from bench.run.config import RunConfig
from bench.run import serial


def quality_knobs(method_cls) -> dict:
    """name -> tuple of sweep values, for the method's quality knobs (checked against their ranges)."""
    knobs = {}
    for name, p in method_cls.params.items():
        if not p.quality:
            continue
        if not p.sweep:
            raise ValueError(f"method '{method_cls.name}': quality parameter '{name}' declares no sweep values")
        knobs[name] = tuple(p.check(method_cls.name, name, v) for v in p.sweep)
    return knobs


def sweep_param_sets(method_cls) -> list[dict]:
    """Parameter overrides to run: [{}] (defaults) for a method without quality knobs, the grid of
    values of a single knob, or one knob at a time around the defaults (defaults first, no duplicates)."""
    knobs = quality_knobs(method_cls)
    if not knobs:
        return [{}]
    defaults = {k: p.default for k, p in method_cls.params.items()}
    if len(knobs) == 1:
        (name, values), = knobs.items()
        return [{name: v} for v in values]
    sets, seen = [], set()
    for candidate in [{}] + [{name: v} for name, values in knobs.items() for v in values]:
        key = store.params_json(dict(defaults, **candidate))
        if key not in seen:
            seen.add(key)
            sets.append(candidate)
    return sets



def sweep_config(scenes: list, methods: list, **kwargs):
    """A RunConfig whose `params` expand each method's quality knobs (see sweep_param_sets)."""
    params = {}
    for m in methods:
        try:
            cls = load_method(m)
        except MethodLoadError:  # the runner records the failure as a row and goes on
            params[m] = [{}]
            continue
        params[m] = sweep_param_sets(cls)
    return RunConfig(scenes=list(scenes), methods=list(methods), params=params, **kwargs)


def run_sweep(scenes: list, methods: list, log=print, **kwargs):
    """Run the sweep and write its tables; returns (sweep table, pareto table, runner)."""
    cfg = sweep_config(scenes, methods, **kwargs)
    _, runner = serial.run(cfg, log=log)
    sweep_path, pareto_path = write_sweep(runner.run_dir)
    return pd.read_csv(sweep_path), pd.read_csv(pareto_path), runner
