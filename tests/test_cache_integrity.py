"""Issue #15: cache entries (row cache and reference cache) carry checksums; a bad entry is a miss,
evicted with a one-line warning; a hit takes its labels from the current run."""
import json

import numpy as np
import pytest

from bench.model.imageio import read_exr, write_exr
from bench.run.serial import RunConfig, run
from bench.model.scene import Scene
from tests.conftest import make_open_box


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))


def cfg(tmp_path, out, **kw):
    base = dict(scenes=[make_open_box()], methods=["direct"], width=32, height=24, frames=2, warmup=1,
                out=tmp_path / out, references=False, progress=False)
    base.update(kw)
    return RunConfig(**base)


def renamed(scene, name):
    return Scene.build(name, scene.vertices, scene.faces, scene.albedo, scene.lights, scene.cameras,
                       normals=scene.normals)


def entry_dir(tmp_path):
    [d] = [p for p in (tmp_path / "cache" / "rows").glob("*/*") if p.is_dir()]
    return d


def test_cache_hit_takes_labels_from_the_current_run(tmp_path):
    """The key hashes the scene's content: a scene of the same content under another name used to
    get a row labelled with the first scene's name."""
    run(cfg(tmp_path, "a"), log=lambda m: None)
    df, runner = run(cfg(tmp_path, "b", scenes=[renamed(make_open_box(), "other_box")]), log=lambda m: None)
    [row] = df.to_dict("records")
    assert row["status"] == "cached" and row["scene"] == "other_box"
    assert row["image_dir"] == "images/other_box/main/direct"
    assert (runner.run_dir / row["image_dir"] / "combined.exr").is_file()
    assert row["scene_hash"] == make_open_box().content_hash()


def test_two_scenes_with_one_name_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="two scenes are named 'open_box'") as info:
        run(cfg(tmp_path, "a", scenes=[make_open_box(), make_open_box(intensity=3.0)]), log=lambda m: None)
    assert "\n" not in str(info.value)


def _truncate(d):
    path = d / "combined.exr"
    path.write_bytes(path.read_bytes()[:200])


def _binary_row(d):
    (d / "row.json").write_bytes(bytes(range(256)) * 4)


def _empty_row(d):
    (d / "row.json").write_text("{}")


def _wrong_image(d):  # a valid EXR of the right shape, but not the one stored
    write_exr(d / "indirect.exr", np.full(read_exr(d / "indirect.exr").shape, 0.5, np.float32))


def _edited_row(d):  # a row edited by hand: its checksum no longer holds
    entry = json.loads((d / "row.json").read_text())
    entry["row"]["frame_ms"] = 0.001
    (d / "row.json").write_text(json.dumps(entry))


@pytest.mark.parametrize("damage, problem", [
    (_truncate, "damaged combined.exr"), (_binary_row, "unreadable row.json"), (_empty_row, "no checksums"),
    (_wrong_image, "damaged indirect.exr"), (_edited_row, "checksum does not match"),
])
def test_damaged_row_cache_entry_is_a_miss_and_evicted(tmp_path, damage, problem):
    run(cfg(tmp_path, "a"), log=lambda m: None)
    damage(entry_dir(tmp_path))
    logs = []
    df, runner = run(cfg(tmp_path, "b"), log=logs.append)
    [row] = df.to_dict("records")
    assert row["status"] == "ok" and row["scene"] == "open_box" and row["method"] == "direct"
    [warning] = [m for m in logs if "row cache entry" in m]
    assert problem in warning and "evicted" in warning and "\n" not in warning
    assert np.array_equal(read_exr(tmp_path / "a/images/open_box/main/direct/indirect.exr"),
                          read_exr(tmp_path / "b/images/open_box/main/direct/indirect.exr"))
    # the re-rendered row was stored again, intact: the next run is a hit
    df, _ = run(cfg(tmp_path, "c"), log=lambda m: None)
    assert list(df.status) == ["cached"]


# ---------------------------------------------------------------------------- the reference cache
def _moments(value=0.25, n=8):
    from reference.render import Moments
    h, w = 6, 8
    return Moments(n, np.full((h, w, 3), value), np.full((h, w, 3), 0.01), np.full((h, w), float(n)))


def test_reference_entry_with_a_wrong_image_is_evicted(tmp_path, capsys):
    from reference import cache
    root = tmp_path / "refs"
    d = cache.store("ab" * 16, _moments(), {"spp": 8}, root)
    moments, meta = cache.load("ab" * 16, root)
    assert moments.n == 8 and set(meta["files"]) == {"mean.exr", "m2.exr", "hits.exr"}
    write_exr(d / "mean.exr", np.full((6, 8, 3), 0.75, np.float32))  # valid, but not what was stored
    assert cache.load("ab" * 16, root) is None
    err = capsys.readouterr().err.strip()
    assert "damaged mean.exr" in err and "evicted" in err and "\n" not in err
    assert not d.exists()


@pytest.mark.parametrize("damage", [
    lambda d: (d / "meta.json").write_bytes(b"\xff\xfe\x00garbage"),
    lambda d: (d / "m2.exr").write_bytes((d / "m2.exr").read_bytes()[:100]),
])
def test_unreadable_reference_entry_is_a_miss(tmp_path, capsys, damage):
    from reference import cache
    root = tmp_path / "refs"
    d = cache.store("cd" * 16, _moments(), {"spp": 8}, root)
    damage(d)
    assert cache.load("cd" * 16, root) is None and not d.exists()
    assert "evicted" in capsys.readouterr().err


def test_reference_entry_from_before_checksums_gets_them(tmp_path):
    from reference import cache
    root = tmp_path / "refs"
    d = cache.store("ef" * 16, _moments(), {"spp": 8}, root)
    meta = json.loads((d / "meta.json").read_text())
    del meta["files"]
    (d / "meta.json").write_text(json.dumps(meta))
    moments, meta = cache.load("ef" * 16, root)
    assert moments.n == 8 and "files" in json.loads((d / "meta.json").read_text())
    write_exr(d / "hits.exr", np.zeros((6, 8, 1), np.float32))
    assert cache.load("ef" * 16, root) is None
