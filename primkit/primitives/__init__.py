"""primkit.primitives (moved here from primkit/primitives.py; split into modules in the next commits)."""

from .cuboids import *  # noqa: F401,F403
from .cuboids import __all__  # noqa: F401
