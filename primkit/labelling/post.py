"""Labeller post-steps: named rules a labeller file asks for, applied after the decision.

A labeller decides each element on its own
(:meth:`primkit.labelling.labeller.Labeller.labels_from`). A rule that holds for one category,
not for any labelled set, runs after that decision as a *post-step*: it is stored in the
labeller's file under its name with every parameter, and a labeller applies the steps its file
lists, in order. No step is switched on by how a label is spelled: the labels a step reads are
its parameters (which label is a chair's arms, which its seat), so a labelled set that says
"armrest" or "Seat" gets the same rule when the step is told so, and a lamp's "arms" get no chair
rule unless the step is asked for.

* ``chair.arms_from_side_region``: whether a shape has arms at all, read from what rises beside
  its seat (:class:`primkit.labelling.presence.PresenceRule`);
* ``chair.seat_layer_cut``: where the seat ends and the legs begin, one horizontal cut on a voxel
  grid's layers (:class:`primkit.labelling.layers.LayerCut`).

Recipes name several steps at once: ``"chair"`` is both, in that order. When fitting
(:meth:`primkit.labelling.labeller.Labeller.fit`'s ``post``, ``primkit name-parts --post``)
each step is given as

* a recipe or a step name (``"chair"``, ``"chair.seat_layer_cut"``): the step's defaults, chosen
  on PartNet validation chairs;
* a name with parameters, ``"chair.arms_from_side_region:label=armrest,veto=0.02"`` (what the
  command line takes), or a dict ``{"step": "chair.seat_layer_cut", "upper": "Seat"}``: the
  defaults with those parameters changed;
* a step object (``PresenceRule(label="armrest")``).

In a file a step is ``{"step": NAME, **every parameter}``.
"""

from __future__ import annotations

import json

from .layers import LayerCut
from .presence import PresenceRule

__all__ = ["STEPS", "RECIPES", "step_to_dict", "step_from_dict", "resolve_post", "parse_post", "post_names"]

#: The post-steps by name.
STEPS = {PresenceRule.STEP: PresenceRule, LayerCut.STEP: LayerCut}
#: Names for several steps at once, in the order they run.
RECIPES = {"chair": (PresenceRule.STEP, LayerCut.STEP)}


def step_to_dict(step) -> dict:
    """A step as a labeller file stores it: ``{"step": NAME, **every parameter}``."""
    return {"step": step.STEP, **step.to_dict()}


def step_from_dict(d):
    """The inverse of :func:`step_to_dict`; ValueError (one line) on an unknown step or anything
    but every parameter of it."""
    if not isinstance(d, dict) or d.get("step") not in STEPS:
        got = d.get("step") if isinstance(d, dict) else d
        raise ValueError(f"unknown post-step {got!r} (known: {', '.join(STEPS)})")
    try:
        return STEPS[d["step"]].from_dict({k: v for k, v in d.items() if k != "step"})
    except ValueError as exc:  # the parameter's own message, said of the step
        raise ValueError(str(exc) if d["step"] in str(exc) else f"{d['step']}: {exc}") from None


def post_names() -> list:
    """Every recipe and step name ``resolve_post`` takes."""
    return [*RECIPES, *STEPS]


def resolve_post(post) -> list:
    """The step objects ``post`` names (the module notes), in order: None or ``()`` none; a
    string or a dict is one item, a list several."""
    if post is None:
        return []
    items = list(post) if isinstance(post, (list, tuple)) else [post]
    out = []
    for item in items:
        if hasattr(item, "STEP"):
            out.append(item)
        elif isinstance(item, dict):
            name = item.get("step")
            if name not in STEPS:
                raise ValueError(f"unknown post-step {name!r} (known: {', '.join(STEPS)})")
            out.append(_with(STEPS[name](), {k: v for k, v in item.items() if k != "step"}))
        elif isinstance(item, str):
            out.extend(parse_post(item))
        else:
            raise ValueError(f"a post-step is a name, a dict or a step, not {type(item).__name__}")
    return out


def parse_post(text: str) -> list:
    """The steps one command-line value names: ``"chair"``, ``"chair.seat_layer_cut"`` or
    ``"chair.arms_from_side_region:label=armrest,veto=0.02"`` (values read as JSON where they
    parse, else as text)."""
    name, _, given = str(text).partition(":")
    name = name.strip()
    if name in RECIPES:
        if given:
            raise ValueError(f"the recipe {name!r} takes no parameters (give its steps: {', '.join(RECIPES[name])})")
        return [STEPS[step]() for step in RECIPES[name]]
    if name not in STEPS:
        raise ValueError(f"unknown post-step {name!r} (known: {', '.join(post_names())})")
    params = {}
    for pair in filter(None, (p.strip() for p in given.split(","))):
        key, eq, value = pair.partition("=")
        if not eq:
            raise ValueError(f"post-step parameter {pair!r} is not KEY=VALUE")
        try:
            params[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            params[key.strip()] = value.strip()
    return [_with(STEPS[name](), params)]


def _with(step, params: dict):
    """``step`` with ``params`` changed (ValueError, one line, on a parameter it lacks)."""
    known = step.to_dict()
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(f"{step.STEP} has no parameter {', '.join(unknown)} (it has {', '.join(known)})")
    return step.from_dict({**known, **params})
