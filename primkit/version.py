"""primkit's version (read by the model files, the command line and the wheel)."""

__version__ = "0.1.0"
