"""val_clustered's paraboloid map pass (issue #11: the map stage was 67-74% of the frame on the
scenes of 5-8 k triangles, one tessellated primitive per VAL and triangle): small (VAL, triangle)
pairs are rasterised by a compute pass, only large ones reach the GL pipeline, and the maps are
still the exact first-hit distances."""
import moderngl
import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler
from bench.protocol.method import resolve_params
from methods.val_clustered.clustering import LIFT_SCALE
from methods.val_clustered.method import ClusteredVirtualAreaLights
from methods.val_clustered.shadow_maps import NEAR_SCALE
from tests.conftest import make_grid_box
from tests.methods.test_val_clustered import first_hits, orthonormal_basis

NEAR_IGNORE = ClusteredVirtualAreaLights.params["near_ignore"].default

W, H = 64, 48


def map_frame(ctx, scene, params):
    """One default frame by hand, counting the primitives the map stage sends to the rasteriser."""
    cls = ClusteredVirtualAreaLights
    gpu = GpuScene(ctx, scene, seed=0)
    view = gpu.view("main", W, H)
    passes = SharedPasses(gpu, view, cls.needs)
    method = cls()
    try:
        method.prepare(gpu, scene, gpu.facts, resolve_params(cls, params), view)
        maps = method.maps
        query = ctx.query(primitives=True)
        render_maps = maps.render
        primitives = []

        def counted(*args, **kwargs):   # the paper's VALs, then the split round's
            with query:
                render_maps(*args, **kwargs)
            primitives.append(query.primitives)
        maps.render = counted
        prof = StageProfiler(ctx)
        passes.render(prof)
        method.render(Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=0, seed=0), prof)
        ctx.finish()
        atlas = np.frombuffer(maps.atlas.read(), np.float32).reshape(maps.atlas.height, maps.atlas.width)
        return {"vals": method.clustering.read(), "atlas": atlas.copy(), "primitives": sum(primitives),
                "tiles_x": maps.tiles_x, "resolution": maps.resolution, "lift": LIFT_SCALE * gpu.radius,
                "near_min": NEAR_SCALE * gpu.radius, "triangles": gpu.positions[gpu.faces].astype(np.float64)}
    finally:
        method.release()
        passes.release()
        gpu.release()


def test_small_pairs_skip_the_rasteriser_and_maps_match_ray_cast(gl_ctx):
    """A box of 24 x 24-cell walls (3456 small triangles, many of them crossing a VAL's plane where
    the walls meet the floor) at the default setting (30 VALs, 128^2 maps): the map stage sends
    fewer primitives through the GL pipeline than a tenth of the (VAL, triangle) pairs (every pair went through the
    tessellation pipeline before, each at least one primitive), and every VAL's map still holds,
    at each texel, the distance to the first surface along that texel's direction beyond the
    VAL's ignore radius (ray cast; silhouette texels within half a texel of an edge may differ)."""
    scene = make_grid_box(24)
    r = map_frame(gl_ctx, scene, {})
    vals, res, atlas = r["vals"], r["resolution"], r["atlas"]
    active = np.flatnonzero(vals["count"] > 0)
    assert len(active) >= 20
    pairs = len(active) * len(r["triangles"])
    assert r["primitives"] < 0.1 * pairs, (r["primitives"], pairs)
    centres = ((np.arange(res) + 0.5) / res) * 2.0 - 1.0
    u, v = np.meshgrid(centres, centres)
    inside = u * u + v * v < 1.0
    q = 1.0 + u * u + v * v
    local = np.stack([2 * u / q, 2 * v / q, (1 - u * u - v * v) / q], axis=-1)[inside]
    for j in active[::6]:
        n = vals["normal"][j].astype(np.float64)
        t, b = orthonormal_basis(n)
        dirs = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:] * n
        origin = vals["origin"][j].astype(np.float64)
        ignore = max(r["near_min"], NEAR_IGNORE * float(vals["size"][j]))   # the default near_ignore
        expected = first_hits(origin, dirs, r["triangles"], ignore)
        ty, tx = divmod(j, r["tiles_x"])
        got = atlas[ty * res:(ty + 1) * res, tx * res:(tx + 1) * res][inside].astype(np.float64)
        got[got > 1e37] = np.inf
        both_drawn = np.isfinite(expected) & np.isfinite(got)
        close = np.isinf(expected) & np.isinf(got)
        g, e = got[both_drawn], expected[both_drawn]
        close[both_drawn] = np.abs(g - e) <= 0.01 * np.minimum(g, e)
        assert (~close).mean() < 0.01, (j, (~close).mean())
        assert np.isfinite(got).mean() > 0.2          # the walls fill much of the maps


def test_maps_are_deterministic(gl_ctx):
    """The compute pass lists pairs in an order that varies with thread timing; the maps must not
    (every path keeps the minimum distance), so the same seed gives the same image."""
    scene = make_grid_box(24)
    a = map_frame(gl_ctx, scene, {"cluster_count": 8, "vpl_count": 256})
    b = map_frame(gl_ctx, scene, {"cluster_count": 8, "vpl_count": 256})
    assert np.array_equal(a["atlas"], b["atlas"])


def test_chunked_map_pass_gives_the_same_maps(gl_ctx, monkeypatch):
    """Scenes whose (VAL, triangle) pairs exceed MAX_MAP_PAIRS are processed in chunks of
    triangles (bounded pair buffer): chunks of 100 triangles give the same maps as one chunk."""
    import methods.val_clustered.shadow_maps as val_maps
    scene = make_grid_box(12)
    params = {"cluster_count": 8, "vpl_count": 256}
    whole = map_frame(gl_ctx, scene, params)
    monkeypatch.setattr(val_maps, "MAX_MAP_PAIRS", 8 * 100)
    chunked = map_frame(gl_ctx, scene, params)
    assert np.isfinite(whole["atlas"][whole["atlas"] < 1e37]).all() and (whole["atlas"] < 1e37).mean() > 0.2
    assert np.array_equal(whole["atlas"], chunked["atlas"])
