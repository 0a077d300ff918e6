"""primkit.geometry (moved here from primkit/geometry.py; split into modules in the next commits)."""

from .frames import *  # noqa: F401,F403
from .frames import __all__  # noqa: F401
