"""Procedural street scenes: the 19 Cityscapes classes, per-pixel depth, and road anomalies.

Every frame is a pure function of ``(split, index, seed)`` and the resolution: a small 3-D scene
(flat ground, a straight road to a vanishing point, facades, walls, fences, trees, poles with
signs and lights, vehicles, people, two-wheelers) is drawn through a pinhole camera with OpenCV's
polygon filling, far to near. Each drawn part is a *surface* with its own class, colour (the
official Cityscapes colour of its class, jittered per instance), texture strength and depth
model, so the image is the official palette only as a base tone: per-instance colour, texture
noise, a vertical light gradient, scene brightness / colour cast and distance haze make the
colour of a pixel an uncertain cue for its class.

Splits (``SPLITS``): ``"train"`` and ``"val"`` hold in-distribution content only. ``"anomaly"``,
``"anomaly_small"`` (small objects 25-80 m away, brought nearer where they would be under ~4
pixels tall) and ``"anomaly_large"`` (large objects 5-20 m away) add 1-3 objects no training
frame has (``scene_objects.anomaly_object``: rocks, boxes, cones in odd colours, animal-like
blobs with spots) standing on the road; ``"anomaly"`` mixes both sizes. Their ``"label"`` is
Fishyscapes-style: 0 in-distribution, 1 anomaly, 255 void. Void is a band of ``void_band``
pixels around each anomaly (annotations are uncertain at object borders, as in Fishyscapes);
with ``off_road_void=True`` every pixel that is neither road nor anomaly is void as well (as in
SegmentMeIfYouCan RoadObstacle21, which scores the road only).

For MMF (docs/papers/mmf.md#synthetic-extensions), all off by default (frames are then byte-identical to those without the
options): ``disparity=True`` adds ``"disparity"`` = f B / Z in pixels (0 on the sky) with the
Cityscapes stereo baseline B = ``BASELINE`` and the frame's focal length, plus ``"camera"``
(Cityscapes' camera-file fields), with ``disparity_noise=(sigma_rel, hole_fraction)`` for a
multiplicative Gaussian error and randomly missing (0) pixels; ``void_objects=k`` places up to k
muted street-clutter objects (bins, boards, pallets, sacks) on the road of ``"train"`` / ``"val"``
frames, 255 in ``"label"`` / ``"semantic"`` and True in ``"void"`` (the analogue of Cityscapes
void, which MMF trains on as anomaly); ``roi=True`` adds ``"roi"``, the road region (road,
anomalies and clutter standing on it), where MMF is evaluated. Clutter and noise draw from their
own random streams, so a frame's scene and image elsewhere are those of the plain frame.

Depth is metric (float32, metres along the optical axis); the sky gets ``SKY_DEPTH``.
NumPy and OpenCV only (no grain, no JAX).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np

from jaxanom.data.cityscapes_labels import CLASS_COLORS, IGNORE_INDEX
from jaxanom.data.scene_objects import (
    ANOMALY, BICYCLE, BUILDING, BUS, CAR, CLUTTER, FENCE, LIGHT, MOTORCYCLE, POLE, ROAD, SIDEWALK, SIGN, SKY,
    TERRAIN, TRAIN, TRUCK, VEGETATION, WALL, anomaly_object, clutter_object, person, pole, tone, tree, two_wheeler,
    vehicle)

SPLITS = {"train": 0, "val": 1, "anomaly": 2, "anomaly_small": 3, "anomaly_large": 4}
ANOMALY_SPLITS = ("anomaly", "anomaly_small", "anomaly_large")
SKY_DEPTH = 1000.0
BASELINE = 0.209313  # metres: the Cityscapes stereo baseline (camera/*.json "extrinsic")


# Texture strength (relative luminance noise) of each class, then of anomalies and clutter.
_TEXTURE = np.array([0.06, 0.06, 0.09, 0.08, 0.10, 0.05, 0.05, 0.04, 0.28, 0.16, 0.02, 0.09,
                     0.09, 0.05, 0.06, 0.05, 0.05, 0.07, 0.07, 0.18, 0.12], dtype=np.float32)
_GROUND, _SIDE, _FRONTAL, _SKY = range(4)  # depth models of a surface
_Z_NEAR = 0.3  # metres: polygons are clipped to z >= _Z_NEAR before projection
# Vehicle classes drawn with equal chance per slot, cars three times: the rare Cityscapes classes
# (two-wheelers, buses, trains) need enough pixels to be learnable at 64 x 128.
VEHICLE_MIX = (CAR, CAR, CAR, TRUCK, BUS, TRAIN, MOTORCYCLE, BICYCLE)


@dataclasses.dataclass(frozen=True)
class _Camera:
    """Pinhole camera at height ``h`` looking along +z: u = cx + f x / z, v = cy + f (h - y) / z."""

    height: int
    width: int
    f: float
    cx: float
    cy: float
    h: float

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) points with z >= _Z_NEAR -> (N, 2) pixel coordinates (u, v)."""
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        return np.stack([self.cx + self.f * x / z, self.cy + self.f * (self.h - y) / z], axis=1)


def _clip_near(xyz: np.ndarray) -> np.ndarray:
    """Clip a closed 3-D polygon (N, 3) to the half-space z >= _Z_NEAR (Sutherland-Hodgman)."""
    if xyz[:, 2].min() >= _Z_NEAR:
        return xyz
    out = []
    for a, b in zip(xyz, np.roll(xyz, -1, axis=0)):
        a_in, b_in = a[2] >= _Z_NEAR, b[2] >= _Z_NEAR
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (_Z_NEAR - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out, dtype=np.float64).reshape(-1, 3)


class _Painter:
    """Draws surfaces into a surface-id map and keeps each surface's class, colour and depth model."""

    def __init__(self, camera: _Camera):
        self.cam = camera
        self.ids = np.zeros((camera.height, camera.width), dtype=np.int32)
        self.cls: list[int] = []
        self.color: list[np.ndarray] = []
        self.kind: list[int] = []
        self.param: list[float] = []

    def _surface(self, cls: int, color, kind: int, param: float) -> int:
        self.cls.append(cls)
        self.color.append(np.asarray(color, dtype=np.float32))
        self.kind.append(kind)
        self.param.append(param)
        return len(self.cls) - 1

    def _fill(self, sid: int, xyz: np.ndarray) -> None:
        xyz = _clip_near(xyz)
        if len(xyz) < 3:
            return
        uv = np.clip(self.cam.project(xyz), -1e6, 1e6)
        cv2.fillPoly(self.ids, [np.round(uv * 16).astype(np.int32)], sid, lineType=cv2.LINE_8, shift=4)

    def sky(self, color) -> None:
        self.ids[:] = self._surface(SKY, color, _SKY, SKY_DEPTH)

    def ground(self, cls: int, color, x0: float, x1: float, z0: float, z1: float) -> None:
        """A rectangle on the ground plane y = 0."""
        sid = self._surface(cls, color, _GROUND, 0.0)
        self._fill(sid, np.array([[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]], float))

    def side(self, cls: int, color, x: float, z0: float, z1: float, y0: float, y1: float) -> None:
        """A rectangle on the vertical plane x = const (facades, walls, fences along the road)."""
        sid = self._surface(cls, color, _SIDE, x)
        self._fill(sid, np.array([[x, y0, z0], [x, y0, z1], [x, y1, z1], [x, y1, z0]], float))

    def frontal(self, parts: list, x: float, z: float) -> None:
        """An object facing the camera at lateral position ``x``, depth ``z``; parts in metres."""
        for cls, color, poly in parts:
            sid = self._surface(cls, color, _FRONTAL, z)
            pts = np.asarray(poly, float)
            self._fill(sid, np.column_stack([pts[:, 0] + x, pts[:, 1], np.full(len(pts), z)]))


# ----------------------------------------------------------------------------- scene layout

@dataclasses.dataclass(frozen=True)
class _Street:
    """Widths in metres, left and right of the camera: road, sidewalk, grass strip beyond it."""

    road_l: float
    road_r: float
    walk_l: float
    walk_r: float
    strip_l: float
    strip_r: float

    @classmethod
    def sample(cls, rng: np.random.Generator) -> "_Street":
        road, walk = rng.uniform(3.0, 8.0, 2), rng.uniform(1.5, 4.0, 2)
        strip = rng.uniform(1.0, 4.0, 2) * (rng.random(2) < 0.7)
        return cls(*road, *walk, *strip)


def _draw_ground(painter: _Painter, rng: np.random.Generator, s: _Street, far: float = 400.0) -> None:
    """Sky, then the ground plane: land, grass strips, sidewalks, road with a dashed centre line."""
    painter.sky(tone(rng, SKY, 25))
    land = rng.choice([TERRAIN, VEGETATION])
    painter.ground(land, tone(rng, land, 30, 0.8), -far, far, 0.0, far)
    painter.ground(TERRAIN, tone(rng, TERRAIN, 30), -s.road_l - s.walk_l - s.strip_l, -s.road_l - s.walk_l, 0, far)
    painter.ground(TERRAIN, tone(rng, TERRAIN, 30), s.road_r + s.walk_r, s.road_r + s.walk_r + s.strip_r, 0, far)
    painter.ground(SIDEWALK, tone(rng, SIDEWALK, 40), -s.road_l - s.walk_l, -s.road_l, 0, far)
    painter.ground(SIDEWALK, tone(rng, SIDEWALK, 40), s.road_r, s.road_r + s.walk_r, 0, far)
    painter.ground(ROAD, tone(rng, ROAD, 30), -s.road_l, s.road_r, 0, far)
    marking = np.clip(rng.uniform(180, 240) + rng.uniform(-10, 10, 3), 0, 255)
    for z in np.arange(rng.uniform(0, 9), 120, 9.0):
        painter.ground(ROAD, marking, -0.08, 0.08, z, z + 3)


def _draw_roadside(painter: _Painter, rng: np.random.Generator, s: _Street) -> None:
    """Facades along both sides: buildings with window bands, hedges, walls and fences."""
    for sign, edge in ((-1, s.road_l + s.walk_l + s.strip_l), (1, s.road_r + s.walk_r + s.strip_r)):
        z = rng.uniform(0.5, 5)
        while z < 200:
            length = rng.uniform(8, 40)
            kind = rng.choice([BUILDING, BUILDING, BUILDING, VEGETATION, WALL, FENCE])
            x = sign * (edge + rng.uniform(0, 2))
            if kind in (WALL, FENCE):  # a low barrier in front of greenery
                painter.side(VEGETATION, tone(rng, VEGETATION, 30), x + sign * 3, z, z + length, 0, rng.uniform(4, 10))
                top = rng.uniform(1.0, 2.5)
                if kind == WALL:
                    painter.side(WALL, tone(rng, WALL, 30), x, z, z + length, 0, top)
                else:  # a mesh panel with a top rail and posts every 2.5 m
                    mesh, color = tone(rng, FENCE, 30, 0.85), tone(rng, FENCE, 30)
                    painter.side(FENCE, mesh, x, z, z + length, 0, top)
                    painter.side(FENCE, color, x, z, z + length, top - 0.15, top)
                    for zp in np.arange(z, z + length, 2.5):
                        painter.side(FENCE, color, x, zp, zp + 0.15, 0, top)
            elif kind == VEGETATION:
                painter.side(VEGETATION, tone(rng, VEGETATION, 30), x, z, z + length, 0, rng.uniform(3, 12))
            else:
                height = rng.uniform(8, 30)
                painter.side(BUILDING, tone(rng, BUILDING, 30), x, z, z + length, 0, height)
                glass = tone(rng, BUILDING, 20, 0.55)
                for floor in np.arange(2.0, height - 1.0, rng.uniform(2.8, 3.6)):
                    painter.side(BUILDING, glass, x, z + 0.5, z + length - 0.5, floor, floor + 1.4)
            z += length + rng.uniform(0, 6) * (rng.random() < 0.3)


def _place_anomalies(rng: np.random.Generator, s: _Street, split: str, camera: _Camera) -> list[tuple]:
    """1-3 anomalies ``(z, x, width, parts)`` standing on the road, inside the field of view."""
    anomalies = []
    for _ in range(rng.integers(1, 4)):
        regime = split if split != "anomaly" else rng.choice(["anomaly_small", "anomaly_large"])
        if regime == "anomaly_small":
            z, size = rng.uniform(25, 80), rng.uniform(0.25, 0.8)
        else:
            z, size = rng.uniform(5, 20), rng.uniform(0.6, 1.8)
        z = min(z, camera.f * size / 4.0)  # at least ~4 pixels tall
        parts, w = anomaly_object(rng, size)
        seen = (-camera.cx * z / camera.f + w / 2, (camera.width - camera.cx) * z / camera.f - w / 2)
        low, high = max(-s.road_l + w / 2 + 0.3, seen[0]), min(s.road_r - w / 2 - 0.3, seen[1])
        x = rng.uniform(low, high) if low < high else (low + high) / 2
        anomalies.append((z, x, w, parts))
    return anomalies


def _hides(z: float, x: float, w: float, z_behind: float, x_behind: float, w_behind: float) -> bool:
    """Whether an object (depth ``z``, lateral position ``x``, width ``w``, metres) may hide one
    standing behind it: nearer (or within 1 m) and overlapping it in viewing angle, 0.3 m to spare."""
    half, half_behind = (w / 2 + 0.3) / z, (w_behind / 2 + 0.3) / z_behind
    return z < z_behind + 1.0 and abs(x / z - x_behind / z_behind) < half + half_behind


def _place_things(rng: np.random.Generator, s: _Street, anomalies: list[tuple]) -> list[tuple]:
    """Vehicles, pedestrians, poles and trees ``(z, x, width, parts)``; no vehicle hides an anomaly."""
    things = []
    for _ in range(rng.integers(0, 9)):  # vehicles in lanes or parked at the kerb
        cls = rng.choice(VEHICLE_MIX)
        z = rng.uniform(5, 60)
        parts, w = (two_wheeler(rng, cls), 1.3) if cls in (MOTORCYCLE, BICYCLE) else vehicle(rng, cls)
        x = rng.uniform(-s.road_l + w / 2, s.road_r - w / 2)
        if not any(_hides(z, x, w, za, xa, wa) for za, xa, wa, _ in anomalies):
            things.append((z, x, w, parts))
    for _ in range(rng.integers(0, 9)):  # pedestrians on the sidewalks
        left = rng.random() < 0.5
        x = -s.road_l - rng.uniform(0.3, s.walk_l) if left else s.road_r + rng.uniform(0.3, s.walk_r)
        things.append((rng.uniform(4, 40), x, 0.5, person(rng)))
    for sign, kerb, walk in ((-1, s.road_l, s.walk_l), (1, s.road_r, s.walk_r)):
        for z in np.arange(rng.uniform(3, 12), 70, rng.uniform(10, 25)):  # poles near the kerb
            things.append((z, sign * (kerb + 0.4), 0.2, pole(rng, rng.choice([POLE, SIGN, LIGHT]))))
        for _ in range(rng.integers(0, 5)):  # trees on the sidewalk's outer side
            things.append((rng.uniform(5, 70), sign * (kerb + walk - 0.3), 2.0, tree(rng)))
    return things


def _place_clutter(rng: np.random.Generator, s: _Street, count: int) -> list[tuple]:
    """0..``count`` void clutter objects ``(z, x, width, parts)`` standing on the road, 5-60 m away."""
    clutter = []
    for _ in range(rng.integers(0, count + 1)):
        parts, w = clutter_object(rng)
        clutter.append((rng.uniform(5, 60), rng.uniform(-s.road_l + w / 2, s.road_r - w / 2), w, parts))
    return clutter


def _layout(painter: _Painter, rng: np.random.Generator, split: str, clutter_rng: np.random.Generator | None,
            void_objects: int) -> None:
    """Sample one street and draw it into ``painter``, far to near (clutter from ``clutter_rng``)."""
    street = _Street.sample(rng)
    _draw_ground(painter, rng, street)
    _draw_roadside(painter, rng, street)
    anomalies = _place_anomalies(rng, street, split, painter.cam) if split in ANOMALY_SPLITS else []
    objects = anomalies + _place_things(rng, street, anomalies)
    if void_objects and split not in ANOMALY_SPLITS:
        objects += _place_clutter(clutter_rng, street, void_objects)
    for z, x, _, parts in sorted(objects, key=lambda o: -o[0]):
        painter.frontal(parts, x, z)


# ----------------------------------------------------------------------------- rendering

def _render(painter: _Painter, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface-id map -> (image uint8 (H, W, 3), classes uint8 (H, W), depth float32 (H, W))."""
    cam, ids = painter.cam, painter.ids
    height, width = ids.shape
    cls = np.take(np.array(painter.cls, np.uint8), ids)
    kind = np.take(np.array(painter.kind, np.int8), ids)
    param = np.take(np.array(painter.param, np.float32), ids)
    v = np.arange(height, dtype=np.float32)[:, None] + 0.5
    u = np.arange(width, dtype=np.float32)[None, :] + 0.5  # never equal to the random cx
    ground_z = np.float32(cam.f * cam.h) / np.maximum(v - np.float32(cam.cy), np.float32(1e-3))
    side_z = param * (np.float32(cam.f) / (u - np.float32(cam.cx)))
    depth = np.where(kind == _GROUND, ground_z, np.where(kind == _SIDE, side_z, param))
    np.clip(depth, 0.1, SKY_DEPTH, out=depth)

    # Per-pixel gain: texture noise (fine + coarse), light level and a vertical light gradient,
    # then haze toward a bright sky tone with distance (the sky itself keeps its own colour).
    coarse = cv2.resize(rng.standard_normal((height // 16 + 2, width // 16 + 2), dtype=np.float32),
                        (width, height), interpolation=cv2.INTER_CUBIC)
    fine = (rng.random((height, width), dtype=np.float32) - 0.5) * np.float32(np.sqrt(12.0))  # unit variance
    light = np.float32(rng.uniform(0.65, 1.25)) * (1 + np.float32(rng.uniform(-0.25, 0.25)) * (v / height - 0.5))
    gain = (1 + _TEXTURE[cls] * (0.6 * fine + 0.8 * coarse)) * light
    haze = np.exp(np.minimum(depth, 400.0) / np.float32(-rng.uniform(150.0, 600.0)))
    haze[kind == _SKY] = 1.0
    cast = rng.uniform(0.9, 1.1, 3)  # colour of the light
    haze_color = np.clip(CLASS_COLORS[SKY] + 60 + rng.uniform(-20, 20, 3), 0, 255).astype(np.float32)
    colors = (np.array(painter.color, np.float32) * cast).astype(np.float32)
    gain *= haze
    haze = 1 - haze
    channels = []
    for c in range(3):  # per channel planes: far cheaper than (H, W, 3) broadcasting
        plane = np.take(colors[:, c], ids) * gain + haze * haze_color[c]
        channels.append(np.clip(plane, 0, 255, out=plane).astype(np.uint8))
    return np.stack(channels, axis=-1), cls, depth


def _disparity(depth: np.ndarray, sky: np.ndarray, focal: float, noise: tuple[float, float],
               rng: np.random.Generator) -> np.ndarray:
    """f B / Z in pixels, 0 on the sky; then ``noise = (sigma_rel, hole_fraction)``."""
    disparity = np.where(sky, np.float32(0), np.float32(focal * BASELINE) / depth).astype(np.float32)
    sigma, holes = noise
    if sigma:
        disparity *= np.maximum(1 + np.float32(sigma) * rng.standard_normal(depth.shape, dtype=np.float32), 0)
    if holes:
        disparity[rng.random(depth.shape) < holes] = 0
    return disparity


def _check_mmf_options(disparity_noise, void_objects) -> None:
    sigma, holes = disparity_noise
    if sigma < 0 or not 0 <= holes <= 1 or void_objects < 0:
        raise ValueError(f"disparity_noise, void_objects: expected (sigma >= 0, 0 <= hole fraction <= 1) and "
                         f"void_objects >= 0, got {disparity_noise}, {void_objects}")


def generate(split: str, index: int, seed: int = 0, *, height: int = 256, width: int = 512,
             void_band: int = 2, off_road_void: bool = False, disparity: bool = False,
             disparity_noise: tuple[float, float] = (0.0, 0.0), void_objects: int = 0,
             roi: bool = False) -> dict[str, Any]:
    """One synthetic frame, a pure function of its arguments.

    Returns a dict: ``"image"`` (H, W, 3) uint8 RGB; ``"label"`` (H, W) uint8 (trainIds 0..18 for
    ``"train"`` / ``"val"``; 0 / 1 / 255 for anomaly splits); ``"semantic"`` (H, W) uint8 trainIds
    with 255 on anomalies; ``"depth"`` (H, W) float32 metres; ``"name"`` str. With the MMF
    options (module docstring): ``"disparity"`` (H, W) float32 pixels and ``"camera"`` dict
    (``baseline`` m, ``fx``, ``fy``, ``u0``, ``v0`` px); ``"void"`` (H, W) bool; ``"roi"`` (H, W) bool.
    """
    if split not in SPLITS:
        raise ValueError(f"split: expected one of {sorted(SPLITS)}, got {split!r}")
    if height < 8 or width < 8:
        raise ValueError(f"height, width: expected >= 8 pixels each, got {height} x {width}")
    if index < 0 or seed < 0 or void_band < 0:
        raise ValueError(f"index, seed, void_band: expected >= 0, got {index}, {seed}, {void_band}")
    _check_mmf_options(disparity_noise, void_objects)
    rng = np.random.default_rng([seed, SPLITS[split], index])
    camera = _Camera(height, width, f=width * rng.uniform(1.0, 1.2), cx=width * rng.uniform(0.42, 0.58),
                     cy=height * rng.uniform(0.36, 0.48), h=rng.uniform(1.2, 1.8))
    painter = _Painter(camera)
    _layout(painter, rng, split, np.random.default_rng([seed, SPLITS[split], index, 1]), void_objects)
    image, cls, depth = _render(painter, rng)
    anomaly, clutter = cls == ANOMALY, cls == CLUTTER
    semantic = np.where(anomaly | clutter, IGNORE_INDEX, cls).astype(np.uint8)
    if split in ANOMALY_SPLITS:
        label = anomaly.astype(np.uint8)
        if void_band:
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * void_band + 1,) * 2)
            band = cv2.dilate(label, kernel).astype(bool) & ~anomaly
            label[band] = IGNORE_INDEX
        if off_road_void:
            label[(semantic != ROAD) & ~anomaly] = IGNORE_INDEX
    else:
        label = semantic
    frame = {"image": image, "label": label, "semantic": semantic, "depth": depth,
             "name": f"{split}_{seed}_{index:06d}"}
    if disparity:
        noise_rng = np.random.default_rng([seed, SPLITS[split], index, 2])
        frame["disparity"] = _disparity(depth, cls == SKY, camera.f, disparity_noise, noise_rng)
        frame["camera"] = {"baseline": BASELINE, "fx": camera.f, "fy": camera.f, "u0": camera.cx, "v0": camera.cy}
    if void_objects:
        frame["void"] = clutter
    if roi:
        frame["roi"] = (cls == ROAD) | anomaly | clutter
    return frame


class SyntheticScenes:
    """Random-access source of ``num_frames`` frames of one split (``len``, ``[index]``)."""

    def __init__(self, split: str, num_frames: int, seed: int = 0, *, height: int = 256,
                 width: int = 512, void_band: int = 2, off_road_void: bool = False, disparity: bool = False,
                 disparity_noise: tuple[float, float] = (0.0, 0.0), void_objects: int = 0, roi: bool = False):
        if split not in SPLITS:
            raise ValueError(f"split: expected one of {sorted(SPLITS)}, got {split!r}")
        if num_frames < 1:
            raise ValueError(f"num_frames: expected >= 1, got {num_frames}")
        _check_mmf_options(disparity_noise, void_objects)
        self.split, self.num_frames, self.seed = split, num_frames, seed
        self._kwargs = dict(height=height, width=width, void_band=void_band, off_road_void=off_road_void)
        mmf = dict(disparity=disparity, disparity_noise=tuple(disparity_noise), void_objects=void_objects, roi=roi)
        self._kwargs.update({k: v for k, v in mmf.items() if v != generate.__kwdefaults__[k]})

    def __len__(self) -> int:
        return self.num_frames

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not 0 <= index < self.num_frames:
            raise IndexError(f"index {index} out of range for {self.num_frames} frames")
        return generate(self.split, int(index), self.seed, **self._kwargs)

    def __repr__(self) -> str:
        return f"SyntheticScenes({self.split!r}, num_frames={self.num_frames}, seed={self.seed}, {self._kwargs})"
