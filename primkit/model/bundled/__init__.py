"""The bundled models: ``--model chair`` resolves a name to a model file shipped in this folder.

Each bundled model is ``<name>.safetensors`` (a primkit model file, :mod:`primkit.model.modelfile`)
whose metadata carries its model card under ``"card"``: the data it was trained on and the data's
terms, the schedule, the training time, and metrics on shapes it did not train on. ``primkit
models`` prints the cards. How each was trained is in :mod:`primkit.model.presets`. This package
imports nothing of primkit: it only finds files.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["MODEL_DIR", "bundled_models", "resolve_model"]

#: Folder of the bundled model files.
MODEL_DIR = Path(__file__).resolve().parent


def bundled_models() -> dict[str, Path]:
    """``{name: path}`` of the model files shipped with primkit, sorted by name."""
    return {p.stem: p for p in sorted(MODEL_DIR.glob("*.safetensors"))}


def resolve_model(model) -> Path:
    """A model file path from a path or a bundled model's name.

    An existing file wins over a bundled name; anything else raises ``FileNotFoundError`` naming
    the bundled models.
    """
    path = Path(model)
    if path.is_file():
        return path
    bundled = bundled_models()
    if str(model) in bundled:
        return bundled[str(model)]
    names = ", ".join(bundled) or "none installed"
    raise FileNotFoundError(f"{model}: no such model file, and not a bundled model ({names})")
