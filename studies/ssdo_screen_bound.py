"""What any screen-space one-bounce method can see: the exact unshadowed bounce from on-screen senders.

    screen_sender_bounce(gbuffer, direct, camera) -> HxWx3

Every covered pixel of the first depth layer is a sender patch at its GBuffer position, with its
GBuffer normal (facing the camera), its direct radiance and its area (the pixel's solid angle
times depth^2 / |cos| of the view angle); every covered pixel x receives

    L(x) = rho_x / pi * sum_y L_y A_y <n_x, w>+ <n_y, -w>+ / max(eps, |y - x|)^2

with no visibility, the quantity Mitsuba's `indirect_unshadowed` reference integrates over *all*
surfaces. The ratio of its image mean to the reference's is the share of the bounce whose
senders are on screen: SSDO's ceiling on a view. O(covered x lit pixels) in numpy, for small
images (analysis and tests, never a benchmark row).

`python -m studies.ssdo_screen_bound RUN_DIR [RUN_DIR ...]` prints, for every scene/view of
`gibench run` folders that hold SSDO images and references, the ratio of the image means of
SSDO's indirect and of this bound to the `indirect_unshadowed` reference.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bench.gl import render_gbuffer
from bench.gl.context import create_context
from bench.model.corpus import load_scene
from bench.model.imageio import read_exr

EPS_REL = 1e-4  # distance clamp relative to the largest sender-receiver distance on screen


def pixel_areas(position: np.ndarray, normal: np.ndarray, camera, height: int) -> np.ndarray:
    """World area (m^2) of the surface seen through each pixel (HxW; row 0 at the top)."""
    right, up, fwd = camera.basis()
    rel = position - np.asarray(camera.eye, dtype=np.float64)
    dist = np.linalg.norm(rel, axis=2)
    w = rel / np.maximum(dist, 1e-30)[..., None]
    pitch = 2.0 * np.tan(np.radians(camera.fov_y_deg) / 2.0) / height   # pixel side on the image plane at 1 m
    solid_angle = pitch ** 2 * np.clip(w @ fwd, 0.0, None) ** 3
    cos_view = np.abs(np.einsum("ijk,ijk->ij", normal, w))
    return solid_angle * dist ** 2 / np.maximum(cos_view, 1e-3)


def screen_sender_bounce(gbuffer: dict, direct: np.ndarray, camera) -> np.ndarray:
    """The unshadowed one-bounce radiance from on-screen senders (see the module docstring).
    `gbuffer`: `bench.gl.render_gbuffer` output; `direct`: HxWx3 direct radiance of the same view."""
    pos = np.asarray(gbuffer["position"], dtype=np.float64)
    nrm = np.asarray(gbuffer["normal"], dtype=np.float64)
    alb = np.asarray(gbuffer["albedo"], dtype=np.float64)
    mask = np.asarray(gbuffer["mask"], dtype=bool)
    direct = np.asarray(direct, dtype=np.float64)
    if direct.shape != pos.shape:
        raise ValueError(f"screen_sender_bounce: direct image {direct.shape} does not match the GBuffer {pos.shape}")
    area = pixel_areas(pos, nrm, camera, pos.shape[0])
    senders = mask & (direct.sum(axis=2) > 0)
    out = np.zeros_like(direct)
    if not senders.any():
        return out
    ys, ny, ly, ay = pos[senders], nrm[senders], direct[senders], area[senders]
    receivers = np.argwhere(mask)
    lo, hi = pos[mask].min(axis=0), pos[mask].max(axis=0)
    eps = EPS_REL * max(float(np.linalg.norm(hi - lo)), 1e-30)
    chunk = max(1, 2_000_000 // len(ys))   # receivers per block: bounded memory (~200 MB of pairs)
    for start in range(0, len(receivers), chunk):
        idx = receivers[start:start + chunk]
        x, nx = pos[idx[:, 0], idx[:, 1]], nrm[idx[:, 0], idx[:, 1]]
        v = ys[None, :, :] - x[:, None, :]
        d = np.linalg.norm(v, axis=2)
        v /= np.maximum(d, 1e-30)[..., None]
        cos_r = np.clip(np.einsum("rsk,rk->rs", v, nx), 0.0, None)
        cos_s = np.clip(-np.einsum("rsk,sk->rs", v, ny), 0.0, None)
        transfer = cos_r * cos_s * ay[None, :] / np.maximum(d, eps) ** 2
        out[idx[:, 0], idx[:, 1]] = alb[idx[:, 0], idx[:, 1]] / np.pi * (transfer @ ly)
    return out


def _ratio_table(run_dirs) -> list[str]:
    ctx = create_context()
    lines = ["| run | scene | view | WxH | SSDO / ref | screen bound / ref |", "|---|---|---|---|---|---|"]
    for run in run_dirs:
        run = Path(run)
        for ssdo_dir in sorted(run.glob("images/*/*/ssdo")):
            scene_name, view = ssdo_dir.parts[-3], ssdo_dir.parts[-2]
            ref_file = run / "references" / scene_name / view / "indirect_unshadowed.exr"
            if not ref_file.is_file():
                continue
            ref = read_exr(ref_file).astype(np.float64)
            ssdo = read_exr(ssdo_dir / "indirect.exr").astype(np.float64)
            direct = read_exr(ssdo_dir / "direct.exr").astype(np.float64)
            h, w = ref.shape[:2]
            scene = load_scene(scene_name)
            bound = screen_sender_bounce(render_gbuffer(ctx, scene, view, w, h), direct, scene.cameras[view])
            lines.append(f"| {run.name} | {scene_name} | {view} | {w}x{h} | {ssdo.mean() / ref.mean():.3f} "
                         f"| {bound.mean() / ref.mean():.3f} |")
    return lines


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit("usage: python -m studies.ssdo_screen_bound RUN_DIR [RUN_DIR ...]")
    print("\n".join(_ratio_table(sys.argv[1:])))
