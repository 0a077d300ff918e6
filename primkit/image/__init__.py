"""Abstraction from a single image (moved here from image_model.py and views.py)."""
