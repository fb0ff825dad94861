"""``jaxanom fit-stats``: SML class statistics (Eqs. 3-4) of a trained run, written as .npz."""
from __future__ import annotations

import os
import sys
from pathlib import Path

from jaxanom.app.outputs import CLAIM, check_out_outside, claim
from jaxanom.errors import InputError, reading
from jaxanom.sml.policy import DEFAULT_POLICY, DEFAULT_STRENGTH, POLICIES

__all__ = ["DEFAULT_POLICY", "DEFAULT_STRENGTH", "POLICIES", "OneSize", "fit_stats", "stats_table"]


def fit_stats(*, run: str, out: str, frames: int = 200, cityscapes: str | None = None,
              size: tuple[int, int] | None = None, missing: str = "error", policy: str = DEFAULT_POLICY,
              min_count: float = 10_000, strength: float = DEFAULT_STRENGTH, protocol: str = "native",
              plugins=(), overwrite: bool = False) -> Path:
    """Fit the statistics of ``run``'s network on ``frames`` of its training data (or of the train
    split of the Cityscapes folder ``cityscapes``, no labels read), resized to ``size`` (H, W)
    when given; finalize them by ``policy`` (``jaxanom.sml.stats_finalize``) and write ``out``
    (.npz), which records the frames (set, folder, count, size). A converted run (a network
    jaxanom did not train: only a step-0 checkpoint) has no training data: it needs ``cityscapes``.
    ``protocol`` (a ``jaxanom.protocols`` name, a plug-in's included): the frames resized and the output channels
    selected as that protocol scores them (``erfnet-community``: 512x1024, the void output
    dropped), recorded in the file for ``evaluate`` to check. ``plugins``: modules imported first
    (the run imports those it recorded itself). Prints the per-class table and warns on classes
    below ``min_count`` pixels."""
    from jaxanom import sml
    from jaxanom.app.commands.inputs import fitted_on as described, load_plugins
    from jaxanom.app.evaluate import class_statistics, predictor
    from jaxanom.app.experiment import trained_steps, build_network, load_variables
    from jaxanom.app.experiment import frames as run_frames, frames_record as run_frames_record
    from jaxanom.app.predict import size_check
    from jaxanom.data import Cityscapes
    from jaxanom.data.frames import FirstFrames, Resized
    from jaxanom.data.pipeline import evaluation_batches
    from jaxanom.protocols import get_protocol
    from jaxanom.sml.policy import check_policy

    load_plugins(plugins)
    path = Path(out)
    if path.is_dir():
        raise InputError("out", f"{path}: is a folder; expected the path of the .npz file to write")
    if str(out).endswith(("/", os.sep)):
        raise InputError("out", f"{out}: names a folder; expected the path of the .npz file to write")
    if path.suffix != ".npz":
        raise InputError("out", f"{out}: expected a file name ending in .npz (what {{stats}} reads)",
                         mentions=("stats",))
    check_out_outside(out, {"run": run})
    if path.exists() and not overwrite:
        raise InputError("out", f"{path}: file exists; choose another or pass {{overwrite}}", mentions=("overwrite",))
    check_policy(policy, min_count, strength)
    protocol_ = get_protocol(protocol)
    if protocol_.size is not None and size is not None:
        raise InputError("size", f"{{size}} and {{protocol}} {protocol_.name}: the protocol resizes the frames to "
                         f"{protocol_.size[0]}x{protocol_.size[1]} itself; give one of them", mentions=("protocol",))
    with reading("run", run):
        experiment, variables = load_variables(run)
    channels = {"protocol": protocol_.name, "network_outputs": experiment.num_classes,
                "void_dropped": protocol_.classes(experiment.num_classes) < experiment.num_classes}
    if not cityscapes and trained_steps(Path(run)) == 0:
        raise InputError("cityscapes", f"{{cityscapes}} DIR needed: the network in {run} was not trained by jaxanom "
                         "(its only checkpoint is step 0: a convert-weights run), so the run has no training frames "
                         "of its own to fit the statistics on")
    if size is not None:
        size_check(build_network(experiment), variables)(size, "the working size")
    if cityscapes:  # the statistics use the network's predictions only: no labels read
        with reading("cityscapes", cityscapes):
            source = FirstFrames(Cityscapes(cityscapes, "train", with_labels=False), frames)
        fitted_on = {"set": "cityscapes train", "folder": str(Path(cityscapes).resolve())}
    else:
        source = run_frames(experiment, "train", frames)
        fitted_on = run_frames_record(experiment, "train")
    if protocol_.size is not None:
        source = protocol_.images(source)
    elif size is not None:
        source = Resized(source, *size)
    elif cityscapes:
        source = OneSize(source, cityscapes)
    path.parent.mkdir(parents=True, exist_ok=True)
    claim(path.parent / f"{path.name}{CLAIM}", path)
    batches = evaluation_batches(source, batch_size=experiment.batch_size)
    stats = class_statistics(predictor(build_network(experiment), variables), batches,
                             drop_void=channels["void_dropped"])
    final = sml.stats_finalize_report(stats, missing=missing, policy=policy, min_count=min_count, strength=strength)
    record = {"policy": policy, "missing": missing, "min_count": min_count, "strength": strength,
              "frames": len(source)}
    fitted_on.update(count=len(source), size=list(protocol_.size or size or source[0]["image"].shape[:2]))
    sml.save_stats(path, final.mean, final.std, final.count, status=final.status, policy=record, channels=channels,
                   frames=fitted_on)
    print(stats_table(final))
    scarce = [c for c, n in enumerate(final.count) if n < min_count]
    if scarce:
        print(f"jaxanom fit-stats: warning: classes {scarce} have fewer than {min_count:g} predicted pixels "
              f"(counts {[int(final.count[c]) for c in scarce]}); their statistics are "
              f"{'unreliable (consider --policy shrink or min_count)' if policy == 'none' else 'pooled or shrunk as the table says'}",
              file=sys.stderr)
    selection = (f" (the network's {experiment.num_classes} outputs less its void output, as protocol "
                 f"{protocol_.name} scores them)" if channels["void_dropped"] else "")
    print(f"statistics of {len(final.mean)} classes{selection} {described(fitted_on)}, policy {policy} -> {path}")
    return path


def stats_table(final) -> str:
    """Per-class lines: pixels, mean, std, status (and the prior's weight when shrunk)."""
    lines = ["class   pixels       mean      std  status"]
    for c, (n, m, s, status, w) in enumerate(zip(final.count, final.mean, final.std, final.status,
                                                 final.prior_weight)):
        extra = f" (prior weight {w:.2f})" if status == "shrunk" else ""
        lines.append(f"{c:5d} {n:8d} {float(m):10.4f} {float(s):8.4f}  {status}{extra}")
    return "\n".join(lines)


class OneSize:
    """The frames of a random-access source (the Cityscapes folder ``root``), InputError naming
    ``cityscapes`` and ``size`` when one's size differs from the first's (frames are batched, and
    a batch holds frames of one size)."""

    def __init__(self, source, root: str):
        self.source, self.root, self.first = source, root, None

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> dict:
        frame = self.source[index]
        seen = (frame.get("name", str(index)), frame["image"].shape[:2])
        self.first = self.first or seen
        if seen[1] != self.first[1]:
            raise InputError("cityscapes", f"{self.root}: frames differ in size ({self.first[0]} is "
                             f"{self.first[1][0]}x{self.first[1][1]}, {seen[0]} is {seen[1][0]}x{seen[1][1]}); "
                             "pass {size} HxW to resize them to one", mentions=("size",))
        return frame
