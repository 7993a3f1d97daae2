"""Linear float32 EXR images through OpenImageIO (row 0 at the top, like Mitsuba)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def write_exr(path, image: np.ndarray) -> None:
    """Write HxWxC float32 as a half-free, zip-compressed float EXR, atomically."""
    import OpenImageIO as oiio
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # OIIO's write_image fails without an error message on an unaligned or read-only buffer (an
    # array unpickled from a Dask worker is often both): require a C-contiguous aligned copy then
    img = np.require(np.asarray(image, dtype=np.float32), requirements=["C", "A", "W"])
    if img.ndim == 2:
        img = img[..., None]
    h, w, c = img.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    spec.attribute("compression", "zip")
    spec.attribute("DateTime", "")   # no timestamp: the same image always writes the same bytes
    if c == 3:
        spec.channelnames = ("R", "G", "B")
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    out = oiio.ImageOutput.create(str(tmp))
    if out is None or not out.open(str(tmp), spec):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    ok = out.write_image(img)
    out.close()
    if not ok:
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    os.replace(tmp, path)


def read_exr(path) -> np.ndarray:
    import OpenImageIO as oiio
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"cannot read {path}: {oiio.geterror()}")
    try:
        data = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    if data is None:
        raise OSError(f"cannot read {path}: {oiio.geterror()}")
    return np.asarray(data, dtype=np.float32)
