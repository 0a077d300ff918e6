"""Moved to :mod:`primkit.labelling.post`; its names are re-exported here so that existing
imports work."""

from ..labelling.post import *  # noqa: F401,F403
from ..labelling.post import __all__  # noqa: F401
