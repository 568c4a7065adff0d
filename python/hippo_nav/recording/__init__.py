"""The networks as a neuroscientist records them: a session's units over time (`Recording`), the lab's
measures (rate maps, grid and head-direction scores, spacing, spatial information), the population's
topology, figures and NWB export (docs/neuro.md)."""

from hippo_nav.recording.session import GRID_POPULATIONS, Recording, RecordingError

__all__ = ["GRID_POPULATIONS", "Recording", "RecordingError"]
