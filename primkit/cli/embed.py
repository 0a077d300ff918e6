"""``primkit embed`` (distances and a t-SNE map of a collection) and ``primkit similar`` (retrieval).

Both abstract their inputs with a model, describe the chosen parts' chosen properties
(:class:`primkit.embedding.PartDescriptor`) and compare the descriptors; ``--metric voxel-iou``
compares the prepared occupancy grids instead (the paper's baseline).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._common import DeprecatedAlias, add_command
from ._common import (abstraction_options, add_abstraction_options, add_scale_out, add_force, add_output, add_png, check_command_outputs, collect,
                      err, input_paths, model_file, output_names, progress_of, report_errors)

#: primkit.embedding.REGION_WEIGHTS as the help states them (written out: importing the module would
#: load scikit-learn and matplotlib for every command's --help; a test checks the two agree)
_WEIGHTS_HELP = "extent=1, share=1, place=0.25, thickness=0.25, fill=0.25, signature=0.5"

#: Above this many shapes ``embed`` writes no full distance matrix unless --distances yes.
_MATRIX_LIMIT = 4000


def _scales(text):
    """``"orientation=30,size=0.1"`` -> dict."""
    out = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, _, value = item.partition("=")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--units: expected NAME=NUMBER items, got {item!r}") from None
    return out


def _abstract(args, files):
    """Abstract files (:func:`primkit.model.abstraction.abstract_shapes`), keeping only what the
    commands need: the results and the occupancy grids the network read."""
    from dataclasses import replace

    from ..model.abstraction import abstract_shapes, load_model
    from ._common import settings_from_args

    abstractor = load_model(args.model)
    settings = replace(settings_from_args(args, abstractor.settings), resolution=abstractor.resolution)
    out = abstract_shapes(files, abstractor, settings=settings, **abstraction_options(args))
    grids = [a.canonical_shape().occupancy for a in out]
    return abstractor, out.results, np.array(grids, dtype=bool), out.errors


def _thumb_meshes(results, grids, kind, selected, regions=None):
    """One mesh per shape for its thumbnail: the voxel boundary, or the cuboids coloured by part
    index with the unselected parts grey. With ``regions`` (the compared parts by label), each
    shape's voxels of those parts in their label colours and the rest grey and translucent, as
    layers (:func:`primkit.viz.maps.region_layers`)."""
    from ..viz.maps import region_layers
    from ..viz.palette import part_colors
    from ..geometry import voxel_boundary_mesh

    meshes = []
    for i, (r, g) in enumerate(zip(results, grids)):
        if regions is not None and kind == "shape":
            labels, chosen, colours = regions
            meshes.append(region_layers(g, labels[i], chosen, colours))
            continue
        if kind == "shape":
            meshes.append(voxel_boundary_mesh(g))
            continue
        v, f, part = r.canonical.to_mesh()
        colors = part_colors(r.canonical.count)
        if selected is not None:
            grey = np.ones(len(colors), bool)
            grey[selected] = False
            colors[grey] = 200
        meshes.append((v, f, colors[part]))
    return meshes


def _write_csv(path, rows, force):
    """Rows through the csv module (a name holding a comma or a quote stays one field); names from
    file names that are not UTF-8 keep their bytes (surrogateescape)."""
    import csv

    from ..io import atomic_output

    with atomic_output(path, overwrite=force) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
            csv.writer(fh).writerows(rows)


@dataclass
class _Description:
    """What ``embed`` and ``similar`` compare: the descriptor (None for voxel IoU), the collection's
    and the queries' descriptors, and with parts by label each shape's labelled grid (collection
    first, then the queries), the label indices compared and the labels' colours."""

    desc: object = None
    X: np.ndarray | None = None
    Q: np.ndarray | None = None
    labels: list | None = None
    chosen: np.ndarray | None = None
    colours: np.ndarray | None = None


def _weights(text):
    """``"signature=1,place=0.5"`` -> dict (the region weights)."""
    out = _scales(text)
    return out or None


def _describe(args, abstractor, results, grids, queries=None, query_grids=None) -> _Description:
    """The descriptors of the collection (and of extra query results); nothing for voxel IoU.

    With a model labeller and ``--parts`` naming only its labels, each shape's voxels named by it
    are described as regions (:class:`primkit.embedding.RegionDescriptor`); otherwise the chosen
    part indices' cuboids (:class:`primkit.embedding.PartDescriptor`)."""
    from ..embedding import PROPERTIES, PartDescriptor, RegionDescriptor, RegionTable

    if args.metric == "voxel-iou":
        return _Description()
    labelled = _label_grids(args, results, grids, queries, query_grids)
    if labelled is not None:  # --parts names the labeller's labels: each shape's labelled voxels
        names, chosen, labels = labelled
        if args.units:
            raise ValueError("--units sets the cuboid descriptor's units; parts by label take --weights")
        all_grids = list(grids) + (list(query_grids) if queries else [])
        table = RegionTable.from_grids(all_grids, labels, names, [r.name for r in list(results) + list(queries or [])])
        s = len(results)
        desc = RegionDescriptor(chosen, args.what, _weights(args.weights)).fit(table[:s])
        desc.by_label_ = True
        X = desc.transform(table)
        from ..viz.palette import label_colors

        return _Description(desc, X[:s], X[s:] if queries else None, labels, desc.parts_, label_colors(len(names)))
    if args.weights:
        raise ValueError("--weights sets the weights of parts by label (a model with a labeller); cuboids take --units")
    desc = PartDescriptor(args.parts, args.what or PROPERTIES, _scales(args.units),
                          part_names=abstractor.part_names).fit(results)
    X = desc.transform(results)
    Q = desc.transform(queries) if queries else None
    return _Description(desc, X, Q)


def _label_grids(args, results, grids, queries=None, query_grids=None):
    """With a model labeller and --parts naming only its labels: ``(label names, chosen names,
    labelled grids)``, each shape's canonical voxels named by the labeller
    (:func:`primkit.segmentation.bylabel.labelled_grid`), the collection's then the queries'; None
    otherwise (index-based parts)."""
    from ..model.bundled import resolve_model
    from ..segmentation.bylabel import by_label, labelled_grid
    from ..segmentation.labeller import read_labeller

    if args.parts is None:
        return None
    labeller = read_labeller(resolve_model(args.model))
    chosen = by_label(args.parts, None if labeller is None else labeller.names)
    if chosen is None:
        return None
    rs = list(results) + list(queries or [])
    gs = list(grids) + (list(query_grids) if queries else [])
    return list(labeller.names), chosen, [labelled_grid(labeller, g, r.canonical) for r, g in zip(rs, gs)]


def _regions(described, rows):
    """``(labelled grids, compared label indices, label colours)`` of the shapes ``rows`` for their
    thumbnails, or None when the parts are not compared by label."""
    if described.labels is None:
        return None
    return [described.labels[i] for i in rows], described.chosen, described.colours


def _selected(desc):
    """The part indices the thumbnails colour (None: all; parts by label are no indices)."""
    return None if desc is None or getattr(desc, "by_label_", False) else desc.parts_


def _chosen(args, desc) -> str:
    if getattr(desc, "by_label_", False):
        return f"{','.join(desc.part_names_[k] for k in desc.parts_)} (the labeller's voxels)"
    return f"parts {args.parts or 'all'} ({len(desc.parts_)} indices)"


def _picture_path(path):
    from ..io import check_suffix

    return None if path is None else check_suffix(path, ".png", "a picture")


def _cmd_embed(args) -> int:
    from .. import embedding
    from ..viz import maps
    from ..data import plan_run
    from ..io import check_suffix, write_array

    out = Path(args.output)
    names_out = ["distances.npy", "distances.csv", "map.csv"]
    if args.metric == "descriptor":
        names_out += ["descriptors.npy"]
    svg = None if args.svg is None else check_suffix(args.svg, ".svg", "a map")
    # the names are the rows of the CSV files (the plan says which inputs shared one)
    plan = plan_run(args.inputs, out, extra=[out / n for n in names_out] + [_picture_path(args.png), svg],
                    reads=[model_file(args.model)])
    plan.check(args.force)
    abstractor, results, grids, errors = _abstract(args, plan)
    if len(results) < 3:
        err(f"{len(results)} usable shape(s): a map needs at least 3")
        report_errors(errors)
        return 2
    names = [r.name for r in results]
    described = _describe(args, abstractor, results, grids)
    desc, X = described.desc, described.X
    s = len(results)
    if X is None:
        D = embedding.voxel_iou_distances(grids)
    elif args.distances == "yes" or (args.distances == "auto" and s <= _MATRIX_LIMIT):
        D = embedding.descriptor_distances(X)
    else:
        D = None
    out.mkdir(parents=True, exist_ok=True)
    if D is not None:
        write_array(out / "distances.npy", D, overwrite=args.force)
        rows = [["name", *names]] + [[n, *(f"{v:.6g}" for v in row)] for n, row in zip(names, D)]
        _write_csv(out / "distances.csv", rows, args.force)
    else:
        print(f"{s} shapes: no full distance matrix written (--distances yes asks for it)", file=sys.stderr)
    if X is not None:
        write_array(out / "descriptors.npy", X, overwrite=args.force)
    if X is None:
        coords = embedding.tsne_map(distances=D, perplexity=args.perplexity, random_state=args.seed)
    else:
        coords = embedding.tsne_map(X, perplexity=args.perplexity, random_state=args.seed)
    _write_csv(out / "map.csv", [["name", "x", "y"]] + [[n, f"{x:.6g}", f"{y:.6g}"] for n, (x, y) in zip(names, coords)],
               args.force)
    what = "voxel IoU" if X is None else f"{_chosen(args, desc)}, {','.join(desc.what_)}"
    if args.png or args.svg:
        meshes = _thumb_meshes(results, grids, args.thumbnails, _selected(desc), _regions(described, range(s)))
        images = maps.render_thumbnails(meshes, size=args.thumb_size, progress=progress_of(args))
        maps.draw_map(coords, images, args.png, svg=args.svg, title=f"t-SNE map of {s} shapes: {what}")
    print(f"{s} shapes embedded ({what}) -> {out}")
    return report_errors(errors)


def _cmd_similar(args) -> int:
    from .. import embedding
    from ..viz import maps

    out = Path(args.output)
    query_files = collect([args.query])
    if len(query_files) != 1:
        raise ValueError(f"{args.query}: expected one shape file, found {len(query_files)}")
    files = [f for f in collect(args.inputs) if f.resolve() != query_files[0].resolve()]
    if not files:
        raise ValueError(f"no shape files found in {', '.join(args.inputs)} besides the query")
    output_names(query_files + files)
    check_command_outputs(args, [out / "similar.csv", _picture_path(args.png)], input_paths(query_files + files, model_file(args.model)))
    abstractor, results, grids, errors = _abstract(args, query_files + files)
    if not results or str(results[0].source) != str(query_files[0]):
        err(f"{query_files[0]}: the query could not be used")
        report_errors(errors)
        return 2
    query, results, qgrid, grids = results[0], results[1:], grids[:1], grids[1:]
    k = min(args.k, len(results))
    if k < 1:
        err("no usable shapes to rank")
        return report_errors(errors) or 1
    described = _describe(args, abstractor, results, grids, [query], qgrid)
    desc, X, Q = described.desc, described.X, described.Q
    if X is None:
        d = embedding.voxel_iou_distances(qgrid, grids)[0]
        order = np.argsort(d, kind="stable")[:k]
        dist = d[order]
    else:
        nn = embedding.nearest_neighbors(X, k, queries=Q)
        order, dist = nn.indices[0], nn.distances[0]
    rows = [["rank", "name", "distance", "source"]] + [[i + 1, results[j].name, f"{dv:.6g}", results[j].source]
                                                       for i, (j, dv) in enumerate(zip(order, dist))]
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(out / "similar.csv", rows, args.force)
    for i, (j, dv) in enumerate(zip(order, dist)):
        print(f"{i + 1:3d}  {dv:10.4g}  {results[j].name}")
    if args.png:
        sel = _selected(desc)
        shown = [len(results)] + list(order)  # the query's labelled grid comes after the collection's
        meshes = _thumb_meshes([query] + [results[j] for j in order], np.concatenate([qgrid, grids[order]]), args.thumbnails,
                               sel, _regions(described, shown))
        images = maps.render_thumbnails(meshes, size=160, progress=progress_of(args))
        what = "voxel IoU" if X is None else f"{_chosen(args, desc)}, {','.join(desc.what_)}"
        maps.draw_matches(images[0], images[1:], [results[j].name for j in order], dist, args.png,
                               query_name=query.name, title=f"nearest to {query.name} by {what}")
    return report_errors(errors)


def _common_options(p) -> None:
    p.add_argument("--parts", default=None, help="parts to compare, by name or index: back,seat or 3,7 (default: all); "
                   "with a model labeller, names it knows (back, seat, legs, arms) compare each shape's voxels the "
                   "labeller names so (docs/labeller.md), otherwise the parts' cuboids")
    p.add_argument("--what", default=None,
                   help="properties compared. Cuboids: any of size, position, orientation, presence (default: all). "
                        "Parts by label: any of extent, share, place, thickness, fill, signature (default: those "
                        "weighted above 0)")
    p.add_argument("--units", default=None, metavar="NAME=VALUE,...",
                   help="cuboids: the distance's unit for each property, a difference of one unit counts 1 (defaults "
                        "size=0.05, position=0.1 in canonical units, orientation=15 degrees, presence=0.5: an "
                        "absent/present part costs 2)")
    p.add_argument("--scale", dest="units", action=DeprecatedAlias, new="--units")  # the old name: edit --scale scales parts
    p.add_argument("--weights", default=None, metavar="NAME=VALUE,...",
                   help="parts by label: each property's weight after standardising it over the collection; defaults "
                        f"{_WEIGHTS_HELP} (chosen on the PartNet validation chairs; docs/results-applications.md)")
    p.add_argument("--metric", choices=["descriptor", "voxel-iou"], default="descriptor",
                   help="descriptor (the parts' labelled voxels, or their cuboids) or voxel-iou (1 - IoU of the occupancy grids, "
                        "the whole-shape baseline)")
    p.add_argument("--thumbnails", choices=["shape", "cuboids"], default="shape",
                   help="draw each shape's voxel surface (parts by label: the compared parts in their label colours, the "
                        "rest grey and see-through), or its cuboids (selected parts coloured)")
    add_abstraction_options(p)
    add_scale_out(p, shard=False)
    p.add_argument("--samples", type=int, default=None, help="surface samples per shape (default 10000)")
    add_output(p, "output folder")
    add_png(p)
    add_force(p)


def register(subparsers) -> None:
    p = add_command(subparsers, "embed", help="distances between shapes by chosen parts, and a t-SNE map with thumbnails",
        description="Describe each shape by the chosen properties of the chosen parts, and write the distances, the t-SNE coordinates and a map drawn with thumbnails.",
        examples=["primkit embed chairs/ --model chair -o emb/ --png map.png", "primkit embed chairs/ --model chair --parts back --what orientation --refine 100 -o emb-tilt/"])
    p.add_argument("inputs", nargs="+", help="shape files or folders")
    _common_options(p)
    p.add_argument("--distances", choices=["auto", "yes", "no"], default="auto",
                   help=f"write the full distance matrix (auto: up to {_MATRIX_LIMIT} shapes)")
    p.add_argument("--perplexity", type=float, default=30.0, help="t-SNE perplexity (default 30; lowered for small collections)")
    p.add_argument("--seed", type=int, default=0, help="t-SNE random state: the same seed gives the same map")
    p.add_argument("--svg", default=None, metavar="PATH", help="also draw the map into this SVG file")
    p.add_argument("--thumb-size", type=int, default=96, help="thumbnail size in pixels")
    p.set_defaults(func=_cmd_embed)

    p = add_command(subparsers, "similar", help="rank a collection by similarity to a query shape, by chosen parts",
        description="Rank a collection by similarity to a query shape, by the chosen parts and properties; prints the matches and can draw them.",
        examples=["primkit similar query.off chairs/ --model chair --parts back,seat -k 5 -o sim/ --png sim.png"])
    p.add_argument("query", help="the query shape file")
    p.add_argument("inputs", nargs="+", help="shape files or folders to rank (the query itself is left out)")
    p.add_argument("-k", type=int, default=5, help="matches to report (default 5)")
    _common_options(p)
    p.set_defaults(func=_cmd_similar)
