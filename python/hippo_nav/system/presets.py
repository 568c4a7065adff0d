"""Named starting points for a pipeline config: `{"preset": "paper"}` in a config file, `hippo-nav run --preset
paper`, or `--set preset=paper` in a sweep.

A preset is a set of settings laid under a config: whatever the config file (or a sweep's override) sets itself
wins, every other setting the preset names takes the preset's value, the rest their defaults. A run's
`config.json` names its preset and holds every setting resolved, so it loads back to the same config.

- `default`: today's engineered defaults (nothing changed).
- `paper`: the system as Zeng, Li & Si describe it (docs/spec.md §7–§8), kept at its best: the paper's
  patch-normalised whole-image template view cells, compared with every stored template; a familiar view recalls
  the network state stored with it, exactly as stored (the agent is taken to be where the view was first seen);
  the experience map closes a loop by the RatSLAM rule (same view cell and matching codes: the agent is moved
  onto the matched vertex) and is corrected by RatSLAM's relaxation passes, online and at the end. What stays
  engineered, because without it the paper's own method works worse or not at all: the networks' velocity
  pinning (without it a slow bump stalls between velocity slices, docs/model.md), the built-in stereo
  odometry, and the map's guards (a closure only between vertices 50 m apart along the path, inside the
  odometry's gate), without which one look-alike tears the map. docs/results.md ("The paper's system") measures
  what each engineering change adds over it.
"""

from __future__ import annotations

import copy
from typing import Any

from hippo_nav._core import HippoNavError
from hippo_nav._defaults import merged

PRESETS: dict[str, dict[str, Any]] = {
    "default": {},
    "paper": {
        "parts": {"view_cells": "template"},
        # The paper compares a view with every stored template (the restricted search is a departure).
        "view_search": {"near_only": False},
        # RatSLAM's closure: nothing is measured, so the recalled state is placed as it was stored.
        "injection": {"placement": "as_stored"},
        "map": {"closure": "RatSlam", "online_correction": "Relaxation"},
        "correction": {"method": "relaxation"},
    },
}
"""Preset name → the settings it lays under a config (sections as in a config file)."""


def preset_settings(name: object) -> dict[str, Any]:
    """The settings of the preset `name` (a copy), or a one-line error naming the presets."""
    if not isinstance(name, str) or name not in PRESETS:
        shown = repr(name) if len(repr(name)) <= 40 else repr(name)[:40] + "…"
        raise HippoNavError(f"preset {shown}: unknown; choose from {', '.join(PRESETS)}")
    return copy.deepcopy(PRESETS[name])


def under_preset(data: dict[str, Any]) -> dict[str, Any]:
    """`data` (a config as a dict) with its preset's settings laid under it: `data`'s own settings win, key by
    key inside each section. Without a `preset` key, `data` unchanged."""
    if "preset" not in data:
        return data
    return merged(preset_settings(data["preset"]), data)


__all__ = ["PRESETS", "preset_settings", "under_preset"]
