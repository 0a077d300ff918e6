"""primkit.io (moved here from primkit/io.py; split into modules in the next commits)."""

from .formats import *  # noqa: F401,F403
from .formats import __all__  # noqa: F401
