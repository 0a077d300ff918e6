"""Moved to :mod:`primkit.labelling.layers`; its names are re-exported here so that existing
imports work."""

from ..labelling.layers import *  # noqa: F401,F403
from ..labelling.layers import __all__  # noqa: F401
