"""primkit.synthetic (moved here from primkit/synthetic.py; split into modules in the next commits)."""

from .categories import *  # noqa: F401,F403
from .categories import __all__  # noqa: F401
