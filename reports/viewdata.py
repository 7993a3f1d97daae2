"""The comparison viewer's data of one scene view: the reference and method images per
component as base64 float16 (identical images stored once), the shared error-map scales and
the initial exposure. `write_view_script` writes it as `data/view_<i>.js`, loaded by
<script src> (browsers block fetch() of local files); static/viewer.js tone-maps it.

Error maps are |L_method - L_ref| of the luminance (or relative to L_ref + eps) on one scale per
view and component: the largest 99th percentile over the methods, so every map of that view
shares its colour bar.
"""
from __future__ import annotations

import base64
import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd

from bench.model.imageio import read_exr
from bench.protocol.vocabulary import IMAGE_COMPONENTS, REFERENCE_COMPONENTS

LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def _half_b64(img: np.ndarray) -> str:
    a = np.nan_to_num(np.asarray(img, dtype=np.float32)[..., :3], nan=0.0, posinf=65504.0, neginf=-65504.0)
    return base64.b64encode(np.clip(a, -65504.0, 65504.0).astype("<f2").tobytes()).decode("ascii")


def _luminance(img: np.ndarray) -> np.ndarray:
    return np.asarray(img, dtype=np.float32)[..., :3] @ LUMINANCE


def error_scales(reference: np.ndarray, images: list[np.ndarray]) -> tuple[dict, float]:
    """Shared scales ({"abs", "rel"}: the largest 99th percentile over the non-zero `images` of the
    luminance error over covered pixels) and the eps of the relative error (1% of the mean reference luminance)."""
    ref_l = _luminance(reference)
    covered_ref = np.abs(ref_l) > 0
    mean_ref = float(np.abs(ref_l[covered_ref]).mean()) if covered_ref.any() else 0.0
    eps = 0.01 * mean_ref if mean_ref > 0 else 1e-6
    abs_scale = rel_scale = 0.0
    # a method that outputs nothing for this component (e.g. `direct`'s indirect) would set the
    # scale to the reference itself and flatten every other map: it saturates instead
    nonzero = [img for img in images if np.any(np.asarray(img)[..., :3] != 0)]
    for img in nonzero or images:
        lum = _luminance(img)
        covered = covered_ref | (np.abs(lum) > 0)
        if not covered.any():
            continue
        err = np.abs(lum - ref_l)[covered]
        abs_scale = max(abs_scale, float(np.percentile(err, 99)))
        rel_scale = max(rel_scale, float(np.percentile(err / (np.abs(ref_l[covered]) + eps), 99)))
    return {"abs": abs_scale, "rel": rel_scale}, eps


def _auto_ev(img: np.ndarray) -> float:
    lum = _luminance(img)
    lum = lum[lum > 0]
    if lum.size == 0:
        return 0.0
    p = float(np.percentile(lum, 99.5))
    return float(np.clip(round(-np.log2(p) * 10) / 10, -10, 10)) if p > 0 else 0.0


def _read_image(path: Path, shape) -> np.ndarray | None:
    if not path.is_file():
        return None
    img = read_exr(path)[..., :3]
    if shape is not None and img.shape[:2] != tuple(shape):
        raise ValueError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, the run's rows are {shape[1]}x{shape[0]}")
    return img


def view_data(run_dir: Path, rows: pd.DataFrame) -> dict:
    """The viewer's data of one scene view: reference and method images per component."""
    first = rows.iloc[0]
    shape = (int(first["height"]), int(first["width"]))
    ref_dir = run_dir / "references" / str(first["scene"]) / str(first["view"])
    refs = {c: _read_image(ref_dir / f"{c}.exr", shape) for c in REFERENCE_COMPONENTS}
    methods = []
    for i, rec in enumerate(rows.to_dict("records")):
        image_dir = run_dir / str(rec.get("image_dir", ""))
        imgs = {c: _read_image(image_dir / f"{c}.exr", shape) for c in IMAGE_COMPONENTS}
        if any(v is not None for v in imgs.values()):
            methods.append((f"m{i}", rec["label"], imgs))
    ref_combined = (refs["direct"] + refs["indirect_visible"]
                    if refs["direct"] is not None and refs["indirect_visible"] is not None else None)
    component_refs = {
        "combined": [("ref", "Mitsuba reference", ref_combined)],
        "indirect": [("ref_unshadowed", "Mitsuba, no indirect visibility", refs["indirect_unshadowed"]),
                     ("ref_visible", "Mitsuba, with indirect visibility", refs["indirect_visible"])],
        "direct": [("ref", "Mitsuba reference", refs["direct"])],
    }
    labels = {"combined": "Combined", "indirect": "Indirect", "direct": "Direct"}
    blobs: dict[str, str] = {}

    def blob(img) -> str:
        """Identical images (every method's shared direct pass) are stored once."""
        data = _half_b64(img)
        key = hashlib.sha1(data.encode("ascii")).hexdigest()[:12]
        blobs.setdefault(key, data)
        return key

    components = {}
    for comp, ref_list in component_refs.items():
        sources = [{"id": rid, "label": label, "kind": "reference", "blob": blob(img)}
                   for rid, label, img in ref_list if img is not None]
        method_imgs = [(mid, label, imgs[comp]) for mid, label, imgs in methods if imgs.get(comp) is not None]
        sources += [{"id": mid, "label": label, "kind": "method", "blob": blob(img)}
                    for mid, label, img in method_imgs]
        if not sources:
            continue
        reference = next(((rid, img) for rid, _, img in ref_list if img is not None), None)
        entry = {"label": labels[comp], "sources": sources, "reference": None, "eps": 1e-6,
                 "scale": {"abs": 0.0, "rel": 0.0}}
        if reference is not None:
            scale, eps = error_scales(reference[1], [img for _, _, img in method_imgs])
            entry.update(reference=reference[0], eps=eps, scale=scale)
        components[comp] = entry
    exposure_source = ref_combined if ref_combined is not None else next(
        (imgs["combined"] for _, _, imgs in methods if imgs.get("combined") is not None), None)
    return {"scene": str(first["scene"]), "view": str(first["view"]), "width": shape[1], "height": shape[0],
            "auto_ev": _auto_ev(exposure_source) if exposure_source is not None else 0.0,
            "default_component": "combined", "components": components, "blobs": blobs}


def write_view_script(path: Path, key: str, data: dict) -> None:
    """`data/view_<i>.js`: registers the view's data as GIBENCH.views[key]."""
    path.write_text("window.GIBENCH = window.GIBENCH || {}; GIBENCH.views = GIBENCH.views || {};\n"
                    f"GIBENCH.views[{json.dumps(key)}] = {json.dumps(data, separators=(',', ':'))};\n")
