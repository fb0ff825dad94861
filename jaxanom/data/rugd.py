"""RUGD reader (Wigness et al., IROS 2019): ordered video frames of one sequence, official layout.

Layout: ``<root>/RUGD_frames-with-annotations/<sequence>/<sequence>_<number>.png`` (e.g.
``park-2/park-2_01901.png``, five digits), colour-coded labels under the same name in
``<root>/RUGD_annotations/<sequence>/`` and the colour map
``RUGD_annotation-colormap.txt`` (lines ``id name R G B``) in ``RUGD_annotations/`` or in
``<root>``. Frames come in the order of their number (the video order the active-learning gap
of Eq. 16 relies on). Labels are the colour map's ids, with its ``void`` class as 255.
"""
from __future__ import annotations

import re
from pathlib import Path

from jaxanom.data.deepscene import ColourFrames
from jaxanom.data.image_io import require_dir


def read_colormap(path: Path) -> tuple[tuple[str, ...], dict]:
    """``(class names by id, {(R, G, B): id})`` from a RUGD colour-map file; ``void`` maps to 255."""
    names, colours = {}, {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        try:
            index, name, rgb = int(parts[0]), parts[1], tuple(int(v) for v in parts[2:5])
        except (ValueError, IndexError):
            raise ValueError(f"RUGD colour map: line {number} of {path} is not 'id name R G B': {line!r}") from None
        if len(rgb) != 3:
            raise ValueError(f"RUGD colour map: line {number} of {path} is not 'id name R G B': {line!r}")
        names[index] = name
        colours[rgb] = 255 if name == "void" else index
    if not colours:
        raise ValueError(f"RUGD colour map: no entries in {path}")
    return tuple(names.get(i, "") for i in range(max(names) + 1)), colours


class RUGD(ColourFrames):
    """``RUGD(root, sequence)[i]`` -> image, label (colour-map ids, 255 void), name; in video order."""

    def __init__(self, root: str | Path, sequence: str, *, tolerance: int = 0):
        root = Path(root)
        frame_dir = require_dir(root / "RUGD_frames-with-annotations" / sequence, f"RUGD frames of {sequence!r}")
        label_dir = require_dir(root / "RUGD_annotations" / sequence, f"RUGD annotations of {sequence!r}")
        candidates = [root / "RUGD_annotations" / "RUGD_annotation-colormap.txt", root / "RUGD_annotation-colormap.txt"]
        colormap = next((p for p in candidates if p.is_file()), None)
        if colormap is None:
            raise FileNotFoundError(f"RUGD colour map: none of {[str(p) for p in candidates]} exists")
        self.class_names, colours = read_colormap(colormap)
        pattern = re.compile(rf"^{re.escape(sequence)}_(\d+)\.png$")
        numbered = sorted((int(m.group(1)), p) for p in frame_dir.iterdir() if (m := pattern.match(p.name)))
        if not numbered:
            raise FileNotFoundError(f"RUGD frames of {sequence!r}: no {sequence}_<number>.png files in {frame_dir}")
        frames = []
        for _, image in numbered:
            label = label_dir / image.name
            if not label.is_file():
                raise FileNotFoundError(f"RUGD annotation: {label} (for frame {image.name}) does not exist")
            frames.append((image.stem, image, label))
        super().__init__(frames, colours, tolerance)
