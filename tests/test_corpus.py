"""The scene corpus: procedural generators, real scenes from scenes/*.npz, the registry."""
from pathlib import Path

import numpy as np
import pytest

import bench.model.corpus as corpus
from bench.model.corpus import list_scenes, load_scene
from bench.model.corpus.procedural import sphere_inside_indirect
from bench.model.scene import SceneError, compute_facts

REPO = Path(__file__).resolve().parents[1]
SMALL = ("cornell_spot", "cornell_tiled", "rooms", "hidden_bounce", "big_floor", "lit_wall_corner", "sphere_inside",
         "highpoly_10k")
REAL = {  # expected triangles: file count - duplicates (import) - zero-area (Scene.build) +- edits
    "cornell_box": 36 - 4 - 2,        # 4 duplicated 'Bottom Face' triangles, the 2-triangle emitter quad dropped
    "sponza": 66_450 - 10 - 6,
    "sibenik": 75_284 - 153 - 7,
    "conference": 331_179,
    "holodeck": 4_015 - 11,
    "lost_empire": 224_998,
    "bunny": 69_451 + 512,            # + the added floor
    "teapot": 15_704 + 512,           # + the added floor
}


@pytest.fixture(scope="module")
def entries():
    return {e.name: e for e in list_scenes()}


def test_list_scenes_names_counts_purposes(entries):
    required = set(SMALL) | {"highpoly_100k", "highpoly_1m", "highpoly_4m"} | set(REAL)
    assert required <= set(entries)
    for e in entries.values():
        assert isinstance(e.triangle_count, int) and e.triangle_count > 0
        assert e.purpose and "\n" not in e.purpose and e.kind in ("procedural", "real")
    for name, target in (("highpoly_10k", 1e4), ("highpoly_100k", 1e5), ("highpoly_1m", 1e6), ("highpoly_4m", 4e6)):
        assert abs(entries[name].triangle_count - target) <= 0.01 * target
    for name in ("sponza", "sibenik", "bunny"):
        assert "non-commercial" in entries[name].licence


def test_list_scenes_builds_nothing(monkeypatch):
    def refuse(*_a, **_k):
        raise AssertionError("list_scenes built geometry")
    for cls in (corpus.geometry.Grid, corpus.geometry.Heightfield, corpus.geometry.Icosphere, corpus.real.ArchivePart):
        monkeypatch.setattr(cls, "build", refuse)
    assert len(list_scenes()) == len(corpus.SCENES)


@pytest.mark.parametrize("name", SMALL)
def test_small_scenes_build_and_validate(name, entries):
    scene = load_scene(name)
    assert scene.name == name and scene.purpose == entries[name].purpose
    assert scene.triangle_count == entries[name].triangle_count
    assert "main" in scene.cameras and scene.lights
    facts = compute_facts(scene)
    assert facts.dropped_degenerate == 0 and facts.area_min_m2 > 0
    assert np.allclose(np.linalg.norm(scene.normals, axis=1), 1)
    lo, hi = scene.bounds()
    for light in scene.lights:  # point and spot lights sit inside the scene's bounds
        if light.kind != "directional":
            assert np.all(light.position > lo) and np.all(light.position < hi), (name, light)


def test_generators_are_deterministic():
    assert load_scene("big_floor").content_hash() == load_scene("big_floor").content_hash()
    assert load_scene("highpoly_10k").content_hash() == load_scene("highpoly_10k").content_hash()


def test_sphere_inside_closed_light_inside_analytic():
    scene = load_scene("sphere_inside")
    assert compute_facts(scene).closed
    # inside the polyhedron: closer to the centre than every face plane
    v = scene.vertices[scene.faces]
    n = scene.face_normals()
    plane_distance = np.abs(np.einsum("ij,ij->i", n, v[:, 0]))
    light = scene.lights[0]
    assert light.kind == "point" and np.linalg.norm(light.position) == pytest.approx(0.3)
    assert np.linalg.norm(light.position) < plane_distance.min()
    assert np.linalg.norm(scene.cameras["main"].eye) < plane_distance.min()
    assert np.allclose(np.linalg.norm(scene.vertices, axis=1), 1.0)
    assert sphere_inside_indirect(1.0, 0.5, 1.0) == pytest.approx(0.25 / np.pi)
    off = load_scene("sphere_inside", light_offset=0.6, radius=2.0)
    assert off.name == "sphere_inside-radius2-light_offset0.6"
    assert np.allclose(off.lights[0].position, [1.2, 0, 0])


def test_big_floor_has_few_huge_triangles():
    areas = load_scene("big_floor").areas()
    assert 2 <= int((areas > 100.0).sum()) <= 4 and int((areas < 0.01).sum()) > 1000


def test_rooms_light_and_camera_in_different_rooms():
    scene = load_scene("rooms")
    assert 0 < scene.lights[0].position[0] < 4 and 4 < scene.cameras["main"].eye[0] < 8


def test_options_inline_and_errors():
    tiled = load_scene("cornell_tiled", n=2)
    assert tiled.name == "cornell_tiled-n2"
    assert tiled.triangle_count == 4 * load_scene("cornell_spot").triangle_count
    assert load_scene("cornell_tiled:n=2").content_hash() == tiled.content_hash()
    with pytest.raises(SceneError, match="unknown scene 'nope'; known: cornell_spot, cornell_tiled"):
        load_scene("nope")
    with pytest.raises(SceneError, match="has no option 'm' \\(options: n, grid\\)"):
        load_scene("cornell_tiled", m=3)
    with pytest.raises(SceneError, match="option n=2.5 must be an integer"):
        load_scene("cornell_tiled", n=2.5)
    with pytest.raises(SceneError, match="light_offset must be in"):
        load_scene("sphere_inside", light_offset=1.5)


def test_highpoly_declared_count_matches_built(entries):
    scene = load_scene("highpoly_10k")
    assert scene.triangle_count == entries["highpoly_10k"].triangle_count
    assert abs(scene.triangle_count - 10_000) <= 100


def test_toml_path_goes_to_the_scene_file_loader():
    scene = load_scene(str(REPO / "scenes" / "examples" / "two_quads.toml"))
    assert scene.name == "two_quads"
    with pytest.raises(SceneError, match="only apply to corpus scenes"):
        load_scene(REPO / "scenes" / "examples" / "two_quads.toml", n=2)


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_scenes_load_from_npz(name, entries):
    scene = load_scene(name)
    assert scene.triangle_count == REAL[name] == entries[name].triangle_count
    assert "main" in scene.cameras and scene.lights
    assert entries[name].kind == "real"
    assert np.all(np.isfinite(scene.normals)) and scene.albedo.max() <= 1
    folder = REPO / "scenes" / name
    assert (folder / "SOURCE.txt").is_file() and (folder / "CONVERSION.md").is_file()


def test_real_scene_conversions():
    box = load_scene("cornell_box")
    # float Kd kept (uint8 would give 0.6314): the red wall is 0.63 0.065 0.05
    assert np.any(np.all(np.abs(box.albedo - [0.63, 0.065, 0.05]) < 2e-5, axis=1))
    assert box.bounds()[1][1] == pytest.approx(1.99)  # the emitter quad at y = 1.98 is gone, ceiling stays
    conf = load_scene("conference")
    assert conf.bounds()[1][1] == pytest.approx(650.2925 * 0.004, rel=1e-4)  # scaled to metres


def test_missing_archives_are_reported(monkeypatch, tmp_path):
    monkeypatch.setenv("GIBENCH_SCENES_DIR", str(tmp_path))
    with pytest.raises(SceneError, match="mesh.npz' not found \\(run scripts/import_real_scenes.py\\)"):
        load_scene("teapot")


@pytest.mark.parametrize("spec, option", [("cornell_tiled:n=NaN", "n"), ("cornell_tiled:n=1e400", "n"),
                                          ("rooms:intensity=NaN", "intensity"), ("big_floor:intensity=1e400", "intensity")])
def test_non_finite_options_name_the_option(spec, option):
    """NaN / Inf (JSON's NaN, 1e400) ended in a bare ValueError/OverflowError or a light's error (issue #27)."""
    with pytest.raises(SceneError, match=f"option {option}=.* must be a finite number"):
        load_scene(spec)
