"""What the viewer tests share: the first four procedural chairs abstracted by the bundled chair
model, and a stand-in for Open3D's window that records what a viewer's action asks of it."""

from __future__ import annotations

import pytest

from primkit import io
from primkit.model.abstraction import Abstraction


@pytest.fixture(scope="module")
def shapes(chairs, prepared_chairs):
    """``([Abstraction] of chairs 0-3, the chair Abstractor)``."""
    from primkit.model.abstractor import Abstractor

    model = Abstractor.load("chair")
    results = model.predict(prepared_chairs[:4])
    return [Abstraction(r, given=io.Mesh(c.vertices, c.faces), shape=p)
            for r, c, p in zip(results, chairs[:4], prepared_chairs[:4])], model


class RecordingWindow:
    """What an action can ask of Open3D's ``O3DVisualizer``, recorded."""

    def __init__(self):
        self.shown, self.added, self.removed, self.boxes = {}, [], [], []

    def show_geometry(self, name, visible):
        self.shown[name] = bool(visible)

    def add_geometry(self, d):
        self.added.append(d["name"])

    def remove_geometry(self, name):
        self.removed.append(name)

    def post_redraw(self):
        pass

    def show_message_box(self, title, text):
        self.boxes.append((title, text))


@pytest.fixture
def recording_window():
    """The :class:`RecordingWindow` class: each call of it is a new window."""
    return RecordingWindow
