"""The near field of point emitters that stand for surface areas (VPLs, surfels): one bound of
their 1/d^2 for every method that sums them (shaders/near_field.glsl, `near_field_d2`).

A method declares the parameters `near_field` (one of NEAR_FIELDS) and `near_field_scale`, with
the docs, defaults and range below, and compiles its programs with `near_field_defines(...)`.
"""
from __future__ import annotations

NEAR_FIELDS = ("clamp", "disc_element", "footprint")
NEAR_FIELD_DOC = ("how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands "
                  "for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint "
                  "max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2")
NEAR_SCALE_DOC = "s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for"
NEAR_FIELD_DEFAULT = "footprint"   # chosen over the corpus (studies/vpl_near_field.py; the methods' NOTES.md)
NEAR_SCALE_DEFAULT = 1.0
NEAR_SCALE_RANGE = (1e-3, 100.0)


def near_field_defines(near_field: str, scale: float) -> dict:
    """The defines of near_field.glsl for a method's `near_field` and `near_field_scale` parameters."""
    return {"NEAR_FIELD": NEAR_FIELDS.index(near_field), "NEAR_FIELD_SCALE": float(scale)}
