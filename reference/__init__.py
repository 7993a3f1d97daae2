"""Mitsuba 3 ground truth for gibench.

    env          import Mitsuba (llvm_ad_rgb, else scalar_rgb with a warning) or say what to install
    convert      Scene + camera -> Mitsuba scene dict (same triangles, albedo, lights, view)
    integrators  direct / indirect_visible / indirect_unshadowed (Python, registered with Mitsuba)
    render       pixel-exact batch renderer: per-pixel mean and sum of squared deviations
    cache        content-addressed store of accumulated references (EXR + JSON)
    api          get_reference (convergence control), build_references (parallel precompute)

Depends on the scene model only (`bench.model.scene`, `bench.model.imageio`): never on the rasteriser or
a method it judges.
"""
