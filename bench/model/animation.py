"""Scenes in motion (issue #25): keyframed tracks over a number of frames, and the static scene of
each frame.

A `Sequence` is a base Scene, a frame count N and tracks. A track animates one thing:
  * a camera by name: `eye`, `target` (points), `fov_y_deg`;
  * a light by index (its order in the scene): `position`, `target` (spot), `direction`
    (directional), `intensity` (point and spot, RGB W/sr), `irradiance` (directional, RGB W/m^2);
  * a mesh group by name (a set of vertices: a scene file's `[[mesh]]` table, a procedural
    scene's part): `translate` (metres), `rotate_deg` (about fixed X, then Y, then Z, as scene
    files), `scale` (per axis), applied about the group's bounding-box centre in the base scene:
    p' = centre + translate + R S (p - centre), normals by the inverse transpose.
Each track has keys {frame: values}; a field is interpolated linearly between the two keys that
set it around a frame and held after the last. Frame 0 is the base scene unless a key at frame 0
says otherwise: a field first keyed at frame k moves from its base value at frame 0 to that key. `frame(t)` is a full,
validated Scene (the same name for every frame; its content hash, and so every cache key
downstream, is the frame's own: a frame equal to a static scene shares its references, and
nothing is reused across frames that differ). `changes(t)` says what moved since frame t-1
("camera", "light", "geometry"), which is what a method must redo.

Every bad input is a SceneError with one line naming the sequence and the culprit.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from bench.model.scene import Camera, DirectionalLight, PointLight, Scene, SceneError, SpotLight

MAX_FRAMES = 10_000
KINDS = ("camera", "light", "mesh")
CHANGE_OF_KIND = {"camera": "camera", "light": "light", "mesh": "geometry"}
FIELDS = {
    "camera": {"eye": 3, "target": 3, "fov_y_deg": 1},
    "light": {"position": 3, "target": 3, "direction": 3, "intensity": 3, "irradiance": 3},
    "mesh": {"translate": 3, "rotate_deg": 3, "scale": 3},
}
LIGHT_FIELDS = {PointLight: ("position", "intensity"), SpotLight: ("position", "target", "intensity"),
                DirectionalLight: ("direction", "irradiance")}
MESH_IDENTITY = {"translate": (0.0, 0.0, 0.0), "rotate_deg": (0.0, 0.0, 0.0), "scale": (1.0, 1.0, 1.0)}


@dataclass(frozen=True)
class Track:
    kind: str                 # "camera", "light" or "mesh"
    target: object            # camera name, light index, mesh group name
    keys: tuple               # ((frame, {field: tuple of floats}), ...) sorted by frame

    def fields(self) -> set:
        return {f for _, values in self.keys for f in values}

    def value(self, name: str, t: float, at_rest=None):
        """The field `name` at frame t (linear between the keys that have it, held outside), None
        if no key has it. `at_rest`: its value in the base scene, frame 0's unless a key at frame 0
        sets it (then a field keyed later moves from the base scene's value to its first key)."""
        pts = [(k, np.asarray(v[name], dtype=np.float64)) for k, v in self.keys if name in v]
        if at_rest is not None and (not pts or pts[0][0] > 0):
            pts.insert(0, (0, np.atleast_1d(np.asarray(at_rest, dtype=np.float64))))
        if not pts:
            return None
        if t <= pts[0][0]:
            return pts[0][1]
        for (k0, v0), (k1, v1) in zip(pts, pts[1:]):
            if t <= k1:
                w = (t - k0) / (k1 - k0)
                return (1.0 - w) * v0 + w * v1
        return pts[-1][1]


def _vector(value, size: int, what: str) -> tuple:
    v = np.atleast_1d(np.asarray(value, dtype=np.float64)) if not isinstance(value, str) else np.array([np.nan])
    if size == 3 and v.shape == (1,):
        v = np.repeat(v, 3)   # a number means grey (intensity) or uniform (scale)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{what} must be {'a number' if size == 1 else f'{size} finite numbers'}, got {value!r}")
    return tuple(float(x) for x in v)


def make_track(sequence: str, kind: str, target, keys, frames: int) -> Track:
    """A validated track: keys as {frame: {field: value}} or [(frame, {field: value}), ...]."""
    what = f"sequence '{sequence}': {kind} track '{target}'"
    if kind not in KINDS:
        raise SceneError(f"sequence '{sequence}': unknown track kind '{kind}' (expected one of {', '.join(KINDS)})")
    items = sorted(keys.items()) if isinstance(keys, dict) else sorted(keys, key=lambda kv: kv[0])
    if not items:
        raise SceneError(f"{what} has no keys")
    out, seen = [], set()
    for frame, values in items:
        if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= int(frame) < frames:
            raise SceneError(f"{what}: key frame {frame!r} must be an integer in [0, {frames - 1}]")
        if int(frame) in seen:
            raise SceneError(f"{what}: two keys at frame {frame}")
        seen.add(int(frame))
        if not isinstance(values, dict) or not values:
            raise SceneError(f"{what}: key at frame {frame} must set at least one field")
        checked = {}
        for name, value in values.items():
            if name not in FIELDS[kind]:
                raise SceneError(f"{what}: unknown field '{name}' at frame {frame} "
                                 f"(fields: {', '.join(FIELDS[kind])})")
            checked[name] = _vector(value, FIELDS[kind][name], f"{what}: {name} at frame {frame}")
            if name == "fov_y_deg" and not 0.0 < checked[name][0] < 180.0:
                raise SceneError(f"{what}: fov_y_deg at frame {frame} must be in (0, 180), got {value!r}")
            if name in ("intensity", "irradiance") and min(checked[name]) < 0:
                raise SceneError(f"{what}: {name} at frame {frame} must be >= 0, got {value!r}")
            if name == "scale" and min(abs(x) for x in checked[name]) < 1e-9:
                raise SceneError(f"{what}: scale at frame {frame} must not be 0, got {value!r}")
        out.append((int(frame), checked))
    return Track(kind, target, tuple(out))


def _rotation(deg) -> np.ndarray:
    """About fixed X, then Y, then Z (scene files' `rotate_deg`)."""
    rx, ry, rz = (math.radians(float(a)) for a in deg)
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return z @ y @ x


@dataclass(frozen=True)
class Sequence:
    """A base scene in motion over `frames` frames (the module's docstring)."""
    name: str
    base: Scene
    frames: int
    tracks: tuple
    groups: dict = field(default_factory=dict)    # mesh group name -> vertex indices (int64)
    purpose: str = ""

    @classmethod
    def build(cls, name: str, base: Scene, frames: int, tracks, groups: dict | None = None,
              purpose: str = "") -> "Sequence":
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 2 <= frames <= MAX_FRAMES:
            raise SceneError(f"sequence '{name}': frames must be an integer in [2, {MAX_FRAMES}], got {frames!r}")
        groups = {str(k): np.unique(np.asarray(v, dtype=np.int64)) for k, v in (groups or {}).items()}
        for gname, verts in groups.items():
            if verts.size == 0 or verts.min() < 0 or verts.max() >= len(base.vertices):
                raise SceneError(f"sequence '{name}': mesh group '{gname}' has no vertex or one out of range")
        built = []
        for track in tracks:
            if not isinstance(track, Track):
                track = make_track(name, *track, frames=int(frames))
            cls._check_target(name, base, groups, track)
            built.append(track)
        if not built:
            raise SceneError(f"sequence '{name}': no track (a sequence must move something)")
        moving = [groups[t.target] for t in built if t.kind == "mesh"]
        if moving:
            cls._check_groups_separate(name, base, groups, {t.target for t in built if t.kind == "mesh"})
        return cls(name=name, base=base, frames=int(frames), tracks=tuple(built), groups=groups, purpose=purpose)

    @staticmethod
    def _check_target(name, base, groups, track) -> None:
        what = f"sequence '{name}': {track.kind} track '{track.target}'"
        if track.kind == "camera" and track.target not in base.cameras:
            raise SceneError(f"{what}: the scene has no camera '{track.target}' (cameras: {sorted(base.cameras)})")
        if track.kind == "light":
            if not isinstance(track.target, (int, np.integer)) or not 0 <= int(track.target) < len(base.lights):
                raise SceneError(f"{what}: light index must be in [0, {len(base.lights) - 1}]")
            light = base.lights[int(track.target)]
            allowed = LIGHT_FIELDS[type(light)]
            wrong = sorted(track.fields() - set(allowed))
            if wrong:
                raise SceneError(f"{what}: a {type(light).__name__} has no {', '.join(wrong)} "
                                 f"(it animates {', '.join(allowed)})")
        if track.kind == "mesh" and track.target not in groups:
            raise SceneError(f"{what}: no mesh group '{track.target}' (groups: {sorted(groups) or 'none'})")

    @staticmethod
    def _check_groups_separate(name, base, groups, moving: set) -> None:
        """A moving group shares no vertex with the rest of the scene (it would stretch a triangle)."""
        owner = np.full(len(base.vertices), -1, dtype=np.int64)
        names = sorted(moving)
        for i, g in enumerate(names):
            owner[groups[g]] = i
        tri = owner[base.faces]
        mixed = np.any(tri != tri[:, :1], axis=1)
        if mixed.any():
            f = int(np.flatnonzero(mixed)[0])
            raise SceneError(f"sequence '{name}': triangle {f} joins a moving mesh group to other geometry "
                             f"({int(mixed.sum())} such triangles): give the moving mesh its own vertices")

    # -------------------------------------------------------------- frames
    def check_frame(self, t) -> int:
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 0 <= int(t) < self.frames:
            raise SceneError(f"sequence '{self.name}': frame {t!r} outside [0, {self.frames - 1}]")
        return int(t)

    def frame(self, t: int) -> Scene:
        """The static scene of frame t."""
        t = self.check_frame(t)
        base = self.base
        cameras = dict(base.cameras)
        lights = list(base.lights)
        vertices, normals = base.vertices, base.normals
        for track in self.tracks:
            values = {f: track.value(f, t, self._at_rest(track, f)) for f in track.fields()}
            if track.kind == "camera":
                cam = cameras[track.target]
                cameras[track.target] = dataclasses.replace(
                    cam, **{k: (float(v[0]) if k == "fov_y_deg" else v) for k, v in values.items()})
            elif track.kind == "light":
                i = int(track.target)
                lights[i] = dataclasses.replace(lights[i], **values)
            else:
                if all(np.array_equal(values.get(k, v), v) for k, v in MESH_IDENTITY.items()):
                    continue   # at rest: the base scene's vertices exactly (a frame at rest is the static scene)
                if vertices is base.vertices:
                    vertices, normals = base.vertices.copy(), base.normals.copy()
                verts = self.groups[track.target]
                lo, hi = base.vertices[verts].min(axis=0), base.vertices[verts].max(axis=0)
                centre = 0.5 * (lo + hi)
                scale = np.asarray(values.get("scale", MESH_IDENTITY["scale"]), dtype=np.float64)
                rot = _rotation(values.get("rotate_deg", MESH_IDENTITY["rotate_deg"]))
                move = np.asarray(values.get("translate", MESH_IDENTITY["translate"]), dtype=np.float64)
                m = rot @ np.diag(scale)
                vertices[verts] = centre + move + (base.vertices[verts] - centre) @ m.T
                n = base.normals[verts] @ np.linalg.inv(m)   # the inverse transpose, applied to row vectors
                normals[verts] = n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        # the base scene was validated; a frame changes only what its tracks move (lights and cameras
        # validate themselves, moved vertices stay finite), so it is the base with those replaced: not
        # rebuilt, whose renormalised normals would make a frame at rest differ from its static scene
        return dataclasses.replace(base, vertices=vertices, normals=normals, lights=lights, cameras=cameras,
                                   source=f"{base.source}; sequence '{self.name}' frame {t}", _hash=None)

    def _at_rest(self, track: Track, name: str):
        """A field's value in the base scene (frame 0 unless keyed there)."""
        if track.kind == "camera":
            return getattr(self.base.cameras[track.target], name)
        if track.kind == "light":
            return getattr(self.base.lights[int(track.target)], name)
        return MESH_IDENTITY[name]

    def changes(self, t: int) -> frozenset:
        """What differs between frame t-1 and frame t: a subset of {"camera", "light", "geometry"}
        (frame 0: everything, nothing came before it)."""
        t = self.check_frame(t)
        if t == 0:
            return frozenset(CHANGE_OF_KIND.values())
        out = set()
        for track in self.tracks:
            for f in track.fields():
                rest = self._at_rest(track, f)
                if not np.array_equal(track.value(f, t, rest), track.value(f, t - 1, rest)):
                    out.add(CHANGE_OF_KIND[track.kind])
        return frozenset(out)
