"""Synthetic off-road sequences: a camera driving along a winding trail, with fine-grained labels.

Every frame is a pure function of ``(domain, sequence, index, seed)`` and the resolution. The
world of one sequence is fixed: a trail ``x_c(z) = A sin(z / lambda + phi)`` whose surface
(earth, gravel, fallen leaves, lime / mud) and verge (grass, mud) come from hashed value noise in
world coordinates; bushes, trees, stones and logs stand at hashed places in 4 m cells along the
trail; a forest band and the sky close the view. The camera moves 0.5 m per frame along the
trail, so neighbouring frames are near-duplicates (the hard-frame gap of Eq. 16 relies on that).

Texture separates the classes more than colour does: each class mixes two tones of its domain's
palette with its own noise frequency and grain, all in world (or object) coordinates, so a
surface keeps its texture while the camera moves.

Domains (``DOMAINS``) play the paper's roles: ``"A"`` summer trails (training); ``"B"`` and
``"C"`` new terrain (more gravel, leaves and lime), an autumn palette and warmer, lower light
(``B`` for active learning, ``C`` for testing, different worlds); ``"D"`` and ``"E"`` a darker
forest-trail look in the manner of DeepScene (train / test).

Labels: ``LV3`` (10 classes, the generator's own), mapped by ``to_granularity`` to ``"lv2"``
(6), ``"lv1"`` (4) and ``"deepscene"`` (5: trail, grass, vegetation, sky, obstacle, the
Freiburg Forest classes). NumPy and OpenCV only.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np

LV3 = ("earth", "gravel", "leaves", "mud", "grass", "bush", "tree", "stone", "log", "sky")
EARTH, GRAVEL, LEAVES, MUD, GRASS, BUSH, TREE, STONE, LOG, SKY = range(10)
GRANULARITIES = {
    "lv3": (LV3, np.arange(10)),
    "lv2": (("hard trail", "soft ground", "grass", "shrubs and trees", "obstacle", "sky"),
            np.array([0, 0, 1, 1, 2, 3, 3, 4, 4, 5])),
    "lv1": (("trail", "vegetation", "obstacle", "sky"), np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 3])),
    "deepscene": (("trail", "grass", "vegetation", "sky", "obstacle"), np.array([0, 0, 0, 0, 1, 2, 2, 4, 4, 3])),
}
METRES_PER_FRAME = 0.5  # metres the camera moves per frame
_CELL = 4.0  # metres of trail per object cell
_FAR = 45.0  # metres: beyond this the ground gives way to the forest band


@dataclasses.dataclass(frozen=True)
class Domain:
    """Terrain, objects, palette and light of a domain.

    ``surface``: probabilities of gravel / leaves / mud patches on the trail (earth elsewhere);
    ``verge_mud``: of mud patches on the verge; ``objects``: expected bushes, trees, stones, logs
    per 4 m cell; ``palette``: (10, 2, 3) two RGB tones per LV3 class; ``light``: brightness;
    ``cast``: RGB gain.
    """

    surface: tuple[float, float, float]
    verge_mud: float
    objects: tuple[float, float, float, float]
    trail_width: float
    amplitude: float
    palette: np.ndarray
    light: float
    cast: tuple[float, float, float]


_SUMMER = np.array([
    [[132, 100, 68], [104, 78, 52]], [[150, 146, 138], [96, 92, 88]], [[150, 104, 48], [92, 64, 30]],
    [[196, 188, 170], [120, 110, 96]], [[88, 140, 52], [60, 104, 36]], [[58, 106, 46], [34, 72, 30]],
    [[40, 80, 34], [74, 58, 40]], [[128, 126, 120], [84, 84, 82]], [[120, 84, 50], [80, 54, 34]],
    [[150, 190, 235], [215, 230, 245]]], dtype=np.float32)
_AUTUMN = _SUMMER.copy()
_AUTUMN[GRASS] = [[150, 146, 70], [112, 104, 50]]
_AUTUMN[BUSH] = [[140, 96, 40], [96, 80, 36]]
_AUTUMN[TREE] = [[170, 96, 30], [90, 62, 36]]
_AUTUMN[LEAVES] = [[190, 120, 40], [140, 70, 30]]
_AUTUMN[SKY] = [[170, 180, 196], [220, 222, 226]]
_FOREST = _SUMMER * 0.8
_FOREST[GRASS] = [[70, 150, 40], [40, 110, 26]]
_FOREST[TREE] = [[30, 66, 26], [56, 50, 34]]
_FOREST[SKY] = [[180, 205, 240], [235, 240, 250]]

DOMAINS = {
    "A": Domain((0.15, 0.05, 0.05), 0.08, (0.8, 1.2, 0.4, 0.15), 1.6, 4.0, _SUMMER, 1.0, (1.0, 1.0, 1.0)),
    "B": Domain((0.35, 0.3, 0.2), 0.15, (0.6, 1.0, 0.8, 0.35), 2.0, 6.0, _AUTUMN, 0.82, (1.08, 0.98, 0.86)),
    "C": Domain((0.35, 0.3, 0.2), 0.15, (0.6, 1.0, 0.8, 0.35), 2.0, 6.0, _AUTUMN, 0.82, (1.08, 0.98, 0.86)),
    "D": Domain((0.1, 0.15, 0.1), 0.05, (1.2, 2.4, 0.3, 0.3), 1.2, 3.0, _FOREST, 0.9, (0.96, 1.0, 1.04)),
    "E": Domain((0.1, 0.15, 0.1), 0.05, (1.2, 2.4, 0.3, 0.3), 1.2, 3.0, _FOREST, 0.9, (0.96, 1.0, 1.04)),
}
_DOMAIN_ID = {name: i for i, name in enumerate(DOMAINS)}
# Per-class texture: noise frequency (1/m) of the tone mix, of the grain, grain strength, and
# the anisotropy of the grain (ratio of its vertical to horizontal frequency; > 1: streaks).
_TEXTURE = np.array([
    [0.6, 6.0, 0.10, 1.0], [1.5, 40.0, 0.35, 1.0], [2.5, 12.0, 0.30, 1.0], [0.4, 3.0, 0.06, 1.0],
    [1.0, 30.0, 0.25, 0.2], [2.0, 10.0, 0.30, 1.0], [1.2, 8.0, 0.35, 0.3], [1.0, 14.0, 0.18, 1.0],
    [0.5, 10.0, 0.20, 4.0], [0.05, 0.3, 0.03, 1.0]], dtype=np.float32)


def _hash(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """A uniform value in [0, 1) per integer lattice point (a splitmix64-style mix)."""
    with np.errstate(over="ignore"):  # multiplication modulo 2**64 is the point
        h = (np.asarray(ix).astype(np.int64).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
             ^ np.asarray(iy).astype(np.int64).astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ np.uint64(salt) * np.uint64(0x165667B19E3779F9))
        h ^= h >> np.uint64(31)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(29)
    return (h >> np.uint64(40)).astype(np.float32) / np.float32(1 << 24)


def value_noise(x: np.ndarray, y: np.ndarray, salt: int) -> np.ndarray:
    """Smooth noise in [0, 1] at real coordinates: hashed lattice values, smoothstep-interpolated."""
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    ix, iy = x0.astype(np.int64), y0.astype(np.int64)
    top = _hash(ix, iy, salt) * (1 - fx) + _hash(ix + 1, iy, salt) * fx
    bottom = _hash(ix, iy + 1, salt) * (1 - fx) + _hash(ix + 1, iy + 1, salt) * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def _trail(z, amplitude: float, salt: int):
    """Trail centre x_c(z) (metres) of a sequence's world."""
    phase = 2 * np.pi * _hash(np.array(salt), np.array(0), 7)
    return amplitude * np.sin(z / 14.0 + phase) + 0.4 * amplitude * np.sin(z / 5.3 + 2 * phase)


def _ground_classes(x, z, trail_x, domain: Domain, salt: int) -> np.ndarray:
    """LV3 class of ground points (world metres)."""
    edge = domain.trail_width * (1 + 0.25 * (value_noise(z * 0.4, x * 0.0, salt + 1) - 0.5)) \
        + 0.3 * (value_noise(x * 2, z * 2, salt + 2) - 0.5)
    on_trail = np.abs(x - trail_x) < edge
    cls = np.where(on_trail, EARTH, GRASS)
    for offset, (kind, p) in enumerate(zip((GRAVEL, LEAVES, MUD), domain.surface)):
        patch = value_noise(x * 0.45, z * 0.22, salt + 10 + offset) > 1 - p ** 0.5 * 0.75
        cls = np.where(on_trail & patch & (cls == EARTH), kind, cls)
    verge = value_noise(x * 0.5, z * 0.3, salt + 20) > 1 - domain.verge_mud ** 0.5 * 0.75
    return np.where(~on_trail & verge, MUD, cls).astype(np.uint8)


def _objects(domain: Domain, salt: int, z_from: float, z_to: float, trail) -> list[tuple]:
    """``(z, x, kind, size, rng seed)`` of every object in the cells covering [z_from, z_to]."""
    found = []
    for cell in range(int(np.floor(z_from / _CELL)), int(np.floor(z_to / _CELL)) + 1):
        rng = np.random.default_rng([salt, cell & 0xFFFFFFFF, 99])
        for kind, rate in zip((BUSH, TREE, STONE, LOG), domain.objects):
            for _ in range(rng.poisson(rate)):
                z = (cell + rng.uniform()) * _CELL
                side = rng.choice([-1.0, 1.0])
                if kind == TREE:
                    offset, size = domain.trail_width + rng.uniform(2.0, 12.0), rng.uniform(2.5, 5.0)
                elif kind == BUSH:
                    offset, size = domain.trail_width + rng.uniform(0.4, 6.0), rng.uniform(0.5, 1.2)
                elif kind == STONE:
                    offset, size = rng.uniform(0.0, domain.trail_width + 3.0), rng.uniform(0.25, 0.7)
                else:
                    offset, size = domain.trail_width + rng.uniform(-0.8, 4.0), rng.uniform(1.2, 3.0)
                found.append((z, float(trail(z)) + side * offset, kind, size, int(rng.integers(1 << 30))))
    return found


def _draw_object(ids, tex, obj, index, cam, f, cy, cx, h) -> None:
    """Draw one object into the class map ``ids`` and its local texture coordinates ``tex``."""
    z, x, kind, size, seed = obj
    zr, xr = z - cam[1], x - cam[0]
    if zr < 1.0:
        return
    s = f / zr  # pixels per metre
    u, v = cx + s * xr, cy + s * h
    rng = np.random.default_rng(seed)
    mask = np.zeros(ids.shape, np.uint8)
    if kind == TREE:
        trunk = max(1, int(round(0.12 * size * s)))
        cv2.rectangle(mask, (int(u) - trunk, int(v - 0.45 * size * s)), (int(u) + trunk, int(v)), 1, -1)
        axes = (max(1, int(0.35 * size * s * rng.uniform(0.8, 1.2))), max(1, int(0.4 * size * s)))
        cv2.ellipse(mask, (int(u), int(v - 0.75 * size * s)), axes, 0, 0, 360, 1, -1)
    elif kind == BUSH:
        axes = (max(1, int(0.6 * size * s)), max(1, int(0.45 * size * s)))
        cv2.ellipse(mask, (int(u), int(v - 0.3 * size * s)), axes, 0, 0, 360, 1, -1)
    elif kind == STONE:
        axes = (max(1, int(0.55 * size * s)), max(1, int(0.4 * size * s)))
        cv2.ellipse(mask, (int(u), int(v)), axes, 0, 180, 360, 1, -1)
    else:
        angle = rng.uniform(-20, 20)
        box = ((u, v - 0.12 * s), (size * s, max(2.0, 0.25 * s)), angle)
        cv2.fillPoly(mask, [np.round(cv2.boxPoints(box)).astype(np.int32)], 1)
    hit = mask.astype(bool)
    ids[hit] = kind
    rows, cols = np.nonzero(hit)
    tex[rows, cols, 0] = (cols - u) / s + 37.0 * index
    tex[rows, cols, 1] = (rows - v) / s


def generate_frame(domain: str, sequence: int, index: int, seed: int = 0, *, height: int = 128,
                   width: int = 256) -> dict[str, Any]:
    """One frame: ``"image"`` (H, W, 3) uint8 RGB, ``"label"`` (H, W) uint8 LV3 ids, ``"name"``."""
    if domain not in DOMAINS:
        raise ValueError(f"domain: expected one of {sorted(DOMAINS)}, got {domain!r}")
    if height < 16 or width < 16:
        raise ValueError(f"height, width: expected >= 16 pixels each, got {height} x {width}")
    if min(sequence, index, seed) < 0:
        raise ValueError(f"sequence, index, seed: expected >= 0, got {sequence}, {index}, {seed}")
    d = DOMAINS[domain]
    salt = int(_hash(np.array(seed), np.array(_DOMAIN_ID[domain] * 1000 + sequence), 3) * (1 << 24))
    trail = lambda z: _trail(z, d.amplitude, salt)  # noqa: E731
    f, cy, cx, h = 0.9 * width, 0.42 * height, 0.5 * width, 1.5
    z_cam = METRES_PER_FRAME * index
    cam = (float(0.5 * (trail(z_cam + 2.0) + trail(z_cam))), z_cam)

    v, u = np.mgrid[0:height, 0:width].astype(np.float32) + 0.5
    below = v > cy + f * h / _FAR
    zr = np.where(below, f * h / np.maximum(v - cy, 1e-3), _FAR)
    xw, zw = cam[0] + (u - cx) * zr / f, cam[1] + zr
    azimuth = (u - cx) / f + 0.002 * z_cam
    band_top = cy - height * (0.08 + 0.14 * value_noise(azimuth * 12, np.zeros_like(u), salt + 30))
    ids = np.where(below, _ground_classes(xw, zw, trail(zw), d, salt),
                   np.where(v > band_top, TREE, SKY)).astype(np.uint8)
    tex = np.stack([np.where(below, xw, azimuth * 40), np.where(below, zw, (v - cy) / f * 40)], -1)
    objects = sorted(_objects(d, salt, z_cam + 1.0, z_cam + _FAR, trail), key=lambda o: -o[0])
    for i, obj in enumerate(objects):
        _draw_object(ids, tex, obj, i, cam, f, cy, cx, h)

    t = _TEXTURE[ids]
    mix = value_noise(tex[..., 0] * t[..., 0], tex[..., 1] * t[..., 0], salt + 40)
    grain = value_noise(tex[..., 0] * t[..., 1], tex[..., 1] * t[..., 1] * t[..., 3], salt + 41) - 0.5
    tones = d.palette[ids]
    rgb = tones[..., 0, :] * (1 - mix[..., None]) + tones[..., 1, :] * mix[..., None]
    rgb *= 1 + 2 * t[..., 2:3] * grain[..., None]
    haze = np.where(ids == SKY, 0.0, np.clip(zr / (2.5 * _FAR), 0, 0.35))[..., None]
    rgb = rgb * (1 - haze) + d.palette[SKY, 1] * haze
    rgb *= d.light * np.asarray(d.cast, np.float32) * (1.05 - 0.1 * v[..., None] / height)
    return {"image": np.clip(rgb + 0.5, 0, 255).astype(np.uint8), "label": ids,
            "name": f"{domain}{sequence:02d}_{seed}_{index:05d}"}


def to_granularity(label: np.ndarray, granularity: str) -> np.ndarray:
    """LV3 labels (255 kept) -> the ids of ``granularity`` in ``GRANULARITIES``."""
    if granularity not in GRANULARITIES:
        raise ValueError(f"granularity: expected one of {sorted(GRANULARITIES)}, got {granularity!r}")
    table = np.full(256, 255, np.uint8)
    table[:10] = GRANULARITIES[granularity][1]
    return table[np.asarray(label, np.uint8)]


class OffroadSequence:
    """Random-access frames ``start .. start + num_frames - 1`` of one synthetic sequence.

    ``[i]`` -> ``{"image", "label" (in ``granularity``), "lv3", "name"}``.
    """

    def __init__(self, domain: str, sequence: int, num_frames: int, seed: int = 0, *, start: int = 0,
                 granularity: str = "lv3", height: int = 128, width: int = 256):
        if domain not in DOMAINS:
            raise ValueError(f"domain: expected one of {sorted(DOMAINS)}, got {domain!r}")
        if granularity not in GRANULARITIES:
            raise ValueError(f"granularity: expected one of {sorted(GRANULARITIES)}, got {granularity!r}")
        if num_frames < 1 or start < 0:
            raise ValueError(f"num_frames, start: expected >= 1 and >= 0, got {num_frames}, {start}")
        self.domain, self.sequence, self.num_frames, self.seed = domain, sequence, num_frames, seed
        self.start, self.granularity, self.size = start, granularity, (height, width)

    def __len__(self) -> int:
        return self.num_frames

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not 0 <= index < self.num_frames:
            raise IndexError(f"index {index} out of range for {self.num_frames} frames")
        frame = generate_frame(self.domain, self.sequence, self.start + int(index), self.seed,
                               height=self.size[0], width=self.size[1])
        return {**frame, "lv3": frame["label"], "label": to_granularity(frame["label"], self.granularity)}

    def __repr__(self) -> str:
        return (f"OffroadSequence({self.domain!r}, {self.sequence}, num_frames={self.num_frames}, "
                f"seed={self.seed}, start={self.start}, granularity={self.granularity!r})")
