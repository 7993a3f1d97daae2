"""The method registry: fake entry points, lazy listing, failing plugins."""
import sys
import types
from importlib.metadata import EntryPoint

import pytest

from bench.kit.conformance import ladder_problems, manual_problems, parameter_problems
from bench.protocol import registry
from bench.protocol.method import MethodBase, Param, ParamError, resolve_params


class FakeGood(MethodBase):
    name = "fake_good"
    summary = "a fake method"
    params = {"n": Param(4, "count", 1, 16), "mode": Param("a", "mode", choices=("a", "b"))}

    def render(self, frame, prof):
        raise AssertionError("not rendered in these tests")


@pytest.fixture
def fake_entry_points(monkeypatch):
    mod = types.ModuleType("fake_gibench_plugins")
    mod.FakeGood = FakeGood
    mod.Misnamed = type("Misnamed", (FakeGood,), {"name": "other"})
    mod.NotAMethod = object
    monkeypatch.setitem(sys.modules, "fake_gibench_plugins", mod)
    eps = [EntryPoint("fake_good", "fake_gibench_plugins:FakeGood", registry.GROUP),
           EntryPoint("fake_broken", "no_such_module_xyz.sub:Thing", registry.GROUP),
           EntryPoint("fake_misnamed", "fake_gibench_plugins:Misnamed", registry.GROUP),
           EntryPoint("fake_incomplete", "fake_gibench_plugins:NotAMethod", registry.GROUP)]
    monkeypatch.setattr(registry, "entry_points", lambda group: [e for e in eps if e.group == group])
    return eps


def test_listing_is_lazy(fake_entry_points):
    # the broken plugin is listed although its module does not exist: listing imports nothing
    assert registry.list_methods() == ["fake_broken", "fake_good", "fake_incomplete", "fake_misnamed"]
    assert "no_such_module_xyz" not in sys.modules


def test_load_good(fake_entry_points):
    assert registry.load_method("fake_good") is FakeGood


def test_failing_plugin_names_itself(fake_entry_points):
    with pytest.raises(registry.MethodLoadError, match="method 'fake_broken' failed to load"):
        registry.load_method("fake_broken")


def test_unknown_method(fake_entry_points):
    with pytest.raises(registry.MethodLoadError, match="unknown method 'nope'.*fake_good"):
        registry.load_method("nope")


def test_malformed_plugins(fake_entry_points):
    with pytest.raises(registry.MethodLoadError, match="declares name 'other'"):
        registry.load_method("fake_misnamed")
    with pytest.raises(registry.MethodLoadError, match="lacks"):
        registry.load_method("fake_incomplete")


def test_real_registry_lists_the_baselines():
    names = registry.list_methods()
    for name in ("direct", "ir_unshadowed", "ir_shadowed", "manylights", "flc", "ssdo", "dss"):
        assert name in names


def test_params_are_range_checked():
    assert resolve_params(FakeGood, {}) == {"n": 4, "mode": "a"}
    assert resolve_params(FakeGood, {"n": 16.0})["n"] == 16
    with pytest.raises(ParamError, match="parameter 'n'=17 outside"):
        resolve_params(FakeGood, {"n": 17})
    with pytest.raises(ParamError, match="'mode'='c' not one of"):
        resolve_params(FakeGood, {"mode": "c"})
    with pytest.raises(ParamError, match="unknown parameter"):
        resolve_params(FakeGood, {"q": 1})
    with pytest.raises(ParamError, match="must be an integer"):
        resolve_params(FakeGood, {"n": 2.5})
    assert parameter_problems(FakeGood) == []   # the conformance suite's parameters check agrees


@pytest.mark.parametrize("name", registry.list_methods())
def test_quality_ladder_is_well_formed(name):
    # a ladder (issue #14) is 3-5 distinct valid rungs, fast -> accurate, with the defaults among
    # them, and the manual says what it is: the conformance suite's declared-ladder and manual checks
    cls = registry.load_method(name)
    assert ladder_problems(cls) == [], name
    assert [p for p in manual_problems(cls) if "ladder" in p] == [], name


def test_the_ladder_check_names_each_fault():
    for ladder, fault in (((), None), (({}, {"n": 8}), "the ladder has 2 rungs, not 3-5"),
                          (({"n": 2}, {"n": 8}, {"n": 16}), "the defaults ({}) are not a rung"),
                          (({"n": 2}, {}, {"n": 4}), "two rungs resolve to the same parameters"),
                          (({"n": 2}, {}, {"n": 17}), "rung {'n': 17} is invalid")):
        problems = ladder_problems(type("Laddered", (FakeGood,), {"ladder": ladder}))
        assert (problems == []) if fault is None else any(p.startswith(fault) for p in problems), (ladder, problems)
