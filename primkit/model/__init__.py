"""The learned abstractor (moved here from the top-level modules)."""
