"""Writing renders: an sRGB PNG (colour-science's sRGB encoding), the linear image as ``.npy`` (and ``.exr`` through
the OpenEXR package), and the JSON report.

The PNG is ``sRGB(clip(exposure * L, 0, 1))`` of the linear radiance ``L`` in W/(mm^2 sr); the ``.npy`` and ``.exr``
hold ``L`` itself (``H x W x 3``, float32 for EXR, float64 for NumPy).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from jaxsss.serialize import json_ready

__all__ = ["encode_srgb", "write_exr", "write_outputs", "write_png"]


def encode_srgb(image: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """``(H, W, 3)`` uint8 sRGB of a linear image (IEC 61966-2-1 transfer function, via colour-science)."""
    import colour  # here, not at the top: importing colour-science takes ~2 s (it loads matplotlib and scipy)

    linear = np.clip(np.nan_to_num(np.asarray(image, dtype=np.float64) * exposure), 0.0, 1.0)
    encoded = colour.cctf_encoding(linear, function="sRGB")
    return np.round(np.clip(encoded, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_png(path, image: np.ndarray, exposure: float = 1.0) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(encode_srgb(image, exposure)).save(path)
    return path


def write_exr(path, image: np.ndarray) -> Path:
    """Linear float32 RGB EXR (OpenEXR's Python bindings)."""
    import OpenEXR

    path = Path(path)
    rgb = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"RGB": rgb}) as f:
        f.write(str(path))
    return path


def write_outputs(png_path, image: np.ndarray, report: dict, *, exposure: float = 1.0, exr: bool = True,
                  json_path=None) -> dict[str, str]:
    """Write ``X.png`` (sRGB), ``X.npy`` (linear), optionally ``X.exr`` and the JSON report; returns the paths."""
    png_path = Path(png_path)
    out = {"png": str(write_png(png_path, image, exposure))}
    npy = png_path.with_suffix(".npy")
    np.save(npy, np.asarray(image, dtype=np.float64))
    out["npy"] = str(npy)
    if exr:
        out["exr"] = str(write_exr(png_path.with_suffix(".exr"), image))
    if json_path is not None:
        json_path = Path(json_path)
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(json_ready({**report, "outputs": out}), indent=2) + "\n")
        out["json"] = str(json_path)
    return out
