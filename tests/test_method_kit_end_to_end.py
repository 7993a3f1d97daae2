"""Issue #28's path for a method author, end to end, in subprocesses, with the package outside
the tree: `gibench new-method mymethod --dir X`, `pip install -e X` (into a throw-away venv that
sees this interpreter's packages, offline), `gibench check-method mymethod`, the package's own
tests, and `gibench run --methods direct,mymethod`. Everything it makes is removed at the end;
this interpreter's environment never sees the plugin."""
from __future__ import annotations

import csv
import importlib.util
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NAME = "mymethod"


def _run(argv, env, cwd=None, timeout=300) -> str:
    done = subprocess.run([str(a) for a in argv], env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        command = " ".join(map(str, argv))
        pytest.fail(f"{command} exited {done.returncode}:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return done.stdout


def _builds_editable_without_isolation() -> bool:
    """setuptools builds an editable wheel by itself from 70.1; before, it needs `wheel`."""
    import setuptools
    major, minor = (int(p) for p in setuptools.__version__.split(".")[:2])
    return (major, minor) >= (70, 1) or importlib.util.find_spec("wheel") is not None


def test_new_method_install_check_and_run_outside_the_tree(tmp_path):
    work = tmp_path / "author"
    package, venv, run_dir = work / "x", work / "venv", work / "run"
    env = dict(os.environ, GIBENCH_CACHE_DIR=str(work / "cache"),
               PYTHONPATH=os.pathsep.join([str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep)
                                                         if p]))
    try:
        out = _run([sys.executable, "-m", "bench.cli", "new-method", NAME, "--dir", package], env)
        assert f"wrote {package / NAME / 'method.py'}" in out
        # a venv of its own that also sees this interpreter's packages (gibench, numpy, moderngl, ...)
        _run([sys.executable, "-m", "venv", "--without-pip", venv], env)
        python = venv / "bin" / "python"
        purelib = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], env).strip())
        (purelib / "gibench_env.pth").write_text(
            "".join(f"import site; site.addsitedir({p!r})\n" for p in site.getsitepackages()))
        isolation = ["--no-build-isolation"] if _builds_editable_without_isolation() else []
        _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-input", *isolation,
              "-e", package], env)

        assert f"{NAME} " in _run([python, "-m", "bench.cli", "list", "methods"], env)
        checked = _run([python, "-m", "bench.cli", "check-method", NAME], env)
        assert checked.splitlines()[-1] == f"{NAME}: 11 of 11 checks passed", checked
        _run([python, "-m", "pytest", "-q", "-p", "no:cacheprovider", package / "tests"], env, cwd=package)
        _run([python, "-m", "bench.cli", "run", "--methods", f"direct,{NAME}", "--scenes", "cornell_spot",
              "--res", "32x24", "--frames", "1", "--timing-budget", "0", "--error-frames", "2", "--no-reference",
              "--no-progress", "--out", run_dir], env)
        with open(run_dir / "results.csv") as fh:
            rows = [(r["method"], r["params"], r["status"]) for r in csv.DictReader(fh)]
        assert rows == [("direct", "{}", "ok"), (NAME, '{"flux_stride":4}', "ok"), (NAME, '{"flux_stride":2}', "ok"),
                        (NAME, '{"flux_stride":1}', "ok")], rows
    finally:
        shutil.rmtree(work, ignore_errors=True)
    # the plugin was installed into the throw-away venv only
    assert f"{NAME} " not in _run([sys.executable, "-m", "bench.cli", "list", "methods"], env)
