// Bunnell's disk-to-point transfer (GPU Gems 2 ch. 14, as the article) from one emitter disk
// to one receiver texel, added to the irradiance of the receiver's side facing the emitter:
//     E(r) += B_e  a_e |cos_e| |cos_r| / (pi d^2 + a_leaf),
// B_e the radiosity of the emitter's side facing r. For a texel a_leaf = a_e. A node of the
// hierarchy (transfer_node) replaces B_e a_e |cos_e| by the power its leaves send towards r
// (pbgi_records.glsl: exact for a flat node, and for any node whose leaves all face r on the
// same side) and keeps its leaves' area-weighted mean area as a_leaf, so it adds what its
// texels would (a disk of the summed area would saturate early in pi d^2 + a).
#ifndef PBGI_TRANSFER_GLSL
#define PBGI_TRANSFER_GLSL
void transfer(Surfel e, float a_leaf, vec3 xr, vec3 nr, inout vec3 front, inout vec3 back) {
    vec3 v = xr - e.position_area.xyz;   // emitter -> receiver
    float d2 = dot(v, v);
    if (d2 <= 0.0) return;                   // the receiver's own surfel
    vec3 w = v * inversesqrt(d2);
    float cos_e = dot(e.normal.xyz, w);
    float cos_r = -dot(nr, w);
    float t = e.position_area.w * abs(cos_e) * abs(cos_r) / (PI * d2 + a_leaf);
    vec3 b = cos_e > 0.0 ? e.radiosity_front.rgb : e.radiosity_back.rgb;
    if (cos_r > 0.0) front += b * t; else back += b * t;
}

void transfer_node(EmitterNode e, vec3 xr, vec3 nr, inout vec3 front, inout vec3 back) {
    vec3 v = xr - e.position_area.xyz;
    float d2 = dot(v, v);
    if (d2 <= 0.0) return;
    vec3 w = v * inversesqrt(d2);
    float cos_r = -dot(nr, w);
    vec3 power;
    for (int c = 0; c < 3; ++c)
        power[c] = max(dot(w, e.flux_odd[c].xyz) + abs(dot(w, e.flux_even[c].xyz)), 0.0);
    vec3 t = power * (abs(cos_r) / (PI * d2 + e.shape.x));
    if (cos_r > 0.0) front += t; else back += t;
}
#endif
