"""The validated scene model and its facts."""
import numpy as np
import pytest

from bench.model.scene import Camera, PointLight, Scene, SceneError, SpotLight, compute_facts

TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
CAM = {"main": Camera([2, 2, 2], [0, 0, 0])}
LIGHT = [PointLight([0.2, 0.2, 0.2], 1.0)]


def build(**kw):
    args = dict(name="t", vertices=TETRA_V, faces=TETRA_F, albedo=[0.5, 0.5, 0.5], lights=LIGHT, cameras=CAM)
    args.update(kw)
    return Scene.build(**args)


def test_valid_scene_and_facts():
    s = build()
    f = compute_facts(s)
    assert f.triangle_count == 4 and f.closed
    assert f.total_area_m2 == pytest.approx(1.5 + np.sqrt(3) / 2)
    assert f.triangles_above(0.5) == 1 and f.triangles_above(0.4) == 4
    assert f.scene_radius == pytest.approx(np.sqrt(3) / 2)


def test_open_geometry_is_not_closed():
    assert not compute_facts(build(faces=TETRA_F[:3])).closed


@pytest.mark.parametrize("kw, message", [
    (dict(vertices=np.where(np.arange(12).reshape(4, 3) == 4, np.nan, TETRA_V)), "non-finite vertex 1"),
    (dict(lights=[]), "no light"),
    (dict(cameras={}), "no camera"),
    (dict(faces=np.array([[0, 1, 9]])), "out of range"),
    (dict(albedo=[1.5, 0, 0]), "outside \\[0, 1\\]"),
    (dict(faces=np.array([[0, 1, 1], [0, 1, 1]])), "all 2 triangles have zero area"),
])
def test_bad_input_one_line_errors(kw, message):
    with pytest.raises(SceneError, match=message) as info:
        build(**kw)
    assert "\n" not in str(info.value) and "'t'" in str(info.value)


def test_degenerate_triangles_dropped_and_counted():
    faces = np.concatenate([TETRA_F, [[0, 1, 1], [0, 1, 0]]])
    collinear = np.concatenate([TETRA_V, [[2, 0, 0]]])
    faces = np.concatenate([faces, [[0, 1, 4]]])  # 0, 1, 4 are collinear: zero area
    s = build(vertices=collinear, faces=faces)
    assert s.triangle_count == 4 and s.dropped_degenerate == 3
    assert compute_facts(s).dropped_degenerate == 3


def test_light_and_camera_validation():
    with pytest.raises(SceneError, match="cutoff_angle_deg"):
        SpotLight([0, 1, 0], [0, 0, 0], 1.0, cutoff_angle_deg=95)
    with pytest.raises(SceneError, match="point light position"):
        PointLight([0, np.inf, 0], 1.0)
    with pytest.raises(SceneError, match="parallel"):
        Camera([0, 2, 0], [0, 0, 0], up=[0, 1, 0])


def test_content_hash_tracks_albedo():
    a, b = build(), build(albedo=[0.5, 0.5, 0.6])
    assert a.content_hash() == build().content_hash() and a.content_hash() != b.content_hash()


def test_spot_falloff_is_mitsubas():
    s = SpotLight([0, 1, 0], [0, 0, 0], 1.0, cutoff_angle_deg=30, beam_width_deg=20)
    cos = np.cos(np.radians([0, 19.9, 25, 29.9, 30.1]))
    assert np.allclose(s.falloff(cos), [1, 1, 0.5, 0.01, 0], atol=1e-6)


@pytest.mark.parametrize("name", ["../../escape", "a/b", "/abs", ".hidden", "", "a b", "a..b", "x" * 101, 3])
def test_unsafe_names_are_rejected(name):
    """The name becomes a folder under a run's images/ and references/ (issue #15)."""
    with pytest.raises(SceneError, match="is not allowed") as info:
        build(name=name)
    assert "\n" not in str(info.value)


def test_corpus_style_names_are_safe():
    for name in ("cornell_spot", "rooms-n3", "big_floor-size2.5-height-0.5", "open_box"):
        assert build(name=name).name == name


@pytest.mark.parametrize("camera", ["a/../../../escaped", "../x", "a\\b", ".hidden", "", "v@1", 7])
def test_unsafe_camera_names_are_rejected(camera):
    """A camera name becomes a folder images/<scene>/<view>/ (issue #27): the scene name's check covers it."""
    with pytest.raises(SceneError, match=f"scene 't': camera name .* is not allowed") as info:
        build(cameras={camera: Camera([2, 2, 2], [0, 0, 0])})
    assert "\n" not in str(info.value)


def test_one_check_for_every_name_in_a_path():
    from bench.model.scene import check_path_name, check_scene_name
    assert check_path_name("val_clustered", "method name") == "val_clustered"
    with pytest.raises(SceneError, match="^method name 'a/b' is not allowed"):
        check_path_name("a/b", "method name")
    with pytest.raises(SceneError, match="^scene name '../x' is not allowed"):
        check_scene_name("../x")
