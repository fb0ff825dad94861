"""Shapes of the things in a synthetic street, as flat polygons in metres.

Every builder returns ``parts``: a list of ``(class, rgb colour (3,) float, polygon (N, 2))`` for an
object standing on the ground at local x = 0 (x to the right, y up), listed back to front;
``jaxanom.data.synthetic`` places them in the scene and draws them. Colours are the class's
official Cityscapes colour faded and jittered per instance (``tone``); anomalies use saturated
colours and shapes that no in-distribution object has.
"""
from __future__ import annotations

import cv2
import numpy as np

from jaxanom.data.cityscapes_labels import CLASS_COLORS

(ROAD, SIDEWALK, BUILDING, WALL, FENCE, POLE, LIGHT, SIGN, VEGETATION, TERRAIN, SKY, PERSON,
 RIDER, CAR, TRUCK, BUS, TRAIN, MOTORCYCLE, BICYCLE) = range(19)
ANOMALY = 19  # class code of anomaly surfaces inside the generator (255 in semantic maps)
CLUTTER = 20  # class code of void clutter (MMF's void-as-anomaly training objects; 255 in semantic maps)



def tone(rng: np.random.Generator, cls: int, spread: float = 35.0, scale: float = 1.0):
    """The class's official colour, faded toward a random grey and jittered per instance."""
    fade = rng.uniform(0.0, 0.5)
    base = (1 - fade) * CLASS_COLORS[cls].astype(np.float32) + fade * rng.uniform(60, 160)
    return np.clip(base * scale + rng.uniform(-spread, spread, 3), 0, 255)


def _rect(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def _ellipse(cx, cy, rx, ry, n=14, rng=None, rough=0.0):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1.0 if rng is None else 1.0 + rough * rng.uniform(-1, 1, n)
    return np.column_stack([cx + rx * r * np.cos(t), cy + ry * r * np.sin(t)])


def _segment(p0, p1, width):
    (x0, y0), (x1, y1) = p0, p1
    d = np.array([y0 - y1, x1 - x0], float)
    d *= 0.5 * width / max(np.hypot(*d), 1e-9)
    return [(x0 + d[0], y0 + d[1]), (x1 + d[0], y1 + d[1]), (x1 - d[0], y1 - d[1]), (x0 - d[0], y0 - d[1])]


def vehicle(rng, cls):
    """Rear view of a car, truck, bus or train."""
    w, h = {CAR: (1.8, 1.5), TRUCK: (2.5, 3.6), BUS: (2.55, 3.2), TRAIN: (2.9, 3.9)}[cls]
    w, h = w * rng.uniform(0.9, 1.1), h * rng.uniform(0.9, 1.1)
    body, dark = tone(rng, cls), tone(rng, cls, 15, 0.4)
    parts = [(cls, dark, _rect(-0.42 * w, 0, -0.2 * w, 0.4)), (cls, dark, _rect(0.2 * w, 0, 0.42 * w, 0.4))]
    if cls == CAR:
        parts += [(cls, body, _rect(-w / 2, 0.3, w / 2, 0.62 * h)),
                  (cls, body, [(-0.45 * w, 0.62 * h), (0.45 * w, 0.62 * h), (0.33 * w, h), (-0.33 * w, h)]),
                  (cls, dark, [(-0.38 * w, 0.66 * h), (0.38 * w, 0.66 * h), (0.3 * w, 0.95 * h), (-0.3 * w, 0.95 * h)])]
    elif cls == TRUCK:  # a closed box, no rear window
        parts += [(cls, body, _rect(-w / 2, 0.35, w / 2, h)),
                  (cls, dark, _rect(-0.45 * w, 0.35, 0.45 * w, 0.5))]
    elif cls == BUS:  # a wide rear window and a lit destination board
        board = np.clip(np.array([240, 160, 40]) + rng.uniform(-30, 15, 3), 0, 255)
        parts += [(cls, body, _rect(-w / 2, 0.35, w / 2, h)),
                  (cls, dark, _rect(-0.42 * w, 0.55 * h, 0.42 * w, 0.85 * h)),
                  (cls, board, _rect(-0.3 * w, 0.88 * h, 0.3 * w, 0.96 * h))]
    else:  # a tram front: pale skirt stripe, two windscreens, a pantograph on the roof
        pale = np.clip(np.array([210, 210, 200]) + rng.uniform(-30, 30, 3), 0, 255)
        parts += [(cls, body, _rect(-w / 2, 0.35, w / 2, h)),
                  (cls, pale, _rect(-w / 2, 0.35, w / 2, 0.25 * h)),
                  (cls, dark, _rect(-0.45 * w, 0.5 * h, -0.03 * w, 0.88 * h)),
                  (cls, dark, _rect(0.03 * w, 0.5 * h, 0.45 * w, 0.88 * h)),
                  (cls, dark, [(-0.3 * w, h), (0.3 * w, h), (0.1 * w, 1.12 * h), (-0.1 * w, 1.12 * h)])]
    lamp = np.clip(np.array([200, 30, 30]) + rng.uniform(-30, 30, 3), 0, 255)
    parts += [(cls, lamp, _rect(-0.48 * w, 0.45, -0.36 * w, 0.55)), (cls, lamp, _rect(0.36 * w, 0.45, 0.48 * w, 0.55))]
    return parts, w


def person(rng, cls=PERSON, base=0.0):
    """Front view of a person (``cls`` RIDER when riding), feet at height ``base``."""
    s = rng.uniform(1.55, 1.95)
    skin = np.clip(np.array([200, 160, 130]) * rng.uniform(0.5, 1.1), 0, 255)
    coat, trousers = tone(rng, cls, 50), tone(rng, cls, 40, 0.5)
    y = lambda r: base + r * s  # noqa: E731
    parts = [(cls, trousers, _rect(-0.17 * s / 1.8, y(0), -0.02, y(0.47))),
             (cls, trousers, _rect(0.02, y(0), 0.17 * s / 1.8, y(0.47))),
             (cls, coat, [(-0.13 * s, y(0.45)), (0.13 * s, y(0.45)), (0.14 * s, y(0.82)), (-0.14 * s, y(0.82))]),
             (cls, coat, _segment((-0.14 * s, y(0.8)), (-0.2 * s, y(0.5)), 0.07 * s)),
             (cls, coat, _segment((0.14 * s, y(0.8)), (0.2 * s, y(0.5)), 0.07 * s)),
             (cls, skin, _ellipse(0, y(0.9), 0.07 * s, 0.09 * s))]
    return parts


def two_wheeler(rng, cls):
    """Side view of a bicycle or motorcycle with its rider."""
    r = 0.34 if cls == BICYCLE else 0.32
    base, dark = tone(rng, cls), tone(rng, cls, 10, 0.3)
    parts = [(cls, dark, _ellipse(-0.55, r, r, r)), (cls, dark, _ellipse(0.55, r, r, r))]
    if cls == BICYCLE:
        parts += [(cls, base, _segment((-0.55, r), (0.0, 0.9), 0.05)),
                  (cls, base, _segment((0.0, 0.9), (0.55, r), 0.05)),
                  (cls, base, _segment((-0.55, r), (0.5, 0.95), 0.05))]
    else:
        parts += [(cls, base, [(-0.6, 0.45), (0.5, 0.45), (0.65, 0.85), (0.1, 1.0), (-0.5, 0.85)])]
    return parts + person(rng, RIDER, base=0.55)


def pole(rng, with_item):
    """A pole, optionally carrying a traffic sign or a traffic light at its top."""
    h = rng.uniform(3.5, 7.0)
    parts = [(POLE, tone(rng, POLE), _rect(-0.08, 0, 0.08, h))]
    if with_item == SIGN:
        c, size = tone(rng, SIGN, 30), rng.uniform(0.8, 1.4)
        shape = rng.integers(3)
        poly = (_rect(-size / 2, h - size, size / 2, h) if shape == 0 else
                _ellipse(0, h - size / 2, size / 2, size / 2) if shape == 1 else
                [(-size / 2, h), (size / 2, h), (0, h - size)])
        parts.append((SIGN, c, poly))
    elif with_item == LIGHT:
        parts.append((LIGHT, tone(rng, LIGHT, 30, 0.5), _rect(-0.3, h - 1.4, 0.3, h)))
        lit = rng.integers(3)
        for k, lamp in enumerate([(230, 40, 30), (240, 190, 40), (40, 220, 90)]):
            color = np.array(lamp, np.float32) * (1.0 if k == lit else 0.35)
            parts.append((LIGHT, color, _ellipse(0, h - 0.25 - 0.45 * k, 0.17, 0.17, n=8)))
    return parts


def tree(rng):
    h = rng.uniform(4.0, 10.0)
    crown = tone(rng, VEGETATION, 30)
    return [(VEGETATION, tone(rng, VEGETATION, 20, 0.5), _rect(-0.15, 0, 0.15, 0.5 * h)),
            (VEGETATION, crown, _ellipse(0, 0.7 * h, 0.25 * h, 0.3 * h, n=20, rng=rng, rough=0.15))]


def _odd_color(rng):
    """A saturated colour far from the street palette's usual tones (cyan, lime, violet, ...)."""
    hsv = np.uint8([[[rng.integers(0, 180), rng.integers(200, 256), rng.integers(170, 256)]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def anomaly_object(rng, size):
    """An object no training frame has, about ``size`` metres tall; returns (parts, width)."""
    kind = rng.integers(4)
    c1, c2 = _odd_color(rng), _odd_color(rng)
    if kind == 0:  # rock: rough dark blob
        w = size * rng.uniform(1.0, 1.8)
        grey = np.clip(rng.uniform(60, 140) + rng.uniform(-20, 20, 3), 0, 255)
        return [(ANOMALY, grey, _ellipse(0, size / 2, w / 2, size / 2, n=11, rng=rng, rough=0.25))], w
    if kind == 1:  # box with a lighter top face and a coloured tape stripe
        w = size * rng.uniform(0.8, 1.6)
        return [(ANOMALY, c1, _rect(-w / 2, 0, w / 2, size)),
                (ANOMALY, np.clip(c1 * 1.3, 0, 255),
                 [(-w / 2, size), (w / 2, size), (0.4 * w, 1.15 * size), (-0.6 * w, 1.15 * size)]),
                (ANOMALY, c2, _rect(-w / 2, 0.45 * size, w / 2, 0.6 * size))], w
    if kind == 2:  # cone in odd colours with a band
        w = 0.6 * size
        return [(ANOMALY, c2, _rect(-w / 2, 0, w / 2, 0.08 * size)),
                (ANOMALY, c1, [(-0.4 * w, 0.08 * size), (0.4 * w, 0.08 * size), (0.05 * w, size), (-0.05 * w, size)]),
                (ANOMALY, c2, [(-0.25 * w, 0.45 * size), (0.25 * w, 0.45 * size),
                               (0.2 * w, 0.6 * size), (-0.2 * w, 0.6 * size)])], w
    # animal-like blob: body, legs, head, spots
    w = size * rng.uniform(1.3, 2.2)
    legs = (-0.35 * w, -0.2 * w, 0.2 * w, 0.35 * w)
    parts = [(ANOMALY, c1, _rect(x - 0.05 * w, 0, x + 0.05 * w, 0.55 * size)) for x in legs]
    parts.append((ANOMALY, c1, _ellipse(0, 0.7 * size, w / 2, 0.3 * size, n=16, rng=rng, rough=0.1)))
    parts.append((ANOMALY, c1, _ellipse(0.55 * w, 0.95 * size, 0.15 * w, 0.15 * size, n=10)))
    for _ in range(3):  # spots
        centre = rng.uniform(-0.3, 0.3) * w, rng.uniform(0.6, 0.8) * size
        parts.append((ANOMALY, c2, _ellipse(*centre, 0.08 * w, 0.08 * size, n=8)))
    return parts, w


def clutter_object(rng):
    """Street clutter that no class covers (bin, board, pallet, sack) in a muted colour: the
    synthetic analogue of Cityscapes void, unlike the saturated anomalies; returns (parts, width)."""
    kind = rng.integers(4)
    hsv = np.uint8([[[rng.integers(0, 180), rng.integers(20, 90), rng.integers(70, 170)]]])
    c1 = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)
    c2 = np.clip(c1 * rng.uniform(0.6, 0.85), 0, 255)
    if kind == 0:  # wheelie bin: body and lid
        w, h = rng.uniform(0.5, 0.8), rng.uniform(0.9, 1.2)
        return [(CLUTTER, c1, _rect(-w / 2, 0, w / 2, h)), (CLUTTER, c2, _rect(-0.55 * w, h, 0.55 * w, 1.08 * h))], w
    if kind == 1:  # advertising board on two legs
        w, h = rng.uniform(0.6, 1.2), rng.uniform(0.8, 1.3)
        return [(CLUTTER, c2, _rect(-0.4 * w, 0, -0.3 * w, 0.4 * h)), (CLUTTER, c2, _rect(0.3 * w, 0, 0.4 * w, 0.4 * h)),
                (CLUTTER, c1, _rect(-w / 2, 0.35 * h, w / 2, h))], w
    if kind == 2:  # stacked pallets: slats
        w, h = rng.uniform(1.0, 1.3), rng.uniform(0.3, 0.8)
        slats = np.arange(0.0, h, 0.15)
        return [(CLUTTER, c1 if k % 2 else c2, _rect(-w / 2, y, w / 2, min(y + 0.15, h))) for k, y in enumerate(slats)], w
    w = rng.uniform(0.5, 0.9)  # sack: a squat blob
    return [(CLUTTER, c1, _ellipse(0, 0.25 * w, w / 2, 0.25 * w, n=12, rng=rng, rough=0.1))], w
