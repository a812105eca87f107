"""Stage 1, the cloud: an image read as a relief (Sood 2015, ch. 3: digital image to freeform surface).

PNG, JPEG, BMP and TIFF images are decoded by Pillow. Each pixel becomes one point:

- intensity: grayscale images as they are (8 or 16 bit, or float); colour images by the luminance
  ``Y = 0.299 R + 0.587 G + 0.114 B`` (Sood eq. 3.1; alpha ignored, palettes expanded);
- optional Gaussian blur (Sood §3.2.2-3.2.3) with a 3x3 or 5x5 kernel, the binomial kernels
  ``[1 2 1]/4`` and ``[1 4 6 4 1]/16`` in each direction (what OpenCV's ``GaussianBlur`` uses for
  these sizes), borders mirrored without repeating the edge pixel;
- height: the intensity range of the image mapped linearly onto ``[z_min_mm, z_max_mm]`` (Sood
  eq. 3.3: ``Z = (I - I_min) (Z_max - Z_min) / (I_max - I_min) + Z_min``) with ``dark = "low"``
  (dark pixels low, the thesis' default), or reversed with ``dark = "high"``; a uniform image lies
  at the height its darkest pixel would get;
- position: the image fitted to ``size_mm`` along its longer side, aspect kept, pixel spacing
  ``size_mm / (longer side - 1)``; column ``c`` at ``x = c x spacing``, row ``r`` (row 0 at the top
  of the image) at ``y = (rows - 1 - r) x spacing``, so the relief reads as the picture seen from +Z;
- faces: two triangles per 2x2 block of neighbouring pixels, counter-clockwise seen from +Z.

An image with more pixels than ``max_points`` is first scaled down with Pillow (area averaging; JPEG
decoded at a reduced scale where possible) to the largest size within the limit, aspect kept.
``input.units`` does not apply: the relief parameters are millimetres. Errors: ``unreadable_file``
(Pillow cannot identify or decode the image), ``truncated_file`` (the image data ends early),
``too_few_points`` (fewer than 2 x 2 pixels), ``too_many_points`` (beyond what Pillow decodes
safely, about 179 million pixels).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from planning.errors import InputError, InputTooLarge, ParameterError
from planning.inputs.source import _Source

__all__ = ["IMAGE_FORMATS", "gaussian_blur", "luminance", "relief_from_intensity"]

#: File name extensions read as images, and the Pillow format each must decode as.
IMAGE_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".bmp": "BMP", ".tif": "TIFF",
                 ".tiff": "TIFF"}
_LUMA = np.array([0.299, 0.587, 0.114])
_KERNELS = {3: np.array([1.0, 2.0, 1.0]) / 4.0, 5: np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0}
_GRAY_MODES = ("L", "I", "F")


def _looks_like_image(head: bytes, size: int) -> bool:
    """PNG, JPEG, TIFF magic bytes, or a BMP whose header states the file size."""
    if head.startswith((b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff", b"II*\x00", b"MM\x00*")):
        return True
    return head.startswith(b"BM") and len(head) >= 6 and int.from_bytes(head[2:6], "little") == size


def luminance(rgb) -> np.ndarray:
    """``(H, W, 3)`` red, green, blue -> ``(H, W)`` float64 ``0.299 R + 0.587 G + 0.114 B``."""
    arr = np.asarray(rgb, dtype=np.float64)
    return arr[..., 0] * _LUMA[0] + arr[..., 1] * _LUMA[1] + arr[..., 2] * _LUMA[2]


def gaussian_blur(intensity, kernel: int) -> np.ndarray:
    """Blur an ``(H, W)`` image with the 3x3 or 5x5 Gaussian (binomial) kernel; 0 returns a copy.

    Separable: ``[1 2 1]/4`` or ``[1 4 6 4 1]/16`` along rows then columns; borders mirrored without
    repeating the edge pixel (``d c b | a b c d``), as OpenCV's default border.
    """
    img = np.array(intensity, dtype=np.float64)
    if kernel in (0, 1, None):
        return img
    if kernel not in _KERNELS:
        raise ParameterError(f"input.relief.blur is {kernel!r}; allowed values are 0, 3 and 5.",
                             parameter="input.relief.blur", value=kernel, allowed=[0, 3, 5])
    k = _KERNELS[kernel]
    half = kernel // 2
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (half, half)
        padded = np.pad(img, pad, mode="reflect")
        out = np.zeros_like(img)
        n = img.shape[axis]
        for j, w in enumerate(k):                       # 3 or 5 shifted, weighted copies
            out += w * (padded[j:j + n] if axis == 0 else padded[:, j:j + n])
        img = out
    return img


def relief_from_intensity(intensity, *, size_mm: float = 100.0, z_min_mm: float = 0.0,
                          z_max_mm: float = 10.0, dark: str = "low",
                          blur: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(H*W, 3)`` mm (row-major from the top-left pixel) and faces ``(2(H-1)(W-1), 3)``.

    ``intensity`` is ``(H, W)``, bright = high values; see the module text for the mapping.
    """
    img = np.asarray(intensity, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 2:
        raise InputError(f"The image is {img.shape[-1] if img.ndim else 0} x "
                         f"{img.shape[0] if img.ndim else 0} pixels; a relief needs at least 2 x 2.",
                         code="too_few_points")
    if dark not in ("low", "high"):
        raise ParameterError(f"input.relief.dark is {dark!r}; allowed values are 'low' and 'high'.",
                             parameter="input.relief.dark", value=dark, allowed=["low", "high"])
    if not (np.isfinite(size_mm) and size_mm > 0):
        raise ParameterError(f"input.relief.size_mm must be a positive number, got {size_mm!r}.",
                             parameter="input.relief.size_mm", value=size_mm)
    if not (z_max_mm > z_min_mm):
        raise ParameterError(f"input.relief.z_max_mm ({z_max_mm!r}) must be above z_min_mm "
                             f"({z_min_mm!r}).", parameter="input.relief.z_max_mm", value=z_max_mm)
    img = gaussian_blur(img, blur)
    rows, cols = img.shape
    lo, hi = float(img.min()), float(img.max())
    t = (img - lo) / (hi - lo) if hi > lo else np.zeros_like(img)
    if dark == "high":
        t = 1.0 - t
    z = z_min_mm + t * (z_max_mm - z_min_mm)
    spacing = float(size_mm) / (max(rows, cols) - 1)
    r, c = np.divmod(np.arange(rows * cols), cols)
    points = np.column_stack((c * spacing, (rows - 1 - r) * spacing, z.reshape(-1)))
    return points, _pixel_faces(rows, cols)


def _pixel_faces(rows: int, cols: int) -> np.ndarray:
    """Two counter-clockwise (seen from +Z) triangles per 2x2 block of pixels (row 0 at the top)."""
    a = (np.arange(rows - 1)[:, None] * cols + np.arange(cols - 1)[None, :]).reshape(-1)
    b, c, d = a + 1, a + cols, a + cols + 1          # right, below, below right
    tri = np.empty((2 * a.size, 3), dtype=np.int64)
    tri[0::2] = np.column_stack((a, c, d))
    tri[1::2] = np.column_stack((a, d, b))
    return tri


def _image_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Cannot read the image{src.quoted}: {msg}", code=code)


def _read_image(src: _Source, max_points: int, relief):
    from PIL import Image, UnidentifiedImageError

    with src.file() as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            img = Image.open(fh, formats=sorted(set(IMAGE_FORMATS.values())))
            label = f"image-{img.format.lower()}"
            width, height = img.size
            target = _fitted_size(width, height, max_points)
            if target != (width, height) and img.format == "JPEG":
                img.draft("RGB" if img.mode not in ("L", "1") else "L", target)
            intensity = _intensity(img, target)
        except Image.DecompressionBombError as exc:
            raise InputTooLarge(f"The image{src.quoted} is too large to decode safely ({exc}). Scale it "
                                "down (a few million pixels are plenty) and submit it again.",
                                code="too_many_points", max_points=int(max_points)) from None
        except UnidentifiedImageError:
            raise _image_error(src, "it is not a PNG, JPEG, BMP or TIFF image Pillow can identify; the "
                                    "file is damaged or in another format.") from None
        except (OSError, ValueError, SyntaxError) as exc:
            text = str(exc)
            code = "truncated_file" if "truncat" in text.lower() else "unreadable_file"
            raise _image_error(src, f"{text.rstrip('.')}; the image is "
                                    f"{'cut off' if code == 'truncated_file' else 'damaged'}. Send the "
                                    "complete file.", code=code) from None
    points, faces = relief_from_intensity(
        intensity, size_mm=relief.size_mm, z_min_mm=relief.z_min_mm, z_max_mm=relief.z_max_mm,
        dark=relief.dark, blur=relief.blur)
    return points, None, faces, label


def _fitted_size(width: int, height: int, max_points: int) -> tuple[int, int]:
    """The image size within ``max_points`` pixels, aspect kept (the size itself if it fits)."""
    if width * height <= max_points:
        return width, height
    scale = math.sqrt(max_points / (width * height))
    w, h = max(2, int(width * scale)), max(2, int(height * scale))
    while w * h > max_points and max(w, h) > 2:     # only where the 2-pixel minimum kicked in
        if w >= h:
            w -= 1
        else:
            h -= 1
    return w, h


def _intensity(img, target: tuple[int, int]) -> np.ndarray:
    """Decode to one float64 intensity per pixel (grayscale as is, colour as luminance), resized."""
    from PIL import Image

    mode = img.mode
    if mode in ("LA", "La"):
        img = img.getchannel(0)
    elif mode == "1":
        img = img.convert("L")
    elif mode.startswith("I;16") or mode == "I":
        img = img.convert("I")
    elif mode not in _GRAY_MODES:
        img = img.convert("RGB")
    if img.size != target:
        img = img.resize(target, Image.Resampling.BOX)
    arr = np.asarray(img, dtype=np.float64)
    return luminance(arr) if arr.ndim == 3 else arr
