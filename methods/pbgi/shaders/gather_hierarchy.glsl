// Hierarchical point-based gather (`gather=hierarchy`): the emitters are the leaves under the
// nodes [u_first, u_end) of the emitter octree (hierarchy.py), walked without a stack. One
// workgroup per receiver tile (at most TILE_TEXELS consecutive leaves of the tree: a compact
// cluster of texels, whatever their charts), so every decision of the walk is the same for
// the tile's texels: control flow and node loads are uniform over the workgroup (what a SIMD
// rasteriser needs).
// - a flat node whose plane holds the whole flat tile is skipped: each of its leaves sees the
//   tile's texels at cos_e = 0 and adds nothing;
// - a node is used whole (transfer_node) when its bounding radius is below u_refine_ratio times
//   its distance to the tile's bounding sphere;
// - else it is refined (its first child is next), as is a node whose subtree runs past u_end
//   (the next range counts those leaves), so split ranges add up to the whole sum;
// - a texel (leaf) is always summed exactly, from its surfel.
// The sums are added to the accumulation images (this bounce's irradiance front/back and the
// running total); each texel belongs to one tile, so one invocation writes it per dispatch.
// The number of nodes the walk visits is added to visits[tile] (diagnostics).
#include "pbgi_records.glsl"
#include "transfer.glsl"
layout(local_size_x = TILE_TEXELS) in;

struct ReceiverTile { vec4 centre_radius; vec4 normal_flat; ivec4 leaves; };   // leaves: first, count
layout(std430, binding = BINDING_PBGI_TEXELS) readonly buffer TexelBlock { ivec2 texels[]; };
layout(std430, binding = BINDING_PBGI_SURFELS) readonly buffer SurfelBlock { Surfel surfels[]; };
layout(std430, binding = BINDING_PBGI_EMITTERS) readonly buffer NodeBlock { EmitterNode nodes[]; };
layout(std430, binding = BINDING_PBGI_NODE_LINKS) readonly buffer LinkBlock { ivec2 links[]; };   // (skip, first leaf)
layout(std430, binding = BINDING_PBGI_TILES) readonly buffer TileBlock { ReceiverTile tiles[]; };
layout(std430, binding = BINDING_PBGI_VISITS) buffer VisitBlock { uint visits[]; };
layout(rgba32f, binding = 0) uniform image2D u_bounce_front;
layout(rgba32f, binding = 1) uniform image2D u_bounce_back;
layout(rgba32f, binding = 2) uniform image2D u_total_front;
layout(rgba32f, binding = 3) uniform image2D u_total_back;
uniform int u_first;
uniform int u_end;
uniform float u_refine_ratio;
uniform int u_tile_offset;   // tiles dispatched in batches of at most 65535 work groups

void main() {
    int tile = u_tile_offset + int(gl_WorkGroupID.x);
    ReceiverTile rt = tiles[tile];
    int lane = int(gl_LocalInvocationIndex);
    bool receiver = lane < rt.leaves.y;
    int leaf = rt.leaves.x + min(lane, rt.leaves.y - 1);
    ivec2 px = texels[leaf];
    vec3 xr = surfels[leaf].position_area.xyz, nr = surfels[leaf].normal.xyz;
    vec3 tile_c = rt.centre_radius.xyz;
    float tile_r = rt.centre_radius.w;
    bool tile_flat = rt.normal_flat.w > 0.5;
    vec3 front = vec3(0.0), back = vec3(0.0);
    uint visited = 0u;
    int i = u_first;
    while (i < u_end) {
        visited += 1u;
        ivec2 link = links[i];
        if (link.x == i + 1) {               // a texel
            if (receiver) transfer(surfels[link.y], surfels[link.y].position_area.w, xr, nr, front, back);
            i = link.x;
            continue;
        }
        vec4 pa = nodes[i].position_area, ar = nodes[i].axis_radius, shape = nodes[i].shape;
        vec3 v = tile_c - pa.xyz;
        float dist = length(v);
        float gap = dist - tile_r;           // from the node's centre to the tile's bounding sphere
        if (tile_flat && shape.y > 0.5 && abs(dot(v, ar.xyz)) <= PLANE_TOLERANCE * ar.w
                && abs(dot(rt.normal_flat.xyz, ar.xyz)) >= 1.0 - FLAT_COSINE_TOLERANCE) {
            i = link.x;                      // coplanar
            continue;
        }
        bool use = link.x <= u_end && gap > 0.0 && ar.w < u_refine_ratio * gap;
        if (use) {
            if (receiver) transfer_node(nodes[i], xr, nr, front, back);
            i = link.x;
        } else {
            i += 1;
        }
    }
    if (lane == 0) visits[tile] += visited;
    if (receiver) {
        imageStore(u_bounce_front, px, imageLoad(u_bounce_front, px) + vec4(front, 0.0));
        imageStore(u_bounce_back, px, imageLoad(u_bounce_back, px) + vec4(back, 0.0));
        imageStore(u_total_front, px, imageLoad(u_total_front, px) + vec4(front, 0.0));
        imageStore(u_total_back, px, imageLoad(u_total_back, px) + vec4(back, 0.0));
    }
}
