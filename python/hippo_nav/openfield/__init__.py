"""Open-field sessions: the spatial memory driven along a rodent's foraging path (RatInABox, or a CSV),
with the arena's landmarks as view cells, every unit recorded (docs/neuro.md)."""

from hippo_nav.openfield.config import LESIONS, LandmarkConfig, OpenFieldConfig
from hippo_nav.openfield.folder import SESSION_FILES, SessionFolder, analyse_session
from hippo_nav.openfield.session import LandmarkViews, engine_config, record_session
from hippo_nav.openfield.trajectory import Trajectory, foraging_trajectory, trajectory_from_csv

__all__ = [
    "LESIONS",
    "SESSION_FILES",
    "LandmarkConfig",
    "LandmarkViews",
    "OpenFieldConfig",
    "SessionFolder",
    "Trajectory",
    "analyse_session",
    "engine_config",
    "foraging_trajectory",
    "record_session",
    "trajectory_from_csv",
]
