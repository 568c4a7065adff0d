"""Local view cells (docs/spec.md §7): view descriptors behind one protocol, and what they observe.

- `base.py`: the `ViewDescriptor` protocol every descriptor implements, its `ViewObservation` answer, and
  `NO_VIEW_CELL`.
- `template.py`: the paper's descriptor, a patch-normalised whole-image template matched with a horizontal
  shift search in Rust (`crates/hippo_views`); the reference choice (`TemplateViewCells`).
- `words.py`: ORB features quantised into a bag of binary words (Rust, `crates/hippo_views/src/words`),
  the best-ranked stored views verified by epipolar geometry (OpenCV) (`WordViewCells`); recognises
  revisits from another lane, at another angle, under other light (docs/views.md).

```python
from hippo_nav.datasets import KittiOdometry
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence
from hippo_nav.view_cells import TemplateViewCells, TemplateViewConfig
dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stop=3)
cells = TemplateViewCells.for_camera(TemplateViewConfig(), dataset.calibration)
first = cells.observe(cells.describe(dataset[0]))           # a new cell
again = cells.observe(cells.describe(dataset[0]))           # the same view: familiar, cell 0
(first.status, first.cell_id), (again.status, again.cell_id)   # (('new', 0), ('familiar', 0))
```

Which descriptor a run uses is the config's `parts.view_cells`, a name in `DESCRIPTORS`; each descriptor's
settings are its own config section (`views` for the template, `view_words` for the words). Adding a
descriptor is its module here and one line in `DESCRIPTORS` (docs/architecture.md). How a cell's stored
network state is kept and recalled: `hippo_nav.engine.recall`.
"""

from collections.abc import Callable

from hippo_nav.plugs import Part
from hippo_nav.view_cells.base import NO_VIEW_CELL, Observation, ViewDescriptor, ViewObservation, ViewStatus
from hippo_nav.view_cells.template import TemplateViewCells, TemplateViewConfig, field_of_view_rad
from hippo_nav.view_cells.words import Vocabulary, WordViewCells, WordViewConfig, train_vocabulary

DescriptorFactory = Callable[..., ViewDescriptor]  # (its config section, the camera) → the descriptor

DESCRIPTORS: dict[str, Part[DescriptorFactory]] = {
    "template": Part(TemplateViewCells.for_camera, TemplateViewConfig, "views"),
    "words": Part(WordViewCells.for_camera, WordViewConfig, "view_words"),
}

__all__ = [
    "DESCRIPTORS",
    "NO_VIEW_CELL",
    "DescriptorFactory",
    "Observation",
    "TemplateViewCells",
    "TemplateViewConfig",
    "ViewDescriptor",
    "ViewObservation",
    "ViewStatus",
    "Vocabulary",
    "WordViewCells",
    "WordViewConfig",
    "field_of_view_rad",
    "train_vocabulary",
]
