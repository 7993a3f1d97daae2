"""Scenes in motion, rendered (issue #25): a method follows a sequence frame by frame, redoing the
work a motion invalidates inside the frame's clock; sequence rows of a run are judged against a
reference per frame."""
from __future__ import annotations

import time

import numpy as np
import pandas as pd
import pytest

from bench.model.animation import Sequence
from bench.model.corpus.sequences import load_sequence
from bench.protocol.method import SkipRow
from bench.protocol.registry import load_method
from bench.run.harness import run_method
from bench.run.sequence import run_sequence
from tests.conftest import make_open_box

W, H = 40, 24


@pytest.mark.gl
@pytest.mark.parametrize("method", ["direct", "ir_unshadowed", "ssdo", "val_clustered"])
def test_frame_zero_of_a_sequence_is_the_static_image(gl_ctx, method):
    """Frame 0 is the scene at rest, seen by a fresh instance: the static row's image, bit for bit."""
    seq = load_sequence("cornell_spot_moving_block", frames=2, rest=0)
    cls = load_method(method)
    moving = run_sequence(gl_ctx, cls, seq, "main", W, H, {}, shadow_resolution=256)
    static = run_method(gl_ctx, cls, seq.frame(0), "main", W, H, {}, shadow_resolution=256, frames=1)
    assert np.array_equal(moving.images[0][0], static.direct) and np.array_equal(moving.images[0][1], static.indirect)
    combined = [d + i for d, i in moving.images]
    assert not np.array_equal(combined[1], combined[0])   # the block moved: another image
    assert [f.changes for f in moving.frames] == [("camera", "geometry", "light"), ("geometry",)]


class CountingDirect(load_method("direct")):
    """`direct` that counts its preparations and makes each update cost at least 30 ms."""
    name = "counting_direct"
    prepared = 0

    def prepare(self, gpu, scene, facts, params, view):
        type(self).prepared += 1
        super().prepare(gpu, scene, facts, params, view)

    def update(self, gpu, scene, facts, params, view, changes):
        time.sleep(0.03)
        super().update(gpu, scene, facts, params, view, changes)


@pytest.mark.gl
def test_motion_work_is_redone_inside_the_frame_clock_and_only_when_something_moved(gl_ctx):
    box = make_open_box()
    # the light moves over frames 0-2, then rests: frames 3 and 4 change nothing
    seq = Sequence.build("sweep", box, 5, [("light", 0, {0: {"position": [0.2, 1.2, 0.1]}, 2: {"position": [-0.4, 1.2, 0.3]}})])
    CountingDirect.prepared = 0
    result = run_sequence(gl_ctx, CountingDirect, seq, "main", W, H, {}, shadow_resolution=256)
    assert CountingDirect.prepared == 3                       # frame 0, then the frames the light moved in
    assert [f.changes for f in result.frames][1:] == [("light",), ("light",), (), ()]
    moved, rested = result.frames[1:3], result.frames[3:]
    assert all(f.update_ms >= 30.0 and f.frame_ms >= f.update_ms for f in moved)
    assert all(f.update_ms == 0.0 for f in rested)
    assert np.array_equal(result.images[3][0], result.images[4][0])   # at rest: the same image


class NoGeometry(load_method("direct")):
    name = "no_geometry"
    cannot_follow = {"geometry": "its light cuts are built once for fixed geometry"}


@pytest.mark.gl
def test_a_method_that_cannot_follow_a_motion_is_skipped_with_its_reason(gl_ctx):
    with pytest.raises(SkipRow, match="cannot follow geometry motion: its light cuts are built once"):
        run_sequence(gl_ctx, NoGeometry, load_sequence("cornell_spot_moving_block", frames=2, rest=0), "main", W, H)
    run_sequence(gl_ctx, NoGeometry, load_sequence("rooms_light_sweep", frames=2, rest=0), "main", W, H)   # light: it follows


@pytest.mark.gl
@pytest.mark.mitsuba
def test_sequence_rows_of_a_run(tmp_path, monkeypatch):
    """`gibench run --sequences`: a row per method with the errors averaged over the frames and their
    worst frame, the frame times of the moving frames, per-frame values and images beside it; a re-run
    renders no reference again."""
    from bench.cli import main
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "run"
    argv = ["run", "--sequences", "rooms_light_sweep", "--sequence-frames", "3", "--sequence-rest", "0", "--views", "main",
            "--methods", "direct,ir_unshadowed", "--defaults-only", "--res", f"{W}x{H}", "--reference-spp", "8",
            "--no-progress", "--out", str(out)]
    assert main(argv) == 0
    rows = pd.read_csv(out / "results.csv")
    assert list(rows["method"]) == ["direct", "ir_unshadowed"] and set(rows["status"]) == {"ok"}
    assert set(rows["sequence"]) == {"rooms_light_sweep"} and set(rows["extra.sequence_frames"]) == {3}
    for _, row in rows.iterrows():
        frames = pd.read_csv(out / row["image_dir"] / "frames.csv")
        assert list(frames["t"]) == [0, 1, 2] and list(frames["changes"])[1:] == ["light", "light"]
        assert row["relmse.indirect"] == pytest.approx(frames["relmse.indirect"].mean())
        assert row["worst.relmse.indirect"] == pytest.approx(frames["relmse.indirect"].max())
        assert row["frame_ms"] == pytest.approx(frames["frame_ms"].iloc[1:].median())
        assert (out / row["image_dir"] / "frame_002_indirect.exr").is_file()
    # ir_unshadowed bounces light, direct has none: the indirect error says so in every frame
    assert rows.set_index("method").loc["ir_unshadowed", "worst.relmse.indirect"] < \
        rows.set_index("method").loc["direct", "relmse.indirect"]
    from reports import build_report   # the report's sequences: plots over frames and a filmstrip per view
    html = build_report(out, tmp_path / "report").read_text()
    assert "<h2 id='sequences'>" in html and "rooms_light_sweep/main: error over frames" in html
    assert (tmp_path / "report" / "plots" / "sequence_time_0.svg").is_file()
    strip = sorted(p.name for p in (tmp_path / "report" / "data" / "sequence_0").glob("*.png"))
    assert strip == sorted([f"{who}_{t:03d}.png" for who in ("reference", "direct", "ir_unshadowed") for t in range(3)])
    cached = sorted(p.name for p in (tmp_path / "cache" / "references").glob("*/*"))
    assert len(cached) == 3 * 3                                       # three components of three frames
    assert main(argv + ["--force"]) == 0
    assert sorted(p.name for p in (tmp_path / "cache" / "references").glob("*/*")) == cached
    again = tmp_path / "again"                                         # a re-run renders nothing: rows from the cache
    assert main(argv[:-1] + [str(again)]) == 0
    rerun = pd.read_csv(again / "results.csv")
    assert set(rerun["status"]) == {"cached"}
    assert list(rerun["relmse.indirect"]) == list(rows["relmse.indirect"])
    assert (again / rows["image_dir"][0] / "frame_002_combined.exr").is_file()
    assert (again / "references" / "rooms_light_sweep" / "main" / "frame_001_indirect_visible.exr").is_file()


def test_pbgi_lag_after_the_light_moves_is_measured_past_the_frames_at_rest(tmp_path, monkeypatch):
    """pbgi's amortised gather follows a moving light over its emitter window (~19 frames on rooms):
    longer than the frames at rest, so the row renders settling frames until its error is back, and
    its lag_frames is a measured number beyond the rest, not a lower bound."""
    from bench.cli import main
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "run"
    # a sixteenth of the default lightmap and of its emitter budget: the same window, cheaper frames
    assert main(["run", "--sequences", "rooms_light_sweep", "--sequence-frames", "3", "--sequence-rest", "1",
                 "--views", "main", "--methods", "pbgi", "--param", "pbgi.texel_density=36",
                 "--param", "pbgi.emitter_budget=128", "--res", "32x18", "--reference-spp", "8",
                 "--error-frames", "2", "--no-progress", "--out", str(out)]) == 0
    row = pd.read_csv(out / "results.csv").iloc[0]
    assert row["status"] == "ok" and np.isfinite(row["lag_frames"]) and row["lag_frames"] > 1
    frames = pd.read_csv(out / row["image_dir"] / "frames.csv")
    assert list(frames["settling"][:4]) == [0] * 4 and frames["settling"][4:].all() and len(frames) > 4
    assert len(frames) == 2 + 1 + row["lag_frames"]   # the last settling frame is the one back at its level
    assert not (out / row["image_dir"] / "frame_004_combined.exr").exists()   # settling frames keep no images


def test_unknown_sequence_is_bad_input(capsys):
    from bench.cli import main
    with pytest.raises(SystemExit) as exit_:
        main(["run", "--sequences", "moon_walk"])
    assert exit_.value.code == 2 and "unknown sequence 'moon_walk'" in capsys.readouterr().err


def test_lag_counts_frames_after_the_motion_until_the_error_is_back():
    from bench.run.sequence_rows import lag_after
    errors = np.array([0.1, 0.5, 0.9, 0.6, 0.3, 0.105, 0.1])   # the motion ends at frame 2
    assert lag_after(errors, 2, 0.1) == 3                      # frame 5 is within 10% of 0.1
    assert lag_after(errors, 2, 0.9) == 0                      # a method that keeps nothing is back at once
    assert lag_after(errors, 2, 0.01) is None                  # not back by the end


class LaggingDirect(load_method("direct")):
    """`direct` that follows a moving light two frames late: it shows the image of two frames ago
    and keeps its history through updates (a method that reuses earlier frames)."""
    name = "lagging_direct"

    def prepare(self, gpu, scene, facts, params, view):
        super().prepare(gpu, scene, facts, params, view)
        self.history = []

    def update(self, gpu, scene, facts, params, view, changes):
        history = self.history
        super().update(gpu, scene, facts, params, view, changes)
        self.history = history

    def render(self, frame, prof):
        from bench.gl import read_rgb
        out = super().render(frame, prof)
        self.history.append(read_rgb(out.direct).copy())
        return type(out)(direct=self.history[max(0, len(self.history) - 3)], indirect=None)


@pytest.mark.gl
def test_a_method_that_keeps_state_shows_the_past_after_the_motion(gl_ctx):
    box = make_open_box()
    seq = Sequence.build("sweep", box, 6, [("light", 0, {0: {"position": [0.2, 1.2, 0.1]}, 2: {"position": [-0.4, 1.2, 0.3]}})])
    lagging = run_sequence(gl_ctx, LaggingDirect, seq, "main", W, H, {}, shadow_resolution=256)
    prompt = run_sequence(gl_ctx, load_method("direct"), seq, "main", W, H, {}, shadow_resolution=256)
    shown = [d for d, _ in lagging.images]
    truth = [d for d, _ in prompt.images]
    assert np.array_equal(shown[2], truth[0]) and not np.array_equal(shown[2], truth[2])   # two frames late
    assert np.array_equal(shown[4], truth[2]) and np.array_equal(shown[5], truth[5])      # caught up at rest


@pytest.mark.gl
def test_settling_frames_measure_a_lag_longer_than_the_rest(gl_ctx):
    """The light moves in the last frame (no frame at rest): a method two frames late is not back
    by the end, so the same instance renders settling frames at rest until it is (its history
    kept: the frames shown are the last pose's after two of them), and no more; a cap bounds them."""
    box = make_open_box()
    seq = Sequence.build("late", box, 4, [("light", 0, {0: {"position": [0.2, 1.2, 0.1]}, 3: {"position": [-0.4, 1.2, 0.3]}})])
    truth = run_sequence(gl_ctx, load_method("direct"), seq, "main", W, H, {}, shadow_resolution=256).images[-1][0]

    def unsettled(result):
        return not np.array_equal(result.images[-1][0], truth)
    lagging = run_sequence(gl_ctx, LaggingDirect, seq, "main", W, H, {}, shadow_resolution=256,
                           unsettled=unsettled, settle_max=8)
    assert [f.settling for f in lagging.frames] == [False] * 4 + [True] * 2
    assert [f.t for f in lagging.frames] == list(range(6)) and all(not f.changes for f in lagging.frames[4:])
    assert np.array_equal(lagging.images[-1][0], truth) and not np.array_equal(lagging.images[-2][0], truth)
    capped = run_sequence(gl_ctx, LaggingDirect, seq, "main", W, H, {}, shadow_resolution=256,
                          unsettled=lambda result: True, settle_max=3)
    assert len(capped.frames) == 4 + 3


@pytest.mark.gl
@pytest.mark.parametrize("method", ["direct", "manylights"])
def test_frame_one_is_a_static_render_at_frame_ones_pose(gl_ctx, method):
    """A stateless method (its frames identical for a view) shows at frame 1 exactly what a static
    row of frame 1's scene shows."""
    cls = load_method(method)
    assert cls.frames_identical(cls.params and {k: p.default for k, p in cls.params.items()})
    seq = load_sequence("cornell_spot_moving_block", frames=2, rest=0)
    moving = run_sequence(gl_ctx, cls, seq, "main", W, H, {}, shadow_resolution=256)
    static = run_method(gl_ctx, cls, seq.frame(1), "main", W, H, {}, shadow_resolution=256, frames=1)
    assert np.array_equal(moving.images[1][0], static.direct) and np.array_equal(moving.images[1][1], static.indirect)


@pytest.mark.gl
def test_visibility_gates_keeps_its_topology_when_only_the_camera_moves(gl_ctx, monkeypatch):
    """The topology of empty space depends on geometry: a camera move inside the same empty space
    reuses it (only the GPU side is rebuilt), a moved block builds it again in that frame."""
    import methods.visibility_gates.method as gates
    from bench.model.corpus import load_scene
    built = []
    real = gates.build_topology
    monkeypatch.setattr(gates, "build_topology", lambda *a, **k: built.append(1) or real(*a, **k))
    gates._TOPOLOGY_CACHE.clear()
    box = load_scene("cornell_spot")
    walk = Sequence.build("look", box, 3, [("camera", "main", {2: {"eye": [0.2, 1.1, 0.8]}})])
    result = run_sequence(gl_ctx, gates.VisibilityGates, walk, "main", W, H, {"vpl_count": 64}, shadow_resolution=256)
    assert len(built) == 1 and all(f.update_ms > 0 for f in result.frames[1:])
    gates._TOPOLOGY_CACHE.clear()
    built.clear()
    run_sequence(gl_ctx, gates.VisibilityGates, load_sequence("cornell_spot_moving_block", frames=3, rest=0), "main",
                 W, H, {"vpl_count": 64}, shadow_resolution=256)
    assert len(built) == 3                                 # frame 0, then each frame the block moved


@pytest.mark.gl
def test_a_budgeted_run_with_scenes_and_sequences(tmp_path, monkeypatch):
    """Under a budget the plan holds the scenes' rows and the sequences' rows; both run."""
    from bench.run import serial
    from bench.run.config import RunConfig
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    cfg = RunConfig(scenes=[make_open_box()], methods=["direct"], width=W, height=H, frames=1, warmup=1,
                    references=False, error_frames=1, progress=False, out=tmp_path / "run", budget_s=3600.0,
                    sequences=["rooms_light_sweep"], sequence_frames=2, sequence_rest=0, sequence_width=W,
                    sequence_height=H)
    df, _ = serial.run(cfg, log=lambda m: None)
    assert sorted(df["scene"]) == ["open_box", "rooms_light_sweep", "rooms_light_sweep"]
    assert set(df["status"]) == {"ok"}
