"""Moved to :mod:`primkit.labelling.presence`; its names are re-exported here so that existing
imports work."""

from ..labelling.presence import *  # noqa: F401,F403
from ..labelling.presence import __all__  # noqa: F401
