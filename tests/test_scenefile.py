"""TOML scene files and mesh loading (bench.model.scenefile)."""
from pathlib import Path

import numpy as np
import pytest

from bench.model.scene import SceneError, compute_facts
from bench.model.meshfile import MeshData, clean_mesh, read_mesh, read_mesh_npz, transform_matrix, write_mesh_npz
from bench.model.scenefile import load_scene_file

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "scenes" / "examples" / "two_quads.toml"

QUAD_OBJ = """mtllib m.mtl
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
usemtl grey
f 1 2 3
f 1 3 4
"""
QUAD_MTL = "newmtl grey\nKd 0.123 0.456 0.789\n"

LIGHT = '[[light]]\ntype = "point"\nposition = [0.5, 1, 0.5]\nintensity = 1\n'
CAMERA = '[camera.main]\neye = [0.5, 2, 2]\ntarget = [0.5, 0, 0.5]\n'


def write_scene(tmp_path, body: str, obj: str = QUAD_OBJ, mtl: str = QUAD_MTL) -> Path:
    (tmp_path / "m.obj").write_text(obj)
    (tmp_path / "m.mtl").write_text(mtl)
    path = tmp_path / "scene.toml"
    path.write_text(body)
    return path


def scene_text(mesh_extra: str = "", light: str = LIGHT, camera: str = CAMERA, top: str = "",
               mesh_file: str = "m.obj") -> str:
    return f'{top}[[mesh]]\nfile = "{mesh_file}"\n{mesh_extra}\n{light}\n{camera}'


def test_example_scene_loads():
    s = load_scene_file(EXAMPLE)
    assert s.name == "two_quads" and s.triangle_count == 4
    assert [l.kind for l in s.lights] == ["point", "spot", "directional"]
    assert s.cameras["main"].fov_y_deg == 50
    # floor: the quad rotated flat and scaled to 2 x 2 m; wall: its material overridden to green
    floor = s.vertices[np.unique(s.faces[:2])]
    assert np.allclose(floor[:, 1], 0, atol=1e-12) and np.allclose(np.ptp(floor, axis=0), [2, 0, 2])
    assert np.allclose(s.albedo[:2], 0.8) and np.allclose(s.albedo[2:], [0.2, 0.8, 0.2])
    assert np.allclose(np.abs(s.normals[np.unique(s.faces[:2])]), [0, 1, 0], atol=1e-12)
    assert compute_facts(s).total_area_m2 == pytest.approx(8.0)


def test_docstring_example_is_the_shipped_file():
    import textwrap
    import tomllib

    import bench.model.scenefile as sf
    doc = sf.__doc__.split("Complete example (`scenes/examples/two_quads.toml`)::\n", 1)[1].split("\nTransform order", 1)[0]
    assert tomllib.loads(textwrap.dedent(doc)) == tomllib.loads(EXAMPLE.read_text())


def test_float_kd_is_used_not_uint8(tmp_path):
    s = load_scene_file(write_scene(tmp_path, scene_text()))
    assert np.allclose(s.albedo, [0.123, 0.456, 0.789], atol=0, rtol=1e-12)


def test_first_of_repeated_kd_lines(tmp_path):
    s = load_scene_file(write_scene(tmp_path, scene_text(), mtl="newmtl grey\nKd 0.3 0.2 0.1\nKd 1 1 1\n"))
    assert np.allclose(s.albedo, [0.3, 0.2, 0.1])


def test_material_groups_keep_their_albedo(tmp_path):
    # trimesh groups faces per material: each triangle must still get its own material's Kd.
    obj = ("mtllib m.mtl\n" + "".join(f"v {x} 0 {z}\n" for z in range(2) for x in range(4)) +
           "usemtl a\nf 1 2 6\nusemtl b\nf 2 3 7\nusemtl a\nf 3 4 8\nusemtl c\nf 1 6 5\n")
    mtl = "newmtl a\nKd 0.1 0.1 0.1\nnewmtl b\nKd 0.5 0.5 0.5\nnewmtl c\n"
    s = load_scene_file(write_scene(tmp_path, scene_text(top="default_albedo = 0.25\n"), obj=obj, mtl=mtl))
    centroid_x = s.vertices[s.faces].mean(axis=1)[:, 0]
    # centroid x of each triangle -> its albedo (material 'c' has no Kd: the default)
    expected = {2 / 3: 0.1, 5 / 3: 0.5, 8 / 3: 0.1, 1 / 3: 0.25}
    assert s.triangle_count == 4
    for x, a in expected.items():
        i = int(np.argmin(np.abs(centroid_x - x)))
        assert centroid_x[i] == pytest.approx(x) and s.albedo[i] == pytest.approx([a] * 3)


def test_material_override_exclude_and_transform(tmp_path):
    extra = ('translate = [1, 2, 3]\nscale = [2, 1, 1]\nrotate_deg = [0, 90, 0]\n'
             '[mesh.materials]\ngrey = [0.5, 0.4, 0.3]\n')
    s = load_scene_file(write_scene(tmp_path, scene_text(extra)))
    assert np.allclose(s.albedo, [0.5, 0.4, 0.3])
    expected = (np.array([[0, 0, 0, 1], [1, 0, 0, 1], [1, 0, 1, 1], [0, 0, 1, 1.0]]) @ transform_matrix(
        [1, 2, 3], [0, 90, 0], [2, 1, 1]).T)[:, :3]
    # rotating +90 about Y sends +x to -z
    assert np.allclose(expected[1] - expected[0], [0, 0, -2])
    got = s.vertices[np.unique(s.faces)]
    assert np.allclose(np.sort(got, axis=0), np.sort(expected, axis=0))
    with pytest.raises(SceneError, match="exclude_materials removes every triangle"):
        load_scene_file(write_scene(tmp_path, scene_text('exclude_materials = ["grey"]')))


def test_zero_area_and_duplicate_triangles_are_dropped_and_counted(tmp_path):
    obj = QUAD_OBJ + "v 2 0 0\nf 1 2 5\nf 3 1 2\n"  # 1,2,5 collinear; 3 1 2 repeats 1 2 3
    s = load_scene_file(write_scene(tmp_path, scene_text(), obj=obj))
    assert s.triangle_count == 2 and s.dropped_degenerate == 1
    assert compute_facts(s).dropped_degenerate == 1
    assert "1 duplicate triangles dropped" in s.source


def _assert_one_line(exc, *parts):
    text = str(exc.value)
    assert "\n" not in text, text
    for part in parts:
        assert part in text, (part, text)


@pytest.mark.parametrize("body, parts", [
    (scene_text(mesh_file="nothere.obj"), ["scene.toml", "nothere.obj", "not found"]),
    (scene_text(light=""), ["scene.toml", "no light"]),
    (scene_text(camera=""), ["scene.toml", "no camera"]),
    (scene_text(top="colour = 1\n"), ["scene.toml", "top level", "unknown key 'colour'"]),
    (scene_text("scael = 2"), ["scene.toml", "[[mesh]] #1 ('m.obj')", "unknown key 'scael'"]),
    (scene_text(light=LIGHT + "power = 3\n"), ["scene.toml", "[[light]] #1 (point)", "unknown key 'power'"]),
    (scene_text(camera=CAMERA + "fov = 40\n"), ["scene.toml", "[camera.main]", "unknown key 'fov'"]),
    (scene_text("[mesh.materials]\ngray = 0.5"), ["scene.toml", "material 'gray' is not in the mesh file", "'grey'"]),
    (scene_text(light=LIGHT.replace("intensity = 1", 'intensity = "bright"')), ["[[light]] #1 (point)", "'intensity'"]),
    (scene_text(light=LIGHT.replace("[0.5, 1, 0.5]", "[0.5, 1]")), ["'position' must be a list of 3 numbers"]),
    (scene_text(light=LIGHT.replace('"point"', '"area"')), ["unknown light type 'area'"]),
    (scene_text(light=LIGHT.replace("intensity = 1\n", "")), ["[[light]] #1 (point)", "missing key 'intensity'"]),
    (scene_text("scale = true"), ["[[mesh]] #1", "'scale' must be a number"]),
    (scene_text("albedo = [0.5, 2, 0.5]"), ["'albedo' = [0.5, 2.0, 0.5] must be [0, 1]"]),
    (scene_text(camera="[[camera]]\neye = [0, 1, 2]\n"), ["'camera' must be a table of named cameras"]),
    (scene_text(camera=CAMERA.replace("target = [0.5, 0, 0.5]", "target = [0.5, 2, 2]")), ["[camera.main]", "target equals its eye"]),
    ("[[mesh]\nfile = 'm.obj'", ["scene.toml", "invalid TOML"]),
])
def test_bad_scene_files_give_one_line_errors(tmp_path, body, parts):
    with pytest.raises(SceneError) as info:
        load_scene_file(write_scene(tmp_path, body))
    _assert_one_line(info, *parts)


def test_unreadable_and_nan_meshes(tmp_path):
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex many\nend_header\n")
    path = write_scene(tmp_path, scene_text(mesh_file="bad.ply"))
    with pytest.raises(SceneError) as info:
        load_scene_file(path)
    _assert_one_line(info, "scene.toml", "bad.ply", "unreadable")

    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(SceneError) as info:
        load_scene_file(write_scene(tmp_path, scene_text(mesh_file="nan.obj")))
    _assert_one_line(info, "scene.toml", "nan.obj", "non-finite vertex 2")

    (tmp_path / "empty.obj").write_text("# nothing\n")
    with pytest.raises(SceneError) as info:
        load_scene_file(write_scene(tmp_path, scene_text(mesh_file="empty.obj")))
    _assert_one_line(info, "empty.obj", "no triangles")

    (tmp_path / "m.xyz").write_text("0 0 0\n")
    with pytest.raises(SceneError) as info:
        load_scene_file(write_scene(tmp_path, scene_text(mesh_file="m.xyz")))
    _assert_one_line(info, "m.xyz", "unsupported format")


def test_ply_without_colour_gets_default_albedo(tmp_path):
    import trimesh
    trimesh.creation.box().export(tmp_path / "box.ply")
    s = load_scene_file(write_scene(tmp_path, scene_text(top="default_albedo = 0.3\n", mesh_file="box.ply")))
    assert s.triangle_count == 12 and np.allclose(s.albedo, 0.3)
    # a box with a 45 degree crease angle is flat-shaded: every vertex normal is its face normal
    face_n = s.face_normals()
    assert np.allclose(np.einsum("tkc,tc->tk", s.normals[s.faces], face_n), 1.0)
    assert compute_facts(s).closed


def test_gltf_base_colour(tmp_path):
    import trimesh
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name="paint", baseColorFactor=[51, 102, 204, 255]))
    mesh.export(tmp_path / "box.glb")
    s = load_scene_file(write_scene(tmp_path, scene_text(mesh_file="box.glb")))
    assert s.triangle_count == 12 and np.allclose(s.albedo, [0.2, 0.4, 0.8])


def test_crease_angle_smooths_a_fine_sphere_and_file_normals_win():
    import trimesh
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    mesh = clean_mesh(v, f, np.zeros(len(f), int))
    assert len(mesh.vertices) == len(v)  # smooth: no vertex split
    assert np.allclose(np.einsum("ij,ij->i", mesh.normals, mesh.vertices / np.linalg.norm(mesh.vertices, axis=1)[:, None]), 1, atol=2e-3)
    flat = clean_mesh(v, f, np.zeros(len(f), int), crease_angle_deg=0)
    assert len(flat.vertices) == 3 * len(f)
    up = np.tile([0.0, 1.0, 0.0], (len(v), 1))
    given = clean_mesh(v, f, np.zeros(len(f), int), file_normals=up, has_file_normals=np.ones(len(f), bool))
    assert np.allclose(given.normals, [0, 1, 0])


def test_npz_round_trip_and_toml_reference(tmp_path):
    (tmp_path / "m.obj").write_text(QUAD_OBJ)
    (tmp_path / "m.mtl").write_text(QUAD_MTL)
    mesh = read_mesh(tmp_path / "m.obj")
    albedo = mesh.triangle_albedo()
    write_mesh_npz(tmp_path / "m.npz", mesh, {"name": "quad"}, albedo, np.ones(mesh.triangle_count, bool))
    back = read_mesh_npz(tmp_path / "m.npz")
    assert isinstance(back, MeshData) and back.material_names == ["grey"]
    assert np.array_equal(back.faces, mesh.faces) and np.allclose(back.vertices, mesh.vertices)
    assert np.allclose(back.albedo, albedo, atol=1e-5)
    path = tmp_path / "npz.toml"
    path.write_text(scene_text(mesh_file="m.npz", mesh_extra="[mesh.materials]\ngrey = 0.5"))
    s = load_scene_file(path)
    assert s.triangle_count == 2 and np.allclose(s.albedo, 0.5)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    path.write_text(scene_text(mesh_file="junk.npz"))
    with pytest.raises(SceneError, match="junk.npz' is unreadable"):
        load_scene_file(path)


# ---------------------------------------------------------------------------- issue #15: names and paths
@pytest.mark.parametrize("name", ["../../escape", "a/b", ".hidden", "", "x y", "..", "a..b", "é"])
def test_unsafe_scene_names_are_rejected(tmp_path, name):
    """A scene name is a folder of every run: `../../escape` wrote images outside --out."""
    with pytest.raises(SceneError) as info:
        load_scene_file(write_scene(tmp_path, scene_text(top=f'name = "{name}"\n')))
    assert "\n" not in str(info.value) and "scene.toml" in str(info.value)


def test_safe_scene_names_load(tmp_path):
    for name in ("rooms-n3", "big_floor-size2.5", "A_b.c+d=e"):
        assert load_scene_file(write_scene(tmp_path, scene_text(top=f'name = "{name}"\n'))).name == name


def test_mesh_outside_the_scene_folder_needs_opt_in(tmp_path):
    outside = tmp_path / "meshes"
    outside.mkdir()
    (outside / "q.obj").write_text(QUAD_OBJ.replace("mtllib m.mtl\n", ""))
    folder = tmp_path / "scene"
    folder.mkdir()
    for file in ("../meshes/q.obj", str(outside / "q.obj")):
        path = write_scene(folder, scene_text(mesh_file=file))
        with pytest.raises(SceneError) as info:
            load_scene_file(path)
        _assert_one_line(info, "scene.toml", "outside the scene file's folder", "allow_meshes_outside = true")
        path.write_text(scene_text(mesh_file=file, top="allow_meshes_outside = true\n"))
        assert load_scene_file(path).triangle_count == 2
    path.write_text(scene_text(top='allow_meshes_outside = "yes"\n'))
    with pytest.raises(SceneError, match="must be true or false"):
        load_scene_file(path)


def test_random_bytes_mesh_is_one_clear_line(tmp_path):
    """A random-bytes OBJ was reported as a missing `charset_normalizer` module."""
    rng = np.random.default_rng(5)
    (tmp_path / "noise.obj").write_bytes(rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(SceneError) as info:
        load_scene_file(write_scene(tmp_path, scene_text(mesh_file="noise.obj")))
    _assert_one_line(info, "noise.obj", "is not a .obj file", "not UTF-8 text")
    assert "charset_normalizer" not in str(info.value)


def test_camera_names_are_checked_before_any_mesh(tmp_path):
    """`[camera."a/../../../escaped"]` wrote EXRs outside the run folder (issue #27)."""
    camera = '[camera."a/../../../escaped"]\neye = [0.5, 2, 2]\ntarget = [0.5, 0, 0.5]\n'
    path = write_scene(tmp_path, scene_text(camera=camera, mesh_file="absent.obj"))
    with pytest.raises(SceneError, match=r"scene\.toml': \[camera\]: camera name 'a/../../../escaped' is not allowed"):
        load_scene_file(path)


def test_non_utf8_scene_file_names_itself(tmp_path):
    path = write_scene(tmp_path, "# 20\xb0 C\n" + scene_text())
    path.write_bytes(path.read_text().encode("latin-1"))
    with pytest.raises(SceneError, match=r"scene file '.*scene\.toml' is not UTF-8 text \(byte 4: 0xb0\)"):
        load_scene_file(path)


@pytest.mark.parametrize("mtllib", ["Quad.mtl", "../m.mtl", "sub/none.mtl", ""])
def test_missing_material_library_is_an_error(tmp_path, mtllib):
    """An OBJ whose `mtllib` is missing rendered grey, with the hash of an OBJ without mtllib (issue #27)."""
    folder = tmp_path / "scene"
    folder.mkdir()
    (tmp_path / "m.mtl").write_text(QUAD_MTL)   # outside the OBJ's folder: trimesh does not read it
    path = write_scene(folder, scene_text(), obj=QUAD_OBJ.replace("mtllib m.mtl", f"mtllib {mtllib}"))
    (folder / "m.mtl").unlink()
    with pytest.raises(SceneError, match=f"m.obj': its material library \\(mtllib '{mtllib}'\\) is not in the OBJ's "
                                         f"folder") as info:
        load_scene_file(path)
    assert "\n" not in str(info.value) and "scene.toml" in str(info.value)
    # without the mtllib line the default albedo is asked for, and given
    (folder / "m.obj").write_text(QUAD_OBJ.replace("mtllib m.mtl\n", ""))
    assert np.allclose(load_scene_file(path).albedo, 0.8)
