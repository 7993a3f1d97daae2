"""val_clustered at its default parameters against per-VPL hard shadows (issue #23): the defaults
(map origin at the cluster's medoid VPL with nothing ignored, the CSSM kernel matched to a box of
the paper's penumbra width, 8 Fourier terms) keep the light of `rooms` (zero-thickness walls
between three rooms, the light in room 1) where the walls put it; the paper's setting (origin
at the cluster's mean, geometry within 0.5 x the VAL's size of it ignored, 4 terms) lets it
through the walls and along their junctions."""
import numpy as np
import pytest

from bench.analysis.metrics import relmse
from bench.run.harness import run_method
from methods.ir_shadowed.method import InstantRadiosityShadowed
from methods.val_clustered.method import ClusteredVirtualAreaLights, interleave_block

W, H = 96, 72
PAPER = {"val_origin": "centre", "near_ignore": 0.5, "cssm_kernel": "lod", "fourier_terms": 4, "interleave": 8,
         "contact_test": "off", "blur_visibility_diff": 1.0, "csm_depth_range": "unit"}


@pytest.fixture(scope="module")
def rooms():
    from bench.model.corpus import load_scene
    return load_scene("rooms")


def render(ctx, cls, scene, view, params):
    return run_method(ctx, cls, scene, view, W, H, params, seed=0, frames=1).indirect


def test_defaults_follow_per_vpl_shadows_through_a_door(gl_ctx, rooms):
    """Camera in room 2 looking through door 1 at lit room 1: against ir_shadowed with the same
    1024 VPLs, the default image's relMSE is under a quarter of no indirect light's and its mean
    within issue #23's band. The paper's setting (0.72 of no indirect light's at 96 x 72) leaks
    along the junctions of the walls with the door wall (the 4-term step's ramp). The per-VPL
    shadows are ir_shadowed's distance test (`shadow_test=distance`, its default when this test was
    written): its one-footprint tolerance lets light past a zero-thickness wall's junctions as
    val_clustered's contact test does (its manual: a coplanar surface past the wall reads as the
    receiver's own plane), so this test measures the CSSM's leaks, not that shared one; against
    ir_shadowed's default plane test the defaults read 0.42 of no indirect light's (NOTES.md)."""
    s = render(gl_ctx, InstantRadiosityShadowed, rooms, "main", {"vpl_count": 1024, "shadow_test": "distance"})
    v = render(gl_ctx, ClusteredVirtualAreaLights, rooms, "main", {})
    black = relmse(np.zeros_like(s), s)
    assert relmse(v, s) < 0.25 * black, (relmse(v, s), black)
    assert 0.85 <= v.mean() / s.mean() <= 1.15, v.mean() / s.mean()


def test_defaults_keep_light_out_of_the_far_room(gl_ctx, rooms):
    """Camera in room 3 looking through door 2 into room 2 (the light two rooms away): the paper's
    map origin at the cluster's mean, with the geometry near it ignored, lights room 2 and room 3
    through the wall between rooms 1 and 2 (relMSE 1.9 against ir_shadowed at 96 x 72); the
    defaults cut that error by more than two thirds."""
    s = render(gl_ctx, InstantRadiosityShadowed, rooms, "far", {"vpl_count": 1024})
    paper = render(gl_ctx, ClusteredVirtualAreaLights, rooms, "far", PAPER)
    v = render(gl_ctx, ClusteredVirtualAreaLights, rooms, "far", {})
    assert relmse(v, s) < 0.3 * relmse(paper, s), (relmse(v, s), relmse(paper, s))


def test_interleave_block_follows_the_image_width():
    """interleave=0 (the default) scales the paper's 8 x 8 blocks of an 800-pixel-wide image to the
    image width (the benchmark's 320 x 180: 3 x 3); an explicit block size is kept."""
    assert ClusteredVirtualAreaLights.params["interleave"].default == 0
    assert [interleave_block(0, w) for w in (64, 96, 160, 320, 800, 1600)] == [1, 1, 2, 3, 8, 16]
    assert interleave_block(5, 320) == 5 and interleave_block(1, 800) == 1
