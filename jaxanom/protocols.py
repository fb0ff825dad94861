"""Evaluation protocols by name: how a table turns a dataset's frames into the pixels it counts.

Published road-anomaly numbers differ in more than the network: the size the network sees, the
resampling filter, whether a void output takes part in the scores, which frames count, and how
FPR at 95% TPR reads the curve. A ``Protocol`` names those choices so that a table can be
reproduced by name (``jaxanom evaluate --protocol NAME``):

- ``native`` (jaxanom's default): each image at its own size, the metrics at the labels' size,
  every output channel in the scores (a void class included: docs/decisions/espnet.md measured
  that dropping it hurts), every frame, FPR at the first point with TPR >= 95%.
- ``erfnet-community``: the protocol of the many public ERFNet road-anomaly evaluations (their
  MSP / max logit / max entropy table on RoadAnomaly21 and RoadObstacle21): the image resized
  to 512x1024 with PIL's BILINEAR (antialiased when shrinking), the labels to 512x1024 with
  PIL's NEAREST, the metrics at that size; the void (20th) channel dropped before the scores
  (the ``void`` method reads it); frames without an anomaly pixel skipped; pixels pooled over
  frames; AP as scikit-learn's ``average_precision_score`` (the step sum) and FPR95 as
  ood-metrics' ``fpr_at_95_tpr`` (linear interpolation on the ROC).

Protocols are plug-ins like scoring methods (``PROTOCOLS`` is a ``jaxanom.registry.Registry``):
jaxanom's two are registered here (this module is in ``jaxanom.builtins``), and a module of
one's own registers another with ``register(Protocol(...))``, loaded by ``--plugin MODULE`` or
an installed package's entry-point group ``jaxanom.protocols``; ``get_protocol`` finds a name
when a command runs, so a plug-in's protocol is as good as jaxanom's.
"""
from __future__ import annotations

import dataclasses
import sys
from typing import Iterable, Iterator, Mapping, Sequence

import numpy as np

from jaxanom import builtins, registry
from jaxanom.data.resize import resize_image_antialiased, resize_labels_nearest
from jaxanom.errors import InputError
from jaxanom.void_methods import VOID_CHANNEL, without_channel

ENTRY_POINTS = "jaxanom.protocols"


@dataclasses.dataclass(frozen=True)
class Protocol:
    """``size``: (H, W) the network sees, None for each image's own; ``drop_void``: the scores
    read every channel but a void one; ``skip_frames_without_anomaly``: frames whose (resized)
    label holds no anomaly pixel are not counted; the conventions as in
    ``jaxanom.metrics.anomaly_metrics``."""

    name: str
    description: str
    size: tuple[int, int] | None = None
    drop_void: bool = False
    skip_frames_without_anomaly: bool = False
    ap_convention: str = "step"
    fpr_convention: str = "first"

    def __post_init__(self):  # a plug-in's protocol is refused where it is made, in one line
        from jaxanom.metrics.anomaly import AP_CONVENTIONS, FPR_CONVENTIONS

        description = self.description
        if not (isinstance(description, str) and description.strip() and "\n" not in description.strip()):
            raise ValueError(f"description of protocol {self.name!r}: expected one line, got {self.description!r}")
        size = self.size
        if size is not None and not (isinstance(size, tuple) and len(size) == 2
                                     and all(isinstance(n, int) and n > 0 for n in size)):
            raise ValueError(f"size of protocol {self.name!r}: expected None or (H, W) positive ints, got {self.size!r}")
        if self.ap_convention not in AP_CONVENTIONS or self.fpr_convention not in FPR_CONVENTIONS:
            raise ValueError(f"conventions of protocol {self.name!r}: expected ap_convention of {AP_CONVENTIONS} and "
                             f"fpr_convention of {FPR_CONVENTIONS}, got {self.ap_convention!r}, {self.fpr_convention!r}")

    def source(self, source: Sequence[Mapping]) -> Sequence[dict]:
        """``source`` (``len`` and ``[i]`` of records ``{"image" (H, W, 3) uint8, "label" (H, W),
        "name"?}``) with every frame resized to ``size`` when read, or ``source`` itself."""
        return source if self.size is None else _Resized(source, self.size)

    def images(self, source: Sequence[Mapping]) -> Sequence[dict]:
        """``source``'s frames as ``{"image", "name"?}``, resized as ``Protocol.source`` resizes them:
        what fitting statistics reads (a training frame's label, depth and ROI left out)."""
        return source if self.size is None else _Resized(source, self.size, images_only=True)

    def classes(self, outputs: int) -> int:
        """How many classes the methods (but ``void``) see of a network with ``outputs`` channels:
        one fewer where the protocol drops a void output (``void_methods.VOID_CHANNEL``)."""
        return outputs - 1 if self.drop_void and outputs == VOID_CHANNEL + 1 else outputs

    def outputs(self, predict):
        """``predict`` (images -> ``{"logits", ...}``) whose logits are those the methods (but
        ``void``) see: without the void output where the protocol drops it."""
        if not self.drop_void:
            return predict

        def call(images):
            out = predict(images)
            if self.classes(out["logits"].shape[-1]) == out["logits"].shape[-1]:
                return out
            return {**out, "logits": without_channel(out["logits"])}

        return call

    def counts(self, label) -> bool:
        """Whether a frame of (resized) ``label`` counts: not when the protocol skips frames
        without an anomaly pixel (1) and it has none."""
        return not self.skip_frames_without_anomaly or bool(np.any(np.asarray(label) == 1))

    def frames(self, records: Iterable[Mapping]) -> Iterator[dict]:
        """The records this protocol counts, resized to ``size`` if it has one."""
        for record in records:
            record = dict(record) if self.size is None else resize_frame(record, self.size)
            if self.counts(record["label"]):
                yield record


class _Resized:
    """A frame source read through ``resize_frame`` (lazily: one frame in memory at a time);
    ``images_only``: its frames' images and names only."""

    def __init__(self, source: Sequence[Mapping], size: tuple[int, int], images_only: bool = False):
        self._source, self._size, self._images_only = source, size, images_only

    def __len__(self) -> int:
        return len(self._source)

    def __getitem__(self, index: int) -> dict:
        record = self._source[index]
        if self._images_only:
            record = {key: record[key] for key in ("image", "name") if key in record}
        return resize_frame(record, self._size)


def resize_frame(record: Mapping, size: tuple[int, int]) -> dict:
    """``record`` at ``size`` (H, W), both by PIL (``jaxanom.data.resize``): its image antialiased,
    its label and road region (``"roi"``, if any) by nearest neighbour as the labels; its depth or
    disparity left out (the protocols' networks read the image only, and no such map is defined
    at another size)."""
    resized = {key: value for key, value in record.items() if key not in ("depth", "disparity")}
    resized["image"] = resize_image_antialiased(record["image"], size)
    for key in ("label", "roi"):
        if key in record:
            resized[key] = resize_labels_nearest(record[key], size)
    return resized


PROTOCOLS: registry.Registry[Protocol] = registry.Registry("protocol", ENTRY_POINTS, lambda: builtins.MODULES)


def register(protocol: Protocol) -> Protocol:
    """Add ``protocol`` under its name (``registry.NAME_RULE``), registered by the calling module;
    ValueError in one line when the name is not a name or another protocol has it. Returns it."""
    if not isinstance(protocol, Protocol):
        raise ValueError(f"protocol: expected a jaxanom.protocols.Protocol, got {type(protocol).__name__}")
    return PROTOCOLS.add(protocol.name, protocol, sys._getframe(1).f_globals.get("__name__", "?"))


def protocol_names() -> tuple[str, ...]:
    """Every registered protocol's name: jaxanom's own first, then installed plug-ins', then loaded modules'."""
    return PROTOCOLS.names()


def get_protocol(name: str) -> Protocol:
    """The protocol called ``name``; InputError naming ``protocol`` and the known names (and an
    entry point that failed to load, which might have provided it) otherwise."""
    found = PROTOCOLS.find(name)
    if found is None:
        raise InputError("protocol", f": expected one of {', '.join(PROTOCOLS.names())}, got {name!r} (a plug-in's "
                         f"protocol: load its module, e.g. with --plugin MODULE){PROTOCOLS.broken_note()}")
    return found


register(Protocol("native", "each image at its own size, every channel, every frame, FPR at the first point with TPR "
                  ">= 95 percent (jaxanom's default)"))
register(Protocol(
    "erfnet-community", "512x1024 PIL resize of images (antialiased bilinear) and labels (nearest), void channel "
    "dropped, frames without anomalies skipped, interpolated FPR95 (the public ERFNet evaluations)",
    size=(512, 1024), drop_void=True, skip_frames_without_anomaly=True, fpr_convention="interp"))
