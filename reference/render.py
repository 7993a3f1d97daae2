"""Pixel-exact batch rendering: per-pixel sample moments of one reference component.

Rather than `mi.render` (whose film only keeps the filtered mean), camera rays are generated
here from the converted sensor at exact film positions: the pixel centre (i + 0.5, j + 0.5)
like the rasteriser (`pixel_sampling="center"`, the default: the reference then measures the
lighting error only, not aliasing) or uniformly over the pixel (`"box"`, the box-filtered
film). Each sample's radiance comes back to numpy, where the batch's per-pixel mean and sum
of squared deviations (M2) are computed exactly in float64; batches merge with Chan's
parallel formula, so accumulating more samples later is exact.

Deterministic: the sampler of a batch is seeded from (seed, index of the batch's first sample
per pixel); lanes are decorrelated by Mitsuba's independent sampler (TEA hash of seed, lane).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reference.integrators import radiance

MAX_LANES = 1 << 21   # samples traced per kernel launch (memory bound)
PIXEL_SAMPLING = ("center", "box")


@dataclass
class Moments:
    """Per-pixel running moments: n samples, mean (HxWx3), M2 = sum of squared deviations, hits."""
    n: int
    mean: np.ndarray
    m2: np.ndarray
    hits: np.ndarray  # HxW, primary rays that hit a surface

    @classmethod
    def empty(cls, width: int, height: int) -> "Moments":
        return cls(0, np.zeros((height, width, 3)), np.zeros((height, width, 3)), np.zeros((height, width)))

    def merge(self, other: "Moments") -> "Moments":
        if self.n == 0:
            return other
        if other.n == 0:
            return self
        n = self.n + other.n
        delta = other.mean - self.mean
        mean = self.mean + delta * (other.n / n)
        m2 = self.m2 + other.m2 + delta * delta * (self.n * other.n / n)
        return Moments(n, mean, m2, self.hits + other.hits)

    def variance_of_mean(self) -> np.ndarray:
        """Unbiased per-pixel variance of the mean estimate: M2 / (n - 1) / n."""
        if self.n < 2:
            return np.full_like(self.mean, np.nan)
        return np.maximum(self.m2, 0.0) / ((self.n - 1) * self.n)

    def coverage(self) -> np.ndarray:
        return self.hits > 0

    def noise_floor(self) -> float:
        """Mean over covered pixels and channels of the variance of the mean (the expected MSE
        of the reference itself)."""
        mask = self.coverage()
        if not mask.any():
            return 0.0
        return float(self.variance_of_mean()[mask].mean())


def batch_seed(seed: int, first_sample: int) -> int:
    """A 32-bit seed per batch (splitmix64 of seed and the batch's first sample index)."""
    z = (int(seed) * 0x9E3779B97F4A7C15 + int(first_sample) * 0xBF58476D1CE4E5B9 + 0x94D049BB133111EB) & (2**64 - 1)
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & (2**64 - 1)
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & (2**64 - 1)
    return int((z ^ (z >> 31)) & 0xFFFFFFFF)


def _moments_from_samples(values: np.ndarray, hits: np.ndarray, width: int, height: int) -> Moments:
    """values: (pixels, spp, 3) float64, hits: (pixels, spp) bool."""
    spp = values.shape[1]
    mean = values.mean(axis=1)
    m2 = ((values - mean[:, None]) ** 2).sum(axis=1)
    return Moments(spp, mean.reshape(height, width, 3), m2.reshape(height, width, 3),
                   hits.sum(axis=1).reshape(height, width).astype(np.float64))


def render_moments(mi, mscene, component: str, width: int, height: int, spp: int, seed: int, first_sample: int,
                   pixel_sampling: str = "center", max_layers: int = 1024, lights=None) -> Moments:
    """Render `spp` samples per pixel of `component` and return their per-pixel moments.
    `lights`: LightSampler list for the light-sampled MIS of the one-bounce components."""
    if pixel_sampling not in PIXEL_SAMPLING:
        raise ValueError(f"reference: pixel_sampling '{pixel_sampling}' is not one of {PIXEL_SAMPLING}")
    if spp < 1:
        raise ValueError(f"reference: spp must be >= 1, got {spp}")
    if not mi.variant().startswith(("llvm_", "cuda_")):
        return _render_scalar(mi, mscene, component, width, height, spp, seed, first_sample, pixel_sampling,
                              max_layers, lights)
    pixels = width * height
    chunk = max(1, min(spp, MAX_LANES // pixels))
    out = Moments.empty(width, height)
    done = 0
    while done < spp:
        n = min(chunk, spp - done)
        out = out.merge(_render_jit(mi, mscene, component, width, height, n,
                                    batch_seed(seed, first_sample + done), pixel_sampling, max_layers, lights))
        done += n
    return out


def _render_jit(mi, mscene, component, width, height, spp, seed, pixel_sampling, max_layers, lights) -> Moments:
    import drjit as dr
    lanes = width * height * spp
    # sizes and seed as opaque variables, not literals: one compiled kernel serves every batch
    spp_v, width_v = dr.opaque(mi.UInt32, spp), dr.opaque(mi.UInt32, width)
    idx = dr.arange(mi.UInt32, lanes)
    pixel = idx // spp_v
    px, py = pixel % width_v, pixel // width_v
    sampler = mi.load_dict({"type": "independent", "sample_count": spp})
    sampler.seed(dr.opaque(mi.UInt32, seed), lanes)
    offset = sampler.next_2d() if pixel_sampling == "box" else mi.Point2f(0.5, 0.5)
    inv_size = mi.Point2f(dr.opaque(mi.Float, 1.0 / width), dr.opaque(mi.Float, 1.0 / height))
    position = mi.Point2f((mi.Float(px) + offset.x) * inv_size.x, (mi.Float(py) + offset.y) * inv_size.y)
    sensor = mscene.sensors()[0]
    ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5, 0.5))
    L, hit = radiance(mi, mscene, sampler, ray, mi.Bool(True), component, max_layers, lights)
    dr.eval(L, hit)
    values = np.stack([np.asarray(L[c], dtype=np.float64) for c in range(3)], axis=-1)
    hits = np.asarray(hit, dtype=bool)
    return _moments_from_samples(values.reshape(width * height, spp, 3), hits.reshape(width * height, spp),
                                 width, height)


def _render_scalar(mi, mscene, component, width, height, spp, seed, first_sample, pixel_sampling,
                   max_layers, lights) -> Moments:
    """The scalar_rgb fallback: the same estimator, one Python call per sample (slow)."""
    sensor = mscene.sensors()[0]
    sampler = mi.load_dict({"type": "independent", "sample_count": 1})
    values = np.zeros((width * height, spp, 3))
    hits = np.zeros((width * height, spp), dtype=bool)
    base = batch_seed(seed, first_sample)
    for p in range(width * height):
        x, y = p % width, p // width
        for s in range(spp):
            sampler.seed(batch_seed(base, p * spp + s))
            off = sampler.next_2d() if pixel_sampling == "box" else mi.Point2f(0.5, 0.5)
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((x + off[0]) / width, (y + off[1]) / height),
                                       mi.Point2f(0.5, 0.5))
            L, hit = radiance(mi, mscene, sampler, ray, True, component, max_layers, lights)
            values[p, s] = [L[0], L[1], L[2]]
            hits[p, s] = bool(hit)
    return _moments_from_samples(values, hits, width, height)
