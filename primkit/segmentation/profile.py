"""Moved to :mod:`primkit.labelling.profile`; its names are re-exported here so that existing
imports work."""

from ..labelling.profile import *  # noqa: F401,F403
from ..labelling.profile import __all__  # noqa: F401
