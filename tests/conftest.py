"""Shared fixtures: the headless GL context (a test fails on any pending GL error), small scenes."""
from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")


@pytest.fixture(scope="session")
def _session_gl_ctx():
    from bench.gl import create_context
    return create_context()


@pytest.fixture
def gl_ctx(_session_gl_ctx):
    """The GL context; the test fails if it leaves a GL error behind."""
    from bench.gl import check_gl
    ctx = _session_gl_ctx
    ctx.error  # clear any error left by a previous test's teardown (glGetError resets it)
    yield ctx
    check_gl(ctx, "the test")


def make_open_box(light_position=(0.2, 1.2, 0.1), intensity=2.0):
    """Floor + back wall + left wall (6 triangles), a point light inside: no shadowing."""
    from bench.model.scene import Camera, PointLight, Scene
    v = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1],
                  [-1, 0, -1], [1, 0, -1], [1, 2, -1], [-1, 2, -1],
                  [-1, 0, -1], [-1, 0, 1], [-1, 2, 1], [-1, 2, -1]], float)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [8, 10, 9], [8, 11, 10]])
    albedo = np.array([[0.8, 0.8, 0.8]] * 2 + [[0.2, 0.8, 0.2]] * 2 + [[0.8, 0.2, 0.2]] * 2)
    return Scene.build("open_box", v, f, albedo, [PointLight(light_position, [intensity] * 3)],
                       {"main": Camera([0, 1, 3.5], [0, 0.8, 0], fov_y_deg=50)})


@pytest.fixture
def open_box():
    return make_open_box()


def grid_quad(origin, u, v, n):
    """An n x n grid of quads (2 n^2 triangles) spanning origin + [0,1]u + [0,1]v."""
    origin, u, v = (np.asarray(a, float) for a in (origin, u, v))
    s = np.linspace(0, 1, n + 1)
    verts = origin + s[:, None, None] * u + s[None, :, None] * v
    verts = verts.reshape(-1, 3)
    idx = np.arange((n + 1) * (n + 1)).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return verts, faces


def scene_from_parts(name, parts, colours, lights, cameras):
    """A Scene from (vertices, faces) parts, each with one albedo colour."""
    from bench.model.scene import Scene
    verts, faces, albedo, offset = [], [], [], 0
    for (v, f), col in zip(parts, colours):
        verts.append(v)
        faces.append(f + offset)
        albedo.append(np.tile(col, (len(f), 1)))
        offset += len(v)
    return Scene.build(name, np.concatenate(verts), np.concatenate(faces), np.concatenate(albedo), lights, cameras)


def make_grid_box(n=6, light_position=(0.2, 1.2, 0.1), intensity=2.0):
    """The open box of make_open_box with each wall an n x n grid (6 n^2 triangles)."""
    from bench.model.scene import Camera, PointLight
    parts = [grid_quad([-1, 0, -1], [0, 0, 2], [2, 0, 0], n),   # floor, normal +y
             grid_quad([-1, 0, -1], [2, 0, 0], [0, 2, 0], n),   # back wall, normal +z
             grid_quad([-1, 0, -1], [0, 2, 0], [0, 0, 2], n)]   # left wall, normal +x
    colours = ([0.8, 0.8, 0.8], [0.2, 0.8, 0.2], [0.8, 0.2, 0.2])
    return scene_from_parts("grid_box", parts, colours, [PointLight(light_position, [intensity] * 3)],
                            {"main": Camera([0, 1, 3.5], [0, 0.8, 0], fov_y_deg=50)})


def cli_run_config(monkeypatch, argv: list):
    """The RunConfig the CLI builds for `argv` (run or sweep), caught before anything renders."""
    import bench.cli as cli
    import bench.run.serial
    seen = []

    class Stop(Exception):
        pass

    def fake_run(cfg, log=None, **kw):
        seen.append(cfg)
        raise Stop
    monkeypatch.setattr(bench.run.serial, "run", fake_run)
    with pytest.raises(Stop):
        cli.main(argv)
    return seen[0]
