// ir_shadowed's gather: ir_unshadowed's gather (compiled with VPL_SHADOWS=1) with the hemicube
// visibility test per VPL.
#include "vpl_shadow.glsl"
#include "vpl_gather.glsl"
