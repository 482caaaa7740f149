"""Procedural textures and backgrounds: pure functions of a random generator and a size.

Each returns an RGB image (h, w, 3) uint8. Used for backgrounds, the floor and distractors.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from dream.errors import InputError

NOISE_OCTAVES = 4
NOISE_BASE_CELLS = (2, 6)          # coarsest noise grid, cells per side
CHECKER_CELLS = (2, 24)            # checker squares per image width
STRIPE_PERIOD_FRACTION = (0.02, 0.3)
SHAPES_COUNT = (5, 40)
PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")
DRAW_SCALE = 0.5                   # procedural textures are drawn at this scale, then resized


def random_color(rng: np.random.Generator) -> np.ndarray:
    return rng.integers(0, 256, 3).astype(np.float32)


PALETTE_LEVELS = 256


def _colorize(t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Blend two colours by t (h, w) in [0, 1], through a 256-entry palette (fast)."""
    ramp = np.linspace(0.0, 1.0, PALETTE_LEVELS, dtype=np.float32)[:, None]
    palette = np.clip(a + (b - a) * ramp, 0, 255).astype(np.uint8)
    index = np.clip(t * (PALETTE_LEVELS - 1) + 0.5, 0, PALETTE_LEVELS - 1).astype(np.uint8)
    return palette[index]


@lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    u.setflags(write=False)
    v.setflags(write=False)
    return u, v


def noise(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Multi-octave value noise between two random colours."""
    t = np.zeros((h, w), np.float32)
    cells = int(rng.integers(*NOISE_BASE_CELLS))
    amplitude, total = 1.0, 0.0
    for _ in range(NOISE_OCTAVES):
        grid = rng.random((cells + 1, cells + 1)).astype(np.float32)
        t += amplitude * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amplitude
        amplitude *= 0.5
        cells *= 2
    t = (t / total - t.min() / total)
    t /= max(float(t.max()), 1e-6)
    return _colorize(t, random_color(rng), random_color(rng))


def _rotated_coordinates(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    angle = rng.uniform(0, np.pi)
    u, v = _pixel_grid(h, w)
    c, s = np.float32(np.cos(angle)), np.float32(np.sin(angle))
    return u * c + v * s, v * c - u * s


def checkers(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    cell = w / rng.integers(*CHECKER_CELLS)
    x, y = _rotated_coordinates(rng, h, w)
    t = ((np.floor(x / cell) + np.floor(y / cell)) % 2).astype(np.float32)
    return _colorize(t, random_color(rng), random_color(rng))


def stripes(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    period = max(2.0, w * rng.uniform(*STRIPE_PERIOD_FRACTION))
    x, _ = _rotated_coordinates(rng, h, w)
    wave = np.sin(2 * np.pi * x / period)
    t = (wave > 0).astype(np.float32) if rng.random() < 0.5 else (wave + 1) / 2
    return _colorize(t.astype(np.float32), random_color(rng), random_color(rng))


def gradient(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    x, _ = _rotated_coordinates(rng, h, w)
    lo, hi = float(x.min()), float(x.max())
    return _colorize((x - lo) / max(hi - lo, 1e-6), random_color(rng), random_color(rng))


def shapes(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Random filled circles, rectangles and thick lines on a random colour."""
    image = np.empty((h, w, 3), np.uint8)
    image[:] = random_color(rng).astype(np.uint8)
    scale = max(h, w)
    for _ in range(int(rng.integers(*SHAPES_COUNT))):
        color = tuple(int(c) for c in random_color(rng))
        kind = rng.integers(3)
        p = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        if kind == 0:
            cv2.circle(image, p, int(rng.uniform(0.02, 0.2) * scale), color, -1)
        elif kind == 1:
            q = (p[0] + int(rng.uniform(-0.3, 0.3) * scale), p[1] + int(rng.uniform(-0.3, 0.3)
                                                                         * scale))
            cv2.rectangle(image, p, q, color, -1)
        else:
            q = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            cv2.line(image, p, q, color, max(1, int(rng.uniform(0.005, 0.05) * scale)))
    return image


BOARD_SQUARES = (4, 10)            # a calibration board's squares per side
BOARD_BORDER_SQUARES = 0.5         # its white margin, in squares


def calibration_board(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A black-and-white checkerboard with a white margin, as printed calibration targets are
    (squares aligned with the texture's axes)."""
    n = int(rng.integers(BOARD_SQUARES[0], BOARD_SQUARES[1] + 1))
    cell = min(h, w) / (n + 2 * BOARD_BORDER_SQUARES)
    u, v = _pixel_grid(h, w)
    i = np.floor(u / cell - BOARD_BORDER_SQUARES)
    j = np.floor(v / cell - BOARD_BORDER_SQUARES)
    inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
    black = inside & ((i + j) % 2 == 0)
    image = np.full((h, w, 3), 255, np.uint8)
    image[black] = 0
    return image


def list_photos(folder: str | Path) -> tuple[Path, ...]:
    """Image files of a user's photo folder, sorted (so the choice is reproducible)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("background photo folder not found", folder,
                         "give a folder of .png/.jpg photos or set background.photos to null")
    photos = tuple(sorted(p for p in folder.iterdir() if p.suffix.lower() in PHOTO_EXTENSIONS))
    if not photos:
        raise InputError("no .png/.jpg photos in the background folder", folder)
    return photos


def read_photo(path: Path) -> np.ndarray:
    """A background photo as (H, W, 3) uint8 BGR; an `InputError` naming it when OpenCV
    cannot decode it."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError("unreadable background photo", path,
                         "remove it from background.photos or re-save it as .png/.jpg")
    return bgr


def read_plate(config) -> np.ndarray:
    """The recipe's `background.plate` as (H, W, 3) uint8 RGB; an `InputError` naming it when
    it is missing, unreadable or not of the images' size (`intrinsics.width`, `height`)."""
    plate = Path(config.background.plate)
    if not plate.is_file():
        raise InputError("background plate not found", plate,
                         "give an image of the camera's size or set background.plate to null")
    bgr = read_photo(plate)
    size = (config.intrinsics.width, config.intrinsics.height)
    if bgr.shape[1::-1] != size:
        raise InputError(f"the background plate is {bgr.shape[1]}x{bgr.shape[0]} pixels, the "
                         f"images {size[0]}x{size[1]}", plate,
                         "set intrinsics.width and intrinsics.height to the plate's size")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def photo(rng: np.random.Generator, h: int, w: int, photos: tuple[Path, ...]) -> np.ndarray:
    """A random crop of a random photo, resized to (h, w)."""
    path = photos[int(rng.integers(len(photos)))]
    bgr = read_photo(path)
    H, W = bgr.shape[:2]
    scale = rng.uniform(0.5, 1.0)
    ch, cw = max(2, int(H * scale)), max(2, int(W * scale))
    y, x = int(rng.integers(0, H - ch + 1)), int(rng.integers(0, W - cw + 1))
    crop = cv2.resize(bgr[y:y + ch, x:x + cw], (w, h), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(crop, cv2.COLOR_BGR2RGB)


PROCEDURAL: dict[str, Callable[[np.random.Generator, int, int], np.ndarray]] = {
    "noise": noise, "checkers": checkers, "stripes": stripes, "gradient": gradient,
    "shapes": shapes,
}


def random_texture(rng: np.random.Generator, h: int, w: int, kinds: dict[str, float],
                   photos: tuple[Path, ...] = ()) -> np.ndarray:
    """A texture of a kind drawn with the given weights ('photo' only when photos exist).

    Procedural kinds are drawn at `DRAW_SCALE` of the size and upscaled (4x less work)."""
    names = [k for k, wgt in kinds.items() if wgt > 0 and (k != "photo" or photos)]
    if not names:
        names = list(PROCEDURAL)
    weights = np.array([kinds.get(k, 1.0) for k in names], float)
    kind = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    if kind == "photo":
        return photo(rng, h, w, photos)
    small = PROCEDURAL[kind](rng, max(1, round(h * DRAW_SCALE)), max(1, round(w * DRAW_SCALE)))
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
