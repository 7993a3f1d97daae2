"""Scenes in motion, the model (issue #25): keyframed tracks, the static scene of each frame, what
changed between frames, the corpus sequences, and the one-line errors of bad sequences."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.model.animation import Sequence, make_track
from bench.model.corpus import load_scene
from bench.model.corpus.sequences import SEQUENCES, load_sequence
from bench.model.scene import DirectionalLight, PointLight, Scene, SceneError
from tests.conftest import make_open_box


def test_tracks_interpolate_linearly_and_hold_outside_their_keys():
    track = make_track("s", "light", 0, {2: {"position": [0, 0, 0]}, 6: {"position": [4, 8, -4]}}, frames=10)
    assert np.allclose(track.value("position", 0), [0, 0, 0])        # held before the first key
    assert np.allclose(track.value("position", 3), [1, 2, -1])
    assert np.allclose(track.value("position", 6), [4, 8, -4])       # exact at a key
    assert np.allclose(track.value("position", 9), [4, 8, -4])       # held after the last
    assert track.value("intensity", 3) is None                        # a field no key sets


def test_a_field_missing_from_a_key_comes_from_the_keys_that_have_it():
    track = make_track("s", "camera", "main", {0: {"eye": [0, 1, 0], "fov_y_deg": 40}, 4: {"eye": [4, 1, 0]},
                                                8: {"fov_y_deg": 60}}, frames=9)
    assert np.allclose(track.value("eye", 2), [2, 1, 0]) and np.allclose(track.value("eye", 8), [4, 1, 0])
    assert track.value("fov_y_deg", 4)[0] == pytest.approx(50.0)


@pytest.mark.parametrize("name", list(SEQUENCES))
def test_corpus_sequences_start_at_their_static_scene_and_differ_every_frame(name):
    seq = load_sequence(name, frames=4, rest=0)
    static = load_scene(SEQUENCES[name].scene)
    assert seq.frame(0).content_hash() == static.content_hash()   # frame 0 shares the static scene's references
    hashes = [seq.frame(t).content_hash() for t in range(seq.frames)]
    assert len(set(hashes)) == seq.frames                          # no reference is reused across frames
    moved = {"light": "light", "camera": "camera", "geometry": "geometry"}[SEQUENCES[name].moves]
    assert all(seq.changes(t) == {moved} for t in range(1, seq.frames))
    assert seq.changes(0) == {"camera", "light", "geometry"}


def test_a_frame_is_the_static_scene_built_from_its_state():
    """rooms_light_sweep at frame t is exactly `rooms` with the light where the track puts it: the
    same content, hence the same cache key, as a static scene a user would write for that frame."""
    seq = load_sequence("rooms_light_sweep", frames=5, rest=0)
    static = load_scene("rooms")
    for t in range(seq.frames):
        position = seq.tracks[0].value("position", t)
        light = PointLight(position, static.lights[0].intensity)
        by_hand = Scene.build(static.name, static.vertices, static.faces, static.albedo, [light], static.cameras,
                              normals=static.normals)
        assert seq.frame(t).content_hash() == by_hand.content_hash()


def test_a_moving_mesh_moves_rigidly_and_nothing_else_moves():
    seq = load_sequence("cornell_spot_moving_block", frames=3, rest=0)
    block = seq.groups["short_block"]
    first, last = seq.frame(0), seq.frame(2)
    assert np.allclose(last.vertices[block] - first.vertices[block], [-0.7, 0.0, 0.0])
    rest = np.setdiff1d(np.arange(len(first.vertices)), block)
    assert np.array_equal(last.vertices[rest], first.vertices[rest])
    assert np.allclose(last.areas(), first.areas())               # a rigid motion keeps every area
    assert np.array_equal(last.normals, first.normals)             # a translation turns no normal


def test_rotation_turns_normals_with_the_mesh():
    box = make_open_box()
    floor = np.unique(box.faces[:2])   # the floor's own 4 vertices
    seq = Sequence.build("spin", box, 2, [("mesh", "floor", {0: {"rotate_deg": [0, 0, 0]}, 1: {"rotate_deg": [90, 0, 0]}})],
                         groups={"floor": floor})
    turned = seq.frame(1)
    assert np.allclose(turned.normals[floor], [0.0, 0.0, 1.0], atol=1e-12)   # +y turned 90 deg about x is +z
    assert np.allclose(turned.face_normals()[:2], [0.0, 0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("frames, tracks, groups, message", [
    (1, [("light", 0, {0: {"position": [0, 1, 0]}})], None, "frames must be an integer in"),
    (4, [], None, "no track"),
    (4, [("light", 0, {4: {"position": [0, 1, 0]}})], None, "key frame 4 must be an integer in [0, 3]"),
    (4, [("light", 0, {0: {"colour": [1, 1, 1]}})], None, "unknown field 'colour'"),
    (4, [("light", 3, {0: {"position": [0, 1, 0]}})], None, "light index must be in [0, 0]"),
    (4, [("light", 0, {0: {"direction": [0, -1, 0]}})], None, "a PointLight has no direction"),
    (4, [("camera", "side", {0: {"eye": [0, 1, 3]}})], None, "no camera 'side'"),
    (4, [("camera", "main", {0: {"fov_y_deg": 200}})], None, "fov_y_deg at frame 0 must be in (0, 180)"),
    (4, [("camera", "main", {0: {"eye": [0, float("nan"), 3]}})], None, "must be 3 finite numbers"),
    (4, [("mesh", "lid", {0: {"translate": [0, 1, 0]}})], None, "no mesh group 'lid'"),
    (4, [("mesh", "g", {0: {"scale": 0}})], {"g": [0, 1, 2, 3]}, "scale at frame 0 must not be 0"),
    (4, [("mesh", "g", {3: {"translate": [0, 1, 0]}})], {"g": [0, 1]}, "joins a moving mesh group to other geometry"),
    (4, [("wobble", 0, {0: {}})], None, "unknown track kind 'wobble'"),
])
def test_bad_sequences_are_one_line_errors(frames, tracks, groups, message):
    with pytest.raises(SceneError) as err:
        Sequence.build("bad", make_open_box(), frames, tracks, groups)
    assert message in str(err.value) and "\n" not in str(err.value) and "'bad'" in str(err.value)


def test_unknown_sequence_and_frame_out_of_range():
    with pytest.raises(SceneError, match="unknown sequence 'nope'; known: rooms_light_sweep"):
        load_sequence("nope")
    seq = load_sequence("rooms_light_sweep", frames=3, rest=0)
    with pytest.raises(SceneError, match=r"frame 3 outside \[0, 2\]"):
        seq.frame(3)


def test_directional_light_tracks_direction_and_irradiance():
    box = make_open_box()
    sun = DirectionalLight([0.0, -1.0, 0.0], [1.0, 1.0, 1.0])
    lit = Scene.build("sun_box", box.vertices, box.faces, box.albedo, [sun], box.cameras, normals=box.normals)
    seq = Sequence.build("dusk", lit, 3, [("light", 0, {0: {"irradiance": 2.0}, 2: {"irradiance": 0.0,
                                                                                   "direction": [1.0, -1.0, 0.0]}})])
    mid = seq.frame(1).lights[0]
    assert np.allclose(mid.irradiance, [1.0, 1.0, 1.0])
    assert seq.changes(1) == {"light"} and seq.changes(2) == {"light"}


@pytest.mark.mitsuba
def test_a_frames_reference_is_the_static_scenes(tmp_path):
    """The reference of a sequence frame and of the same state written as a static scene are one
    cache entry, and rendering them apart (two caches) gives the same image."""
    from reference.api import get_reference
    seq = load_sequence("rooms_light_sweep", frames=3, rest=0)
    static = load_scene("rooms")
    light = PointLight(seq.tracks[0].value("position", 2), static.lights[0].intensity)
    by_hand = Scene.build(static.name, static.vertices, static.faces, static.albedo, [light], static.cameras,
                          normals=static.normals)
    a = get_reference(seq.frame(2), "main", 32, 18, "indirect_visible", spp_cap=8, cache_dir=tmp_path / "a")
    b = get_reference(by_hand, "main", 32, 18, "indirect_visible", spp_cap=8, cache_dir=tmp_path / "b")
    assert a.key == b.key and np.array_equal(a.mean, b.mean)
    first = get_reference(seq.frame(0), "main", 32, 18, "indirect_visible", spp_cap=8, cache_dir=tmp_path / "a")
    assert first.key != a.key and not np.array_equal(first.mean, a.mean)   # the light moved: another image


def test_list_sequences(capsys):
    from bench.cli import main
    assert main(["list", "sequences"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in SEQUENCES) and "moves light" in out and "moves geometry" in out


# ---------------------------------------------------------------------------- scene files
EXAMPLE_FILE = Path(__file__).resolve().parents[1] / "scenes" / "examples" / "two_quads.toml"


def test_scene_file_animation():
    from bench.model.scenefile import load_scene_file, load_sequence_file
    seq = load_sequence_file(EXAMPLE_FILE)
    assert seq.frames == 24 and seq.frame(0).content_hash() == load_scene_file(EXAMPLE_FILE).content_hash()
    assert seq.changes(5) == {"camera", "light", "geometry"}
    last = seq.frame(23)
    assert np.allclose(last.lights[0].position, [-0.3, 1.5, 0.5]) and last.cameras["main"].fov_y_deg == 40
    moved = seq.groups["mesh1"]
    assert np.allclose(last.vertices[moved] - seq.base.vertices[moved], [0.0, 0.5, 0.0])


@pytest.mark.parametrize("animation, message", [
    ("frames = 1", "'frames' must be an integer >= 2"),
    ("frames = 4\nspeed = 2", "unknown key 'speed'"),
    ("frames = 4\n[[animation.mesh]]\nindex = 7\nkeys = [{frame = 0, translate = [0, 1, 0]}]", "names no [[mesh]] table"),
    ("frames = 4\n[[animation.light]]\nindex = 0\nkeys = [{frame = 9, position = [0, 1, 0]}]",
     "key frame 9 must be an integer in [0, 3]"),
    ("frames = 4\n[[animation.camera]]\nname = 'main'\nkeys = [{frame = 0, eye = 'up'}]", "eye at frame 0 must be 3 finite"),
    ("frames = 4\n[[animation.light]]\nindex = 'sun'\nkeys = []", "'index' must be an integer"),
])
def test_scene_file_animation_errors_name_the_file(tmp_path, animation, message):
    from bench.model.scenefile import load_scene_file
    text = EXAMPLE_FILE.read_text().split("[animation]")[0] + "[animation]\n" + animation + "\n"
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    (tmp_path / "quad.obj").write_text((EXAMPLE_FILE.parent / "quad.obj").read_text())
    for mtl in EXAMPLE_FILE.parent.glob("*.mtl"):
        (tmp_path / mtl.name).write_text(mtl.read_text())
    with pytest.raises(SceneError) as err:
        load_scene_file(bad)
    assert message in str(err.value) and str(bad) in str(err.value) and "\n" not in str(err.value)


def test_frame_zero_is_the_base_scene_unless_keyed_there():
    box = make_open_box()   # its camera's fov is 50 deg
    seq = Sequence.build("zoom", box, 9, [("camera", "main", {8: {"fov_y_deg": 30}})])
    assert seq.frame(0).content_hash() == box.content_hash()
    assert seq.frame(4).cameras["main"].fov_y_deg == pytest.approx(40.0)
    assert seq.frame(8).cameras["main"].fov_y_deg == pytest.approx(30.0)
    assert seq.changes(1) == {"camera"}


def test_corpus_sequences_rest_after_their_motion():
    seq = load_sequence("rooms_light_sweep", frames=3, rest=2)
    assert seq.frames == 5 and [sorted(seq.changes(t)) for t in range(1, 5)] == [["light"], ["light"], [], []]
    assert seq.frame(4).content_hash() == seq.frame(2).content_hash()   # at rest: one reference for the rest


# ---------------------------------------------------------------------------- properties
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

finite = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False)
vec = st.tuples(finite, finite, finite)


@st.composite
def light_tracks(draw):
    frames = draw(st.integers(2, 30))
    count = draw(st.integers(1, min(frames, 5)))
    key_frames = sorted(draw(st.sets(st.integers(0, frames - 1), min_size=count, max_size=count)))
    keys = {k: {"position": list(draw(vec))} for k in key_frames}
    return frames, keys


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(light_tracks())
def test_interpolation_stays_between_its_keys_and_hits_them(track):
    frames, keys = track
    t = make_track("p", "light", 0, keys, frames)
    points = np.array([v["position"] for v in keys.values()])
    for f in range(frames):
        v = t.value("position", f)
        assert np.all(v >= points.min(0) - 1e-9) and np.all(v <= points.max(0) + 1e-9)   # never overshoots
    for k, v in keys.items():
        assert np.allclose(t.value("position", k), v["position"])
    ks = sorted(keys)
    for a, b in zip(ks, ks[1:]):   # linear between two keys: equal steps
        steps = np.diff([t.value("position", f) for f in range(a, b + 1)], axis=0)
        assert np.allclose(steps, steps[0], atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(vec, st.tuples(st.floats(-180, 180), st.floats(-180, 180), st.floats(-180, 180)))
def test_a_rigid_mesh_motion_keeps_areas_and_unit_normals(move, turn):
    box = make_open_box()
    floor = np.unique(box.faces[:2])
    seq = Sequence.build("rigid", box, 2, [("mesh", "floor", {1: {"translate": list(move), "rotate_deg": list(turn)}})],
                         groups={"floor": floor})
    moved = seq.frame(1)
    assert np.allclose(moved.areas(), box.areas(), rtol=1e-9, atol=1e-12)
    assert np.allclose(np.linalg.norm(moved.normals, axis=1), 1.0)
    assert np.allclose(moved.face_normals()[:2], moved.normals[floor][:1], atol=1e-9)   # normals turn with the faces
    assert seq.frame(1).content_hash() == moved.content_hash()                          # deterministic
