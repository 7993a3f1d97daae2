"""Reference integrators (Python, registered with Mitsuba as `gibench_<component>`).

All lights of a gibench scene are delta emitters (point, spot, directional), so direct light
is evaluated exactly by looping over every emitter with a shadow ray (no light sampling noise).
Surfaces are two-sided diffuse; Mitsuba's `twosided` BSDF orients each evaluation by the side
of the shading normal that `si.wi` is on, as the GL GBuffer does.

| component            | radiance leaving the first hit x towards the camera                               |
|----------------------|-----------------------------------------------------------------------------------|
| direct               | sum_l f_x(w_l) L_l V(x, l)                            (exact for delta lights)    |
| direct_unshadowed    | the same without V (calibration of the GL pass without shadow maps)               |
| indirect_visible     | int f_x Ld(y -> x) G(x, y) V(x, y) dA_y: one bounce with visibility (the          |
|                      | physically correct first bounce); Ld(y -> x) = shadowed direct light y reflects   |
| indirect_unshadowed  | int f_x Ld(y -> x) G(x, y) dA_y without V(x, y): one bounce without indirect      |
|                      | visibility (what FLC, SSDO and DSS estimate); y emits from the side facing x      |
|                      | the light that side receives (two-sided, as manylights' VPLs)                     |

G(x, y) = |cos_y| / d^2 (cos_x is inside f_x), cos_y against y's geometric normal.

The one-bounce integrals are estimated per light l with two techniques combined by the
balance heuristic (multiple importance sampling, one sample each):

* A, BSDF sampling: a cosine-distributed direction at x. For `indirect_visible` the first
  surface y hit; for `indirect_unshadowed` *every* surface y_k the ray crosses (each point y
  with cos_x > 0 lies on exactly one such ray, at some layer k, so summing the layers
  estimates the integral over all surfaces, occluded or not). Area density of y:
  p_A(y) = pdf_x(w) |cos_y| / d^2.
* B, light sampling: a point y first hit by a ray emitted from light l (point: uniform
  sphere; spot: uniform cone of the cutoff angle; directional: uniform disk covering the
  scene's bounding sphere), connected to x (through a shadow ray for `indirect_visible`).
  Area density: p_B(y) = p_w |cos_y,l| / r^2 (point, spot) or |cos_y,l| / (pi R^2).

Each technique contributes f / (p_A + p_B): bounded where either density is large, so neither
the 1/d^2 singularity of B near corners nor A's misses of a small lit spot (a spot aimed at
the ceiling) make fireflies. Without light samplers (`lights=None`, e.g. `mi.render` with the
registered plugins) only technique A runs, with weight 1: also unbiased, noisier.

| parameter  | default | meaning                                                                  |
|------------|---------|--------------------------------------------------------------------------|
| max_layers | 1024    | surfaces crossed per ray in `indirect_unshadowed` (guards against loops) |

Each registered integrator's `sample()` returns the radiance and, as AOVs `m2.R/G/B`, its
square, so `mi.render` also yields the per-pixel second moment; gibench's own renderer
(`reference.render`) calls `radiance()` directly and accumulates exact per-pixel moments.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from bench.protocol.vocabulary import REFERENCE_COMPONENTS

COMPONENTS = REFERENCE_COMPONENTS   # what a reference can be asked for (the vocabulary's order)
# calibration only: direct light without shadow rays (to compare with the GL pass minus shadow maps)
EXTRA_COMPONENTS = ("direct_unshadowed",)
DEFAULT_MAX_LAYERS = 1024


@dataclass(frozen=True)
class LightSampler:
    """How technique B emits from one light (coordinates re-centred like the Mitsuba scene).

    emitter: the Mitsuba emitter object in the scene (its radiometry is used, not re-derived).
    axis: spot axis, or the directional light's travel direction. For directional lights the
    emission disk has radius `radius` around `center` (the scene's bounding sphere)."""
    emitter: object
    kind: str
    position: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    cos_cutoff: float = -1.0
    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0


def _jit(mi) -> bool:
    return mi.variant().startswith(("llvm_", "cuda_"))


def _not(mi, mask):
    """Logical not of a mask (`~` on a Python bool of the scalar variants would give an int)."""
    return ~mask if _jit(mi) else not mask


def _any(mi, mask) -> bool:
    """Scalar variants: is this lane active (JIT variants always proceed, masked)."""
    return True if _jit(mi) else bool(mask)


# ---------------------------------------------------------------------------- light sampling
def emit_ray(mi, light: LightSampler, sampler, active):
    """Technique B: a ray leaving `light` (see LightSampler)."""
    u = sampler.next_2d(active)
    if light.kind == "point":
        return mi.Ray3f(mi.Point3f(*light.position), mi.warp.square_to_uniform_sphere(u))
    if light.kind == "spot":
        local = mi.warp.square_to_uniform_cone(u, light.cos_cutoff)
        return mi.Ray3f(mi.Point3f(*light.position), mi.Frame3f(mi.Vector3f(*light.axis)).to_world(local))
    d = mi.Vector3f(*light.axis)
    frame = mi.Frame3f(d)
    disk = mi.warp.square_to_uniform_disk_concentric(u) * light.radius
    origin = mi.Point3f(*light.center) + frame.s * disk.x + frame.t * disk.y - d * (2.0 * light.radius)
    return mi.Ray3f(origin, d)


def light_area_pdf(mi, light: LightSampler, n_geo, ds):
    """p_B(y): area density at a point y lit by `light` of being emitted by technique B.
    `ds` is the emitter's direction sample from y (ds.d towards the light, ds.dist)."""
    import drjit as dr
    cos_y = dr.abs(dr.dot(n_geo, ds.d))
    if light.kind == "point":
        return cos_y / (4.0 * math.pi) / dr.square(ds.dist)
    if light.kind == "spot":
        return cos_y / (2.0 * math.pi * (1.0 - light.cos_cutoff)) / dr.square(ds.dist)
    return cos_y / (math.pi * light.radius * light.radius)


def _safe_div(mi, num, den):
    import drjit as dr
    return dr.select(den > 0, num / dr.select(den > 0, den, 1.0), 0.0)


# ---------------------------------------------------------------------------- direct light
def _light_list(scene, lights):
    return [(light.emitter, light) for light in lights] if lights else [(e, None) for e in scene.emitters()]


def direct_from_lights(mi, scene, si, active, shadows: bool = True, lights=None, p_a=None):
    """Radiance leaving `si` towards `si.wi` lit by every (delta) emitter, with shadow rays
    unless `shadows` is False. With `p_a` (technique A's area density of this point) and light
    samplers, each light's term carries the balance-heuristic weight p_A / (p_A + p_B,l)."""
    import drjit as dr
    L = mi.Color3f(0.0)
    if not _any(mi, active):
        return L
    bsdf = si.bsdf()
    ctx = mi.BSDFContext()
    for emitter, light in _light_list(scene, lights):
        ds, spec = emitter.sample_direction(si, mi.Point2f(0.5), active)  # delta lights: sample unused
        ok = active & (ds.pdf > 0)
        visible = ok & _not(mi, scene.ray_test(si.spawn_ray_to(ds.p), ok)) if shadows else ok
        if not _any(mi, visible):
            continue
        term = bsdf.eval(ctx, si, si.to_local(ds.d), visible) * spec
        if p_a is not None and light is not None:
            term *= _safe_div(mi, p_a, p_a + light_area_pdf(mi, light, si.n, ds))
        L += dr.select(visible, term, 0.0)
    return L


# ---------------------------------------------------------------------------- one bounce
def _bounce_ray(mi, sampler, si, active):
    """Cosine-sampled direction at x (twosided diffuse): the ray, the weight rho_x, its pdf, mask."""
    bsdf = si.bsdf()
    bs, weight = bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(active), sampler.next_2d(active), active)
    active = active & (bs.pdf > 0)
    return si.spawn_ray(si.to_world(bs.wo)), weight, bs.pdf, active


def _area_pdf_a(mi, pdf_w, x_p, si_y):
    """Technique A's area density of y: pdf_x(w) |cos_y| / d^2."""
    import drjit as dr
    to_y = si_y.p - x_p
    d2 = dr.squared_norm(to_y)
    return _safe_div(mi, pdf_w * dr.abs(dr.dot(si_y.n, to_y)) / dr.sqrt(d2), d2)


def light_sampled_bounce(mi, scene, sampler, si_x, active, lights, visible: bool):
    """Technique B of the one-bounce estimators, one sample per light, MIS-weighted."""
    import drjit as dr
    total = mi.Color3f(0.0)
    ctx = mi.BSDFContext()
    for light in lights:
        ray = emit_ray(mi, light, sampler, active)
        if not _any(mi, active):
            continue
        si_y = scene.ray_intersect(ray, active)
        on = active & si_y.is_valid()
        if not _any(mi, on):
            continue
        # y is the first surface the light reaches: lit, no shadow ray needed
        ds, spec = light.emitter.sample_direction(si_y, mi.Point2f(0.5), on)
        to_x = si_x.p - si_y.p
        d2 = dr.squared_norm(to_x)
        on &= (d2 > 0) & (ds.pdf > 0)
        w = to_x * dr.rsqrt(dr.select(d2 > 0, d2, 1.0))
        si_y.wi = si_y.to_local(w)
        f_y = si_y.bsdf().eval(ctx, si_y, si_y.to_local(ds.d), on)
        wo_x = si_x.to_local(-w)
        bsdf_x = si_x.bsdf()
        f_x = bsdf_x.eval(ctx, si_x, wo_x, on)
        cos_y = dr.abs(dr.dot(si_y.n, w))
        p_a = bsdf_x.pdf(ctx, si_x, wo_x, on) * cos_y / dr.select(d2 > 0, d2, 1.0)
        p_b = light_area_pdf(mi, light, si_y.n, ds)
        if visible:
            on &= _not(mi, scene.ray_test(si_x.spawn_ray_to(si_y.p), on))
        contribution = f_x * f_y * spec * _safe_div(mi, cos_y / dr.select(d2 > 0, d2, 1.0), p_a + p_b)
        total += dr.select(on, contribution, 0.0)
    return total


def radiance(mi, scene, sampler, ray, active, component: str, max_layers: int = DEFAULT_MAX_LAYERS,
             lights=None):
    """(radiance of `component` along the camera ray, primary-hit mask). `lights`: a list of
    LightSampler enabling light-sampled MIS for the one-bounce components."""
    import drjit as dr
    if component not in COMPONENTS + EXTRA_COMPONENTS:
        raise ValueError(f"reference: unknown component '{component}' "
                         f"(expected one of {', '.join(COMPONENTS + EXTRA_COMPONENTS)})")
    si = scene.ray_intersect(ray, active)
    hit = active & si.is_valid()
    if not _any(mi, hit):
        return mi.Color3f(0.0), hit
    if component in ("direct", "direct_unshadowed"):
        return direct_from_lights(mi, scene, si, hit, shadows=component == "direct"), hit
    lights = list(lights) if lights else None
    bounce, weight, pdf_w, alive = _bounce_ray(mi, sampler, si, hit)
    x_p = si.p
    if lights is not None:
        result = light_sampled_bounce(mi, scene, sampler, si, hit, lights, visible=component == "indirect_visible")
    else:
        result = mi.Color3f(0.0)

    def layer_term(si_y, on):
        p_a = _area_pdf_a(mi, pdf_w, x_p, si_y) if lights is not None else None
        return direct_from_lights(mi, scene, si_y, on, lights=lights, p_a=p_a)

    if component == "indirect_visible":
        if not _any(mi, alive):
            return result, hit
        si_y = scene.ray_intersect(bounce, alive)
        return result + weight * layer_term(si_y, alive & si_y.is_valid()), hit

    def cond(ray_k, acc, alive_k, layer):
        return alive_k

    def body(ray_k, acc, alive_k, layer):
        si_k = scene.ray_intersect(ray_k, alive_k)
        on = alive_k & si_k.is_valid()
        acc += dr.select(on, layer_term(si_k, on), 0.0)
        ray_k = si_k.spawn_ray(ray_k.d)
        layer += 1
        return ray_k, acc, on & (layer < max_layers), layer

    acc = mi.Color3f(0.0)
    if _jit(mi):
        _, acc, _, _ = dr.while_loop((bounce, acc, alive, mi.UInt32(0)), cond, body,
                                     labels=("ray", "acc", "alive", "layer"))
    else:
        state = (bounce, acc, bool(alive), 0)
        while state[2]:
            state = body(*state)
        acc = state[1]
    return result + weight * acc, hit


# ---------------------------------------------------------------------------- registration
def register(mi) -> None:
    """Register `gibench_direct`, `gibench_indirect_visible`, `gibench_indirect_unshadowed`
    (and `gibench_direct_unshadowed`) for `mi.load_dict` / `mi.render` (BSDF sampling only)."""
    for component in COMPONENTS + EXTRA_COMPONENTS:
        mi.register_integrator(f"gibench_{component}", _factory(mi, component))


def _factory(mi, component: str):
    class GibenchIntegrator(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.component = component
            self.max_layers = int(props.get("max_layers", DEFAULT_MAX_LAYERS))

        def sample(self, scene, sampler, ray, medium=None, active=True):
            L, hit = radiance(mi, scene, sampler, mi.Ray3f(ray), active, self.component, self.max_layers)
            return L, hit, [L[0] * L[0], L[1] * L[1], L[2] * L[2]]

        def aov_names(self):
            return ["m2.R", "m2.G", "m2.B"]

        def to_string(self):
            return f"GibenchIntegrator[component={self.component}, max_layers={self.max_layers}]"

    GibenchIntegrator.__name__ = f"Gibench_{component}"
    return lambda props: GibenchIntegrator(props)
