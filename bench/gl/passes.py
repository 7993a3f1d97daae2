"""Shared GL passes, built only when a method needs them: GBuffer, shadow maps, direct lighting,
reflective shadow map. `SharedPasses.render(prof)` runs them under the shared stage names
`gbuffer_shadow`, `direct_light` and `rsm`.

Reuse: the passes depend on the view, the scene (its GpuScene, hence its seed) and the shadow
and RSM resolutions only: never on a frame index, a method or its parameters (render() takes
no frame). The runner therefore renders them once per view and lends them to every method and
rung of the view (bench.run.harness.SharedViewPasses); methods only read them. `restore_state()`
puts the GL state where `render()` would leave it, so a method's frame starts as if the passes
had just been rendered. One exception to "a superset serves everyone": the direct pass is
shadowed exactly when the shadow maps are built, so a method that needs `direct` without
`shadow_map` gets passes of its own variant (`shared_variant`).

Image convention: textures are GL's (row 0 at the bottom); `read_rgb` returns numpy arrays
with row 0 at the top, like EXR files and Mitsuba.

Depth: the GBuffer, shadow and RSM passes write gl_FragDepth linear in the distance (to the
camera, to a point/spot light; depth along a directional light), scaled to [0, 1] by the pass's
far distance. The projections keep near = 1e-5 far (nothing near the eye or light is clipped),
where a 24-bit 1/z depth buffer's step is ~far/170 at the far end, coarser than the shadow
tolerance; linear depth steps are far / 2^24 everywhere. Cost: no early depth test in these
passes. The projection matrices (`View.proj`, `LightLayer.view_proj`) are unchanged.

Emitter convention (every VPL method follows it, as Mitsuba's twosided diffuse with shading
normals): the irradiance of an emitting point y takes its cosine against the shading normal at y
(vertex normals interpolated there), y emits towards x the radiosity of the side of that shading
normal x lies on, and the geometric term |cos| / d^2 uses y's geometric normal. The RSM flux is
rho Phi_in |<n_s, l>| / |<n_g, l>| accordingly.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import numpy as np

from bench.model.scene import DirectionalLight, PointLight, Scene, SpotLight
from bench.protocol.vocabulary import SHARED_STAGES
from .camera import View, look_at, orthographic, perspective
from .context import check_gl, create_context, park
from .gpu_scene import GpuScene
from .profiler import StageProfiler
from .shaders import GLOBAL_DEFINES, has_member, load_program, set_uniforms

SHADER_DIR = Path(__file__).parent / "shaders"
KNOWN_NEEDS = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
RSM_RESOLUTION = 128   # the shared RSM's tile side

# Cube faces in the order shadow.glsl selects them: +X, -X, +Y, -Y, +Z, -Z (axis, up).
WIDE_SPOT_CUTOFF_DEG = 45.0   # a spot wider than this gets cube-face layers (plan_light_layers)
_CUBE_FACES = (((1, 0, 0), (0, 1, 0)), ((-1, 0, 0), (0, 1, 0)), ((0, 1, 0), (0, 0, 1)),
               ((0, -1, 0), (0, 0, 1)), ((0, 0, 1), (0, 1, 0)), ((0, 0, -1), (0, 1, 0)))


def read_rgb(tex: moderngl.Texture) -> np.ndarray:
    """Read an RGBA32F/RGB32F texture as HxWx3 float32, row 0 at the top."""
    comps = tex.components
    data = np.frombuffer(tex.read(), dtype=np.float32).reshape(tex.height, tex.width, comps)
    return np.ascontiguousarray(data[::-1, :, :3])


def read_rgba(tex: moderngl.Texture) -> np.ndarray:
    data = np.frombuffer(tex.read(), dtype=np.float32).reshape(tex.height, tex.width, tex.components)
    return np.ascontiguousarray(data[::-1])


@dataclass(frozen=True)
class LightLayer:
    light_index: int
    view_proj: np.ndarray
    info: np.ndarray  # see ShadowLayer.info in shadow.glsl
    # (offset, scale): the depth test of the shadow and RSM passes runs on (metric - offset) * scale
    # in [0, 1], linear in the light-space metric (distance to the light, or depth along a
    # directional light), so its precision is range / 2^24 everywhere.
    depth_map: tuple = (0.0, 1.0)


def plan_light_layers(gpu: GpuScene, resolution: int) -> tuple[list[LightLayer], list[int], list[int]]:
    """The shadow/RSM layers of every light: point -> 6 cube faces, spot -> 1 perspective layer
    (6 cube faces when its cutoff is wider than WIDE_SPOT_CUTOFF_DEG), directional -> 1.

    A single perspective layer over a cone of half-angle c has texels tan(c) times wider at its
    centre than a cube face's (tan 45 deg = 1), so past 45 degrees the cube is finer everywhere:
    cornell_box's 85-degree spot had one 170-degree layer whose central texel covered 0.12 m^2 of
    floor (35 cm): its shadow lines and every RSM VPL under the light were that coarse. A light
    with six layers is looked up as a cube by the shaders (shadow.glsl), whatever its kind; the
    spot's falloff zeroes the faces' texels outside its cone."""
    layers: list[LightLayer] = []
    first, count = [], []
    R = gpu.radius
    center = np.asarray(gpu.facts.scene_center) - gpu.origin
    for i, light in enumerate(gpu.scene.lights):
        first.append(len(layers))
        wide_spot = isinstance(light, SpotLight) and light.cutoff_angle_deg > WIDE_SPOT_CUTOFF_DEG
        if isinstance(light, PointLight) or wide_spot:
            pos = light.position - gpu.origin
            far = np.linalg.norm(pos - center) + R * 1.01
            near = max(1e-5 * far, 1e-6)
            proj = perspective(90.0, 1.0, near, far)
            for axis, up in _CUBE_FACES:
                vp = proj @ look_at(pos, pos + np.asarray(axis, float), up)
                # every scene point is within `far` of the light: distance / far is in [0, 1]
                layers.append(LightLayer(i, vp, np.array([2.0 / resolution, 0.0, 1.0, 0.0]), (0.0, 1.0 / far)))
        elif isinstance(light, SpotLight):
            pos = light.position - gpu.origin
            far = np.linalg.norm(pos - center) + R * 1.01
            near = max(1e-5 * far, 1e-6)
            fov = min(2.0 * light.cutoff_angle_deg * 1.02, 170.0)
            d = light.direction
            up = (0.0, 1.0, 0.0) if abs(d[1]) < 0.99 else (1.0, 0.0, 0.0)
            vp = perspective(fov, 1.0, near, far) @ look_at(pos, pos + d, up)
            tan_half = np.tan(np.radians(fov) / 2)
            layers.append(LightLayer(i, vp, np.array([2.0 * tan_half / resolution, 0.0, tan_half, 0.0]),
                                     (0.0, 1.0 / far)))
        elif isinstance(light, DirectionalLight):
            d = light.direction
            up = (0.0, 1.0, 0.0) if abs(d[1]) < 0.99 else (1.0, 0.0, 0.0)
            eye = center - d * 2.0 * R
            vp = orthographic(R * 1.01, R * 1.01, 0.0, 4.0 * R) @ look_at(eye, center, up)
            layers.append(LightLayer(i, vp, np.array([2.0 * R * 1.01 / resolution, 1.0, 0.0, 0.0]),
                                     (float(np.dot(eye, d)), 1.0 / (4.0 * R))))
        count.append(len(layers) - first[-1])
    return layers, first, count


class GBuffer:
    """Position, shading normal, albedo, geometric normal (+ triangle id in .w) and depth."""

    def __init__(self, gpu: GpuScene, width: int, height: int):
        ctx = gpu.ctx
        self.gpu, self.width, self.height = gpu, width, height
        self.position = ctx.texture((width, height), 4, dtype="f4")
        self.normal = ctx.texture((width, height), 4, dtype="f4")
        self.albedo = ctx.texture((width, height), 4, dtype="f4")
        self.geo_normal = ctx.texture((width, height), 4, dtype="f4")
        for t in (self.position, self.normal, self.albedo, self.geo_normal):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_texture((width, height))
        self.fbo = ctx.framebuffer([self.position, self.normal, self.albedo, self.geo_normal], self.depth)
        self.program = load_program(ctx, SHADER_DIR / "gbuffer.glsl")
        self.vao = gpu.vertex_array(self.program)

    def render(self, view: View) -> None:
        ctx = self.gpu.ctx
        self.fbo.use()
        ctx.viewport = (0, 0, self.width, self.height)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable_only(moderngl.DEPTH_TEST)
        # depth test on the distance to the camera / far (linear: see gbuffer.glsl)
        set_uniforms(self.program, u_view_proj=view.view_proj, u_camera_pos=tuple(view.eye_local),
                     u_depth_scale=1.0 / float(view.far))
        self.gpu.bind_scene_buffers()
        self.vao.render(moderngl.TRIANGLES)

    def bind(self, program: moderngl.Program, first_unit: int = 0) -> int:
        """Bind the GBuffer textures to `program`'s u_gbuffer_* samplers; returns next free unit."""
        unit = first_unit
        for name, tex in (("u_gbuffer_position", self.position), ("u_gbuffer_normal", self.normal),
                          ("u_gbuffer_albedo", self.albedo), ("u_gbuffer_geo_normal", self.geo_normal)):
            if has_member(program, name):
                tex.use(unit)
                program[name].value = unit
                unit += 1
        return unit

    def read(self) -> dict:
        pos = read_rgba(self.position)
        geo = read_rgba(self.geo_normal)
        return {"position": pos[..., :3] + self.gpu.origin.astype(np.float32), "mask": pos[..., 3] > 0,
                "normal": read_rgb(self.normal), "albedo": read_rgb(self.albedo),
                "geo_normal": geo[..., :3], "triangle": np.where(pos[..., 3] > 0, geo[..., 3], -1).astype(np.int64)}

    def release(self) -> None:
        park(self.gpu.ctx)
        for obj in (self.fbo, self.position, self.normal, self.albedo, self.geo_normal, self.depth, self.program):
            obj.release()


class ShadowMaps:
    """All lights' shadow layers in one R32F atlas (tiles of resolution^2)."""

    def __init__(self, gpu: GpuScene, resolution: int = 1024):
        ctx = gpu.ctx
        self.gpu, self.resolution = gpu, int(resolution)
        self.layers, first, count = plan_light_layers(gpu, self.resolution)
        gpu.set_light_shadow_layers(first, count)
        n = len(self.layers)
        self.tiles_x = int(np.ceil(np.sqrt(n)))
        tiles_y = int(np.ceil(n / self.tiles_x))
        size = (self.tiles_x * self.resolution, tiles_y * self.resolution)
        self.atlas = ctx.texture(size, 1, dtype="f4")
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer([self.atlas], self.depth)
        records = np.zeros((n, 5, 4), dtype=np.float32)
        for k, layer in enumerate(self.layers):
            records[k, :4] = layer.view_proj.T  # column-major mat4
            records[k, 4] = layer.info
        self.layer_buffer = ctx.buffer(records.tobytes())
        self.program = load_program(ctx, SHADER_DIR / "shadow_depth.glsl")
        self.vao = gpu.vertex_array(self.program)

    def render(self) -> None:
        ctx = self.gpu.ctx
        self.fbo.use()
        ctx.scissor = None
        self.fbo.clear(3.0e38, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable_only(moderngl.DEPTH_TEST)
        self.gpu.bind_scene_buffers()
        for k, layer in enumerate(self.layers):
            x, y = k % self.tiles_x, k // self.tiles_x
            ctx.viewport = (x * self.resolution, y * self.resolution, self.resolution, self.resolution)
            set_uniforms(self.program, u_view_proj=layer.view_proj, u_light_index=layer.light_index,
                         u_depth_map=tuple(float(v) for v in layer.depth_map))
            self.vao.render(moderngl.TRIANGLES)

    def bind(self, program: moderngl.Program, unit: int) -> int:
        """Bind atlas + layer records for shadow.glsl; returns the next free texture unit."""
        self.layer_buffer.bind_to_storage_buffer(GLOBAL_DEFINES["BINDING_SHADOW_LAYERS"])
        if has_member(program, "u_shadow_atlas"):
            self.atlas.use(unit)
            program["u_shadow_atlas"].value = unit
            set_uniforms(program, u_shadow_tiles_x=self.tiles_x, u_shadow_resolution=self.resolution)
            return unit + 1
        return unit

    def release(self) -> None:
        park(self.gpu.ctx)
        for obj in (self.fbo, self.atlas, self.depth, self.layer_buffer, self.program):
            obj.release()


class DirectPass:
    """Direct radiance of the GBuffer (RGBA32F), shadowed with the shadow maps when given."""

    def __init__(self, gpu: GpuScene, gbuffer: GBuffer, shadows: ShadowMaps | None):
        ctx = gpu.ctx
        self.gpu, self.gbuffer, self.shadows = gpu, gbuffer, shadows
        self.radiance = ctx.texture((gbuffer.width, gbuffer.height), 4, dtype="f4")
        self.radiance.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo = ctx.framebuffer([self.radiance])
        self.program = load_program(ctx, SHADER_DIR / "direct_pass.glsl")
        self.vao = ctx.vertex_array(self.program, [])

    def render(self) -> None:
        ctx = self.gpu.ctx
        self.fbo.use()
        ctx.viewport = (0, 0, self.gbuffer.width, self.gbuffer.height)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        unit = self.gbuffer.bind(self.program)
        if self.shadows is not None:
            self.shadows.bind(self.program, unit)
        set_uniforms(self.program, u_light_count=self.gpu.light_count, u_shadows=self.shadows is not None)
        self.gpu.bind_scene_buffers()
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def read(self) -> np.ndarray:
        return read_rgb(self.radiance)

    def release(self) -> None:
        park(self.gpu.ctx)
        for obj in (self.fbo, self.radiance, self.program, self.vao):
            obj.release()


class ReflectiveShadowMap:
    """RSM of every light (layers as the shadow maps, lower resolution): position, normal
    facing the light, reflected flux per texel (rgb) and the texel's footprint on the surface in
    m^2 (flux.a). Unlit texels have flux 0 and position.w 0."""

    def __init__(self, gpu: GpuScene, resolution: int = 128):
        ctx = gpu.ctx
        self.gpu, self.resolution = gpu, int(resolution)
        self.layers, _, _ = plan_light_layers(gpu, self.resolution)
        n = len(self.layers)
        self.tiles_x = int(np.ceil(np.sqrt(n)))
        tiles_y = int(np.ceil(n / self.tiles_x))
        size = (self.tiles_x * self.resolution, tiles_y * self.resolution)
        self.position = ctx.texture(size, 4, dtype="f4")
        self.normal = ctx.texture(size, 4, dtype="f4")
        self.flux = ctx.texture(size, 4, dtype="f4")
        for t in (self.position, self.normal, self.flux):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer([self.position, self.normal, self.flux], self.depth)
        self.program = load_program(ctx, SHADER_DIR / "rsm.glsl")
        self.vao = gpu.vertex_array(self.program)

    @property
    def texel_count(self) -> int:
        return len(self.layers) * self.resolution * self.resolution

    def render(self) -> None:
        ctx = self.gpu.ctx
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable_only(moderngl.DEPTH_TEST)
        self.gpu.bind_scene_buffers()
        for k, layer in enumerate(self.layers):
            x, y = k % self.tiles_x, k // self.tiles_x
            ctx.viewport = (x * self.resolution, y * self.resolution, self.resolution, self.resolution)
            set_uniforms(self.program, u_view_proj=layer.view_proj, u_light_index=layer.light_index,
                         u_layer_info=tuple(float(v) for v in layer.info), u_rsm_resolution=self.resolution,
                         u_depth_map=tuple(float(v) for v in layer.depth_map))
            self.vao.render(moderngl.TRIANGLES)

    def bind(self, program: moderngl.Program, unit: int) -> int:
        for name, tex in (("u_rsm_position", self.position), ("u_rsm_normal", self.normal), ("u_rsm_flux", self.flux)):
            if has_member(program, name):
                tex.use(unit)
                program[name].value = unit
                unit += 1
        set_uniforms(program, u_rsm_tiles_x=self.tiles_x, u_rsm_resolution=self.resolution,
                     u_rsm_layer_count=len(self.layers))
        return unit

    def release(self) -> None:
        park(self.gpu.ctx)
        for obj in (self.fbo, self.position, self.normal, self.flux, self.depth, self.program):
            obj.release()


def expand_needs(needs) -> frozenset:
    """Close a method's `needs` over the pass dependencies (direct -> gbuffer (+ shadow_map))."""
    needs = frozenset(needs)
    unknown = needs - KNOWN_NEEDS - {"precompute"}
    if unknown:
        raise ValueError(f"unknown shared pass(es) {sorted(unknown)}; known: {sorted(KNOWN_NEEDS)}")
    if "direct" in needs:
        needs |= {"gbuffer"}
    return needs


def stages_for_needs(needs) -> tuple:
    """The shared stages (in execution order) that SharedPasses(needs).render() times."""
    needs = expand_needs(needs)
    out = []
    if needs & {"gbuffer", "shadow_map"}:
        out.append("gbuffer_shadow")
    if "direct" in needs:
        out.append("direct_light")
    if "rsm" in needs:
        out.append("rsm")
    return tuple(out)


def shared_variant(needs) -> str:
    """Which shared passes can serve `needs`: the direct pass is shadowed exactly when the shadow
    maps are built, so needing `direct` without `shadow_map` takes passes of their own."""
    needs = expand_needs(needs)
    return "unshadowed_direct" if "direct" in needs and "shadow_map" not in needs else "standard"


class SharedPasses:
    """The shared passes one method needs for one view; only those are built and rendered."""

    def __init__(self, gpu: GpuScene, view: View, needs, shadow_resolution: int = 1024,
                 rsm_resolution: int = RSM_RESOLUTION):
        self.gpu, self.view = gpu, view
        self.needs = expand_needs(needs)
        self.gbuffer = GBuffer(gpu, view.width, view.height) if "gbuffer" in self.needs else None
        self.shadows = ShadowMaps(gpu, shadow_resolution) if "shadow_map" in self.needs else None
        self.direct = DirectPass(gpu, self.gbuffer, self.shadows) if "direct" in self.needs else None
        self.rsm = ReflectiveShadowMap(gpu, rsm_resolution) if "rsm" in self.needs else None
        check_gl(gpu.ctx, "building shared passes")

    @property
    def stages(self) -> tuple:
        return stages_for_needs(self.needs)

    def serves(self, needs) -> str | None:
        """None when these passes give a method with `needs` exactly what SharedPasses(needs) would
        (every pass it needs, the direct pass shadowed as its needs say); else why not (one phrase)."""
        needs = expand_needs(needs)
        missing = sorted(needs - self.needs - {"precompute"})
        if missing:
            return f"lack the shared pass(es) {missing}"
        if shared_variant(needs) != shared_variant(self.needs) and "direct" in needs:
            return "have a direct pass shadowed differently"
        return None

    def restore_state(self, needs=None) -> None:
        """Leave the GL state as SharedPasses(needs).render() leaves it, drawing nothing: the bound
        framebuffer (and with it moderngl's per-framebuffer viewport and scissor), the enable flags,
        the scene and shadow-layer storage buffers and the direct pass's texture units. A method
        reading these passes without rendering them then starts its frame as it would after them."""
        needs = self.needs if needs is None else expand_needs(needs)
        why = self.serves(needs)
        if why is not None:
            raise ValueError(f"shared passes {why}")
        last = None
        if "gbuffer" in needs:
            last = self.gbuffer.fbo
        if "shadow_map" in needs:
            last = self.shadows.fbo
        if "direct" in needs:
            last = self.direct.fbo
            unit = self.gbuffer.bind(self.direct.program)
            if self.direct.shadows is not None:
                self.direct.shadows.bind(self.direct.program, unit)
        if "rsm" in needs:
            last = self.rsm.fbo
        if last is None:
            return  # render() would have drawn nothing
        self.gpu.bind_scene_buffers()
        last.use()
        # every pass starts with enable_only(DEPTH_TEST); the direct pass then turns it off, the RSM on
        depth = "rsm" in needs or "direct" not in needs
        self.gpu.ctx.enable_only(moderngl.DEPTH_TEST if depth else moderngl.NOTHING)

    def render(self, prof: StageProfiler) -> None:
        if self.gbuffer is not None or self.shadows is not None:
            with prof.stage("gbuffer_shadow"):
                if self.gbuffer is not None:
                    self.gbuffer.render(self.view)
                if self.shadows is not None:
                    self.shadows.render()
        if self.direct is not None:
            with prof.stage("direct_light"):
                self.direct.render()
        if self.rsm is not None:
            with prof.stage("rsm"):
                self.rsm.render()

    def release(self) -> None:
        for p in (self.direct, self.rsm, self.shadows, self.gbuffer):
            if p is not None:
                p.release()


def frame_random(seed: int, index: int, stream: int = 0) -> int:
    """A uint32 for (seed, frame index, stream): the per-frame `u_rand` of stochastic methods."""
    ss = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(index), int(stream), 0x75726E64])
    return int(ss.generate_state(1, dtype=np.uint32)[0])


@dataclass
class Frame:
    """What a method's render() receives: the GL objects of this view and the frame's index."""
    ctx: moderngl.Context
    gpu: GpuScene
    view: View
    passes: SharedPasses
    index: int
    seed: int
    extra: dict = field(default_factory=dict)

    @property
    def width(self) -> int:
        return self.view.width

    @property
    def height(self) -> int:
        return self.view.height

    def random_u32(self, stream: int = 0) -> int:
        return frame_random(self.seed, self.index, stream)


# ------------------------------------------------------------------ conveniences (tests, reference)
def render_gbuffer(ctx: moderngl.Context, scene: Scene, camera_name: str, width: int, height: int) -> dict:
    """GBuffer of one view read back to numpy (world positions, mask, normals, albedo, triangle id)."""
    gpu = GpuScene(ctx, scene)
    try:
        passes = SharedPasses(gpu, gpu.view(camera_name, width, height), {"gbuffer"})
        passes.render(StageProfiler(ctx))
        check_gl(ctx, "render_gbuffer")
        out = passes.gbuffer.read()
        passes.release()
        return out
    finally:
        gpu.release()


def render_direct(ctx: moderngl.Context, scene: Scene, camera_name: str, width: int, height: int,
                  shadows: bool = True, shadow_resolution: int = 2048) -> np.ndarray:
    """Direct radiance of one view (HxWx3 float32, row 0 at the top)."""
    gpu = GpuScene(ctx, scene)
    try:
        needs = {"direct", "shadow_map"} if shadows else {"direct"}
        passes = SharedPasses(gpu, gpu.view(camera_name, width, height), needs,
                              shadow_resolution=shadow_resolution)
        passes.render(StageProfiler(ctx))
        check_gl(ctx, "render_direct")
        out = passes.direct.read()
        passes.release()
        return out
    finally:
        gpu.release()


__all__ = ["GBuffer", "ShadowMaps", "DirectPass", "ReflectiveShadowMap", "SharedPasses", "Frame",
           "render_gbuffer", "render_direct", "read_rgb", "read_rgba", "SHARED_STAGES", "frame_random",
           "create_context", "expand_needs", "stages_for_needs", "shared_variant"]
