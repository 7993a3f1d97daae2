"""The words every part of gibench shares, each defined once: image and reference components,
which reference judges which image, metric names, row statuses and row identity.

Pure constants and small functions, no imports beyond the standard library: the runner, the
references (`reference/`), the analysis, the gate, the stress suite and the report all read
them from here.
"""
from __future__ import annotations

import json
import math

# ---------------------------------------------------------------------------- images
# What a method renders (each row's images/<scene>/<view>/<method>/<component>.exr).
IMAGE_COMPONENTS = ("direct", "indirect", "combined")
# What Mitsuba renders for a view (references/<scene>/<view>/<component>.exr, + _variance.exr).
REFERENCE_COMPONENTS = ("direct", "indirect_unshadowed", "indirect_visible")
# Error-column component -> (the method image it scores, the reference components summed to judge it).
COMPARISONS = {
    "direct": ("direct", ("direct",)),
    "indirect": ("indirect", ("indirect_unshadowed",)),
    "indirect_visible": ("indirect", ("indirect_visible",)),
    "combined": ("combined", ("direct", "indirect_visible")),
}
ERROR_COMPONENTS = tuple(COMPARISONS)
# The reference component(s) of each error component, and which image a reference component judges.
REFERENCE_PARTS = {component: parts for component, (_, parts) in COMPARISONS.items()}
JUDGES = {"direct": "direct", "indirect_unshadowed": "indirect", "indirect_visible": "indirect"}
# The convergence curve (reference_curves.json) an error component's time-to-error reads.
CURVE_COMPONENTS = {"direct": "direct", "indirect": "indirect_unshadowed", "indirect_visible": "indirect_visible",
                    "combined": "combined"}

# The error frames (bench.run.harness): K more frames of a row, rendered by a fresh instance
# outside every timed region; per component the per-pixel mean, variance and flicker over them,
# written beside the row's images as `<component>_frames_<statistic>.exr`.
FRAME_STAT_COMPONENTS = ("indirect", "combined")
FRAME_STATISTICS = ("mean", "var", "flicker")


def frame_stat_image(component: str, statistic: str) -> str:
    """The image name (file stem) of one statistic of a component over the error frames."""
    return f"{component}_frames_{statistic}"


FRAME_STAT_IMAGES = tuple(frame_stat_image(c, s) for c in FRAME_STAT_COMPONENTS for s in FRAME_STATISTICS)
# The error components the frame statistics judge: those whose method image has statistics.
DECOMPOSITION_COMPONENTS = tuple(c for c, (image, _) in COMPARISONS.items() if image in FRAME_STAT_COMPONENTS)

# ---------------------------------------------------------------------------- timing
# The stages of the shared passes every method of a view reads (bench.gl.passes renders them):
# tables put them first, in this order.
SHARED_STAGES = ("gbuffer_shadow", "direct_light", "rsm")

# ---------------------------------------------------------------------------- metrics
# Error metrics, in the order tables show them (bench.analysis.metrics.METRICS documents each);
# `mean_ratio` is a bias figure (image mean / reference mean: best is closest to 1, not lowest).
ERROR_METRICS = ("mse", "relmse", "smape", "dssim", "flip_mean", "flip_median", "ciede2000")
BIAS_METRICS = ("mean_ratio",)
METRIC_NAMES = ERROR_METRICS + BIAS_METRICS
# The error over frames (bench.analysis.evaluation documents each; components DECOMPOSITION_COMPONENTS,
# rows rendered with more than one error frame): lower is better, each with a 95% interval over
# pixels in `<metric>_ci.<component>`.
DECOMPOSITION_METRICS = ("mse_accumulated", "variance", "bias2", "flicker",
                         "rel_mse_accumulated", "rel_variance", "rel_bias2", "rel_flicker")
INTERVAL_SUFFIX = "_ci"


def metric_column(metric: str, component: str) -> str:
    return f"{metric}.{component}"


def interval_column(metric: str, component: str) -> str:
    """The column of a decomposition metric's 95% interval (half-width) over pixels."""
    return f"{metric}{INTERVAL_SUFFIX}.{component}"


def error_metric_names() -> tuple:
    """Every "lower is better" error metric a row can carry: the single-frame ones (ERROR_METRICS)
    and the error over frames (DECOMPOSITION_METRICS), for the gate and the tables."""
    return ERROR_METRICS + DECOMPOSITION_METRICS


# ---------------------------------------------------------------------------- row statuses
class Status:
    """A row's status column: "ok" (rendered in this run), "cached" (taken from the row cache),
    "skipped: <reason>" (the method declines the scene) or "failed: <reason>" (an error)."""
    OK = "ok"
    CACHED = "cached"
    SKIPPED = "skipped"
    FAILED = "failed"
    WITH_IMAGES = (OK, CACHED)            # rows that have images and measurements
    FINISHED = (OK, CACHED, SKIPPED)      # rows a resumed run does not redo
    MEASURED = (OK,)                      # rows whose timing was measured in that run

    @staticmethod
    def kind(status) -> str:
        """"ok", "cached", "skipped", "failed" (or "" for a missing status) of a status string."""
        if status is None or (isinstance(status, float) and math.isnan(status)):
            return ""
        return str(status).split(":", 1)[0].strip()

    @staticmethod
    def failed(reason: str) -> str:
        return f"{Status.FAILED}: {reason}"

    @staticmethod
    def skipped(reason: str) -> str:
        return f"{Status.SKIPPED}: {reason}"

    @classmethod
    def has_images(cls, status) -> bool:
        return cls.kind(status) in cls.WITH_IMAGES

    @classmethod
    def is_failed(cls, status) -> bool:
        return cls.kind(status) == cls.FAILED


def failure_reason(exc: BaseException) -> str:
    """The one-line reason a failed row records for an exception: its message's first line, or its type."""
    text = str(exc)
    return text.splitlines()[0] if text.strip() else type(exc).__name__


# ---------------------------------------------------------------------------- row identity
def canonical_params(value) -> str:
    """Parameters as compact sorted JSON (a dict, a JSON string, or missing: "{}")."""
    if isinstance(value, str):
        try:
            return json.dumps(json.loads(value), sort_keys=True, separators=(",", ":"))
        except json.JSONDecodeError:
            return value
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    return "{}" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


def _whole(value):
    try:
        f = float(value)
        return int(f) if math.isfinite(f) else str(value)
    except (TypeError, ValueError):
        return str(value)


def row_identity(row: dict) -> tuple:
    """(scene, view, method, params, seed, width, height): what makes two result rows the same row
    (a re-run into a run folder replaces it; the gate matches baseline and candidate rows on it)."""
    return (str(row.get("scene")), str(row.get("view")), str(row.get("method")), canonical_params(row.get("params")),
            _whole(row.get("seed")), _whole(row.get("width")), _whole(row.get("height")))
