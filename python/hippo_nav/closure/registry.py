"""The closure proposers by name: `parts.closure` lists which run, in which order (`chain.py`). Adding a way
of proposing loops is its module in `closure/` (a config section model and a class with `propose` and
`after_map`, `base.ClosureProposer`) and one line here; its settings are then `closure.<section>`."""

from __future__ import annotations

from collections.abc import Callable

from hippo_nav.closure.base import ClosureProposer
from hippo_nav.closure.birdseye import BirdsEyeConfig, BirdsEyeProposer
from hippo_nav.closure.home import HomeConfig, HomeProposer
from hippo_nav.closure.proximity import ProximityConfig, ProximityProposer
from hippo_nav.closure.relocalisation import RelocalisationConfig, RelocalisationProposer
from hippo_nav.closure.sequence import SequenceConfig, SequenceProposer
from hippo_nav.closure.view_cell import ViewCellConfig, ViewCellProposer
from hippo_nav.plugs import Part

__all__ = ["DEFAULT_PROPOSERS", "PROPOSERS", "ProposerFactory"]

ProposerFactory = Callable[..., ClosureProposer]  # its config section → the proposer

PROPOSERS: dict[str, Part[ProposerFactory]] = {
    "relocalisation": Part(RelocalisationProposer, RelocalisationConfig, "relocalisation"),
    "view_cell": Part(ViewCellProposer, ViewCellConfig, "view_cell"),
    "proximity": Part(ProximityProposer, ProximityConfig, "proximity"),
    "home": Part(HomeProposer, HomeConfig, "home"),
    "birdseye": Part(BirdsEyeProposer, BirdsEyeConfig, "birdseye"),
    "sequence": Part(SequenceProposer, SequenceConfig, "sequence"),
}

# Bird's-eye and sequence closures are off by default for their cost where the map has old places around
# (docs/results.md, "Cost"); home closures measure only near where the session began (docs/map.md).
DEFAULT_PROPOSERS = ("relocalisation", "view_cell", "proximity", "home")
