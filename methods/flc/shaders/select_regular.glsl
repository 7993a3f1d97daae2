// Regular-pass triangle selection (stage `regular`, `regular_selection = compute`): the cheap
// part of the regular pass's geometry shader run in compute, so that the draw carries only the
// triangles the geometry shader would do something with: divergent ones (appended there) and
// regular ones that Alg. 1 keeps this frame (level >= 0). Same area, same key, same hash as
// splat_regular.glsl; the geometry shader repeats the exact test, so a triangle kept here on a
// float tie is dropped there (SELECT_MARGIN only ever keeps more). The compaction is an ordered
// scan (not an atomic append): the kept triangles reach the draw in their scene order, so the
// blending order, and the image, are exactly those of the single draw of the whole scene.
// Each invocation owns a chunk of SELECT_CHUNK consecutive triangles (no shared memory, no
// barriers: both are slow on a CPU rasteriser's compute and buy nothing here):
//   SELECT_STEP 1: per chunk, the keep flag of each triangle and the chunk's count.
//   SELECT_STEP 2: one invocation: exclusive scan of the chunk counts, the DrawElementsIndirect
//                  command (count = 3 x kept).
//   SELECT_STEP 3: per chunk, each kept triangle's 3 indices and scene index, in order.
#include "common.glsl"
#include "partition.glsl"
layout(local_size_x = SELECT_GROUP) in;   // SELECT_GROUP chunks per workgroup

layout(std430, binding = BINDING_SELECT_FACES) readonly buffer Faces { uint faces[]; };
layout(std430, binding = BINDING_SELECT_POSITIONS) readonly buffer Positions { float positions[]; };
layout(std430, binding = BINDING_SELECT_RANDOM) readonly buffer VertexRandom { uint vertex_random[]; };
layout(std430, binding = BINDING_SELECT_RANK) buffer Keep { uint keep_flag[]; };     // per triangle
layout(std430, binding = BINDING_SELECT_GROUPS) buffer Chunks { uint chunk_count[]; }; // per chunk
layout(std430, binding = BINDING_SELECT_KEPT_INDICES) writeonly buffer KeptIndices { uint kept_indices[]; };
layout(std430, binding = BINDING_KEPT_TRIANGLES) writeonly buffer KeptTriangles { uint kept_triangles[]; };
// DrawElementsIndirect: count, instance count, first index, base vertex, base instance
layout(std430, binding = BINDING_SELECT_COMMAND) writeonly buffer Command { uint command[5]; };

uniform uint u_triangle_count;
uniform uint u_chunk_total;    // chunks of SELECT_CHUNK triangles
uniform uint u_rand;           // the frame's level draw (Alg. 2), as in splat_regular.glsl


vec3 position(uint v) { return vec3(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]); }

bool kept(uint t) {
    uint i0 = faces[3u * t], i1 = faces[3u * t + 1u], i2 = faces[3u * t + 2u];
    vec3 a = position(i0), b = position(i1), c = position(i2);
    float area = 0.5 * length(cross(b - a, c - a));
    if (area > FLC_DIVERGENT_AREA) return true;     // the geometry shader appends it
    uint key = vertex_random[i0] ^ vertex_random[i1] ^ vertex_random[i2];
    uint h = hash_u32(u_rand ^ key);
    return flc_level(unit_from_u32(h), area * SELECT_MARGIN) >= 0;
}

void main() {
#if SELECT_STEP == 2
    if (gl_GlobalInvocationID.x != 0u) return;   // one invocation scans
    uint total = 0u;
    for (uint c = 0u; c < u_chunk_total; ++c) {
        uint n = chunk_count[c];
        chunk_count[c] = total;   // exclusive: the chunk's first slot
        total += n;
    }
    command[0] = 3u * total;
    command[1] = 1u;
    command[2] = 0u;
    command[3] = 0u;
    command[4] = 0u;
#else
    uint chunk = gl_GlobalInvocationID.x;
    if (chunk >= u_chunk_total) return;
    uint first = chunk * uint(SELECT_CHUNK), last = min(first + uint(SELECT_CHUNK), u_triangle_count);
#if SELECT_STEP == 1
    uint count = 0u;
    for (uint t = first; t < last; ++t) {
        uint k = kept(t) ? 1u : 0u;
        keep_flag[t] = k;
        count += k;
    }
    chunk_count[chunk] = count;
#else
    uint slot = chunk_count[chunk];
    for (uint t = first; t < last; ++t) {
        if (keep_flag[t] == 0u) continue;
        kept_indices[3u * slot] = faces[3u * t];
        kept_indices[3u * slot + 1u] = faces[3u * t + 1u];
        kept_indices[3u * slot + 2u] = faces[3u * t + 2u];
        kept_triangles[slot] = t;
        ++slot;
    }
#endif
#endif
}
