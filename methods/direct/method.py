"""`direct`: direct light only (shadow-mapped point, spot and directional lights).

The floor every GI method adds to: its indirect image is zero. Its frame time is the cost of
the shared passes (GBuffer + shadow maps + direct lighting) that the GI methods also pay.

Parameters: none.
"""
from bench.protocol.method import FrameOutput, MethodBase


class DirectMethod(MethodBase):
    name = "direct"
    summary = "Direct light only (shadow-mapped), no indirect light"
    stages = ()
    params = {}
    needs = frozenset({"direct", "shadow_map"})

    def render(self, frame, prof) -> FrameOutput:
        return FrameOutput(direct=frame.passes.direct.radiance, indirect=None)
