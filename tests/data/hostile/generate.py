#!/usr/bin/env python3
"""Writes the hostile-input corpus of tests/io_hostile.rs and its manifest.

Every file is small and built here from a tetrahedron (4 vertices, 4
triangles), so that the expected outcome is known exactly: either that mesh
(vertex/face counts and some coordinates) or an error naming the file and
the element. `EXPECTED.md` is the manifest the test reads: one table row per
file, `ok V F [i=x,y,z ...]` (vertex and face counts of the soup as read,
vertex i at x,y,z) or `err` with `;`-separated pieces the message must
contain.

Run from anywhere: python3 tests/data/hostile/generate.py
"""

import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
BOM = b"\xef\xbb\xbf"

P = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
T = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
TETRA_OK = "ok 4 4 0=0,0,0 1=1,0,0 3=0,0,1"
# STL stores corners, not vertices: first appearance order is 0, 2, 1, 3.
STL_OK = "ok 4 4 0=0,0,0 1=0,1,0 2=1,0,0 3=0,0,1"

cases = []  # (name, bytes, expected, description)


def case(name, data, expected, what):
    if isinstance(data, str):
        data = data.encode()
    cases.append((name, data, expected, what))


# ---- OBJ --------------------------------------------------------------------


def obj(points=P, faces=T, nl="\n"):
    s = "".join(f"v {x} {y} {z}{nl}" for x, y, z in points)
    s += "".join("f " + " ".join(str(i + 1) for i in f) + nl for f in faces)
    return s


case("obj_bom.obj", BOM + obj().encode(), TETRA_OK, "UTF-8 BOM before the first `v` line")
case("obj_bom_crlf.obj", BOM + obj(nl="\r\n").encode(), TETRA_OK, "BOM and CRLF line ends")
case(
    "obj_continuation.obj",
    "v 0 0 0\nv 1 \\\n 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 \\\n2\nf 1 2 4\r\nf 1 4 3\nf 2 3 \\\r\n  4\n",
    TETRA_OK,
    "`\\` line continuation in `v` and `f` lines, with CRLF",
)
case(
    "obj_comment_backslash.obj",
    "# saved in C:\\models\\\n" + obj(),
    TETRA_OK,
    "a comment ending in a backslash does not swallow the next line",
)
case(
    "obj_nan.obj",
    "v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    "err vertex 2 (line 3);NaN",
    "NaN coordinate",
)
case(
    "obj_inf.obj",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 -inf\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    "err vertex 3 (line 4);infinite",
    "infinite coordinate",
)
case(
    "obj_out_of_range.obj",
    obj(faces=T[:3]) + "f 2 3 9\n",
    "err face 3 (line 8);vertex index 9 out of range",
    "face index past the last vertex",
)
case(
    "obj_negative_out_of_range.obj",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n",
    "err face 0 (line 4);-4 out of range",
    "relative index before the first vertex",
)
case("obj_zero_index.obj", obj() + "f 0 1 2\n", "err line 9;index 0", "index 0 (OBJ is 1-based)")
case(
    "obj_truncated_vertex.obj",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0",
    "err line 4;2 coordinates",
    "file cut inside the last `v` line",
)
case(
    "obj_truncated_corner.obj",
    obj(faces=T[:3]) + "f 2/1 3/1 4/",
    "err line 8;'4/'",
    "file cut inside a `v/vt` corner",
)
case("obj_empty.obj", b"", "err no faces", "empty file")
case("obj_bom_only.obj", BOM, "err no faces", "a BOM and nothing else")
case(
    "obj_face_two_vertices.obj",
    obj(faces=T[:3]) + "f 1 2\n",
    "err face 3;has 2 vertices",
    "face with two corners",
)
case(
    "obj_garbage_coordinate.obj",
    "v 0 0 0\nv 1 0 0x\nv 0 1 0\nf 1 2 3\n",
    "err line 2;'0x'",
    "a coordinate that is not a number",
)

# ---- PLY --------------------------------------------------------------------


def ply_header(fmt, nv=4, nf=4, index="int"):
    return (
        f"ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {nf}\nproperty list uchar {index} vertex_indices\nend_header\n"
    )


def ply_ascii(points=P, faces=T, nv=None, nf=None):
    s = ply_header("ascii", nv if nv is not None else len(points), nf if nf is not None else len(faces))
    s += "".join(f"{x} {y} {z}\n" for x, y, z in points)
    s += "".join(f"{len(f)} " + " ".join(map(str, f)) + "\n" for f in faces)
    return s


def ply_binary(points=P, faces=T, big=False, index="i"):
    e = ">" if big else "<"
    fmt = "binary_big_endian" if big else "binary_little_endian"
    b = ply_header(fmt, len(points), len(faces), "int").encode()
    for p in points:
        b += struct.pack(e + "3f", *p)
    for f in faces:
        b += struct.pack(e + "B", len(f)) + struct.pack(e + "%d%s" % (len(f), index), *f)
    return b


PLY_HEADER_LEN = len(ply_header("binary_little_endian"))  # 9 lines
case("ply_bom.ply", BOM + ply_ascii().encode(), TETRA_OK, "BOM before `ply`")
case("ply_ascii_ok.ply", ply_ascii(), TETRA_OK, "reference: the tetrahedron, ascii")
case("ply_binary_ok.ply", ply_binary(), TETRA_OK, "reference: the tetrahedron, binary little endian")
case(
    "ply_nan_ascii.ply",
    ply_ascii(points=[P[0], (1, "nan", 0), P[2], P[3]]),
    "err vertex 1 (line 11);NaN",
    "NaN in an ascii vertex",
)
case(
    "ply_inf_binary.ply",
    ply_binary(points=[P[0], P[1], (0, float("inf"), 0), P[3]]),
    f"err vertex 2 (byte {PLY_HEADER_LEN + 24});infinite",
    "infinite coordinate in a binary vertex",
)
case(
    "ply_nan_binary_be.ply",
    ply_binary(points=[P[0], P[1], P[2], (0, 0, float("nan"))], big=True),
    f"err vertex 3 (byte {PLY_HEADER_LEN - 3 + 36});NaN",
    "NaN in a big-endian vertex",
)
case(
    "ply_trailing_face_ascii.ply",
    ply_ascii() + "3 0 1 2\n",
    "err line 18;trailing data",
    "one face more than the header announces (ascii)",
)
case(
    "ply_trailing_binary.ply",
    ply_binary() + struct.pack("<B3i", 3, 0, 1, 2),
    f"err byte {PLY_HEADER_LEN + 48 + 4 * 13};13 bytes of trailing data",
    "one face more than the header announces (binary)",
)
case(
    "ply_truncated_ascii_vertex.ply",
    ply_ascii().split("0 1 0\n")[0] + "0 1",
    "err vertex 2 (line 12);end of file",
    "ascii file cut inside a vertex",
)
case(
    "ply_truncated_binary_face.ply",
    ply_binary()[: PLY_HEADER_LEN + 48 + 13 * 2 + 7],
    f"err face 2 (byte {PLY_HEADER_LEN + 48 + 26 + 1});truncated",
    "binary file cut inside face 2",
)
case(
    "ply_more_vertices_declared.ply",
    ply_ascii(nv=5),
    "err line 17;trailing data;counts in the header",
    "header announces 5 vertices, the file has 4 (the first face is read as a vertex)",
)
case(
    "ply_fewer_faces_declared.ply",
    ply_ascii(nf=3),
    "err line 17;trailing data",
    "header announces 3 faces, the file has 4",
)
case(
    "ply_out_of_range.ply",
    ply_ascii(faces=[T[0], (0, 1, 7), T[2], T[3]]),
    "err face 1 (line 15);vertex index 7 out of range",
    "face index past the last vertex",
)
case(
    "ply_negative_index_binary.ply",
    ply_binary(faces=[(0, 2, -1)] + T[1:]),
    "err face 0;not a valid index",
    "negative index in a binary face",
)
case("ply_empty.ply", b"", "err line 1;end_header", "empty file")
case(
    "ply_header_only.ply",
    ply_header("ascii"),
    "err vertex 0;end of file",
    "a header and no data",
)

# ---- OFF --------------------------------------------------------------------


def off_body(vextra=lambda i: "", fextra=lambda f: "", points=P, faces=T):
    s = "".join(f"{x} {y} {z}{vextra(i)}\n" for i, (x, y, z) in enumerate(points))
    s += "".join(f"{len(f)} " + " ".join(map(str, f)) + fextra(f) + "\n" for f in faces)
    return s


def off(header="OFF\n4 4 0\n", **kw):
    return header + off_body(**kw)


case("off_ok.off", off(), TETRA_OK, "reference: the tetrahedron")
case("off_bom.off", BOM + off().encode(), TETRA_OK, "BOM before `OFF`")
case(
    "off_comments.off",
    "OFF\n# made by hand\n\n4 4 0 # counts\n0 0 0\n# a comment between vertices\n1 0 0\n0 1 0\n0 0 1 # last vertex\n"
    + off_body(points=[])
    + "# the end\n",
    TETRA_OK,
    "`#` comments and blank lines everywhere",
)
case("off_counts_on_header.off", off("OFF 4 4 0\n"), TETRA_OK, "the counts on the `OFF` line")
case("off_headerless.off", off("4 4 0\n"), TETRA_OK, "no keyword: the first line holds the counts")
case("off_crlf_tabs.off", off().replace(" ", "\t").replace("\n", "\r\n"), TETRA_OK, "CRLF and tabs")
case(
    "off_coff.off",
    off("COFF\n4 4 0\n", vextra=lambda i: " 255 0 0 255"),
    TETRA_OK,
    "per-vertex RGBA colours",
)
case(
    "off_face_colours.off",
    off(fextra=lambda f: " 0.5 0.5 1.0"),
    TETRA_OK,
    "per-face colours after the indices",
)
case(
    "off_noff.off",
    off("NOFF\n4 4 0\n", vextra=lambda i: " 0 0 1"),
    TETRA_OK,
    "per-vertex normals",
)
case(
    "off_cnoff.off",
    off("CNOFF\n4 4 0\n", vextra=lambda i: " 0 0 1 0.1 0.2 0.3 1.0", fextra=lambda f: " 7"),
    TETRA_OK,
    "normals, colours, and colour-map face colours",
)
case(
    "off_stoff.off",
    off("STOFF\n4 4 0\n", vextra=lambda i: " 0.25 0.75"),
    TETRA_OK,
    "per-vertex texture coordinates",
)
case(
    "off_4off.off",
    "4OFF\n4 4 0\n0 0 0 1\n2 0 0 2\n0 0.5 0 0.5\n0 0 4 4\n" + off_body(points=[]),
    TETRA_OK,
    "homogeneous coordinates, divided by w",
)
case("off_ndim3.off", off("nOFF\n3\n4 4 0\n"), TETRA_OK, "nOFF with dimension 3")
case(
    "off_ndim4.off",
    "nOFF\n4\n4 4 0\n" + off_body(vextra=lambda i: " 0"),
    "err line 2;4-dimensional",
    "nOFF with dimension 4 (unsupported)",
)
case("off_binary.off", b"OFF BINARY\n" + struct.pack(">3i", 4, 4, 0), "err line 1;binary OFF", "binary OFF (unsupported)")
case("off_more_faces_declared.off", off("OFF\n4 5 0\n"), "err line 10 (end of file);4 of the 5 faces", "declares 5 faces, has 4")
case("off_fewer_faces_declared.off", off("OFF\n4 3 0\n"), "err line 10;trailing data", "declares 3 faces, has 4")
case(
    "off_fewer_vertices_declared.off",
    off("OFF\n3 4 0\n"),
    "err face 0 (line 6);vertex count on line 2 is too small",
    "declares 3 vertices, has 4",
)
case(
    "off_more_vertices_declared.off",
    off("OFF\n5 4 0\n"),
    "err line 10 (end of file);3 of the 4 faces",
    "declares 5 vertices, has 4 (the first face is read as a vertex)",
)
case(
    "off_nan.off",
    off(points=[P[0], ("nan", 0, 0), P[2], P[3]]),
    "err vertex 1 (line 4);NaN",
    "NaN coordinate",
)
case(
    "off_overflow.off",
    off(points=[P[0], ("1e39", 0, 0), (0, "1e39", 0), (0, 0, "1e39")]),
    "ok 4 4 2=0,1e39,0",
    "coordinates beyond single precision (a tetrahedron of size 1e39; at size 1 with one such coordinate it would be a needle without area, refused): kept, OFF is read in double precision",
)
case(
    "off_overflow_double.off",
    off(points=[P[0], P[1], (0, "1e400", 0), P[3]]),
    "err vertex 2 (line 5);infinite",
    "a coordinate beyond double precision (reads as infinity)",
)
case(
    "off_out_of_range.off",
    off(faces=T[:2] + [(0, 3, 4), T[3]]),
    "err face 2 (line 9);vertex index 4 out of range",
    "face index past the last vertex",
)
case(
    "off_negative_index.off",
    off(faces=T[:3] + [(1, -2, 3)]),
    "err face 3 (line 10);'-2'",
    "negative face index",
)
case(
    "off_truncated_vertex.off",
    "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0",
    "err vertex 3 (line 6);has 2 coordinates",
    "file cut inside the last vertex",
)
case(
    "off_truncated_face.off",
    off()[:-3],
    "err face 3 (line 10);announces 3 vertices, has 2",
    "file cut inside the last face",
)
case("off_empty.off", b"", "err line 1;empty file", "empty file")
case("off_bad_header.off", "OFX\n4 4 0\n", "err line 1;not an OFF file", "not an OFF keyword")
case(
    "off_face_two_extra.off",
    off(fextra=lambda f: " 1 2" if f == T[1] else ""),
    "err face 1 (line 8);unexpected '1 2'",
    "two stray numbers after a face (no colour has 2)",
)
case(
    "off_face_one_vertex.off",
    off(faces=T[:3] + [(1,)]),
    "err face 3 (line 10);has 1 vertices",
    "a face with one corner",
)
case(
    "off_missing_counts.off",
    "OFF\n",
    "err line 1;before the vertex and face counts",
    "a header and nothing else",
)

# ---- STL --------------------------------------------------------------------


def stl_ascii(points=P, faces=T, kw=str, name="tetra", end=True):
    s = f"{kw('solid')} {name}\n"
    for f in faces:
        s += f" {kw('facet normal')} 0 0 0\n  {kw('outer loop')}\n"
        for k in f:
            x, y, z = points[k]
            s += f"   {kw('vertex')} {x} {y} {z}\n"
        s += f"  {kw('endloop')}\n {kw('endfacet')}\n"
    if end:
        s += f"{kw('endsolid')} {name}\n"
    return s


def stl_binary(points=P, faces=T, count=None, header=b"binary tetra"):
    b = header.ljust(80, b"\0") + struct.pack("<I", len(faces) if count is None else count)
    for f in faces:
        b += struct.pack("<3f", 0, 0, 0)
        for k in f:
            b += struct.pack("<3f", *points[k])
        b += b"\0\0"
    return b


case("stl_ascii_ok.stl", stl_ascii(), STL_OK, "reference: the tetrahedron, ascii")
case("stl_ascii_bom.stl", BOM + stl_ascii().encode(), STL_OK, "BOM before `solid`")
case("stl_ascii_uppercase.stl", stl_ascii(kw=str.upper), STL_OK, "keywords in upper case")
case(
    "stl_ascii_two_solids.stl",
    stl_ascii(faces=T[:2], name="a") + stl_ascii(faces=T[2:], name="b"),
    STL_OK,
    "two solids one after the other",
)
case(
    "stl_ascii_cut_mid_facet.stl",
    stl_ascii().split("   vertex 0 0 1\n")[0],
    "err line 12 (end of file);after 1 complete facets",
    "cut inside facet 1 (after two of its vertices)",
)
case(
    "stl_ascii_no_endsolid.stl",
    stl_ascii(end=False),
    "err line 29 (end of file);after 4 complete facets;'endsolid'",
    "cut between facets: no `endsolid`",
)
case(
    "stl_ascii_nan.stl",
    stl_ascii(points=[P[0], P[1], P[2], (0, 0, "nan")]),
    "err facet 1, vertex 2 (line 13);NaN",
    "NaN coordinate",
)
case(
    "stl_ascii_inf.stl",
    stl_ascii(points=[P[0], ("-inf", 0, 0), P[2], P[3]]),
    "err facet 0, vertex 2 (line 6);infinite",
    "infinite coordinate",
)
case(
    "stl_ascii_bad_keyword.stl",
    stl_ascii().replace("   vertex 0 1 0", "   vertx 0 1 0", 1),
    "err facet 0 (line 5);'vertex'",
    "misspelt keyword",
)
case(
    "stl_ascii_four_vertices.stl",
    stl_ascii().replace("   vertex 1 0 0\n", "   vertex 1 0 0\n   vertex 1 1 1\n", 1),
    "err facet 0 (line 7);'endloop'",
    "a loop with four vertices",
)
case(
    "stl_ascii_trailing_garbage.stl",
    stl_ascii() + "garbage\n",
    "err line 31;another 'solid'",
    "text after `endsolid`",
)
case("stl_binary_ok.stl", stl_binary(), STL_OK, "reference: the tetrahedron, binary")
case(
    "stl_binary_solid_header.stl",
    stl_binary(header=b"solid tetra, but binary"),
    STL_OK,
    "binary with a header starting with `solid`",
)
case(
    "stl_binary_truncated.stl",
    stl_binary()[: 84 + 50 * 3 + 20],
    "err byte 84;announces 4 triangles;inside triangle 3",
    "binary cut inside the last triangle",
)
case(
    "stl_binary_trailing.stl",
    stl_binary() + b"\0" * 7,
    "err byte 84;7 bytes of trailing data",
    "binary with bytes after the last triangle",
)
case(
    "stl_binary_count_too_big.stl",
    stl_binary(count=10),
    "err byte 84;announces 10 triangles",
    "triangle count larger than the data",
)
case(
    "stl_binary_nan.stl",
    stl_binary(points=[P[0], P[1], P[2], (float("nan"), 0, 0)]),
    f"err facet 1, vertex 2 (byte {84 + 50 + 12 + 24});NaN",
    "NaN coordinate (binary)",
)
case(
    "stl_binary_inf.stl",
    stl_binary(points=[P[0], (0, float("inf"), 0), P[2], P[3]]),
    f"err facet 0, vertex 2 (byte {84 + 12 + 24});infinite",
    "infinite coordinate (binary)",
)
case(
    "stl_binary_solid_truncated.stl",
    stl_binary(header=b"solid tetra")[:150],
    "err byte 84;contains NUL bytes;announces 4 triangles",
    "cut binary whose header starts with `solid`",
)
case("stl_binary_short.stl", b"\0" * 50, "err byte 50;too short", "50 bytes: no room for a header")
case("stl_empty.stl", b"", "err empty file", "empty file")


def main():
    for f in os.listdir(HERE):
        if f.split(".")[-1] in ("obj", "ply", "off", "stl"):
            os.remove(os.path.join(HERE, f))
    rows = []
    for name, data, expected, what in cases:
        with open(os.path.join(HERE, name), "wb") as f:
            f.write(data)
        rows.append(f"| {name} | {expected} | {what} |")
    with open(os.path.join(HERE, "EXPECTED.md"), "w") as f:
        f.write(
            "# Hostile inputs and their expected outcome\n\n"
            "Written by `generate.py` (edit it, not this file) and read by\n"
            "`tests/io_hostile.rs`. `ok V F i=x,y,z ...`: the file reads as V\n"
            "vertices and F faces with vertex i at (x, y, z). `err a;b`: reading\n"
            "fails with a message that names the file and contains every piece.\n"
            "None is accepted with wrong data.\n\n"
            "| file | expected | what it is |\n|---|---|---|\n"
        )
        f.write("\n".join(rows) + "\n")
    print(f"{len(cases)} files")


main()
