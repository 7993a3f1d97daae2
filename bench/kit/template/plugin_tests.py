"""Tests of `__method_name__`: gibench's conformance suite (what every method must keep), then the
method's own claims. Run with `pytest tests` after `pip install -e .`."""
import numpy as np

from bench.gl import create_context
from bench.kit.conformance import CheckSettings, check_method
from bench.model.corpus import load_scene
from bench.model.corpus.procedural import sphere_inside_indirect
from bench.run.harness import run_method

from __method_name__.method import __MethodClass__


def test_passes_the_conformance_suite():
    verdicts = check_method("__method_name__", create_context(), CheckSettings())
    failed = [v.line() for v in verdicts if not v.ok]
    assert not failed, "\n".join(failed)


def test_ambient_is_the_analytic_bounce_inside_a_sphere():
    """Inside a closed diffuse sphere every point sees the same first bounce: rho^2 I / (pi R^2)."""
    result = run_method(create_context(), __MethodClass__, load_scene("sphere_inside"), "main", 32, 24, frames=1)
    ratio = result.indirect.mean() / sphere_inside_indirect()
    assert abs(ratio - 1.0) < __MethodClass__.one_bounce_tolerance, ratio
    assert np.isfinite(result.indirect).all()
