"""A Scene uploaded to the GPU: vertex buffers, per-triangle albedo, lights, random attributes.

Coordinates are float32 re-centred on the scene's bounding-box centre (`origin`). Each vertex
carries a uint32 random value `in_vrand` set at load from the seed (FLC's `v_rand`, Alg. 2).
Per-triangle data (albedo) lives in a std430 buffer indexed by gl_PrimitiveID.
"""
from __future__ import annotations

import numpy as np
import moderngl

from bench.model.scene import DirectionalLight, PointLight, Scene, SceneFacts, SpotLight, compute_facts
from .camera import View

LIGHT_KIND = {"point": 0, "spot": 1, "directional": 2}


class GpuScene:
    def __init__(self, ctx: moderngl.Context, scene: Scene, seed: int = 0, facts: SceneFacts | None = None):
        self.ctx = ctx
        self.scene = scene
        self.seed = int(seed)
        self.facts = facts or compute_facts(scene)
        self.origin = np.asarray(self.facts.scene_center, dtype=np.float64)
        self.radius = float(self.facts.scene_radius)

        self.positions = (scene.vertices - self.origin).astype(np.float32)
        self.normals = scene.normals.astype(np.float32)
        self.faces = scene.faces.astype(np.uint32)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x6762656E]))
        self.vertex_random = rng.integers(0, 2**32, size=len(self.positions), dtype=np.uint64).astype(np.uint32)

        self.vbo_position = ctx.buffer(self.positions)
        self.vbo_normal = ctx.buffer(self.normals)
        self.vbo_random = ctx.buffer(self.vertex_random)
        self.ibo = ctx.buffer(self.faces)
        albedo4 = np.zeros((len(self.faces), 4), dtype=np.float32)
        albedo4[:, :3] = scene.albedo
        self.triangle_albedo = ctx.buffer(albedo4)
        self.lights = self._light_records()
        self.light_buffer = ctx.buffer(self.lights.tobytes())
        self._vaos: dict = {}

    @property
    def triangle_count(self) -> int:
        return int(len(self.faces))

    @property
    def light_count(self) -> int:
        return len(self.scene.lights)

    def _light_records(self) -> np.ndarray:
        """std430 `Light` records (see shaders/lights.glsl): 4 vec4 per light."""
        rec = np.zeros((len(self.scene.lights), 4, 4), dtype=np.float32)
        for i, light in enumerate(self.scene.lights):
            rec[i, 0, 3] = LIGHT_KIND[light.kind]
            if isinstance(light, PointLight):
                rec[i, 0, :3] = light.position - self.origin
                rec[i, 2, :3] = light.intensity
            elif isinstance(light, SpotLight):
                rec[i, 0, :3] = light.position - self.origin
                rec[i, 1, :3] = light.direction
                rec[i, 1, 3] = np.cos(np.radians(light.cutoff_angle_deg))
                rec[i, 2, :3] = light.intensity
                rec[i, 2, 3] = np.cos(np.radians(light.beam_width_deg))
                rec[i, 3, 0] = np.radians(light.cutoff_angle_deg)
                rec[i, 3, 1] = np.radians(light.beam_width_deg)
            elif isinstance(light, DirectionalLight):
                rec[i, 1, :3] = light.direction
                rec[i, 2, :3] = light.irradiance
        return rec

    def set_light_shadow_layers(self, first_layers: list[int], layer_counts: list[int]) -> None:
        self.lights[:, 3, 2] = first_layers
        self.lights[:, 3, 3] = layer_counts
        self.light_buffer.write(self.lights.tobytes())

    def bind_scene_buffers(self) -> None:
        from .shaders import GLOBAL_DEFINES
        self.triangle_albedo.bind_to_storage_buffer(GLOBAL_DEFINES["BINDING_TRIANGLE_ALBEDO"])
        self.light_buffer.bind_to_storage_buffer(GLOBAL_DEFINES["BINDING_LIGHTS"])

    def vertex_array(self, program: moderngl.Program, indexed: bool = True) -> moderngl.VertexArray:
        """A VAO for `program` feeding whichever of in_position, in_normal, in_vrand it uses."""
        key = (program.glo, indexed)
        vao = self._vaos.get(key)
        if vao is None:
            content = []
            for buf, fmt, name in ((self.vbo_position, "3f", "in_position"),
                                   (self.vbo_normal, "3f", "in_normal"),
                                   (self.vbo_random, "u", "in_vrand")):
                if name in program:
                    content.append((buf, fmt, name))
            vao = self.ctx.vertex_array(program, content, index_buffer=self.ibo if indexed else None,
                                        index_element_size=4)
            self._vaos[key] = vao
        return vao

    def view(self, camera_name: str, width: int, height: int) -> View:
        try:
            cam = self.scene.cameras[camera_name]
        except KeyError:
            raise KeyError(f"scene '{self.scene.name}' has no camera '{camera_name}'; "
                           f"cameras: {sorted(self.scene.cameras)}") from None
        return View.create(camera_name, cam, width, height, self.origin, self.radius, self.facts.scene_center)

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        for b in (self.vbo_position, self.vbo_normal, self.vbo_random, self.ibo, self.triangle_albedo,
                  self.light_buffer):
            b.release()
