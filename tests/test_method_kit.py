"""The method author's kit (issue #28): `gibench new-method` refuses what it must, `gibench
check-method` fails each deliberately broken plugin of tests/fixtures/plugins with its one reason
and passes every method under methods/ (the end-to-end path from a new package to a run is
tests/test_method_kit_end_to_end.py)."""
from __future__ import annotations

import sys
from importlib.metadata import EntryPoint

import numpy as np
import pytest

import bench.cli as cli
from bench.kit import scaffold
from bench.kit.conformance import CHECKS, CheckSettings, check_class, parameter_problems
from bench.protocol import registry
from bench.protocol.method import FrameOutput, MethodBase, Param
from tests.fixtures.conformance import verdicts_of

FIXTURES = "tests.fixtures.plugins"
# fixture plugin -> (the one check it fails, what the reason says)
BROKEN = {
    "fixture_writes_shared": ("writes_shared.method:WritesShared", "shared_passes", "wrote the shared direct.radiance"),
    "fixture_nondeterministic": ("nondeterministic.method:Nondeterministic", "determinism",
                                 "seed 0 gave different indirect images in two rows"),
    "fixture_nan_pixels": ("nan_pixels.method:NanPixels", "images", "NaN/Inf indirect pixels"),
    "fixture_unranged_parameter": ("unranged_parameter.method:UnrangedParameter", "parameters",
                                   "parameter 'gain' declares no range"),
}


@pytest.fixture
def broken_plugins(monkeypatch):
    """The registry sees the project's methods and the broken fixtures, as if pip-installed."""
    real = registry.entry_points
    fakes = [EntryPoint(name, f"{FIXTURES}.{target}", registry.GROUP) for name, (target, _, _) in BROKEN.items()]
    monkeypatch.setattr(registry, "entry_points", lambda group: list(real(group=group)) +
                        [e for e in fakes if e.group == group])


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_check_method_fails_each_broken_plugin_with_its_reason(gl_ctx, broken_plugins, capsys, name):
    _, check, reason = BROKEN[name]
    assert cli.main(["check-method", name]) == 1
    lines = capsys.readouterr().out.splitlines()
    verdicts = [line for line in lines if line.startswith(("PASS", "FAIL"))]
    assert len(verdicts) == len(CHECKS), lines
    failed = [line for line in verdicts if line.startswith("FAIL")]
    assert len(failed) == 1 and failed[0].split()[1] == check, failed
    assert reason in failed[0], failed[0]
    assert lines[-1] == f"{name}: {len(CHECKS) - 1} of {len(CHECKS)} checks passed; failed: {check}"


@pytest.mark.parametrize("name", registry.list_methods())
def test_every_method_passes_check_method(gl_ctx, name):
    failed = [v.line() for v in verdicts_of(name).values() if not v.ok]
    assert failed == [], f"{name}: " + "; ".join(failed)
    assert list(verdicts_of(name)) == list(CHECKS)


class _Direct(MethodBase):
    """A direct-light method whose variants below break one rule each."""
    name = "direct"
    summary = "direct light"
    needs = frozenset({"direct", "shadow_map"})

    def render(self, frame, prof):
        return FrameOutput(direct=frame.passes.direct.radiance, indirect=None)


def _failed(cls, gl_ctx, checks) -> dict:
    verdicts = {v.check: v for v in check_class(cls, gl_ctx, CheckSettings(width=16, height=12))}
    return {c: verdicts[c].reason for c in checks if not verdicts[c].ok}


def test_undeclared_stages_and_a_readback_inside_a_stage_are_caught(gl_ctx):
    class UndeclaredStage(_Direct):
        stages = ()
        needs = frozenset()   # no shared stage either: the profiler then accepts any name, the check does not

        def render(self, frame, prof):
            with prof.stage("extra"):
                pass
            return FrameOutput(direct=np.zeros((frame.height, frame.width, 3), np.float32), indirect=None)

    assert "timed stage(s) ['extra'] are not declared" in _failed(UndeclaredStage, gl_ctx, ["stages"])["stages"]

    class DeclaresOthers(_Direct):
        stages = ("shade",)   # the profiler refuses 'extra': the row fails, the stages check says why

        def render(self, frame, prof):
            with prof.stage("extra"):
                pass
            return super().render(frame, prof)

    assert "stage 'extra' is not declared" in _failed(DeclaresOthers, gl_ctx, ["stages"])["stages"]

    class ReadsBack(_Direct):
        stages = ("shade",)

        def render(self, frame, prof):
            with prof.stage("shade"):
                frame.passes.direct.radiance.read()
            return super().render(frame, prof)

    assert "Texture.read inside the timed stage 'shade'" in _failed(ReadsBack, gl_ctx, ["stages"])["stages"]


def test_energy_above_the_analytic_bounce_and_a_false_identical_frames_claim_fail(gl_ctx):
    class TooBright(_Direct):
        def render(self, frame, prof):   # 0.2 > 2x rho^2 I / (pi R^2) = 0.0796 on sphere_inside
            return FrameOutput(direct=frame.passes.direct.radiance,
                               indirect=np.full((frame.height, frame.width, 3), 0.2, np.float32))

    assert "more light than one bounce holds" in _failed(TooBright, gl_ctx, ["energy"])["energy"]

    class FalselyIdentical(_Direct):
        @classmethod
        def frames_identical(cls, params):
            return True   # false: the frame index changes the image

        def render(self, frame, prof):
            return FrameOutput(direct=frame.passes.direct.radiance,
                               indirect=np.full((frame.height, frame.width, 3), 1e-3 * frame.index, np.float32))

    assert "declares identical frames" in _failed(FalselyIdentical, gl_ctx, ["determinism"])["determinism"]


def test_parameter_refusals_are_one_line_and_name_the_parameter():
    class Declared(_Direct):
        params = {"n": Param(4, "count", 1, 16), "mode": Param("a", "mode", choices=("a", "b")),
                  "on": Param(True, "switch"), "scale": Param(0.5, "scale", 0.0, 1.0, sweep=(0.0, 2.0))}

    problems = parameter_problems(Declared)
    assert problems == ["parameter 'scale': sweep value 2.0 is refused (method 'direct': parameter 'scale'=2.0 "
                        "outside [0.0, 1.0])"]
    Declared.params["scale"] = Param(0.5, "scale", 0.0, 1.0)
    assert parameter_problems(Declared) == []


def test_new_method_refuses_bad_names_and_used_folders(tmp_path, capsys):
    used = tmp_path / "used"
    used.mkdir()
    (used / "notes.txt").write_text("mine")
    for argv, message in (
            (["new-method", "My-Method", "--dir", str(tmp_path / "a")], "method name 'My-Method' is not allowed"),
            (["new-method", "class", "--dir", str(tmp_path / "a")], "is a Python keyword"),
            (["new-method", "ssdo", "--dir", str(tmp_path / "a")], "already registered"),
            (["new-method", "json", "--dir", str(tmp_path / "a")], "already an importable Python module"),
            (["new-method", "fresh_gi", "--dir", str(used)], "exists and is not an empty folder")):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and message in err, err
    assert not (tmp_path / "a").exists() and sorted(p.name for p in used.iterdir()) == ["notes.txt"]


def test_new_method_writes_the_template_with_its_names(tmp_path):
    written = scaffold.write_package("fresh_gi", tmp_path / "pkg")
    names = sorted(str(p.relative_to(tmp_path / "pkg")) for p in written)
    assert names == ["fresh_gi/README.md", "fresh_gi/__init__.py", "fresh_gi/method.py",
                     "fresh_gi/shaders/ambient.glsl", "fresh_gi/shaders/flux_sum.glsl", "pyproject.toml",
                     "tests/test_fresh_gi.py"]
    for path in written:
        text = path.read_text()
        assert scaffold.NAME_TOKEN not in text and scaffold.CLASS_TOKEN not in text, path
    assert 'fresh_gi = "fresh_gi.method:FreshGi"' in (tmp_path / "pkg/pyproject.toml").read_text()
    assert "| flux_stride | 1       | 1 .. 8 |" in (tmp_path / "pkg/fresh_gi/README.md").read_text()
    compile((tmp_path / "pkg/fresh_gi/method.py").read_text(), "method.py", "exec")
    assert sys.modules.get("fresh_gi") is None
