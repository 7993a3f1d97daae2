"""The report's rendering layer: the Jinja2 environment over this package's `templates/`
(autoescape on), the number format every table shows (`fmt`, also a template filter) and the
page writer. Python modules of the report hand plain values to the templates; the markup lives
in the templates, one per section, and their shared macros in `templates/macros.html`."""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np
from jinja2 import Environment, PackageLoader, StrictUndefined
from markupsafe import Markup

from bench.protocol import results as store

MISSING = "\u2014"


def fmt(v, digits: int = 3) -> str:
    """A number with `digits` significant digits; missing or non-finite values are an em dash."""
    if v is None:
        return MISSING
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,d}"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if not np.isfinite(f):
        return MISSING
    if 10 ** digits <= abs(f) < 1e9:  # large times read better as 28,800 than 2.88e+04
        return f"{f:,.0f}"
    return f"{f:.{digits}g}"


def _escape(value) -> Markup:
    """Every `{{ value }}` is escaped as html.escape(quote=True) does (an apostrophe is &#x27;, as the
    report has always written it; markupsafe would write &#39;); macro output (Markup) passes as is."""
    if hasattr(value, "__html__"):
        return value
    return Markup(html.escape(str(value), quote=True))


ENVIRONMENT = Environment(loader=PackageLoader(__package__, "templates"), autoescape=True, finalize=_escape,
                          undefined=StrictUndefined, trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
ENVIRONMENT.filters["fmt"] = fmt
ENVIRONMENT.globals["MISSING"] = MISSING


def write_page(path: Path, template: str, **context) -> Path:
    """Render `template` with `context` into `path` (written atomically)."""
    store.atomic_write_text(path, ENVIRONMENT.get_template(template).render(**context))
    return path
