"""Loading a frame's RGB image and robot mask, from image files or `.npz` image stacks.

Images come back as (H, W, 3) uint8 RGB; masks as (H, W) bool (non-zero = robot) or as the raw
integer ids. Unreadable, truncated or corrupt files, and images whose size is not the camera's,
are `InputError`s naming the file. `image_size` reads only a PNG or JPEG header.
"""

from __future__ import annotations

import logging
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.io import npz
from dream.io.fields import one_line, read_bytes
from dream.sequence import Frame

logger = logging.getLogger(__name__)

NPZ_SUFFIX = ".npz"
STACK_KEY = "rgb_images"  # the array of an .npz that holds the RGB image stack
RGB_CHANNELS = 3
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_IEND_CHUNK = b"\x00\x00\x00\x00IEND\xaeB`\x82"
PNG_TAIL_BYTES = 1024  # the IEND chunk must lie within this many bytes of the end
_PNG_CHUNK_OVERHEAD = 12  # length (4), type (4) and CRC (4) around a chunk's data
JPEG_SOI = b"\xff\xd8"
JPEG_EOI = b"\xff\xd9"
# JPEG start-of-frame markers (they carry the image size): C0..CF except DHT, JPG, DAC.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_STANDALONE = frozenset(range(0xD0, 0xD8)) | {0x01}  # markers without a length
_JPEG_MAX_SEGMENTS = 1000
_HEADER_BYTES = 64 * 1024  # enough for a PNG header and JPEG headers with EXIF thumbnails
_MASK_ID_BITS = {np.dtype(np.uint8): 8, np.dtype(np.uint16): 16}
_FIX_IMAGE = "replace it with a complete, readable PNG or JPEG image"


def check_size(width: int, height: int, camera: CameraIntrinsics | None, path: Path) -> None:
    """An `InputError` naming `path` when a width x height image does not fit `camera`."""
    if camera is not None and (width, height) != (camera.width, camera.height):
        raise InputError(f"image is {width}x{height} but the camera settings say "
                         f"{camera.width}x{camera.height}", path,
                         "use images of the camera's resolution or fix the camera settings")


def _png_size(data: bytes) -> tuple[int, int] | None:
    # Signature, then the IHDR chunk: length (4), "IHDR" (4), width (4), height (4).
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    pos = len(JPEG_SOI)
    for _ in range(_JPEG_MAX_SEGMENTS):
        if pos + 4 > len(data) or data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # a fill byte before the marker
            pos += 1
            continue
        if marker in _JPEG_STANDALONE:
            pos += 2
            continue
        length = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        if marker in _JPEG_SOF:
            if pos + 9 > len(data):
                return None
            height, width = struct.unpack(">HH", data[pos + 5:pos + 9])
            return width, height
        pos += 2 + length
    return None


def _header_size(data: bytes) -> tuple[int, int] | None:
    if data.startswith(PNG_SIGNATURE):
        return _png_size(data)
    if data.startswith(JPEG_SOI):
        return _jpeg_size(data)
    return None


def _check_png_chunks(data: bytes, path: Path) -> None:
    """Refuse a PNG whose chunks do not fit in the file or whose critical chunks (IHDR, PLTE,
    IDAT, IEND: an upper-case first letter) fail their CRC: a file damaged in the middle.
    OpenCV's libpng would print its own "libpng error" line on such a file before failing; this
    check (zlib's CRC-32, about a millisecond a megabyte) keeps the error to one line."""
    pos = len(PNG_SIGNATURE)
    while pos + _PNG_CHUNK_OVERHEAD <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        end = pos + _PNG_CHUNK_OVERHEAD + length
        if end > len(data):
            raise InputError(f"PNG image is corrupt (its {_chunk_name(kind)} chunk at byte {pos} "
                             "runs past the end of the file)", path, _FIX_IMAGE)
        if kind[:1].isupper():
            crc = struct.unpack(">I", data[end - 4:end])[0]
            if zlib.crc32(data[pos + 4:end - 4]) != crc:
                raise InputError(f"PNG image is corrupt (CRC error in its {_chunk_name(kind)} "
                                 f"chunk at byte {pos})", path, _FIX_IMAGE)
        if kind == b"IEND":
            return
        pos = end


def _chunk_name(kind: bytes) -> str:
    return kind.decode("ascii", "replace") if kind.isalpha() else repr(kind)


def check_file_end(head: bytes, tail: bytes, path: Path) -> None:
    """Refuse a PNG without its end chunk or a JPEG without its end marker (truncated), from
    the file's first bytes (`head`, at least the PNG signature's 8) and its last
    `PNG_TAIL_BYTES` (`tail`; the whole file when it is shorter)."""
    if head.startswith(PNG_SIGNATURE) and PNG_IEND_CHUNK not in tail[-PNG_TAIL_BYTES:]:
        raise InputError("PNG image is truncated (no IEND chunk at its end)", path, _FIX_IMAGE)
    if head.startswith(JPEG_SOI) and not tail.rstrip(b"\x00").endswith(JPEG_EOI):
        raise InputError("JPEG image is truncated (no end-of-image marker)", path, _FIX_IMAGE)


def _check_complete(data: bytes, path: Path) -> None:
    """Refuse truncated PNGs and JPEGs (`check_file_end`) and PNGs with damaged chunks."""
    check_file_end(data, data, path)
    if data.startswith(PNG_SIGNATURE):
        _check_png_chunks(data, path)


def _decode(path: Path, flags: int) -> np.ndarray:
    data = read_bytes(path, _FIX_IMAGE)
    if not data:
        raise InputError("image file is empty", path, _FIX_IMAGE)
    _check_complete(data, path)
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error as exc:
        raise InputError(f"cannot decode the image ({one_line(exc)})", path, _FIX_IMAGE) from None
    if image is None or image.size == 0:
        raise InputError("cannot decode the image (corrupt or unsupported format)", path,
                         _FIX_IMAGE)
    return image


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) in pixels of an image file, from its header when it is a PNG or JPEG."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(_HEADER_BYTES)
    except FileNotFoundError:
        raise InputError("image file not found", path, "add the image or remove the frame"
                         ) from None
    except (OSError, ValueError) as exc:  # ValueError: a path with a NUL character
        raise InputError(f"cannot read the image ({one_line(exc)})", path, _FIX_IMAGE) from None
    size = _header_size(head)
    if size is not None and size[0] > 0 and size[1] > 0:
        return size
    image = _decode(path, cv2.IMREAD_UNCHANGED)
    return image.shape[1], image.shape[0]


def _stack_image(path: Path, index: int | None) -> np.ndarray:
    if index is None:
        raise InputError("the frame refers to an .npz image stack but gives no image index",
                         path, "set image_index")
    npz.check_rgb_stack(npz.read_header(path, STACK_KEY), STACK_KEY, path)
    return npz.read_stack_item(path, STACK_KEY, index)


def load_image(frame: Frame, camera: CameraIntrinsics | None = None) -> np.ndarray:
    """The frame's image as (H, W, 3) uint8 RGB; checked against `camera`'s size when given."""
    path = frame.image_path
    if path is None:
        raise InputError(f"frame {frame.name} has no image", frame.source,
                         "add the image, or use the labels (--use-labels)")
    if path.suffix.lower() == NPZ_SUFFIX:
        rgb = _stack_image(path, frame.image_index)
    else:
        bgr = _decode(path, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    check_size(rgb.shape[1], rgb.shape[0], camera, path)
    return rgb


def _pack_channels(ids: np.ndarray, path: Path) -> np.ndarray:
    """One integer id per pixel from a colour mask (channels equal, or packed r, g, b)."""
    channels = ids[..., :RGB_CHANNELS] if ids.shape[2] >= RGB_CHANNELS else ids
    if all(np.array_equal(channels[..., 0], channels[..., c])
           for c in range(1, channels.shape[2])):
        return channels[..., 0]
    bits = _MASK_ID_BITS.get(channels.dtype)
    if bits is None:
        raise InputError(f"mask has an unsupported pixel type {channels.dtype}", path,
                         "write the mask as an 8- or 16-bit PNG")
    packed = np.zeros(channels.shape[:2], dtype=np.int64)
    for c in range(channels.shape[2]):  # OpenCV's B, G, R order, packed as R, G, B
        packed |= channels[..., c].astype(np.int64) << (bits * c)
    return packed


def load_mask_ids(frame: Frame, camera: CameraIntrinsics | None = None) -> np.ndarray:
    """The frame's mask as (H, W) int64 ids (0 background, non-zero robot, e.g. link + 1)."""
    path = frame.mask_path
    if path is None:
        raise InputError(f"frame {frame.name} has no robot mask", frame.source,
                         "add the mask image")
    ids = _decode(path, cv2.IMREAD_UNCHANGED)
    if ids.ndim == 3:
        ids = _pack_channels(ids, path)
    if ids.ndim != 2 or ids.dtype.kind not in "iu":
        raise InputError(f"mask must be a single-channel integer image, got {ids.shape} "
                         f"{ids.dtype}", path, "write the mask as an 8- or 16-bit PNG")
    check_size(ids.shape[1], ids.shape[0], camera, path)
    return ids.astype(np.int64)


def load_mask(frame: Frame, camera: CameraIntrinsics | None = None) -> np.ndarray:
    """The frame's robot mask as (H, W) bool: True where the mask is non-zero."""
    return load_mask_ids(frame, camera) != 0


def encode_png(image: np.ndarray, path: Path) -> bytes:
    """PNG bytes of an (H, W) integer or (H, W, 3) uint8 RGB image."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    try:
        ok, buf = cv2.imencode(".png", image)
    except cv2.error as exc:
        raise InputError(f"cannot encode the image as PNG ({one_line(exc)})", path) from None
    if not ok:
        raise InputError("cannot encode the image as PNG", path)
    return buf.tobytes()


def mask_ids_for_png(ids: np.ndarray, path: Path) -> np.ndarray:
    """Mask ids in the smallest unsigned type a PNG holds (8 or 16 bit)."""
    top = int(ids.max()) if ids.size else 0
    low = int(ids.min()) if ids.size else 0
    for dtype in (np.uint8, np.uint16):
        if low >= 0 and top <= np.iinfo(dtype).max:
            return ids.astype(dtype)
    raise InputError(f"mask ids range {low}..{top} do not fit a 16-bit PNG", path,
                     "store at most 65535 distinct non-negative ids")
