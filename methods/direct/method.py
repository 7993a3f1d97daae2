"""`direct`: direct light only (shadow-mapped point, spot and directional lights).

The floor every GI method adds to: its indirect image is zero. Its frame time is the cost of
the shared passes (GBuffer + shadow maps + direct lighting) that the GI methods also pay, so a
method's frame over `direct`'s is the overhead ratio the FLC paper quotes.

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter | default | range | meaning |
|-----------|---------|-------|---|
| (none) | | | |
<!-- end of parameters -->

Example:

    gibench run --scenes cornell_spot --methods direct,flc --res 128x96 --defaults-only

Stages: none of its own (the shared `gbuffer_shadow` and `direct_light`). Needs: direct,
shadow_map.

In motion (bench.run.sequence): It keeps nothing of its own (it shows the shared direct pass, which
every frame renders): any motion costs it nothing beyond the frame. Measured update per moved frame
at 160x90, light (rooms_light_sweep) 0 ms, camera (sponza_camera_walk) 0 ms, geometry
(cornell_spot_moving_block) 0 ms (`python -m studies.motion_costs`, 2 cores shared with other work).
"""
from bench.protocol.method import FrameOutput, MethodBase


class DirectMethod(MethodBase):
    name = "direct"
    summary = "Direct light only (shadow-mapped), no indirect light"
    stages = ()
    params = {}
    needs = frozenset({"direct", "shadow_map"})

    @classmethod
    def frames_identical(cls, params: dict) -> bool:
        return True   # the shared direct pass: no random stream, no state

    @classmethod
    def cost_terms(cls, params, size):
        return {}   # one shading pass over the pixels (the shared shadow maps are the view's)

    def render(self, frame, prof) -> FrameOutput:
        return FrameOutput(direct=frame.passes.direct.radiance, indirect=None)
