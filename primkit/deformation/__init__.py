"""primkit.deformation (moved here from primkit/deformation.py; split into modules in the next commits)."""

from .mesh import *  # noqa: F401,F403
from .mesh import __all__  # noqa: F401
