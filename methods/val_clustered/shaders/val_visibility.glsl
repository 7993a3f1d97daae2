// Clustered visibility (paper Sec. 4): for every pixel x and every VAL j, the fraction V_j(x)
// of VAL j that x sees, stored in layer j of an R32F array; the gather multiplies each VPL's
// term by the V of the VAL it maps to. x is first moved off its surface along its geometric
// normal by `u_normal_offset` texel footprints (more at grazing angles), as ir_shadowed does.
//
// VISIBILITY_CSSM = 0: hard, binary test against the paraboloid map at the VAL centre (one
//   shadow map per cluster, as lightcuts-style clustered visibility).
// VISIBILITY_CSSM = 1: parabolic convolution soft shadow maps (paper Sec. 4.1, 4.2):
//   1. search kernel: the angle the VAL (size lambda) subtends from x, at least 2 texels;
//   2. average blocker depth z_avg = [w * (z f_b(d, z))] / [w * f_b(d, z)] from the MIP-mapped
//      basis and basis-z images (f_b = 1 - f: the blocker indicator); no blocker -> V = 1;
//   3. penumbra angle seen from the VAL centre: alpha = atan(lambda (d - z_avg) / (z_avg d));
//   4. F = [w * f(d, z)] with a box kernel of alpha, read as one trilinear MIP lookup, with
//      the CSM reconstruction f = 1/2 + 2 sum_k (cos(c_k d) [w*sin(c_k z)] - sin(c_k d) [w*cos(c_k z)]) / c_k,
//      and V = clamp(1 + s (F - 1/2), 0, 1): a receiver seeing its own surface (F = 1/2) is
//      lit; s = 2 is Annen et al.'s scaled expansion, the default s = 3 also cuts the
//      ringing and the ramp of the 4-term step (see the method's manual).
//   Kernel sizes turn into texture units with the paraboloid's local scale: the map is
//   conformal (a stereographic projection), 1 / (2 (1 + cos theta)) texture widths per radian.
//   Receivers behind the VAL's plane are outside the map: V = 1 (paper Sec. 5.1).
#include "val_records.glsl"
layout(local_size_x = 8, local_size_y = 8) in;
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_geo_normal;
uniform sampler2D u_depth_atlas;
uniform int u_tiles_x;
uniform int u_resolution;
uniform float u_normal_offset;
uniform ivec2 u_size;
layout(r32f, binding = 5) writeonly uniform image2DArray u_visibility;
layout(r32f, binding = 6) writeonly uniform image2D u_visible_share;
uniform sampler2D u_gbuffer_normal;
#if VISIBILITY_CSSM
uniform sampler2D u_basis_sin[TERM_GROUPS];   // atlases tiled as the depth atlas, MIP-mapped
uniform sampler2D u_basis_cos[TERM_GROUPS];
uniform sampler2D u_basis_zsin[TERM_GROUPS];  // half resolution: level L here is level L + 1
uniform sampler2D u_basis_zcos[TERM_GROUPS];
uniform sampler2D u_basis_z;
uniform vec2 u_atlas_size;
uniform float u_blocker_min;  // below this filtered blocker fraction: no blocker
uniform float u_csm_sharpening;  // slope s of the scaled reconstruction clamp(1 + s (F - 1/2))

// Normalised atlas coordinates of map coordinates `tex` in [0, 1]^2 of VAL j's tile for a
// trilinear lookup at full-resolution level `lod`: kept half a texel of the coarser level
// inside the tile, so that the filter never reads a neighbouring VAL's tile (the same
// coordinates serve the half-resolution atlases at level lod - 1).
vec2 atlas_coord(int j, vec2 tex, float lod) {
    float half_texel = 0.5 * exp2(min(ceil(lod), float(MAX_LOD))) / float(u_resolution);
    vec2 tile = vec2(j % u_tiles_x, j / u_tiles_x);
    return (tile + clamp(tex, vec2(half_texel), vec2(1.0 - half_texel))) * float(u_resolution) / u_atlas_size;
}

// Filtered CSM reconstruction at normalised receiver depth d: [w * f(d, z)], f the (unscaled)
// Fourier step, 1 for z > d, 0 for z < d.
float csm_filtered(vec2 at, float lod, float d) {
    float f = 0.0;
    for (int g = 0; g < TERM_GROUPS; ++g) {
        vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
        f += dot(cos(ck * d) / ck, textureLod(u_basis_sin[g], at, lod))
           - dot(sin(ck * d) / ck, textureLod(u_basis_cos[g], at, lod));
    }
    return 0.5 + 2.0 * f;
}

// The blocker search's [w * (z f(d, z))] and [w * z] at level lod >= 1.
vec2 csm_filtered_z(vec2 at, float lod, float d) {
    float zf = 0.0;
    for (int g = 0; g < TERM_GROUPS; ++g) {
        vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
        zf += dot(cos(ck * d) / ck, textureLod(u_basis_zsin[g], at, lod - 1.0))
            - dot(sin(ck * d) / ck, textureLod(u_basis_zcos[g], at, lod - 1.0));
    }
    float z = textureLod(u_basis_z, at, lod - 1.0).r;
    return vec2(0.5 * z + 2.0 * zf, z);
}

uniform float u_contact_band;  // normalised depth over which the sharpened CSM step falls from 1 to 0 (manual)
uniform float u_kernel_scale;  // MIP footprint per kernel width: 1 / sqrt(3) matches a box's variance (manual)

float kernel_lod(float angle, float texture_per_radian) {
    float texels = angle * texture_per_radian * float(u_resolution) * u_kernel_scale;
    return min(log2(max(texels, 1.0)), float(MAX_LOD));
}
#endif

#if CONTACT_TEST
// The unit direction (world) of texel tt's centre in a VAL's map with tangent frame (t, b, n).
vec3 texel_direction(ivec2 tt, vec3 t, vec3 b, vec3 n) {
    vec2 uc = (vec2(tt) + 0.5) / float(u_resolution) * 2.0 - 1.0;
    float uu = dot(uc, uc);
    vec3 dl = vec3(2.0 * uc, 1.0 - uu) / (1.0 + uu);
    return dl.x * t + dl.y * b + dl.z * n;
}

// The stored distance of texel tt of the map at atlas offset `tile` (MAP_EMPTY outside the map).
float map_distance(ivec2 tile, ivec2 tt) {
    if (any(lessThan(tt, ivec2(0))) || any(greaterThanEqual(tt, ivec2(u_resolution)))) return MAP_EMPTY;
    return texelFetch(u_depth_atlas, tile + tt, 0).r;
}

// The tangent from p0 (texel tt's point, distance `stored`) to the point of texel tt + step, and
// whether it lies on p0's surface: that texel and the next one beyond it continue p0's distance.
bool surface_tangent(ivec2 tile, ivec2 tt, ivec2 step, float stored, vec3 o, vec3 p0, vec3 t, vec3 b, vec3 nv,
                     out vec3 tangent) {
    float s1 = map_distance(tile, tt + step);
    float s2 = map_distance(tile, tt + 2 * step);
    float err = s2 >= 0.5 * MAP_EMPTY ? abs(s1 - stored) : abs(2.0 * s1 - s2 - stored);
    tangent = o + s1 * texel_direction(tt + step, t, b, nv) - p0;
    return s1 < 0.5 * MAP_EMPTY && err <= CONTACT_COPLANAR * stored;
}

// Whether the surface texel tt shows (its point p0 = o + stored d0) separates the map origin o
// from the receiver x. Its local plane is reconstructed from the stored points of the texels
// next to it: per map axis each side whose two texels continue p0's distance (second difference
// within CONTACT_COPLANAR of the distance: no depth discontinuity) gives a tangent, and each pair
// of tangents a candidate plane. Beside a crease a candidate is the chord across it, so the texel
// separates only if every candidate has o and x on opposite sides, x more than CONTACT_TOLERANCE
// of the stored distance beyond it: a receiver beside an inside corner lies in front of the
// adjacent wall's own plane, a receiver under a lip or behind a wall beyond every one. A texel
// without a continuing neighbour along an axis (a feature one texel wide) counts as separating.
// The first candidate with o and x on one side ends the test; a v side is fetched when needed.
bool contact_separates(ivec2 tile, ivec2 tt, float stored, vec3 o, vec3 x, vec3 t, vec3 b, vec3 nv) {
    vec3 p0 = o + stored * texel_direction(tt, t, b, nv);
    vec3 tv[2];
    bool valid_v[2];
    bool fetched_v[2] = bool[2](false, false);   // the v sides are fetched when first needed
    for (int i = 0; i < 2; ++i) {
        vec3 tu;
        if (!surface_tangent(tile, tt, ivec2(2 * i - 1, 0), stored, o, p0, t, b, nv, tu)) continue;
        for (int k = 0; k < 2; ++k) {
            if (!fetched_v[k]) {
                valid_v[k] = surface_tangent(tile, tt, ivec2(0, 2 * k - 1), stored, o, p0, t, b, nv, tv[k]);
                fetched_v[k] = true;
            }
            if (!valid_v[k]) continue;
            vec3 nb = cross(tu, tv[k]);
            float len = length(nb);
            if (len <= 0.0) continue;
            nb /= len;
            float side_o = dot(o - p0, nb);
            float side_x = dot(x - p0, nb);
            if (side_o * side_x >= 0.0 || abs(side_x) <= CONTACT_TOLERANCE * stored) return false;
        }
    }
    return true;
}

// The spot width (map texels) of the VAL on the surface texel tt shows if that surface is a contact
// blocker of the lifted receiver (distance d_world from o), else 0: its stored distance lies in
// front of the receiver's own plane (through x, normal n_geo; `plane` = (x - o) . n_geo) along the
// texel's own direction by more than CONTACT_TOLERANCE of that distance, less than `band` in front
// of the lifted receiver, and its surface separates o from x (contact_separates). The map stores
// each texel's exact distance along its centre direction, so a texel showing the receiver's own
// plane compares equal whatever the slope: no depth bias is needed, and a blocker millimetres in
// front of the receiver (a zero-thickness wall at a junction, a lip over a slot) is found where the
// CSM step's ramp or a one-texel bias lets it through. The VAL (size lambda) seen from x through a
// blocker delta = d_world - stored in front of it spans lambda delta / d_world there, seen from o
// (at `stored`) spot_scale delta / stored texels, spot_scale = lambda / (d_world x texel angle);
// at least one texel (the bilinear footprint: the map resolves nothing finer).
float contact_spot(ivec2 tile, ivec2 tt, vec3 o, vec3 x, vec3 n_geo, float plane, vec3 t, vec3 b, vec3 nv,
                   float d_world, float band, float spot_scale) {
    float stored = texelFetch(u_depth_atlas, tile + tt, 0).r;
    if (stored >= d_world || d_world - stored >= band) return 0.0;
    float den = dot(texel_direction(tt, t, b, nv), n_geo);
    float t_own = plane / den;                                        // its distance to x's plane
    if (den != 0.0 && t_own > 0.0 && stored >= t_own * (1.0 - CONTACT_TOLERANCE)) return 0.0;
    if (!contact_separates(tile, tt, stored, o, x, t, b, nv)) return 0.0;
    return max(1.0, spot_scale * (d_world - stored) / stored);
}

// The share of texel cell tt (texel centres at integer coordinates of s) inside the square of
// side w centred at s.
float cell_overlap(vec2 s, vec2 tt, float w) {
    vec2 e = clamp(min(tt + 0.5, s + 0.5 * w) - max(tt - 0.5, s - 0.5 * w), 0.0, 1.0);
    return e.x * e.y;
}

// Contact blockers (see the method's manual): the share of the VAL that the contact blockers
// around map coordinates uv (the lifted receiver's direction) hide from the receiver. Each
// blocking texel k (contact_spot) hides the part of the VAL's spot on it (a square of side W_k
// texels centred on the receiver's direction) that its cell covers, cell / W_k^2 of the VAL:
// b = sum_k overlap(cell_k, spot_k) / W_k^2. For W_k = 1 (a point VAL, or a blocker within the
// hard-shadow limit) that is the bilinear weight of the 2 x 2 footprint; a blocker as wide as the
// spot hides the whole VAL whatever its size. The test runs where one of the bilinear 2 x 2
// texels blocks; then the window holding the widest of their spots (at most CONTACT_SPOT_TEXELS
// texels wide: wider spots are counted inside it only, the rest left to the CSSM) is read.
float contact_blocked(int j, Val c, vec3 o, vec3 x, vec3 n_geo, vec2 uv, float d_world, float band, float texel, float lambda) {
    vec3 t, b;
    orthonormal_basis(c.normal.xyz, t, b);
    ivec2 tile = ivec2(j % u_tiles_x, j / u_tiles_x) * u_resolution;
    vec2 s = (uv * 0.5 + 0.5) * float(u_resolution) - 0.5;
    vec2 i0 = floor(s);
    float plane = dot(x - o, n_geo);
    float spot_scale = lambda * length(x - o) / (texel * d_world);   // texel / |x - o|: the texel angle
    float spots[4];
    float widest = 0.0;
    for (int k = 0; k < 4; ++k) {
        ivec2 tt = clamp(ivec2(i0) + ivec2(k & 1, k >> 1), ivec2(0), ivec2(u_resolution - 1));
        spots[k] = contact_spot(tile, tt, o, x, n_geo, plane, t, b, c.normal.xyz, d_world, band, spot_scale);
        widest = max(widest, spots[k]);
    }
    if (widest <= 1.0) {   // no blocker (0), or every spot within one texel: the bilinear weights
        vec2 fr = s - i0;
        return (spots[0] > 0.0 ? (1.0 - fr.x) * (1.0 - fr.y) : 0.0) + (spots[1] > 0.0 ? fr.x * (1.0 - fr.y) : 0.0)
             + (spots[2] > 0.0 ? (1.0 - fr.x) * fr.y : 0.0) + (spots[3] > 0.0 ? fr.x * fr.y : 0.0);
    }
    float h = 0.5 * min(widest, float(CONTACT_SPOT_TEXELS));
    ivec2 lo = ivec2(ceil(s - 0.5 - h)), hi = ivec2(floor(s + 0.5 + h));
    float blocked = 0.0;
    for (int v = lo.y; v <= hi.y; ++v) {
        for (int u = lo.x; u <= hi.x; ++u) {
            ivec2 tt = clamp(ivec2(u, v), ivec2(0), ivec2(u_resolution - 1));   // the edge texel beyond the map
            float w = contact_spot(tile, tt, o, x, n_geo, plane, t, b, c.normal.xyz, d_world, band, spot_scale);
            if (w > 0.0) blocked += cell_overlap(s, vec2(u, v), w) / (w * w);
        }
    }
    return blocked;
}
#endif

float val_visibility(int j, vec3 x, vec3 n_geo) {
    Val c = vals[j];
    if (c.position.w <= 0.0) return 1.0;  // empty VAL: no VPL maps to it
    vec3 o = val_origin(c);
    vec3 to_val = o - x;
    float dist = length(to_val);
    if (dist <= 0.0) return 1.0;
    vec3 wi = to_val / dist;
    float cos0;
    paraboloid_uv(c, -to_val, cos0);
#if BEHIND_HORIZON == 0
    if (cos0 <= 0.0) return 1.0;
#endif
    // texel footprint at x: 2 / res uv units, (1 + cos theta) radians per uv unit
    float texel = dist * 2.0 * (1.0 + max(cos0, 0.0)) / float(u_resolution);
    vec3 n = dot(n_geo, wi) < 0.0 ? -n_geo : n_geo;
    float cos_r = clamp(dot(n, wi), 0.0, 1.0);
    float sin_r = sqrt(max(1.0 - cos_r * cos_r, 0.0));
    vec3 q = x + n * (u_normal_offset * texel * (0.5 + 1.5 * sin_r));
    vec3 rel = q - o;
    float d_world = length(rel);
    float cos_theta;
    vec2 uv = paraboloid_uv(c, rel, cos_theta);
    bool in_map = cos_theta > 0.0;  // in front of the VAL's plane (else the horizon texel, or visible)
    if (!in_map) {
#if BEHIND_HORIZON
        // behind the VAL's plane (no map there): the map's horizon in the receiver's azimuth
        // holds the receiver's distance or not (see the manual); straight below: visible
        vec3 h = rel - c.normal.xyz * dot(rel, c.normal.xyz);
        if (dot(h, h) <= 1e-12 * d_world * d_world) return 1.0;
        uv = paraboloid_uv(c, h + c.normal.xyz * (1e-3 * length(h)), cos_theta);
#else
        return 1.0;
#endif
    }
#if VISIBILITY_CSSM
    float far = c.flux.w / CSM_DEPTH_RANGE;   // normalised depths span [0, CSM_DEPTH_RANGE] (see cssm_basis.glsl)
#if CONTACT_TEST
    float contact = in_map ? contact_blocked(j, c, o, x, n_geo, uv, d_world, u_contact_band * far, texel, c.normal.w) : 0.0;
    if (contact >= 1.0) return 0.0;
#else
    float contact = 0.0;
#endif
    float d = min(d_world / far, CSM_DEPTH_RANGE);
    float lambda = c.normal.w;
    vec2 tex = uv * 0.5 + 0.5;
    float per_radian = 0.5 / (1.0 + cos_theta);
    float search = 2.0 * atan(0.5 * lambda, d_world);
    float search_lod = max(kernel_lod(search, per_radian), 1.0);  // the basis-z starts at level 1
    vec2 search_at = atlas_coord(j, tex, search_lod);
    float blocked = 1.0 - csm_filtered(search_at, search_lod, d);  // [w * f_b]
    if (blocked < u_blocker_min) return 1.0 - contact;
    vec2 zfz = csm_filtered_z(search_at, search_lod, d);
    float z_avg = clamp((zfz.y - zfz.x) / blocked, 1e-6, d);     // [w * z f_b] / [w * f_b]
    float z_avg_world = z_avg * far;
    float alpha = atan(lambda * (d_world - z_avg_world), z_avg_world * d_world);
    float lod = kernel_lod(alpha, per_radian);
    float rec = csm_filtered(atlas_coord(j, tex, lod), lod, d);
    return clamp(1.0 + u_csm_sharpening * (rec - 0.5), 0.0, 1.0) * (1.0 - contact);
#else
    ivec2 tile = ivec2(j % u_tiles_x, j / u_tiles_x);
    ivec2 t = clamp(ivec2((uv * 0.5 + 0.5) * float(u_resolution)), ivec2(0), ivec2(u_resolution - 1));
    float stored = texelFetch(u_depth_atlas, tile * u_resolution + t, 0).r;
#if CONTACT_TEST
    if (in_map && contact_blocked(j, c, o, x, n_geo, uv, d_world, texel, texel, 0.0) >= 0.5) return 0.0;
#endif
    return d_world <= stored + texel ? 1.0 : 0.0;
#endif
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    if (px.x >= u_size.x || px.y >= u_size.y) return;
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    vec3 ng = texelFetch(u_gbuffer_geo_normal, px, 0).xyz;
    vec3 ns = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec2 share = vec2(0.0);   // VAL-level (visible, unshadowed) transfer: the blur's visibility guide
    for (int j = 0; j < u_cluster_count; ++j) {
        float v = p.w == 0.0 ? 0.0 : val_visibility(j, p.xyz, ng);
        imageStore(u_visibility, ivec3(px, j), vec4(v));
        Val c = vals[j];
        if (p.w == 0.0 || c.position.w <= 0.0) continue;
        vec3 d = c.position.xyz - p.xyz;
        float d2 = dot(d, d);
        if (d2 <= 0.0) continue;
        vec3 w = d * inversesqrt(d2);
        float u = flux_luminance(c.flux.rgb) * max(dot(ns, w), 0.0) * max(-dot(c.normal.xyz, w), 0.0)
                / max(d2, c.normal.w * c.normal.w * INV_PI);
        share += vec2(u * v, u);
    }
    imageStore(u_visible_share, px, vec4(share.y > 0.0 ? share.x / share.y : 1.0));
}
