"""Issue 6's cross-method check (the FLC paper's Sec. 7 comparison): SSDO against the object-space
methods DSS and FLC, with `manylights` (emission lambert: the exact unshadowed one-bounce sum)
as the yardstick of indirect error.

- `hidden_bounce`: everything on screen is lit by a surface behind the camera. SSDO, which
  only knows on-screen senders, misses it; DSS and FLC (when they load) see it.
- `cornell_spot`: the spot lights the ceiling above the camera, and the only directly lit
  surface on screen is a strip of the tall block (by design: "most light on screen is
  indirect"). SSDO therefore misses nearly all of it here too; DSS and FLC land within a small
  factor of the exact sum. The issue expected SSDO within a small factor on this scene as
  well; that does not hold for this corpus scene, and the test records what does hold.
- `cornell_floor_spot` (the same box, the spot aimed at the visible floor): with its senders on
  screen, SSDO picks up light where the exact bounce has it and beats "no indirect light".

FLC runs at its defaults, one real-time frame (issue 10: its defaults estimate the bounce in a
single frame; until then this test ran it in progressive mode with 64 sub-frames because one
default frame scored relMSE 0.74-1.00 on hidden_bounce, as bad as SSDO).

DSS and FLC are included only if they load (`bench.protocol.registry.load_method`); the SSDO-vs-
manylights part always runs.
"""
import numpy as np
import pytest

from bench.model.corpus import load_scene
from bench.model.scene import Scene, SpotLight, compute_facts
from bench.protocol.registry import MethodLoadError, load_method
from bench.run.harness import run_method
from methods.manylights.method import ManyLights
from methods.ssdo.method import ScreenSpaceDirectionalOcclusion as Ssdo

W, H = 128, 96  # the tiled/interleaved methods need a few tiles of pixels: the largest test size
_SCENES: dict = {}
_INDIRECT: dict = {}


def scene(name):
    if name not in _SCENES:
        if name == "cornell_floor_spot":
            base = load_scene("cornell_spot")
            light = SpotLight([0.0, 1.9, 0.2], [0.0, 0.0, -0.3], [20.0] * 3, cutoff_angle_deg=35.0)
            _SCENES[name] = Scene.build(name, base.vertices, base.faces, base.albedo, [light], base.cameras,
                                        normals=base.normals)
        else:
            _SCENES[name] = load_scene(name)
    return _SCENES[name]


OBJECT_SPACE_PARAMS = {"flc": {}, "dss": {}}   # both at their defaults, one frame


def indirect(ctx, method_cls, scene_name, params=None):
    if params is None:
        params = OBJECT_SPACE_PARAMS.get(method_cls.name)
    key = (method_cls.name, scene_name, tuple(sorted((params or {}).items())))
    if key not in _INDIRECT:
        sc = scene(scene_name)
        r = run_method(ctx, method_cls, sc, "main", W, H, params, seed=0, frames=1, facts=compute_facts(sc))
        _INDIRECT[key] = r.indirect.astype(np.float64)
    return _INDIRECT[key]


def rel_mse(image, ref):
    return float(((image - ref) ** 2).mean() / (ref ** 2).mean())


def optional_method(name):
    try:
        return load_method(name)
    except MethodLoadError as exc:
        pytest.skip(f"{name} not available: {exc}")


def test_ssdo_misses_the_hidden_sender(gl_ctx):
    ref = indirect(gl_ctx, ManyLights, "hidden_bounce")
    ssdo = indirect(gl_ctx, Ssdo, "hidden_bounce")
    assert ref.mean() > 0.01 and (ref.sum(axis=2) > 0).mean() > 0.9
    assert ssdo.mean() < 0.05 * ref.mean()
    assert rel_mse(ssdo, ref) > 0.9          # no better than returning no indirect light at all


def test_ssdo_misses_cornell_spots_off_screen_patch(gl_ctx):
    ref = indirect(gl_ctx, ManyLights, "cornell_spot")
    ssdo = indirect(gl_ctx, Ssdo, "cornell_spot")
    assert ref.mean() > 0.01
    assert ssdo.mean() < 0.1 * ref.mean()
    assert rel_mse(ssdo, ref) > 0.8


def test_ssdo_with_on_screen_senders_beats_no_indirect(gl_ctx):
    ref = indirect(gl_ctx, ManyLights, "cornell_floor_spot")
    for params in ({}, {"radius_rel": 0.25}):
        ssdo = indirect(gl_ctx, Ssdo, "cornell_floor_spot", params)
        assert ssdo.mean() > 0.01 * ref.mean()
        assert rel_mse(ssdo, ref) < 1.0, params
        # where SSDO puts light, the exact bounce has light too
        lit = ssdo.sum(axis=2) > 0.01 * ssdo.sum(axis=2).max()
        assert np.all(ref.sum(axis=2)[lit] > 0)
    # a small hemisphere misses most of the visible senders; the default one already reaches them
    # (with each sample's true patch area, a larger one adds no sender, so no more light)
    small = indirect(gl_ctx, Ssdo, "cornell_floor_spot", {"radius_rel": 0.25}).mean()
    default = indirect(gl_ctx, Ssdo, "cornell_floor_spot").mean()
    large = indirect(gl_ctx, Ssdo, "cornell_floor_spot", {"radius_rel": 1.0}).mean()
    assert small < 0.5 * default and default > 0.8 * large, (small, default, large)


@pytest.mark.parametrize("name", ["dss", "flc"])
def test_hidden_bounce_ssdo_error_clearly_larger(gl_ctx, name):
    cls = optional_method(name)
    ref = indirect(gl_ctx, ManyLights, "hidden_bounce")
    err_other = rel_mse(indirect(gl_ctx, cls, "hidden_bounce"), ref)
    err_ssdo = rel_mse(indirect(gl_ctx, Ssdo, "hidden_bounce"), ref)
    assert err_other < 0.5 * err_ssdo, (name, err_other, err_ssdo)


@pytest.mark.parametrize("name", ["dss", "flc"])
def test_cornell_spot_object_space_methods_within_a_small_factor(gl_ctx, name):
    cls = optional_method(name)
    ref = indirect(gl_ctx, ManyLights, "cornell_spot")
    other = indirect(gl_ctx, cls, "cornell_spot")
    assert 0.5 < other.mean() / ref.mean() < 2.0, name
    assert rel_mse(other, ref) < 0.5, name
    assert rel_mse(other, ref) < rel_mse(indirect(gl_ctx, Ssdo, "cornell_spot"), ref), name


def test_dss_and_flc_within_a_small_factor_of_each_other(gl_ctx):
    loaded = []
    for name in ("dss", "flc"):
        try:
            loaded.append(load_method(name))
        except MethodLoadError:
            pass
    if len(loaded) < 2:
        pytest.skip("needs both dss and flc")
    for scene_name in ("hidden_bounce", "cornell_spot"):
        ref = indirect(gl_ctx, ManyLights, scene_name)
        errs = [rel_mse(indirect(gl_ctx, cls, scene_name), ref) for cls in loaded]
        means = [indirect(gl_ctx, cls, scene_name).mean() for cls in loaded]
        assert max(means) < 2.0 * min(means), (scene_name, means)
        assert max(errs) < 0.5, (scene_name, errs)
