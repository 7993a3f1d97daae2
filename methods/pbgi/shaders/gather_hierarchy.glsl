// Hierarchical point-based gather (`gather=hierarchy`): the emitters are the leaves under the
// nodes [u_first, u_end) of the emitter quadtree (hierarchy.py), walked without a stack. One
// workgroup per receiver tile (a block of at most TILE_SIZE^2 texels of one chart, itself a
// node of the tree), so every decision of the walk is the same for the tile's texels: control
// flow and node loads are uniform over the workgroup (what a SIMD rasteriser needs).
// - a flat node whose plane holds the whole flat tile is skipped: each of its leaves sees the
//   tile's texels at cos_e = 0 and adds nothing;
// - a node whose bounding radius is below u_refine_ratio times its distance to the tile's
//   bounding sphere is used whole (its aggregate disk, transfer.glsl);
// - else it is refined (its first child is next), as is a node whose subtree runs past u_end
//   (the next range counts those leaves), so split ranges add up to the whole sum;
// - a texel (leaf) is always summed exactly.
// The sums are added to the accumulation images (this bounce's irradiance front/back and the
// running total); each texel belongs to one tile, so one invocation writes it per dispatch.
#include "pbgi_records.glsl"
#include "lightmap_texel.glsl"
#include "transfer.glsl"
layout(local_size_x = TILE_SIZE, local_size_y = TILE_SIZE) in;

struct ReceiverTile { ivec4 box; ivec4 node; };   // box: x0, y0, x1, y1 (exclusive); node.x: its node
layout(std430, binding = BINDING_PBGI_EMITTERS) readonly buffer NodeBlock { Surfel nodes[]; };
layout(std430, binding = BINDING_PBGI_NODE_LINKS) readonly buffer LinkBlock { ivec2 links[]; };   // (skip, first leaf)
layout(std430, binding = BINDING_PBGI_TILES) readonly buffer TileBlock { ReceiverTile tiles[]; };
layout(rgba32f, binding = 0) uniform image2D u_bounce_front;
layout(rgba32f, binding = 1) uniform image2D u_bounce_back;
layout(rgba32f, binding = 2) uniform image2D u_total_front;
layout(rgba32f, binding = 3) uniform image2D u_total_back;
uniform int u_first;
uniform int u_end;
uniform float u_refine_ratio;

void main() {
    ReceiverTile rt = tiles[gl_WorkGroupID.x];
    ivec2 px = rt.box.xy + ivec2(gl_LocalInvocationID.xy);
    vec3 xr = vec3(0.0), nr = vec3(0.0, 0.0, 1.0); float ar = 0.0;
    bool receiver = all(lessThan(px, rt.box.zw)) && lightmap_surfel(px, xr, nr, ar);
    Surfel tile = nodes[rt.node.x];
    bool tile_flat = tile.radiosity_back.w > 0.5;
    vec3 front = vec3(0.0), back = vec3(0.0);
    int i = u_first;
    while (i < u_end) {
        Surfel e = nodes[i];
        int skip = links[i].x;
        if (skip == i + 1) {                 // a texel
            if (receiver) transfer(e, e.position_area.w, xr, nr, front, back);
            i = skip;
            continue;
        }
        vec3 v = tile.position_area.xyz - e.position_area.xyz;
        float radius = e.normal.w;
        float gap = length(v) - tile.normal.w;   // from the node's centre to the tile's bounding sphere
        if (tile_flat && e.radiosity_back.w > 0.5 && abs(dot(v, e.normal.xyz)) <= PLANE_TOLERANCE * radius
                && abs(dot(tile.normal.xyz, e.normal.xyz)) >= 1.0 - FLAT_COSINE_TOLERANCE) {
            i = skip;                        // coplanar
        } else if (skip <= u_end && gap > 0.0 && radius < u_refine_ratio * gap) {
            if (receiver) transfer(e, e.radiosity_front.w, xr, nr, front, back);
            i = skip;
        } else {
            i += 1;
        }
    }
    if (receiver) {
        imageStore(u_bounce_front, px, imageLoad(u_bounce_front, px) + vec4(front, 0.0));
        imageStore(u_bounce_back, px, imageLoad(u_bounce_back, px) + vec4(back, 0.0));
        imageStore(u_total_front, px, imageLoad(u_total_front, px) + vec4(front, 0.0));
        imageStore(u_total_back, px, imageLoad(u_total_back, px) + vec4(back, 0.0));
    }
}
