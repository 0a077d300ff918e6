"""What the command line says is true: ``-V`` prints the version, the top-level help names every
viewer, every option with a default says it, no help names a path of this repository, one name
means one thing (``embed --units`` against ``edit --scale``, the old ``embed --scale`` a hidden
deprecated alias), and a mesh of polygons that comes back triangulated is said so."""

from __future__ import annotations

import argparse
import re

import pytest

from primkit.cli import build_parser, main


def _parsers(parser, path=("primkit",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


PARSERS = list(_parsers(build_parser()))


def _sub(*path):
    return dict((p[1:], q) for p, q in PARSERS)[path]


def _option_help(parser, option: str) -> str:
    """The help text ``--help`` prints for one option, joined onto one line."""
    text = parser.format_help()
    start = re.search(rf"^  {re.escape(option)}(?=[\s,])", text, re.M).start()
    lines = [text[start:].splitlines()[0]]
    for line in text[start:].splitlines()[1:]:
        if not line.startswith(" " * 10):
            break
        lines.append(line.strip())
    return " ".join(lines)


@pytest.mark.parametrize("flag", ["-V", "--version"])
def test_the_version_flags_print_the_version(flag, capsys):
    from primkit.version import __version__

    with pytest.raises(SystemExit) as exit_:
        main([flag])
    assert exit_.value.code == 0 and capsys.readouterr().out.strip() == f"primkit {__version__}"


def test_the_top_level_help_names_every_viewer():
    view_line = re.search(r"^    view .*?(?=^    \S|\Z)", build_parser().format_help(), re.M | re.S).group(0)
    viewers = _sub("view")._actions[-1].choices
    assert set(viewers) == {"abstraction", "collection", "embedding", "deformation", "open3d"}
    for name in viewers:
        assert name in " ".join(view_line.split()), name


@pytest.mark.parametrize("path,option,default", [
    (("segment",), "--smoothness", "1e-4"), (("embed",), "--seed", "0"),
    (("name-parts",), "--seed", "0"), (("embed",), "--thumb-size", "96"), (("deform",), "--falloff", "3%"),
    (("edit",), "--falloff", "3%"), (("train",), "--seed", "0")])
def test_named_options_show_their_default(path, option, default):
    parser = _sub(*path)
    if option not in parser._option_string_actions:
        pytest.skip(f"primkit {' '.join(path)} has no {option}")
    assert f"default: {default}" in _option_help(parser, option) or f"default {default}" in _option_help(parser, option)


def test_every_option_with_a_default_says_it():
    missing = []
    for path, parser in PARSERS[1:]:  # the subcommands (the top level has -h and -V only)
        for action in parser._actions:
            if (not action.option_strings or action.help == argparse.SUPPRESS or action.default is None
                    or action.default is False or isinstance(action, (argparse._HelpAction, argparse._VersionAction))):
                continue
            if "default" not in _option_help(parser, action.option_strings[0]):
                missing.append(f"{' '.join(path)} {action.option_strings[-1]}")
    assert not missing, missing


def test_no_help_names_a_path_of_this_repository():
    for path, parser in PARSERS:
        text = parser.format_help()
        assert "shared/data" not in text and "../shared" not in text, " ".join(path)


def test_embed_units_and_edit_scale_are_two_names_and_the_old_one_still_parses(capsys):
    embed = _sub("embed")
    assert "--units" in embed.format_help() and "--scale" not in embed.format_help()
    assert "--scale" in _sub("edit").format_help()  # edit --scale: a part's scale factor
    args = build_parser().parse_args(["embed", "x", "-o", "out", "--units", "orientation=30"])
    assert args.units == "orientation=30"
    old = build_parser().parse_args(["embed", "x", "-o", "out", "--scale", "size=0.1"])
    assert old.units == "size=0.1" and not hasattr(old, "scale")
    assert "primkit: note: --scale is deprecated here: use --units" in capsys.readouterr().err


def test_declared_face_counts(tmp_path):
    from primkit.io import declared_face_count

    (tmp_path / "a.off").write_text("OFF 4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n")
    (tmp_path / "b.off").write_text("# comment\nOFF\n\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    (tmp_path / "c.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n  f 1 2 3\n# f 9 9 9\n")
    (tmp_path / "d.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                                    "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    (tmp_path / "e.stl").write_text("solid x\nendsolid x\n")
    got = {p.name: declared_face_count(p) for p in sorted(tmp_path.iterdir())}
    assert got == {"a.off": 2, "b.off": 1, "c.obj": 2, "d.ply": 1, "e.stl": None}
    assert declared_face_count(tmp_path / "missing.obj") is None


@pytest.mark.integration  # a whole `primkit segment` run on one small mesh
def test_segment_says_when_a_mesh_of_quads_comes_back_triangulated(tmp_path, capsys):
    from primkit import io, synthetic

    shape = synthetic.generate("chair", 1, seed=0)[0]
    tri = tmp_path / "tri.obj"
    io.write_mesh(tri, shape.vertices, shape.faces)
    quads = tmp_path / "in" / "quads.obj"  # a cube of 6 quads, big enough to abstract
    quads.parent.mkdir()
    quads.write_text("\n".join(f"v {x} {y} {z}" for x in (0, 1) for y in (0, 1) for z in (0, 1)) + "\n"
                     "f 1 2 4 3\nf 5 7 8 6\nf 1 5 6 2\nf 3 4 8 7\nf 1 3 7 5\nf 2 6 8 4\n")
    common = ["--model", "chair", "--workers", "1", "--cache", str(tmp_path / "cache")]
    assert main(["segment", str(quads), str(tri), "-o", str(tmp_path / "seg"), *common]) == 0
    out = capsys.readouterr().out
    quad_line = next(line for line in out.splitlines() if line.startswith("quads:"))
    tri_line = next(line for line in out.splitlines() if line.startswith("tri:"))
    assert "12 faces" in quad_line and "triangulated: the file's 6 faces are polygons" in quad_line
    assert "triangulated" not in tri_line
    assert len(io.read_labels(tmp_path / "seg" / "quads.seg")) == 12
