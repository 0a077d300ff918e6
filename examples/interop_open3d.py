"""primkit values in Open3D and pyvista: abstract a procedural chair, hand its mesh, coloured
segmentation and cuboids to Open3D (TriangleMesh, LineSet, PointCloud) and to pyvista, bring them
back, and write pictures from both without a screen.

    python examples/interop_open3d.py OUTPUT_FOLDER
"""

import sys
from pathlib import Path

import numpy as np

from primkit import data, io, synthetic
from primkit.viz import interop, render
from primkit.model.abstractor import Abstractor
from primkit.viz.palette import part_colors
from primkit.segmentation import face_labels


def main(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    chair = synthetic.chair(seed=7)
    model = Abstractor.load("chair")
    result = model.predict([data.prepare(io.Mesh(chair.vertices, chair.faces), name="chair")])[0]
    cuboids = result.cuboids
    labels = face_labels(chair.vertices, chair.faces, cuboids)  # primitive index per face
    colors = part_colors(cuboids.count)

    # to Open3D: the segmentation as a coloured TriangleMesh, the cuboids as solids and edges
    seg = interop.mesh_to_o3d(chair.vertices, chair.faces, face_colors=colors[labels])
    boxes = interop.cuboids_to_o3d(cuboids)
    edges = interop.cuboids_to_lineset(cuboids)
    samples = seg.sample_points_uniformly(5000)  # any Open3D operation applies from here
    print(f"Open3D: {seg}, {len(edges.lines)} cuboid edges, {len(samples.points)} samples")

    # and back: arrays again (the segmentation colours survive the trip)
    back = interop.mesh_from_o3d(seg)
    assert np.array_equal(back.face_colors, colors[labels])
    points, point_colors = interop.points_from_o3d(samples)
    io.write_points(out / "samples.ply", points, overwrite=True)

    # an Open3D picture off screen (draw(...) without png= opens Open3D's window instead)
    interop.draw(seg, edges, png=out / "open3d.png")

    # pyvista: the same values as PolyData (cell_data["part"] says which primitive each face is)
    poly = interop.to_pyvista(cuboids)
    print(f"pyvista: {poly.n_cells} cuboid faces, parts {sorted(set(poly.cell_data['part'].tolist()))}")
    render.write_png(out / "pyvista.png", [
        render.Tile("mesh", [render.mesh_layer(chair.vertices, chair.faces)]),
        render.Tile("segmentation", [render.segmentation_layer(chair.vertices, chair.faces, labels, cuboids.count)]),
        render.Tile("cuboids", [render.cuboid_layer(cuboids)]),
    ], columns=3, tile=240, overwrite=True)
    print(f"wrote {out / 'open3d.png'}, {out / 'pyvista.png'} and {out / 'samples.ply'}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(Path(sys.argv[1])))
