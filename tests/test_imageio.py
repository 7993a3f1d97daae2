"""EXR files through OpenImageIO: linear float32, row 0 at the top, the same image the same bytes."""
from __future__ import annotations

import time

import numpy as np

from bench.model.imageio import read_exr, write_exr


def test_the_same_image_writes_the_same_bytes(tmp_path):
    """No timestamp in the header: a re-run that renders the same pixels writes identical files
    (checksums of the row cache and bit-identical comparisons of run folders rely on it)."""
    img = np.random.default_rng(1).random((6, 8, 3), dtype=np.float32)
    write_exr(tmp_path / "a.exr", img)
    time.sleep(1.1)   # OpenImageIO's default DateTime has a resolution of one second
    write_exr(tmp_path / "b.exr", img)
    assert (tmp_path / "a.exr").read_bytes() == (tmp_path / "b.exr").read_bytes()
    assert np.array_equal(read_exr(tmp_path / "a.exr"), img)
