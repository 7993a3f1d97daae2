"""FLC against its own target, at frame level (issue #24): is the estimator unbiased?

FLC's paper (eq. 8-9) estimates the eq. 4 many-lights sum with its emission lobe without bias;
that sum is `manylights` with emission=flc, over VPLs jittered in their triangles (FLC jitters
its VPLs). This study renders N independent FLC frames (seeds 100..100+N-1, frame 0 each) and
two frames of the target with J jitter sets each, averages every image over square blocks of
B x B pixels, and compares per block FLC's mean over frames with the target's by a z statistic
whose spread is measured over frames (FLC's draws are global per frame: one tile offset, one
level hash for the image, so its pixels are not independent samples; frames are), the target's
own spread estimated from its two frames. Prints per scene the ratio of the image means, the
largest |z| with its Bonferroni p-value over the blocks, the blocks above |z| = 3 and the worst
block's relative difference.

    python -m studies.flc_own_target --scenes cornell_spot,lit_wall_corner,sphere_inside,rooms,hidden_bounce,big_floor \\
        --res 64x48 --frames 64 --jitter 64
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats

from bench.gl import create_context
from bench.model.corpus import load_scene
from bench.protocol.registry import load_method
from bench.run.harness import run_method


def block_means(image: np.ndarray, block: int) -> np.ndarray:
    grey = image.mean(axis=2)
    h, w = grey.shape
    return grey[: h - h % block, : w - w % block].reshape(h // block, block, w // block, block).mean(axis=(1, 3)).ravel()


def compare(ctx, scene_name: str, width: int, height: int, frames: int, jitter: int, block: int) -> str:
    scene = load_scene(scene_name)
    camera = next(iter(scene.cameras))
    start = time.perf_counter()
    flc = np.array([block_means(run_method(ctx, load_method("flc"), scene, camera, width, height, frames=1,
                                           seed=seed).indirect, block) for seed in range(100, 100 + frames)])
    targets = [block_means(run_method(ctx, load_method("manylights"), scene, camera, width, height, frames=1, seed=seed,
                                      params={"emission": "flc", "jitter_frames": jitter}).indirect, block)
               for seed in (1, 2)]
    target = (targets[0] + targets[1]) / 2
    target_se = np.abs(targets[0] - targets[1]) / 2      # the sd of a mean of two, from one difference
    mean, se = flc.mean(axis=0), flc.std(axis=0, ddof=1) / np.sqrt(frames)
    z = (mean - target) / (np.sqrt(se ** 2 + target_se ** 2) + 1e-12)
    p_bonferroni = min(1.0, float(2 * stats.norm.sf(np.abs(z).max()) * z.size))
    worst = int(np.argmax(np.abs(z)))
    ratio_sd = flc.mean(axis=1).std(ddof=1) / np.sqrt(frames) / target.mean()
    return (f"| {scene_name} | {mean.mean() / target.mean():.4f} +- {1.96 * ratio_sd:.4f} | {np.abs(z).max():.2f} | "
            f"{p_bonferroni:.2g} | {int((np.abs(z) > 3).sum())} / {z.size} | "
            f"{(mean[worst] - target[worst]) / max(target[worst], 1e-6):+.3f} | {time.perf_counter() - start:.0f} s |")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", default="cornell_spot,lit_wall_corner,sphere_inside,rooms,hidden_bounce,big_floor")
    p.add_argument("--res", default="64x48")
    p.add_argument("--frames", type=int, default=64, help="independent FLC frames (seeds)")
    p.add_argument("--jitter", type=int, default=64, help="the target's jitter sets per frame (manylights jitter_frames)")
    p.add_argument("--block", type=int, default=8, help="block side in pixels")
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.res.split("x"))
    ctx = create_context()
    print("| scene | image mean FLC / target (95%) | max abs z | Bonferroni p | blocks abs z > 3 | worst block FLC / target - 1 | time |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        print(compare(ctx, name, width, height, args.frames, args.jitter, args.block), flush=True)


if __name__ == "__main__":
    main()
