"""The method author's kit: what a GI method outside gibench's tree needs to join a benchmark.

* `scaffold` writes a ready plugin package (`gibench new-method NAME --dir PATH`): pyproject with
  the `gibench.methods` entry point, `method.py` whose docstring is the manual, its GLSL
  programs, a README with the parameter table, a test file. The files come from `template/`, a
  working method (the one-bounce ambient term) whose names are placeholders.
* `conformance` is the suite every method must pass (`gibench check-method NAME`, and the
  project's own tests for every method under `methods/`): one verdict line per check;
  `rendered_checks` renders the rows its checks judge.

The guide is docs/method_guide.md.
"""
