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

Limits, checked from the header (Pillow's ``Image.open`` reads only the header) before any pixel is
decoded: an image of at most ``input.relief.max_pixels`` pixels (and ``input.max_points``, the
smaller applies) is read as it is. A larger one, up to 16 x ``max_pixels`` pixels, is scaled down to
the largest size within the limit, aspect kept, by area averaging: JPEG decoded by libjpeg at 1/2,
1/4 or 1/8 scale (so JPEG is accepted up to 64 x ``max_pixels``) then averaged, other formats decoded
at full size in their own mode (1 byte a pixel for grey, 2 for 16-bit, 4 for RGB(A), 32-bit integer
and float) then averaged, converted to float64 only after; the cloud's warnings name the image's size,
the size planned on and the parameter. Beyond that the image is refused (``too_many_pixels``, HTTP
413), whatever Pillow's own global limit (``Image.MAX_IMAGE_PIXELS``, left as it is) says.

Float pixels (32-bit TIFF) that are NaN or infinite are refused (``non_finite``: how many, the first
one's column and row), or with ``input.relief.fill_missing`` each takes the height of its nearest
finite pixel (Euclidean; the warnings say how many); an image with no finite pixel is always refused.

The data is checked against the header before decoding, since Pillow (with
``ImageFile.LOAD_TRUNCATED_IMAGES`` False, as it must stay) still fills some short files silently: a
PNG whose pixel data inflates to fewer bytes than its rows need, a Huffman-coded JPEG scan shorter
than one bit per block or running to the end of the file (libjpeg pads an early end marker with
grey), an uncompressed TIFF whose strips cover fewer rows than it declares.

``input.units`` does not apply: the relief parameters are millimetres. Errors: ``unreadable_file``
(Pillow cannot identify or decode the image), ``truncated_file`` (the image data ends early),
``too_few_points`` (fewer than 2 x 2 pixels), ``too_many_pixels`` (over 16, JPEG 64, x
``max_pixels`` by its header), ``non_finite`` (NaN or infinite float pixels, without
``fill_missing``).
"""

from __future__ import annotations

import math
import re
import struct
import warnings
import zlib

import numpy as np

from planning.errors import InputError, InputTooLarge, ParameterError
from planning.inputs.source import _Source, quiet_native_stderr

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
    if not np.isfinite(img).all():
        n_bad = int(np.count_nonzero(~np.isfinite(img)))
        raise InputError(f"{n_bad:,} intensity value(s) are NaN or infinite; every pixel needs a finite "
                         "value.", code="non_finite", n_bad=n_bad)
    img = gaussian_blur(img, blur)
    rows, cols = img.shape
    lo, hi = float(img.min()), float(img.max())
    t = (img - lo) / (hi - lo) if hi > lo else np.zeros_like(img)
    if dark == "high":
        t = 1.0 - t
    z = z_min_mm + t * (z_max_mm - z_min_mm)
    spacing = float(size_mm) / (max(rows, cols) - 1)
    points = np.empty((rows, cols, 3))                # filled per coordinate: no (N,) temporaries
    points[..., 0] = np.arange(cols) * spacing
    points[..., 1] = ((rows - 1 - np.arange(rows)) * spacing)[:, None]
    points[..., 2] = z
    return points.reshape(-1, 3), _pixel_faces(rows, cols)


def _pixel_faces(rows: int, cols: int) -> np.ndarray:
    """Two counter-clockwise (seen from +Z) triangles per 2x2 block of pixels (row 0 at the top)."""
    idx = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
    a, b = idx[:-1, :-1], idx[:-1, 1:]               # top left, top right
    c, d = idx[1:, :-1], idx[1:, 1:]                 # below, below right
    tri = np.empty((rows - 1, cols - 1, 2, 3), dtype=np.int64)
    for k, corner in enumerate((a, c, d)):
        tri[:, :, 0, k] = corner
    for k, corner in enumerate((a, d, b)):
        tri[:, :, 1, k] = corner
    return tri.reshape(-1, 3)


def _image_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Cannot read the image{src.quoted}: {msg}", code=code)


def _read_image(src: _Source, max_points: int, relief, notes: list[str] | None = None):
    """Points, normals (None), faces and label of an image read as a relief (see the module text).

    ``notes`` receives a sentence for each thing reading changed (the image scaled down, pixels
    filled): the cloud's warnings.
    """
    from PIL import Image, UnidentifiedImageError

    notes = [] if notes is None else notes
    with src.file() as fh, warnings.catch_warnings(), quiet_native_stderr():
        # Pillow warns about what it tolerates (a header past its global pixel limit, a corrupt
        # EXIF block); every limit and every damage that matters here is checked below and raised
        warnings.simplefilter("ignore")
        try:
            intensity, label = _decode(fh, src, int(max_points), relief, notes)
        except (InputError, ParameterError):
            raise
        except Image.DecompressionBombError as exc:      # our limit comes first; kept as a safety net
            raise InputTooLarge(f"The image{src.quoted} is too large to decode safely ({exc}). Scale it "
                                f"down to about {int(relief.max_pixels):,} pixels (input.relief.max_pixels) and "
                                "submit it again.",
                                code="too_many_pixels", max_pixels=int(relief.max_pixels)) from None
        except UnidentifiedImageError:
            raise _image_error(src, "it is not a PNG, JPEG, BMP or TIFF image Pillow can identify; the "
                                    "file is damaged or in another format.") from None
        except (OSError, ValueError, SyntaxError, EOFError, struct.error, zlib.error) as exc:
            text = str(exc) or type(exc).__name__
            truncated = any(w in text.lower() for w in ("truncat", "not enough image data", "premature"))
            code = "truncated_file" if truncated else "unreadable_file"
            raise _image_error(src, f"{text.rstrip('.')}; the image is "
                                    f"{'cut off' if truncated else 'damaged'}. Send the "
                                    "complete file.", code=code) from None
    points, faces = relief_from_intensity(
        intensity, size_mm=relief.size_mm, z_min_mm=relief.z_min_mm, z_max_mm=relief.z_max_mm,
        dark=relief.dark, blur=relief.blur)
    return points, None, faces, label


def _decode(fh, src: _Source, max_points: int, relief, notes: list[str]) -> tuple[np.ndarray, str]:
    """The header checked, then the pixels decoded (scaled down when needed) as float64 intensities.

    The only reference to the Pillow image lives here, so each conversion frees the one before.
    """
    from PIL import Image

    img = _open(fh)
    fmt = img.format
    label = f"image-{fmt.lower()}"
    width, height = img.size
    max_pixels = int(relief.max_pixels)
    _check_pixels(src, width, height, fmt, max_pixels)
    _check_complete(src, fh, img)
    limit = min(max_pixels, max_points)
    target = _fitted_size(width, height, limit)
    scale = 1
    if target != (width, height) and fmt in _JPEG_FORMATS:
        # libjpeg decodes at 1/2, 1/4 or 1/8 scale: the largest reduction that still covers target
        img.draft("RGB" if img.mode not in ("L", "1") else "L", target)
        scale = max(1, round(width / img.size[0]))
    decoded = img.size
    if decoded[0] * decoded[1] > _DECIMATE_FACTOR * max_pixels:      # a draft that did not reduce
        raise _too_many_pixels(src, width, height, fmt, max_pixels)
    img.load()                                          # OSError here: truncated or damaged data
    mode = img.mode
    if mode == "F":                                     # float pixels: NaN / inf are checked first
        arr = np.asarray(img)
        img = None                                      # frees Pillow's copy
        arr = _finite_heights(arr, src, bool(relief.fill_missing), notes)
        if arr.shape[::-1] != target:
            img = Image.fromarray(np.ascontiguousarray(arr, dtype=np.float32))
            arr = None
            img = img.resize(target, Image.Resampling.BOX)
            arr = np.asarray(img)
            img = None
        intensity = np.asarray(arr, dtype=np.float64)
    else:
        if mode in ("LA", "La"):
            img = img.getchannel(0)
        elif mode == "1":
            img = img.convert("L")
        elif not (mode in ("L", "I", "RGB") or mode.startswith("I;16")):
            img = img.convert("RGB")                    # palette, RGBA, CMYK, ...: alpha dropped
        if img.size != target:                          # area averaging, in the decoded mode
            img = img.resize(target, Image.Resampling.BOX)
        if img.mode.startswith("I;16"):
            img = img.convert("I")
        arr = np.asarray(img, dtype=np.float64)
        img = None
        intensity = luminance(arr) if arr.ndim == 3 else arr
    if target != (width, height):
        notes.append(_scaled_note(width, height, target, scale, decoded, max_pixels, max_points))
    return intensity, label


#: Images up to this many times ``max_pixels`` are scaled down; larger ones are refused.
_DECIMATE_FACTOR = 16
#: JPEG: libjpeg decodes at down to 1/8 scale per side, so its decode stays within max_pixels
#: for images up to 64 times max_pixels.
_JPEG_DECIMATE_FACTOR = 64
_JPEG_FORMATS = ("JPEG", "MPO")


def _open(fh):
    """Pillow's image with its header read, nothing decoded.

    ``Image.open`` refuses any image over twice Pillow's global ``MAX_IMAGE_PIXELS`` (about 179
    million pixels) before the caller sees its size; here the limit is ``max_pixels``, checked right
    after, so such a file is opened again with its format's own opener (which reads the header only)
    to learn its size. ``MAX_IMAGE_PIXELS`` is global and left as it is.
    """
    from PIL import Image, UnidentifiedImageError

    formats = sorted(set(IMAGE_FORMATS.values()))
    try:
        return Image.open(fh, formats=formats)
    except Image.DecompressionBombError:
        pass
    fh.seek(0)
    prefix = fh.read(16)
    for name in formats:
        factory, accept = Image.OPEN[name]
        if accept is None or accept(prefix):
            fh.seek(0)
            return factory(fh, "")
    raise UnidentifiedImageError("cannot identify image file")    # pragma: no cover - opened once above


def _too_many_pixels(src: _Source, width: int, height: int, fmt: str, max_pixels: int) -> InputTooLarge:
    jpeg = fmt in _JPEG_FORMATS
    factor = _JPEG_DECIMATE_FACTOR if jpeg else _DECIMATE_FACTOR
    n = width * height
    return InputTooLarge(
        f"The image{src.quoted} is {width:,} x {height:,} pixels ({n:,} pixels, by its header); "
        f"input.relief.max_pixels = {max_pixels:,} plans at most that many and scales down "
        f"{'JPEG images' if jpeg else 'images'} of up to {factor} times that ({factor * max_pixels:,} "
        "pixels). Scale the image down (to input.relief.max_pixels; a relief needs no more) or raise "
        "input.relief.max_pixels, and submit it again.",
        code="too_many_pixels", n_pixels=int(n), width=int(width), height=int(height),
        max_pixels=int(max_pixels))


def _check_pixels(src: _Source, width: int, height: int, fmt: str, max_pixels: int) -> None:
    """Refuse, from the header, an image beyond what is scaled down (16 or, JPEG, 64 x max_pixels)."""
    factor = _JPEG_DECIMATE_FACTOR if fmt in _JPEG_FORMATS else _DECIMATE_FACTOR
    if width * height > factor * max_pixels:
        raise _too_many_pixels(src, width, height, fmt, max_pixels)


def _scaled_note(width, height, target, scale, decoded, max_pixels, max_points) -> str:
    w, h = target
    what = (f"input.relief.max_pixels = {max_pixels:,}" if max_pixels <= max_points
            else f"input.max_points = {max_points:,}")
    how = (f" (decoded at 1/{scale} scale, {decoded[0]} x {decoded[1]}, then area-averaged)" if scale > 1
           else " (area-averaged)")
    n = width * height
    count = f"{n / 1e6:.1f} million" if n >= 100_000 else f"{n:,}"
    return f"the image is {width} x {height} pixels ({count}); it was scaled down to {w} x {h}{how} to fit {what}"


# --------------------------------------------------------------------------------------------
# the data is all there: checked before decoding, since Pillow fills what is missing silently in
# some cases (a PNG whose pixel data stops early, a JPEG whose scan ends at an end marker, an
# uncompressed TIFF with fewer strips than rows)
# --------------------------------------------------------------------------------------------

def _check_complete(src: _Source, fh, img) -> None:
    """Raise ``truncated_file`` when the file holds less pixel data than its header declares."""
    width, height = img.size
    covered = 0
    for tile in img.tile:                               # what Pillow will decode, per region
        ext = tile[1]
        if ext is None:
            covered = width * height
            break
        x0, y0, x1, y1 = (int(v) for v in ext)
        covered += max(0, min(x1, width) - max(x0, 0)) * max(0, min(y1, height) - max(y0, 0))
    if img.tile and covered < width * height:
        raise _image_error(src, f"its pixel data covers {covered:,} of the {width * height:,} pixels its "
                                f"header declares ({width} x {height}); the image is cut off. Send the "
                                "complete file.", code="truncated_file")
    if img.format in ("PNG", *_JPEG_FORMATS):
        fh.seek(0)
        data = fh.read()
        problem = _png_shortfall(data) if img.format == "PNG" else _jpeg_shortfall(data)
        if problem:
            raise _image_error(src, f"{problem}; the image is cut off. Send the complete file.",
                               code="truncated_file")


_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def _png_shortfall(data: bytes) -> str | None:
    """What is missing when the PNG's IDAT stream inflates to fewer bytes than its IHDR needs.

    Pillow fills the rows after an early end of the zlib stream with zeros and says nothing. The
    stream is inflated in 16 KiB pieces and the output counted, never kept.
    """
    if len(data) < 33 or data[12:16] != b"IHDR":
        return None                                     # Pillow has already refused such a file
    width, height, depth, colour, _, _, interlace = struct.unpack_from(">IIBBBBB", data, 16)
    bits = _PNG_CHANNELS.get(colour, 1) * depth
    passes = ([(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
               (0, 1, 1, 2)] if interlace else [(0, 0, 1, 1)])
    need = 0
    for x0, y0, dx, dy in passes:
        pw, ph = (width - x0 + dx - 1) // dx, (height - y0 + dy - 1) // dy
        if pw > 0 and ph > 0:
            need += ph * (1 + (pw * bits + 7) // 8)
    view = memoryview(data)
    inflate = zlib.decompressobj()
    got, pos = 0, 8
    while pos + 8 <= len(data) and got < need and not inflate.eof:
        length, kind = struct.unpack_from(">I4s", data, pos)
        if kind == b"IDAT":
            body = view[pos + 8:pos + 8 + length]
            for i in range(0, len(body), 1 << 14):
                got += len(inflate.decompress(body[i:i + (1 << 14)]))
                if got >= need or inflate.eof:
                    break
        elif kind == b"IEND":
            break
        pos += 12 + length
    if got >= need:
        return None
    return (f"its pixel data inflates to {got:,} of the {need:,} bytes its header declares ({width} x "
            f"{height} pixels)")


#: a marker inside JPEG data: 0xFF followed by neither a stuffed 0x00, a restart marker nor a fill 0xFF
_JPEG_MARKER = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")
_SOF_HUFFMAN = {0xC0: "sequential", 0xC1: "sequential", 0xC2: "progressive", 0xC3: "lossless"}
_SOF_ALL = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_shortfall(data: bytes) -> str | None:
    """What is missing when a JPEG scan holds fewer bytes than its blocks need, or ends the file.

    libjpeg fills the blocks after an early end marker with grey and Pillow only sees a warning it
    drops: a header claiming 13000 x 13000 pixels over 300 bytes of data decodes as a grey picture.
    Every block of a Huffman-coded scan takes at least one bit (sequential: its DC and end-of-block
    codes; progressive: the DC scans; lossless: one bit per sample), so a scan shorter than its blocks
    / 8 bytes is cut off. Arithmetic-coded JPEGs have no such bound and are not checked.
    """
    n = len(data)
    pos = 2                                             # after SOI
    kind, comps, width, height = None, {}, 0, 0
    while pos < n:
        if data[pos] != 0xFF:                           # junk between segments: look for a marker
            m = _JPEG_MARKER.search(data, pos)
            if m is None:
                return None
            pos = m.start()
        while pos < n and data[pos] == 0xFF:
            pos += 1
        if pos >= n:
            return None
        marker = data[pos]
        pos += 1
        if marker == 0xD9:                              # EOI
            return None
        if marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:
            continue
        if pos + 2 > n:
            return None
        length = int.from_bytes(data[pos:pos + 2], "big")
        seg = data[pos + 2:pos + length]
        pos += length
        if marker in _SOF_ALL and len(seg) >= 6:
            kind = _SOF_HUFFMAN.get(marker)
            height, width, nf = int.from_bytes(seg[1:3], "big"), int.from_bytes(seg[3:5], "big"), seg[5]
            comps = {seg[6 + 3 * i]: (seg[7 + 3 * i] >> 4, seg[7 + 3 * i] & 15)
                     for i in range(nf) if 8 + 3 * i < len(seg)}
        elif marker == 0xDA:                            # SOS: the entropy-coded data follows
            m = _JPEG_MARKER.search(data, pos)
            if m is None:
                return "its scan data runs to the end of the file, with no end marker"
            have = m.start() - pos
            need = _jpeg_scan_bits(seg, kind, comps, width, height)
            if have * 8 < need:
                return (f"a scan holds {have:,} bytes of data where its {width} x {height} pixels need "
                        f"at least {(need + 7) // 8:,}")
            pos = m.start()
    return None


def _jpeg_scan_bits(seg: bytes, kind, comps: dict, width: int, height: int) -> int:
    """The fewest bits the scan's data can take (0 where no bound is known)."""
    if kind is None or not comps or not seg or width <= 0 or height <= 0:
        return 0
    ns = seg[0]
    ids = [seg[1 + 2 * i] for i in range(ns) if 1 + 2 * i < len(seg)]
    if len(seg) < 4 + 2 * ns:
        return 0
    ss = seg[1 + 2 * ns]
    if kind == "progressive" and ss != 0:               # AC scans: end-of-band runs, no bound
        return 0
    hmax = max(h for h, _ in comps.values()) or 1
    vmax = max(v for _, v in comps.values()) or 1
    bits = 0
    for cid in ids:
        if cid not in comps:
            continue
        h, v = comps[cid]
        cw, ch = -(-width * h // hmax), -(-height * v // vmax)
        bits += cw * ch if kind == "lossless" else -(-cw // 8) * -(-ch // 8)
    return bits


# --------------------------------------------------------------------------------------------
# float images: NaN and infinite pixels
# --------------------------------------------------------------------------------------------

def _finite_heights(arr: np.ndarray, src: _Source, fill: bool, notes: list[str]) -> np.ndarray:
    """``arr`` with no NaN or infinite pixel: refused (``non_finite``), or each filled from its nearest
    finite pixel (``fill``; Euclidean distance, on the bounding box of the bad pixels grown by one
    pixel, which holds the nearest finite pixel of each)."""
    finite = np.isfinite(arr)
    if finite.all():
        return arr
    bad = ~finite
    del finite
    n_bad = int(np.count_nonzero(bad))
    row, col = divmod(int(np.argmax(bad)), arr.shape[1])
    n_nan = int(np.count_nonzero(np.isnan(arr)))
    n_pos = int(np.count_nonzero(np.isposinf(arr)))
    kinds = ", ".join(f"{k:,} {name}" for k, name in ((n_nan, "NaN"), (n_pos, "+inf"),
                                                       (n_bad - n_nan - n_pos, "-inf")) if k)
    if n_bad == arr.size:
        raise InputError(f"The image{src.quoted} has no valid height: all its {n_bad:,} pixels are NaN or "
                         f"infinite ({kinds}). Export the height map again.", code="non_finite",
                         n_bad=n_bad, first_column=col, first_row=row)
    if not fill:
        raise InputError(
            f"The image{src.quoted} has {n_bad:,} pixel(s) with no valid height ({kinds}; first at column "
            f"{col}, row {row}, counting from 0 at the top left): they would flatten or shift the whole "
            "relief. Fill them in the software that wrote the height map, or set "
            "input.relief.fill_missing = true to give each the height of its nearest valid pixel.",
            code="non_finite", n_bad=n_bad, first_column=col, first_row=row)
    from scipy import ndimage

    rows = np.flatnonzero(bad.any(axis=1))
    cols = np.flatnonzero(bad.any(axis=0))
    r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, arr.shape[0])
    c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, arr.shape[1])
    sub = bad[r0:r1, c0:c1]
    near = ndimage.distance_transform_edt(sub, return_distances=False, return_indices=True)
    out = np.array(arr, dtype=np.float32 if arr.dtype == np.float32 else np.float64)
    box = out[r0:r1, c0:c1]
    box[sub] = box[near[0][sub], near[1][sub]]
    notes.append(f"{n_bad:,} pixel(s) of the image had no valid height ({kinds}) and took the height of "
                 "their nearest valid pixel (input.relief.fill_missing)")
    return out


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
