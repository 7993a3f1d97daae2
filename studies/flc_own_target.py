"""FLC against its own target, at frame level (issue #24): is the estimator unbiased?

FLC's paper (eq. 8-9) estimates the eq. 4 many-lights sum with its emission lobe without bias;
that sum is `manylights` with emission=flc, over VPLs jittered in their triangles (FLC jitters
its VPLs). This study renders N independent FLC frames (seeds 100..100+N-1, frame 0 each) and
T frames of the target with J jitter sets each, averages every image over square blocks of
B x B pixels, and compares per block FLC's mean over frames with the target's by a z statistic
whose spread is measured over frames (FLC's draws are global per frame: one tile offset, one
level hash for the image, so its pixels are not independent samples; frames are), the target's
own spread from its T frames. A scene of huge triangles (`--refine`, default
big_floor: its 80 m floor is 2 triangles, one VPL each, lit only under a 3.5 m^2 spot) has its
target rendered on `studies.flc_analysis.refined_scene(scene, 0.5)`, as studies.flc_study does:
otherwise 64 jittered positions on the floor rarely land in the spot, and the target is a
heavy-tailed estimate whose few frames do not show its spread.

FLC runs with each `--near-field` given: `paper_eps` is eq. 5 as printed (d_i = max(eps, d), the
target's own bound), the estimator eq. 8-9 is unbiased for; `disc_element` (FLC's default) bounds
1/d^2 by the disc of the level's area, a regularisation the target lacks, so near the VPLs of a
corner it sits below the target by design. Prints per scene the ratio of the image means, the
largest |z| with its Bonferroni p-value over the blocks, the blocks above |z| = 3 and the worst
block's relative difference.

    python -m studies.flc_own_target --scenes cornell_spot,lit_wall_corner,sphere_inside,rooms,hidden_bounce,big_floor \\
        --res 64x48 --frames 64 --jitter 32 --target-frames 4
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
from studies.flc_analysis import refined_scene


def block_means(image: np.ndarray, block: int) -> np.ndarray:
    grey = image.mean(axis=2)
    h, w = grey.shape
    return grey[: h - h % block, : w - w % block].reshape(h // block, block, w // block, block).mean(axis=(1, 3)).ravel()


def compare(ctx, scene_name: str, width: int, height: int, frames: int, jitter: int, target_frames: int, block: int,
            refine: bool, near_fields: list[str]) -> list[str]:
    scene = load_scene(scene_name)
    target_scene = refined_scene(scene, 0.5) if refine else scene
    camera = next(iter(scene.cameras))
    start = time.perf_counter()
    targets = [block_means(run_method(ctx, load_method("manylights"), target_scene, camera, width, height, frames=1, seed=seed,
                                      params={"emission": "flc", "jitter_frames": jitter}).indirect, block)
               for seed in range(1, 1 + target_frames)]
    target = np.mean(targets, axis=0)
    target_se = np.std(targets, axis=0, ddof=1) / np.sqrt(target_frames)
    lines = []
    for near_field in near_fields:
        flc = np.array([block_means(run_method(ctx, load_method("flc"), scene, camera, width, height, frames=1, seed=seed,
                                               params={"near_field": near_field}).indirect, block)
                        for seed in range(100, 100 + frames)])
        lines.append(_line(scene_name, near_field, flc, target, target_se, frames, time.perf_counter() - start))
    return lines


def _line(scene_name, near_field, flc, target, target_se, frames, seconds) -> str:
    mean, se = flc.mean(axis=0), flc.std(axis=0, ddof=1) / np.sqrt(frames)
    z = (mean - target) / (np.sqrt(se ** 2 + target_se ** 2) + 1e-12)
    p_bonferroni = min(1.0, float(2 * stats.norm.sf(np.abs(z).max()) * z.size))
    worst = int(np.argmax(np.abs(z)))
    ratio_sd = flc.mean(axis=1).std(ddof=1) / np.sqrt(frames) / target.mean()
    return (f"| {scene_name} | {near_field} | {mean.mean() / target.mean():.4f} +- {1.96 * ratio_sd:.4f} | {np.abs(z).max():.2f} | "
            f"{p_bonferroni:.2g} | {int((np.abs(z) > 3).sum())} / {z.size} | "
            f"{(mean[worst] - target[worst]) / max(target[worst], 1e-6):+.3f} | {seconds:.0f} s |")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", default="cornell_spot,lit_wall_corner,sphere_inside,rooms,hidden_bounce,big_floor")
    p.add_argument("--res", default="64x48")
    p.add_argument("--frames", type=int, default=64, help="independent FLC frames (seeds)")
    p.add_argument("--jitter", type=int, default=32, help="the target's jitter sets per frame (manylights jitter_frames)")
    p.add_argument("--target-frames", type=int, default=4, help="the target's frames (seeds): their spread is its own")
    p.add_argument("--block", type=int, default=8, help="block side in pixels")
    p.add_argument("--near-field", default="paper_eps,disc_element", help="FLC near_field values to run")
    p.add_argument("--refine", default="big_floor", help="scenes whose target is rendered on the refined scene")
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.res.split("x"))
    ctx = create_context()
    print("| scene | FLC near_field | image mean FLC / target (95%) | max abs z | Bonferroni p | blocks abs z > 3 | worst block FLC / target - 1 | time |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        for line in compare(ctx, name, width, height, args.frames, args.jitter, args.target_frames, args.block,
                            name in args.refine.split(","), args.near_field.split(",")):
            print(line, flush=True)


if __name__ == "__main__":
    main()
