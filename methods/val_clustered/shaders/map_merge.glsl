// The splat image (map_split.glsl: distances as float bits, atomic minimum) into the depth
// atlas, drawn full screen over the atlas with MIN blending; each texel of the splat image is
// reset to the empty value (the atlas's clear value) as it is read, ready for the next frame.
#include "fullscreen.glsl"
layout(r32ui, binding = 0) uniform coherent uimage2D u_splat;

#if defined FRAGMENT_SHADER
layout(location = 0) out float out_distance;
void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    uint bits = imageLoad(u_splat, texel).r;
    imageStore(u_splat, texel, uvec4(floatBitsToUint(MAP_EMPTY)));
    out_distance = uintBitsToFloat(bits);
}
#endif
