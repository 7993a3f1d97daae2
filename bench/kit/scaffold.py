"""`gibench new-method NAME --dir PATH`: a ready plugin package, copied from `template/`.

The template is a working method (bench/kit/template/method.py: the one-bounce ambient term)
whose name and class are the placeholders `__method_name__` and `__MethodClass__`; the copy
replaces them and fills the parameter tables of its manual and README from its declarations
(bench.protocol.manual), so the new package passes `gibench manuals` and `gibench check-method`
as written. Layout of the package written:

    PATH/pyproject.toml              the entry point in `gibench.methods`
    PATH/NAME/__init__.py
    PATH/NAME/method.py              the method; its docstring is the manual
    PATH/NAME/shaders/*.glsl         its GL programs (one file per program)
    PATH/NAME/README.md              the parameter table again
    PATH/tests/test_NAME.py          the conformance suite and the method's own claim
"""
from __future__ import annotations

import importlib.util
import keyword
import re
from pathlib import Path

from bench.protocol import manual
from bench.protocol.registry import list_methods

TEMPLATE_DIR = Path(__file__).parent / "template"
NAME_TOKEN, CLASS_TOKEN = "__method_name__", "__MethodClass__"
# A method name is its entry point, its Python package and its folders in run folders: lower-case
# letters, digits and _, starting with a letter (a Python identifier and a safe path name).
METHOD_NAME = re.compile(r"[a-z][a-z0-9_]{0,62}")
# template file -> where the package keeps it (NAME: the method's name)
FILES = {"pyproject.toml": "pyproject.toml", "__init__.py": "NAME/__init__.py", "method.py": "NAME/method.py",
         "README.md": "NAME/README.md", "shaders/flux_sum.glsl": "NAME/shaders/flux_sum.glsl",
         "shaders/ambient.glsl": "NAME/shaders/ambient.glsl", "plugin_tests.py": "tests/test_NAME.py"}


def class_name(name: str) -> str:
    """The method class's name: the method's name in CamelCase (`my_gi` -> `MyGi`)."""
    return "".join(part[:1].upper() + part[1:] for part in name.split("_") if part) or "Method"


def check_new_name(name: str) -> str:
    """`name` if a new method may take it, else ValueError (one line saying why)."""
    if not isinstance(name, str) or not METHOD_NAME.fullmatch(name):
        raise ValueError(f"method name {name!r} is not allowed: use 1-63 lower-case letters, digits and _, "
                         f"starting with a letter (it is the entry point and the Python package)")
    if keyword.iskeyword(name):
        raise ValueError(f"method name {name!r} is a Python keyword")
    if name in list_methods():
        raise ValueError(f"method name {name!r} is already registered (gibench list methods)")
    if importlib.util.find_spec(name) is not None:
        raise ValueError(f"method name {name!r} is already an importable Python module; choose another")
    return name


def template_text(relative: str, name: str) -> str:
    """One template file with the placeholders replaced and the parameter tables filled."""
    from bench.kit.template.method import __MethodClass__ as template_cls
    text = (TEMPLATE_DIR / relative).read_text()
    if relative in ("method.py", "README.md"):
        text = text.replace(f"{manual.BEGIN}\n{manual.END}", manual.param_table(template_cls))
    return text.replace(CLASS_TOKEN, class_name(name)).replace(NAME_TOKEN, name)


def write_package(name: str, directory: Path) -> list[Path]:
    """Write the plugin package of method `name` into `directory` (absent or empty); the files written."""
    check_new_name(name)
    directory = Path(directory)
    if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
        raise ValueError(f"{directory} exists and is not an empty folder; give a new --dir")
    written = []
    for relative, target in FILES.items():
        path = directory / target.replace("NAME", name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(template_text(relative, name))
        written.append(path)
    return written
