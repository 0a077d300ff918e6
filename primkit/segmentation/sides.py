"""Moved to :mod:`primkit.labelling.sides`; its names are re-exported here so that existing
imports work."""

from ..labelling.sides import *  # noqa: F401,F403
from ..labelling.sides import __all__  # noqa: F401
