// The tiled receiver layout shared by deinterleave.glsl (writes it) and vpl_splat.glsl (reads it).
#ifndef FLC_RECEIVERS_GLSL
#define FLC_RECEIVERS_GLSL
uniform ivec2 u_screen;        // full-resolution W, H
uniform int u_tiles_per_axis;  // 2^L: 4^L interleaved tiles
uniform ivec2 u_tile_size;     // one tile's pixels (ceil(W / 2^L), ceil(H / 2^L))

// Tiled texel q (tile phase = q / tile size) -> the full-resolution pixel phase + 2^L i it stands for.
ivec2 tiled_to_pixel(ivec2 q) {
    ivec2 phase = q / u_tile_size;
    return phase + u_tiles_per_axis * (q - phase * u_tile_size);
}

// Texel: uvec4(position bits xyz, octahedral normal in two 16-bit snorms) in an unsigned
// integer texture (bits kept exactly: a float target could flush denormal patterns).
// packSnorm2x16 writes -1 as -32767 and never the pattern -32768 (0x8000): that pair marks
// "no receiver".
const uint RECEIVER_NONE = 0x80008000u;
uint encode_receiver_normal(vec3 n) {
    n /= abs(n.x) + abs(n.y) + abs(n.z);
    vec2 e = n.z >= 0.0 ? n.xy : (1.0 - abs(n.yx)) * vec2(n.x >= 0.0 ? 1.0 : -1.0, n.y >= 0.0 ? 1.0 : -1.0);
    return packSnorm2x16(e);
}
vec3 decode_receiver_normal(uint w) {
    vec2 e = unpackSnorm2x16(w);
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (n.z < 0.0) n.xy = (1.0 - abs(n.yx)) * vec2(n.x >= 0.0 ? 1.0 : -1.0, n.y >= 0.0 ? 1.0 : -1.0);
    return normalize(n);
}
#endif
