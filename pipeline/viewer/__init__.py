"""A browser viewer of scenes, predictions and attention: one self-contained HTML file.

`write_viewer(data, out, predictions=..., run=...)` reads a dataset split (and the predictions of
one predictor on its scenes, from a predictions file or by evaluating a run) and writes a page
that draws the road and every agent to scale with a time slider, the observed history, the true
future and the predicted mean, the chosen agent's attention (edges, weights beside the labelled
one, the curve over time) and a sortable list of the scenes with their ADE/FDE and attention
accuracy. Script, style and data are inline: the file opens from disk in a current browser with
no server and no network (docs/VIEWER.md).

Modules: `inputs` (read and check what is shown), `scores` (per-scene metrics), `content`
(the page's description and arrays), `pack` (the arrays as one compact blob), `page` (the HTML
from the package's template, style and script).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

from pipeline.files import atomic_output
from pipeline.viewer.content import page_spec, scene_arrays
from pipeline.viewer.inputs import Shown, ViewerError, read_inputs
from pipeline.viewer.pack import pack, raw_size
from pipeline.viewer.page import render_page

__all__ = [
    "MAX_ARRAY_BYTES",
    "Viewer",
    "ViewerError",
    "build_page",
    "make_viewer",
    "write_viewer",
]

# The arrays a page may carry, as the browser holds them once inflated: a 100-scene split of 22
# cars with predictions is 8.5 MB; this allows about 780 such scenes (docs/VIEWER.md).
MAX_ARRAY_BYTES = 64 * 2**20


@dataclass(frozen=True)
class Viewer:
    """A viewer page, made and not yet written."""

    text: str  # the HTML
    shown: int  # scenes in the page
    available: int  # scenes there were (more than shown where thinned)
    split: str
    predictor: str | None

    def summary(self, path: str | os.PathLike) -> str:
        """One line: the file, the scenes shown, what was left out, the size."""
        what = f"predictions of {self.predictor}" if self.predictor else "no predictions"
        left = self.available - self.shown
        thinned = f" (the first {self.shown}; {left} left out)" if left else ""
        size = len(self.text.encode("utf-8")) / 1e6
        return (
            f"{path}: {self.shown} of {self.available} {self.split} scenes{thinned}, "
            f"{what}; {size:.1f} MB"
        )


def check_size(shown: Shown, limit: int = MAX_ARRAY_BYTES) -> None:
    """ViewerError unless the shown scenes' arrays fit in `limit` bytes; the message says how
    many scenes would fit (the first scene's arrays measure a scene)."""
    per_scene = raw_size(scene_arrays(_first(shown))) + 64  # + alignment of each array
    if per_scene * shown.n <= limit:
        return
    fit = max(limit // per_scene, 1)
    raise ViewerError(
        f"{shown.n} scenes of {shown.data.num_agents} agent slots make about "
        f"{per_scene * shown.n / 2**20:.1f} MB of arrays, more than a browser page should hold "
        f"({limit / 2**20:.0f} MB); keep the first scenes with --max-scenes (at most {fit} fit)"
    )


def _first(shown: Shown) -> Shown:
    pred = shown.predictions
    return replace(
        shown,
        data=shown.data.subset([0]),
        rows=shown.rows[:1],
        predictions=None if pred is None else pred.select([0]),
    )


def build_page(shown: Shown, title: str | None = None, limit: int = MAX_ARRAY_BYTES) -> str:
    """The HTML text of the viewer of `shown` (ViewerError if it is too large)."""
    check_size(shown, limit)
    header, blob = pack(scene_arrays(shown))
    return render_page(page_spec(shown, title), header, blob)


def make_viewer(
    data: str | os.PathLike,
    predictions: str | os.PathLike | None = None,
    run: str | os.PathLike | None = None,
    split: str | None = None,
    max_scenes: int | None = None,
    title: str | None = None,
    progress: bool = False,
    limit: int = MAX_ARRAY_BYTES,
) -> Viewer:
    """The viewer of a dataset split, with the predictions of a file or of a run evaluated here
    (see `inputs.read_inputs`). Raises ViewerError (one line) for bad or mismatched inputs and
    for inputs too large for `limit` without `max_scenes`."""
    shown = read_inputs(data, predictions, run, split, max_scenes, progress)
    return Viewer(
        text=build_page(shown, title, limit),
        shown=shown.n,
        available=shown.available,
        split=shown.split,
        predictor=None if shown.predictions is None else shown.predictions.predictor,
    )


def write_viewer(data: str | os.PathLike, out: str | os.PathLike, **options) -> Viewer:
    """`make_viewer(data, **options)` written to `out` atomically (an existing file is
    replaced: callers check first); OSError where `out` cannot be written."""
    viewer = make_viewer(data, **options)
    with atomic_output(out) as temp:
        temp.write_text(viewer.text, encoding="utf-8")
    return viewer
