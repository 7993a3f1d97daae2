// The near field of a point emitter standing for a surface area A (a VPL, a surfel): how its
// 1/d^2 is bounded close to a receiver at distance d (bench.gl.near_field.NEAR_FIELDS). Returns
// the squared distance the transfer divides by, at least eps^2:
//   NEAR_FIELD 0, clamp:        max(eps, d)^2       (eps relative to the scene radius)
//   NEAR_FIELD 1, disc_element: d^2 + A / pi        (the form factor of a disc of area A facing the
//                                                    receiver: Bunnell 2005, FLC's disc element)
//   NEAR_FIELD 2, footprint:    max(d^2, s A / pi)  (a clamp at the radius of s times the emitter's
//                                                    own area: the transfer never exceeds 1/s times
//                                                    the exitance of the surface it samples;
//                                                    s = NEAR_FIELD_SCALE)
#ifndef NEAR_FIELD_GLSL
#define NEAR_FIELD_GLSL
#ifndef NEAR_FIELD
#define NEAR_FIELD 0
#endif
#ifndef NEAR_FIELD_SCALE
#define NEAR_FIELD_SCALE 1.0
#endif
float near_field_d2(float dist, float area, float eps) {
#if NEAR_FIELD == 1
    return max(eps * eps, dist * dist + area * INV_PI);
#elif NEAR_FIELD == 2
    return max(eps * eps, max(dist * dist, NEAR_FIELD_SCALE * area * INV_PI));
#else
    float dc = max(eps, dist);
    return dc * dc;
#endif
}
#endif
