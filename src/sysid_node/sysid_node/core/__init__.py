"""Pure DSRA numerics (no rclpy): batch and recursive subspace identification, modal
extraction, mode tracking, LTI simulation. See the package README."""

from .batch import identify
from .inputs import InputError
from .modal import ModalParameters
from .model import IdentifiedModel
from .recursive import SEED_EXAMPLE_SETTINGS, RecursiveDSRA
from .stabilization import StabilizationDiagram, stabilization_diagram
from .tracking import ModeTracker, TrackedMode

__all__ = [
    "SEED_EXAMPLE_SETTINGS",
    "IdentifiedModel",
    "InputError",
    "ModalParameters",
    "ModeTracker",
    "RecursiveDSRA",
    "StabilizationDiagram",
    "TrackedMode",
    "identify",
    "stabilization_diagram",
]
