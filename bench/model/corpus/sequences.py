"""The corpus's sequences (issue #25): corpus scenes in motion, each moving one kind of thing.

    rooms_light_sweep          the point light of `rooms` walks from room 1 through door 1 into room 2
    sponza_camera_walk         the camera of `sponza` walks 24 m down the atrium
    cornell_spot_moving_block  the short block of `cornell_spot` slides 0.7 m across the floor

Each is `bench.model.animation.Sequence` over its corpus scene at default options: FRAMES frames
of motion (`load_sequence(name, frames=N)`: the keys are at the first and last of them, and the
light's at the door, so more frames sample the same motion finer), then REST frames at rest
(`rest=R`), over which a method that reuses earlier frames catches up (its `lag_frames`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from bench.model.animation import Sequence
from bench.model.scene import SceneError

FRAMES = 6   # frames of motion (RunConfig.sequence_frames)
REST = 6     # then frames at rest (RunConfig.sequence_rest)


@dataclass(frozen=True)
class SequenceEntry:
    name: str
    scene: str                # the corpus scene it moves
    moves: str                # "light", "camera" or "geometry"
    purpose: str
    tracks: Callable          # frames -> [(kind, target, keys)]
    groups: Callable | None = None   # () -> {group: vertex indices of the base scene}


def _short_block_vertices() -> np.ndarray:
    """The vertices of cornell_spot's short block: parts 6-10 of cornell_parts (room walls 0-5, then
    the short block's five faces, then the tall block's), counted as `assemble` concatenates them."""
    from bench.model.corpus import procedural
    parts = procedural.plan_cornell_spot().parts
    counts = [len(p.build()[0]) for p in parts]
    start = sum(counts[:6])
    return np.arange(start, start + sum(counts[6:11]), dtype=np.int64)


def _rooms_light(frames: int) -> list:
    last = frames - 1
    door = max(1, min(last - 1, round(0.5 * last)))   # near door 1 (x = 4, z 0.6-1.5, 2.1 m high) at mid-sequence
    return [("light", 0, {0: {"position": [1.0, 2.2, -1.2]}, door: {"position": [3.2, 1.8, 1.0]},
                          last: {"position": [6.0, 1.8, 1.0]}})]


def _sponza_walk(frames: int) -> list:
    return [("camera", "main", {0: {"eye": [-14.0, 2.5, 0.0], "target": [0.0, 4.0, 0.0]},
                                frames - 1: {"eye": [10.0, 2.5, 0.0], "target": [17.0, 4.0, 0.0]}})]


def _block_slide(frames: int) -> list:
    return [("mesh", "short_block", {0: {"translate": [0.0, 0.0, 0.0]}, frames - 1: {"translate": [-0.7, 0.0, 0.0]}})]


SEQUENCES: dict = {e.name: e for e in (
    SequenceEntry("rooms_light_sweep", "rooms", "light",
                  "the light of rooms walks from room 1 through door 1 into room 2: lighting changes every frame",
                  _rooms_light),
    SequenceEntry("sponza_camera_walk", "sponza", "camera",
                  "the camera walks 24 m down sponza's atrium: new surfaces enter the view every frame",
                  _sponza_walk),
    SequenceEntry("cornell_spot_moving_block", "cornell_spot", "geometry",
                  "cornell_spot's short block slides 0.7 m across the floor: geometry moves, light and camera stay",
                  _block_slide, lambda: {"short_block": _short_block_vertices()}),
)}


def load_sequence(name: str, frames: int = FRAMES, rest: int = REST) -> Sequence:
    """A corpus sequence by name: `frames` frames of motion, then `rest` frames at rest."""
    from bench.model.corpus import load_scene
    entry = SEQUENCES.get(str(name))
    if entry is None:
        raise SceneError(f"unknown sequence '{name}'; known: {', '.join(SEQUENCES)}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise SceneError(f"sequence '{name}': frames must be an integer >= 2, got {frames!r}")
    if isinstance(rest, bool) or not isinstance(rest, (int, np.integer)) or rest < 0:
        raise SceneError(f"sequence '{name}': rest must be an integer >= 0, got {rest!r}")
    base = load_scene(entry.scene)
    groups = entry.groups() if entry.groups else {}
    return Sequence.build(name, base, int(frames) + int(rest), entry.tracks(int(frames)), groups,
                          purpose=entry.purpose)


def sequence_names() -> list:
    return list(SEQUENCES)


__all__ = ["FRAMES", "REST", "SEQUENCES", "SequenceEntry", "load_sequence", "sequence_names"]
