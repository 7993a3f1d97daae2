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
    from bench.scene import Camera, PointLight, Scene
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
