"""The conformance checks that render (bench.kit.conformance lists them all).

Every row is rendered through bench.run.execute.render_outcome, the one function a run renders
rows with, with images kept even when they hold NaN or Inf pixels (so the images check can count
them). The rows, on the first check scene the method does not decline: the defaults (A), the
same again from a fresh GpuScene (B), with the view's shared passes lent (C: every pass of its
variant, as a run with other methods lends them), each other ladder rung; then the defaults on
`sphere_inside` (with error frames), and one row with a parameter out of its range, which must
fail before any GL work.
"""
from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass, field

import moderngl
import numpy as np

from bench.gl import GpuScene
from bench.gl.passes import KNOWN_NEEDS, expand_needs, read_rgba, shared_variant
from bench.model.corpus import load_scene
from bench.model.corpus.procedural import sphere_inside_indirect
from bench.model.scene import compute_facts
from bench.protocol.method import resolve_params
from bench.protocol.vocabulary import SHARED_STAGES, Status, frame_stat_image
from bench.run.config import RunConfig
from bench.run.execute import build_shared_passes, render_outcome

ENERGY_SCENE = "sphere_inside"
# The excess over the analytic one bounce a method may show on sphere_inside unless it states its
# own (`one_bounce_tolerance`): the tessellated sphere (0.3%) and the noise left in a mean over
# ENERGY_FRAMES frames of a stochastic estimate (FLC: 0.987 .. 1.014 over seeds 0-3) fit in it; a
# radiometric factor (pi, 2, an albedo) does not.
DEFAULT_ONE_BOUNCE_TOLERANCE = 0.05
# The energy check judges the mean of this many frames (the row's error frames): a method whose
# random draws are global per frame moves its whole image with the seed (FLC: 0.95 .. 1.03 of
# the analytic value over seeds 0-3), and the check is of its bias, not of one frame's draw.
ENERGY_FRAMES = 4
IMAGES = ("direct", "indirect", "combined")


@dataclass
class Row:
    """One rendered row of the checks: what it is, its outcome, the GL error it left behind."""
    label: str
    outcome: dict
    gl_error_after: str = "GL_NO_ERROR"
    readbacks: list = field(default_factory=list)   # (stage, what) read back inside a timed stage

    @property
    def status(self) -> str:
        return self.outcome["status"]

    @property
    def reason(self) -> str:
        return self.outcome.get("reason", "")

    def image(self, name: str) -> np.ndarray:
        return self.outcome["images"][name]


# ---------------------------------------------------------------------------- shared-pass snapshots
def snapshot(passes) -> dict:
    """Every texture of the shared passes, read back, and each texture's sampling parameters."""
    out = {}
    textures = {}
    g = passes.gbuffer
    if g is not None:
        for name in ("position", "normal", "albedo", "geo_normal"):
            textures[f"gbuffer.{name}"] = getattr(g, name)
        out["gbuffer.depth"] = np.frombuffer(g.depth.read(), np.float32).copy()
        textures["gbuffer.depth"] = g.depth
    if passes.shadows is not None:
        textures["shadows.atlas"] = passes.shadows.atlas
    if passes.direct is not None:
        textures["direct.radiance"] = passes.direct.radiance
    if passes.rsm is not None:
        for name in ("position", "normal", "flux"):
            textures[f"rsm.{name}"] = getattr(passes.rsm, name)
    for key, tex in textures.items():
        if key != "gbuffer.depth":
            out[key] = read_rgba(tex)
        out[f"{key} (parameters)"] = np.array([str((tex.filter, tex.repeat_x, tex.repeat_y, tex.anisotropy))])
    return out


def changed_textures(before: dict, after: dict) -> list[str]:
    return [k for k in before if not np.array_equal(before[k], after[k], equal_nan=before[k].dtype.kind == "f")]


# ---------------------------------------------------------------------------- readback in a stage
class _ReadbackWatch:
    """Counts texture, buffer and framebuffer reads while a timed stage is open (a read blocks
    until the GPU is done: inside a stage it times the pipeline's drain, not the stage)."""
    TARGETS = ((moderngl.Texture, ("read", "read_into")), (moderngl.Buffer, ("read", "read_into", "read_chunks")),
               (moderngl.Framebuffer, ("read", "read_into")))

    def __init__(self):
        self.stage = None
        self.found: list = []

    @contextmanager
    def installed(self):
        originals = []
        for kind, names in self.TARGETS:
            for name in names:
                original = getattr(kind, name, None)
                if original is None:
                    continue
                originals.append((kind, name, original))
                setattr(kind, name, self._wrap(original, f"{kind.__name__}.{name}"))
        try:
            yield self
        finally:
            for kind, name, original in originals:
                setattr(kind, name, original)

    def _wrap(self, original, what: str):
        watch = self

        def read(*args, **kwargs):
            if watch.stage is not None:
                watch.found.append((watch.stage, what))
            return original(*args, **kwargs)
        return read


class _WatchedProfiler:
    """The row's StageProfiler, telling the watch which stage is open."""

    def __init__(self, prof, watch: _ReadbackWatch):
        self._prof, self._watch = prof, watch

    def __getattr__(self, name):
        return getattr(self._prof, name)

    @contextmanager
    def stage(self, name: str):
        with self._prof.stage(name):
            self._watch.stage = name
            try:
                yield
            finally:
                self._watch.stage = None


def watched(cls, watch: _ReadbackWatch):
    """`cls` whose render() receives a profiler that reports its open stage to `watch`."""
    def render(self, frame, prof):
        return cls.render(self, frame, _WatchedProfiler(prof, watch))
    return type(cls.__name__, (cls,), {"render": render, "__module__": cls.__module__, "__doc__": cls.__doc__})


# ---------------------------------------------------------------------------- rendering the rows
class Renderer:
    def __init__(self, cls, ctx, settings):
        self.cls, self.ctx, self.settings = cls, ctx, settings
        self.rows: list[Row] = []

    def config(self, scene, error_frames: int = 1) -> RunConfig:
        s = self.settings
        return RunConfig(scenes=[scene], methods=[self.cls.name], width=s.width, height=s.height, frames=1,
                         warmup=1, seed=s.seed, error_frames=error_frames, references=False, progress=False)

    def render(self, label: str, scene, facts, params: dict, gpu=None, shared=None, error_frames: int = 1,
               watch: _ReadbackWatch | None = None) -> Row:
        cls = self.cls if watch is None else watched(self.cls, watch)
        view = next(iter(scene.cameras))
        outcome = render_outcome(self.ctx, gpu, self.config(scene, error_frames), cls, scene, facts, view, params,
                                 shared=shared, keep_nonfinite=True)
        row = Row(label, outcome, gl_error_after=self.ctx.error)
        if watch is not None:
            row.readbacks = list(watch.found)
        self.rows.append(row)
        return row


def run(cls, ctx, settings, out_of_range: dict | None) -> dict:
    """{check: (problems, what passed)} for parameters (the row part), ladder (rendered rungs),
    images, gl_errors, determinism, shared_passes, stages and energy."""
    r = Renderer(cls, ctx, settings)
    ctx.error   # a fresh start: an error left by earlier work is not this method's
    try:
        defaults = resolve_params(cls, {})
    except Exception as exc:
        why = f"not run: the defaults do not resolve ({' '.join(str(exc).split())})"
        return {c: ([why], "") for c in ("parameters", "ladder", "images", "gl_errors", "determinism",
                                         "shared_passes", "stages", "energy")}
    try:
        identical = cls.frames_identical(defaults) is True
    except Exception:   # the declarations check reports it
        identical = False
    # the checks render on the first scene the method does not decline (SkipRow is the protocol's
    # way to decline a scene by design: visibility_gates declines open ones)
    chosen, declined = None, []
    determinism, shared_problems, shared_passed = [], [], ""
    watch = _ReadbackWatch()
    for scene in (load_scene(name) for name in settings.scenes):
        facts = compute_facts(scene)
        gpu = GpuScene(ctx, scene, seed=settings.seed, facts=facts)
        try:
            with watch.installed():
                a = r.render(f"{scene.name} defaults", scene, facts, {}, gpu=gpu,
                             error_frames=2 if identical else 1, watch=watch)
            if a.status == Status.SKIPPED:
                declined.append(f"{scene.name} ({a.reason})")
                continue
            b = r.render(f"{scene.name} defaults (fresh GpuScene)", scene, facts, {})
            determinism = _determinism(a, b, settings.seed)
            # the images are compared only when two rows of the same seed agree
            shared_problems, shared_passed = _shared_passes(r, scene, facts, gpu, a, compare_images=not determinism)
            chosen = (scene, facts, a)
            break
        finally:
            gpu.release()
    rung_problems, rungs = [], 0
    if chosen is None:
        why = f"every check scene was declined: {'; '.join(declined)}; give --scenes it renders"
        rung_problems.append(f"rungs not rendered: {why}")
        determinism, shared_problems = [f"not judged: {why}"], [f"not judged: {why}"]
    scene, facts, a = chosen or (None, None, None)
    for rung in (getattr(cls, "ladder", ()) or ()) if chosen else ():
        if not isinstance(rung, dict) or not rung:
            continue
        try:
            resolve_params(cls, rung)
        except Exception:   # an invalid rung: the declared-ladder check says so
            continue
        row = r.render(f"{scene.name} rung {rung}", scene, facts, rung)
        rungs += 1
        rung_problems += [f"rung {rung}: {p}" for p in _image_problems(row, settings)]
    energy = r.render(f"{ENERGY_SCENE} defaults", load_scene(ENERGY_SCENE), None, {}, error_frames=ENERGY_FRAMES)
    param_problems = []
    if out_of_range is not None:
        probe = load_scene(settings.scenes[0])
        row = r.render(f"{probe.name} {out_of_range}", probe, None, out_of_range)
        name = next(iter(out_of_range))
        if row.status == Status.OK or f"'{name}'" not in row.reason:
            param_problems.append(f"a row with {out_of_range} was not refused with a ParamError naming "
                                  f"'{name}' ({row.status}: {row.reason})")
    judged = [row for row in r.rows if row.label.endswith("defaults") and row.status != Status.SKIPPED]
    image_problems = [p for row in judged for p in _image_problems(row, settings)]
    if chosen is None:
        image_problems.insert(0, why)
    gl = [f"{row.label}: {row.reason}" for row in r.rows if row.status == Status.FAILED
          and failure_owner(row) == "gl_errors"]
    gl += [f"{row.label}: {row.gl_error_after} left behind after the row (prepare, render or release)"
           for row in r.rows if row.gl_error_after != "GL_NO_ERROR"]
    w, h = settings.width, settings.height
    return {
        "parameters": (param_problems, ""),
        "ladder": (rung_problems, f"{rungs + 1} rung(s) valid and rendered on {scene.name}" if rungs
                   else "no ladder: the defaults are the method's only operating point"),
        "images": (image_problems, f"{', '.join(row.label for row in judged)} at {w}x{h}: finite, non-negative"
                   + (f" (declined {'; '.join(declined)})" if declined else "")),
        "gl_errors": (gl, f"none in {len(r.rows)} rows"),
        "determinism": (determinism, f"seed {settings.seed} gives the same images bit for bit"
                        + (" (frames_identical holds)" if identical else "")),
        "shared_passes": (shared_problems, shared_passed),
        "stages": _stages(cls, a) if chosen else ([f"not judged: {why}"], ""),
        "energy": _energy(cls, energy),
    }


# A failed row's reason -> the check it belongs to (the images check takes the others).
FAILURE_OWNERS = (("GL error", "gl_errors"), ("(frames_identical)", "determinism"),
                  ("is not declared (declared:", "stages"), ("GL timer queries cannot nest", "stages"))


def failure_owner(row: Row) -> str:
    return next((check for marker, check in FAILURE_OWNERS if marker in row.reason), "images")


def _image_problems(row: Row, settings) -> list[str]:
    if row.status == Status.SKIPPED:
        return []
    if row.status != Status.OK:
        return [f"{row.label} failed: {row.reason}"] if failure_owner(row) == "images" else []
    problems = []
    shape = (settings.height, settings.width, 3)
    for name in IMAGES:
        img = row.image(name)
        if img.shape != shape:
            problems.append(f"{row.label}: {name} image of shape {img.shape}, the view is {shape}")
            continue
        bad = int((~np.isfinite(img)).any(axis=2).sum())
        if bad:
            problems.append(f"{row.label}: {bad} NaN/Inf {name} pixels")
        negative = int((np.nan_to_num(img) < 0).any(axis=2).sum())
        if negative:
            problems.append(f"{row.label}: {negative} negative {name} pixels (min {np.nanmin(img):.3g})")
    return problems


def _same(a: Row, b: Row) -> list[str]:
    return [n for n in ("direct", "indirect") if not np.array_equal(a.image(n), b.image(n), equal_nan=True)]


def _determinism(a: Row, b: Row, seed: int) -> list[str]:
    if a.status == Status.FAILED and failure_owner(a) == "determinism":
        return [f"{a.label}: {a.reason}"]
    if a.status != Status.OK or b.status != Status.OK:
        if a.status == b.status == Status.SKIPPED:
            return []
        return [f"not judged on {a.label}: the row {a.status if a.status != Status.OK else b.status}"]
    differ = _same(a, b)
    if differ:
        pixels = int((a.image("indirect") != b.image("indirect")).any(axis=2).sum())
        return [f"seed {seed} gave different {' and '.join(differ)} images in two rows ({a.label}; "
                f"{pixels} indirect pixels differ): draw random numbers from frame.random_u32 or the seed"]
    return []


def lent_needs(needs) -> frozenset:
    """Every shared pass of the method's variant: in a run the view's passes are built for the
    union of its rows' needs, so a method is lent more than it needs (row A, with passes of its
    own, has exactly its needs: a pass it uses without declaring it is None there)."""
    needs = expand_needs(needs)
    if shared_variant(needs) == "unshadowed_direct":
        return needs | {"gbuffer", "direct", "rsm"}
    return needs | KNOWN_NEEDS


def _shared_passes(r: Renderer, scene, facts, gpu, alone: Row, compare_images: bool) -> tuple[list, str]:
    cls = r.cls
    if not getattr(cls, "reuses_shared_passes", True):
        return [], "declares reuses_shared_passes = False: it gets passes of its own in every frame"
    if alone.status != Status.OK:
        return ([] if alone.status == Status.SKIPPED else [f"not judged: {alone.label} {alone.status}"]), \
            f"not judged: {alone.label} skipped"
    view = next(iter(scene.cameras))
    shared = build_shared_passes(r.ctx, gpu, r.config(scene), view, lent_needs(cls.needs))
    try:
        before = snapshot(shared.passes)
        lent = r.render(f"{scene.name} defaults (passes lent)", scene, facts, {}, gpu=gpu, shared=shared)
        changed = changed_textures(before, snapshot(shared.passes))
    finally:
        shared.passes.release()
    if changed:
        return [f"wrote the shared {', '.join(changed)}: shared passes are read-only (or declare "
                f"reuses_shared_passes = False)"], ""
    if lent.status != Status.OK:
        return [f"with the passes lent the row {lent.status}: {lent.reason}"], ""
    problems = []
    differ = _same(alone, lent) if compare_images else []
    if differ:
        problems.append(f"with the passes lent its {' and '.join(differ)} images differ from those with passes "
                        f"of its own (does it depend on state the passes leave?)")
    if lent.outcome["measured"].get("extra.shared_passes_reused") is not True:
        problems.append("the row with the passes lent did not record extra.shared_passes_reused")
    return problems, (f"read only: {len(before) // 2} shared textures unchanged, "
                      + ("the same images as with its own" if compare_images else "images not compared (not "
                         "deterministic)"))


def _stages(cls, row: Row) -> tuple[list, str]:
    if row.status == Status.FAILED and failure_owner(row) == "stages":
        return [f"{row.label}: {row.reason}"], ""
    if row.status != Status.OK:
        return ([] if row.status == Status.SKIPPED else [f"not judged: {row.label} {row.status}"]), \
            f"not judged: {row.label} skipped"
    measured = row.outcome["measured"]
    timed = [s for s in json.loads(measured["samples.stage_ms"]) if s not in SHARED_STAGES]
    skipped = set(json.loads(measured["skipped_stages"]))
    problems = []
    undeclared = [s for s in timed if s not in cls.stages]
    if undeclared:
        problems.append(f"timed stage(s) {undeclared} are not declared in `stages` {list(cls.stages)}")
    missing = [s for s in cls.stages if s not in timed and s not in skipped]
    if missing:
        problems.append(f"declared stage(s) {missing} were neither timed (prof.stage) nor reported in "
                        f"FrameOutput.skipped_stages")
    samples = json.loads(measured["samples.stage_ms"])
    bad = [s for s, v in samples.items() if not all(np.isfinite(x) and x >= 0 for x in v)]
    if bad:
        problems.append(f"stage(s) {bad} have negative or non-finite times")
    if row.readbacks:
        stage, what = row.readbacks[0]
        problems.append(f"{what} inside the timed stage '{stage}': read results back after the frame, never in a "
                        f"stage ({len(row.readbacks)} read(s))")
    return problems, (f"timed {timed}" + (f", skipped {sorted(skipped)}" if skipped else "")
                      + ", no readback inside a stage" if timed or skipped else "no stage of its own")


def _energy(cls, row: Row) -> tuple[list, str]:
    tolerance = getattr(cls, "one_bounce_tolerance", DEFAULT_ONE_BOUNCE_TOLERANCE)
    if tolerance is None:
        return [], "no one-bounce claim (one_bounce_tolerance = None)"
    if row.status == Status.SKIPPED:
        return [], f"{ENERGY_SCENE} skipped by the method ({row.reason})"
    if row.status != Status.OK:
        return [f"not judged: {row.label} failed ({row.reason})"], ""
    indirect = row.image(frame_stat_image("indirect", "mean"))
    finite = np.isfinite(indirect).all(axis=2)
    if not finite.any() or not np.any(indirect[finite]):
        return [], "no one-bounce claim: its indirect image is zero"
    ratio = float(indirect[finite].mean(axis=0).max()) / sphere_inside_indirect()
    text = (f"{ENERGY_SCENE}: mean indirect of {ENERGY_FRAMES} frames {ratio:.4f} x the analytic rho^2 I / (pi R^2), "
            f"allowed up to {1 + tolerance:.4g}")
    if ratio > 1.0 + tolerance:
        return [f"{text}: more light than one bounce holds (a radiometric factor: pi, 2, an albedo, a cosine?)"], ""
    return [], text
