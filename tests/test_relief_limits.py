"""Issue 29: image reliefs within bounded memory, and no relief planned on pixels that are not there.

- ``input.relief.max_pixels`` is checked from the header: an image over it is scaled down (up to 16 x,
  JPEG 64 x, decoded by libjpeg at a reduced scale) with a warning naming its size, beyond that
  refused (``too_many_pixels``, 413); the 28 KB PNG of 4472 x 4472 grey pixels and the 331-byte JPEG
  whose header claims 13000 x 13000 pixels are read in a child process under an address-space limit
  and must stay under 1.5 GiB of resident memory (a memory bound, never a time);
- a file holding less pixel data than its header declares is ``truncated_file``, not a grey relief;
- NaN / infinite float pixels are refused (``non_finite``) or, with ``input.relief.fill_missing``,
  filled from their nearest finite pixel.

The files are made here with Pillow and struct, the expected heights with numpy (block means, brute-force
nearest pixels)."""

from __future__ import annotations

import io
import json
import math
import os
import resource
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from mesh_files import image_bytes

from planning.errors import InputError, InputTooLarge, ParameterError
from planning.inputs.cloud import read_cloud, read_input
from schemas.params import parse_config

ROOT = Path(__file__).resolve().parents[1]
#: the most resident memory a child reading a hostile image may reach
RSS_LIMIT = 1536 << 20
#: the address space a child may add once the readers are imported
AS_HEADROOM = 2 << 30


# ----------------------------------------------------------------------------------------- files

def png_grey(width: int, height: int, value: int = 128) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (width, height), value).save(buf, format="PNG", compress_level=9)
    return buf.getvalue()


def encode(array, fmt: str, **kw) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(array)).save(buf, format=fmt, **kw)
    return buf.getvalue()


def jpeg_claiming(side: int) -> bytes:
    """A valid 8 x 8 grey JPEG (about 330 bytes) whose SOF0 height and width are patched to ``side``."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (8, 8), 128).save(buf, format="JPEG")
    data = bytearray(buf.getvalue())
    sof = data.index(b"\xff\xc0")
    struct.pack_into(">HH", data, sof + 5, side, side)
    return bytes(data)


def png_with_height(data: bytes, height: int) -> bytes:
    """The PNG with its IHDR height replaced (CRC recomputed): the pixel data stays that of the original."""
    out = bytearray(data)
    ihdr = out.index(b"IHDR")
    struct.pack_into(">I", out, ihdr + 8, height)
    struct.pack_into(">I", out, ihdr + 17, zlib.crc32(bytes(out[ihdr:ihdr + 17])))
    return bytes(out)


def png_header_only(width: int, height: int) -> bytes:
    """A PNG signature, an 8-bit grey IHDR of the given size, one tiny IDAT and IEND."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 100)) + chunk(b"IEND", b""))


def tiff_with_height(data: bytes, height: int) -> bytes:
    """A little-endian TIFF with the first IFD's ImageLength (tag 257) replaced."""
    assert data[:2] == b"II"
    out = bytearray(data)
    ifd = struct.unpack_from("<I", data, 4)[0]
    for k in range(struct.unpack_from("<H", data, ifd)[0]):
        entry = ifd + 2 + 12 * k
        tag, kind = struct.unpack_from("<HH", data, entry)
        if tag == 257:
            struct.pack_into("<H" if kind == 3 else "<I", out, entry + 8, height)
    return bytes(out)


def smooth(rows: int, cols: int, seed: int = 0) -> np.ndarray:
    """A sum of Gaussians in [0, 1], ``(rows, cols)`` float64."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols]
    z = np.zeros((rows, cols))
    for _ in range(6):
        cy, cx, s = rng.uniform(0, rows), rng.uniform(0, cols), rng.uniform(0.15, 0.4) * max(rows, cols)
        z += rng.uniform(0.3, 1.0) * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * s * s))
    return (z - z.min()) / np.ptp(z)


def heights(cloud, shape) -> np.ndarray:
    return cloud.points[:, 2].reshape(shape)


def block_mean(a: np.ndarray, k: int) -> np.ndarray:
    rows, cols = a.shape
    return a.reshape(rows // k, k, cols // k, k).mean(axis=(1, 3))


def stretched(a: np.ndarray) -> np.ndarray:
    """The heights of the default relief mapping (0 .. 10 mm over the intensity range)."""
    return (a - a.min()) / np.ptp(a) * 10.0


# ------------------------------------------------------------------------ reading in a child process

_CHILD = r"""
import json, os, resource, sys
sys.path.insert(0, os.environ["SCANMILL_ROOT"])
from planning.errors import PlanningError
from planning.inputs.cloud import read_input
from schemas.params import parse_config

job = json.loads(sys.stdin.read())
params = parse_config(job["config"]).input
with open("/proc/self/status") as fh:
    vm = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:"))
limit = vm + int(job["headroom"])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
try:
    cloud = read_input(job["path"], params)
    result = {"ok": True, "n_points": cloud.n_points, "n_faces": cloud.n_faces, "warnings": list(cloud.warnings)}
except PlanningError as exc:
    result = {"ok": False, "error": type(exc).__name__, "code": exc.code, "status": exc.status,
              "message": exc.message}
except BaseException as exc:
    result = {"ok": False, "error": type(exc).__name__, "code": None, "message": str(exc)[:300]}
result["max_rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps(result))
"""


def read_in_child(path: Path, config: dict | None = None) -> dict:
    """``read_input`` of ``path`` in a fresh Python whose address space may grow by AS_HEADROOM once the
    readers are imported; its answer and its peak resident memory (``max_rss``, bytes: the child's own
    ru_maxrss, which RUSAGE_CHILDREN of this long-lived test process would mix with earlier children)."""
    job = {"path": str(path), "config": config or {}, "headroom": AS_HEADROOM}
    env = dict(os.environ, SCANMILL_ROOT=str(ROOT), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", _CHILD], input=json.dumps(job), capture_output=True,
                          text=True, env=env, cwd=str(ROOT), check=False)
    assert proc.returncode == 0 and proc.stdout.strip(), proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------- the bombs

def test_a_png_bomb_is_refused_by_default_and_scaled_down_under_a_higher_limit_within_bounded_memory(tmp_path):
    path = tmp_path / "grey.png"
    path.write_bytes(png_grey(4472, 4472))
    assert path.stat().st_size < 40_000                          # 20 million pixels in about 29 KB
    default = parse_config({}).input.relief.max_pixels
    assert 4472 * 4472 > 16 * default                            # so the defaults refuse it outright
    refused = read_in_child(path)
    assert not refused["ok"] and refused["code"] == "too_many_pixels", refused
    assert "4,472 x 4,472" in refused["message"] and "input.relief.max_pixels" in refused["message"]
    assert refused["max_rss"] < RSS_LIMIT, refused["max_rss"] / 2**20
    max_pixels = 3_145_728                                       # 20 M pixels are within 16 x this
    result = read_in_child(path, {"input": {"relief": {"max_pixels": max_pixels}}})
    assert result["ok"], result
    side = math.isqrt(max_pixels)                                # a square image stays square
    assert result["n_points"] == side * side <= max_pixels
    assert result["n_faces"] == 2 * (side - 1) ** 2
    note = " ".join(result["warnings"])
    assert "4472 x 4472" in note and f"{side} x {side}" in note and "input.relief.max_pixels" in note
    assert result["max_rss"] < RSS_LIMIT, result["max_rss"] / 2**20


def test_a_jpeg_header_claiming_13000_pixels_square_is_refused_within_bounded_memory(tmp_path):
    data = jpeg_claiming(13000)
    assert len(data) < 400
    path = tmp_path / "tiny.jpg"
    path.write_bytes(data)
    result = read_in_child(path)
    assert not result["ok"] and result["code"] in ("truncated_file", "too_many_pixels"), result
    assert result["error"] in ("InputError", "InputTooLarge") and "tiny.jpg" in result["message"]
    assert result["max_rss"] < RSS_LIMIT, result["max_rss"] / 2**20


def test_the_cli_refuses_the_jpeg_bomb_with_one_error_line_and_writes_nothing(tmp_path):
    path = tmp_path / "tiny.jpg"
    path.write_bytes(jpeg_claiming(13000))
    out = tmp_path / "plan"

    def limit_memory():                                         # today's reader needs 13 GiB here
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "scanmill.cli", "plan", str(path), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, env=env, cwd=str(ROOT), preexec_fn=limit_memory,
                          check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(("error [truncated_file]: ", "error [too_many_pixels]: ")) and "tiny.jpg" in lines[0]
    assert not out.exists()


def test_a_damaged_compressed_tiff_is_one_error_line_without_libtiffs_own_stderr(tmp_path):
    """libtiff writes its complaint about a bad strip ("TIFFFillStrip: ...") straight to file descriptor 2;
    the CLI's promise is one `error [code]` line, so native stderr is kept off the console while reading."""
    from PIL import Image
    img = (np.random.default_rng(0).random((64, 64)) * 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="TIFF", compression="tiff_adobe_deflate")
    data = bytearray(buf.getvalue())
    for i in range(20, 200):                                   # the deflated strip, damaged
        data[i] ^= 0x5A
    path = tmp_path / "bad.tif"
    path.write_bytes(bytes(data))
    out = tmp_path / "plan"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "scanmill.cli", "plan", str(path), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, env=env, cwd=str(ROOT), check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert len(proc.stderr.splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith(("error [unreadable_file]: ", "error [truncated_file]: ")) and "bad.tif" in proc.stderr
    assert not out.exists()


def test_a_jpeg_over_pillows_own_limit_is_judged_by_max_pixels_and_pillow_is_left_as_it_was():
    from PIL import Image, ImageFile

    before = Image.MAX_IMAGE_PIXELS
    relief = {"max_pixels": 4_194_304}                          # JPEG up to 268 M pixels
    # 256 million pixels: over twice Pillow's MAX_IMAGE_PIXELS (its DecompressionBombError), within
    # 64 x max_pixels for a JPEG, so the file is opened and found to hold almost no data
    assert 16000**2 > 2 * Image.MAX_IMAGE_PIXELS
    err = pytest.raises(InputError, read_cloud, jpeg_claiming(16000), relief=relief).value
    assert err.code == "truncated_file" and "16000 x 16000" in err.message
    err = pytest.raises(InputTooLarge, read_cloud, jpeg_claiming(20000), relief=relief).value  # 400 M
    assert err.code == "too_many_pixels" and err.status == 413 and "20,000 x 20,000" in err.message
    err = pytest.raises(InputTooLarge, read_cloud, png_header_only(20000, 20000)).value
    assert err.code == "too_many_pixels" and "20,000 x 20,000" in err.message
    assert "input.relief.max_pixels" in err.message
    assert err.details["max_pixels"] == parse_config({}).input.relief.max_pixels
    assert Image.MAX_IMAGE_PIXELS == before and ImageFile.LOAD_TRUNCATED_IMAGES is False


# ------------------------------------------------------------------------- the limit, small images

def test_an_image_up_to_16_times_max_pixels_is_area_averaged_and_beyond_refused():
    z = smooth(96, 128)
    img = np.round(z * 65535).astype(np.uint16)                   # 16-bit: averaging without 8-bit rounding
    data = image_bytes(img)
    cloud = read_cloud(data, relief={"max_pixels": 768})         # 12,288 pixels = 16 x 768: scaled down
    assert cloud.n_points == 32 * 24
    np.testing.assert_allclose(heights(cloud, (24, 32)), stretched(block_mean(img.astype(float), 4)), atol=1e-3)
    assert len(cloud.warnings) == 1
    note = cloud.warnings[0]
    assert "128 x 96" in note and "32 x 24" in note and "input.relief.max_pixels = 768" in note
    err = pytest.raises(InputTooLarge, read_cloud, data, relief={"max_pixels": 767}).value
    assert err.code == "too_many_pixels" and err.status == 413
    assert "128 x 96" in err.message and "12,288" in err.message and "767" in err.message
    assert "input.relief.max_pixels" in err.message and err.details["max_pixels"] == 767
    small = read_cloud(data, relief={"max_pixels": 12_288})      # within the limit: read as it is
    assert small.n_points == 12_288 and small.warnings == ()
    np.testing.assert_allclose(heights(small, img.shape), stretched(img.astype(float)), atol=1e-9)


def test_max_points_caps_too_and_the_note_names_it():
    img = np.round(smooth(60, 80) * 255).astype(np.uint8)
    cloud = read_cloud(image_bytes(img), max_points=1200)
    assert cloud.n_points == 40 * 30
    assert "80 x 60" in cloud.warnings[0] and "input.max_points = 1,200" in cloud.warnings[0]


def test_a_jpeg_up_to_64_times_max_pixels_is_decoded_at_a_reduced_scale():
    z = smooth(384, 512, seed=3)
    data = encode(np.round(z * 255).astype(np.uint8), "JPEG", quality=95)   # 196,608 pixels = 64 x 3072
    cloud = read_cloud(data, relief={"max_pixels": 3072})
    assert cloud.n_points == 64 * 48
    note = cloud.warnings[0]
    assert "512 x 384" in note and "64 x 48" in note and "1/8 scale" in note and "input.relief.max_pixels" in note
    # libjpeg's 1/8 scale keeps each 8 x 8 block's mean (its DC coefficient)
    np.testing.assert_allclose(heights(cloud, (48, 64)), stretched(block_mean(z * 255, 8)), atol=0.25)
    err = pytest.raises(InputTooLarge, read_cloud, data, relief={"max_pixels": 3071}).value
    assert err.code == "too_many_pixels" and "JPEG" in err.message
    png = image_bytes(np.round(z * 255).astype(np.uint8))       # the same pixels as a PNG: over 16 x
    assert pytest.raises(InputTooLarge, read_cloud, png, relief={"max_pixels": 3072}).value.code == "too_many_pixels"


# ------------------------------------------------------------------------------ data short of its header

def test_files_holding_less_pixel_data_than_their_header_declares_are_truncated(tmp_path):
    img = np.random.default_rng(5).integers(0, 256, (64, 64), dtype=np.uint8)
    jpeg = image_bytes(np.dstack([img] * 3), fmt="JPEG")
    cases = {
        "tall.png": png_with_height(image_bytes(img), 4000),       # Pillow fills the missing rows with 0
        "tall.tif": tiff_with_height(image_bytes(img, fmt="TIFF"), 4000),   # one strip of 64 rows
        "cut.jpg": jpeg[: len(jpeg) // 2],                         # no end marker
    }
    for name, data in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        err = pytest.raises(InputError, read_cloud, path).value
        assert err.code == "truncated_file" and name in err.message, (name, err.code, err.message)


# ------------------------------------------------------------------------------- non-finite pixels

def float_tiff(array) -> bytes:
    return image_bytes(np.asarray(array, dtype=np.float32), fmt="TIFF")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_float_pixel_is_refused_or_filled_from_its_nearest_neighbour(bad):
    z = smooth(40, 50, seed=1).astype(np.float32)
    v = np.float32(0.4321)
    z[6, 11] = z[8, 11] = z[7, 10] = z[7, 12] = v                 # the four nearest pixels agree
    holed = z.copy()
    holed[7, 11] = bad
    err = pytest.raises(InputError, read_cloud, float_tiff(holed)).value
    assert err.code == "non_finite"
    assert "1 pixel" in err.message and "column 11, row 7" in err.message
    assert "input.relief.fill_missing" in err.message
    filled = read_cloud(float_tiff(holed), relief={"fill_missing": True})
    expected = z.copy()
    expected[7, 11] = v
    reference = read_cloud(float_tiff(expected))
    np.testing.assert_array_equal(filled.points, reference.points)
    assert len(filled.warnings) == 1 and "1 pixel" in filled.warnings[0]
    assert "input.relief.fill_missing" in filled.warnings[0]


def test_filled_pixels_take_the_value_of_a_nearest_finite_pixel():
    rng = np.random.default_rng(2)
    z = rng.uniform(0.0, 1.0, (30, 40)).astype(np.float32)
    bad = np.zeros(z.shape, bool)
    bad[0:4, 0:5] = True                                          # a corner block
    bad[12:15, 20:31] = True                                      # a band inside
    bad[rng.integers(0, 30, 12), rng.integers(0, 40, 12)] = True  # scattered pixels
    holed = z.copy()
    holed[bad] = np.nan
    cloud = read_cloud(float_tiff(holed), relief={"fill_missing": True})
    lo, hi = z[~bad].min(), z[~bad].max()                         # the fill adds no new value
    got = lo + heights(cloud, z.shape) / 10.0 * (hi - lo)
    good_rc = np.argwhere(~bad)
    for r, c in np.argwhere(bad):
        d2 = ((good_rc - (r, c)) ** 2).sum(axis=1)
        candidates = z[tuple(good_rc[d2 == d2.min()].T)]
        assert np.isclose(candidates, got[r, c], rtol=0, atol=1e-6).any(), (r, c)
    np.testing.assert_allclose(got[~bad], z[~bad], atol=1e-6)
    assert f"{int(bad.sum())} pixel(s)" in cloud.warnings[0]


def test_non_finite_pixels_are_counted_and_an_image_without_a_finite_pixel_is_refused():
    z = smooth(20, 30).astype(np.float32)
    z[3, 4], z[5, 6], z[19, 29] = np.nan, np.inf, -np.inf
    err = pytest.raises(InputError, read_cloud, float_tiff(z)).value
    assert err.code == "non_finite" and "3 pixel" in err.message and "column 4, row 3" in err.message
    for fill in (False, True):
        err = pytest.raises(InputError, read_cloud, float_tiff(np.full((8, 9), np.nan)),
                            relief={"fill_missing": fill}).value
        assert err.code == "non_finite" and "72" in err.message


def test_a_float_image_over_max_pixels_is_filled_before_it_is_scaled_down():
    z = smooth(64, 64, seed=4).astype(np.float32)
    holed = z.copy()
    holed[10, 10] = np.nan
    err = pytest.raises(InputError, read_cloud, float_tiff(holed), relief={"max_pixels": 256}).value
    assert err.code == "non_finite" and "column 10, row 10" in err.message     # counted at full size
    cloud = read_cloud(float_tiff(holed), relief={"max_pixels": 256, "fill_missing": True})
    assert cloud.n_points == 256 and len(cloud.warnings) == 2
    assert np.isfinite(cloud.points).all()


# ------------------------------------------------------------------------------ through the config

def test_the_parameters_come_through_the_configuration():
    params = parse_config({"input": {"relief": {"max_pixels": 768, "fill_missing": True}}}).input
    assert (params.relief.max_pixels, params.relief.fill_missing) == (768, True)
    defaults = parse_config({}).input.relief
    assert defaults.fill_missing is False and 500 * 500 <= defaults.max_pixels <= 4_194_304
    img = np.round(smooth(96, 128) * 65535).astype(np.uint16)
    cloud = read_input(image_bytes(img), params)
    assert cloud.n_points == 768 and "input.relief.max_pixels = 768" in cloud.warnings[0]
    holed = smooth(20, 20).astype(np.float32)
    holed[4, 4] = np.nan
    assert read_input(float_tiff(holed), params).n_points == 400
    refused = parse_config({"input": {"relief": {"max_pixels": 100}}}).input
    assert pytest.raises(InputTooLarge, read_input, image_bytes(img), refused).value.code == "too_many_pixels"
    assert pytest.raises(InputError, read_input, float_tiff(holed), refused).value.code == "non_finite"
    for bad in ({"max_pixels": 3}, {"max_pixels": 10**9}, {"fill_missing": "maybe"}):
        with pytest.raises(ParameterError):
            parse_config({"input": {"relief": bad}})
