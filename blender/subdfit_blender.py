"""subdfit conversion folders in Blender (one file: an add-on and a script).

Imports a folder written by `subdfit convert` as a mesh object with the
conventions of the outputs (README, "Renderers"):

- `control.obj` read here, not by Blender's OBJ importer, which drops the
  OpenSubdiv `t crease` / `t corner` tags: creases and corners become edge
  and vertex creases (Blender's crease 1.0 is OpenSubdiv's sharpness 10,
  infinitely sharp; sharpness s maps to s / 10);
- the `vt` UVs as UV map "st";
- a Subdivision Surface modifier: Catmull-Clark, Boundary Smooth "Keep
  Corners" (our edge-and-corner boundary rule), UV Smooth "None" (UVs are
  piecewise bilinear per patch), limit surface on, creases on;
- a Displace modifier reading `displacement_vector.exr` (or its UDIM
  tiles) as Non-Color data, image clamp off (offsets are signed),
  midlevel 0, strength 1, UV coordinates, direction "RGB to XYZ" in local
  space: the map holds the displacement vector itself, so the result does
  not depend on Blender's vertex normals, which are those of its
  tessellation and differ from the limit normals along which we displace
  by up to tens of degrees where the surface folds (with the scalar
  `displacement.exr` and direction Normal, spot lands up to 0.7 % of the
  diagonal off `displaced.ply`; with the vector map, to f32 round-off).
  Folders of older versions without the vector map get the scalar map
  along Normal.

Add-on: Edit > Preferences > Add-ons > Install this file, then File >
Import > "subdfit conversion folder". Headless:

    blender -b --python blender/subdfit_blender.py -- OUTDIR [--level L] [--check]
        [--maps STEM]

imports OUTDIR; `--level` is the subdivision level (default log2 of the
folder's tessellation when it is a power of two, else 4); `--check`
compares the evaluated mesh with `limit.ply` (Displace off) and
`displaced.ply` (on) and prints one JSON line `SUBDFIT_CHECK {...}` with
the largest distance to the nearest vertex of each file, as a fraction of
the bounding-box diagonal; `--maps displacement_bilinear` reads the
samples written beside B-spline maps for bilinear hosts (USD) instead.
Depends on nothing but Blender.

B-spline maps (`--displacement-reconstruction bspline`, report.json's
`projectability.displacement.reconstruction`): the Displace modifier has no
cubic filter, so a Geometry Nodes modifier reads them with the Image
Texture node's "Cubic" interpolation, and a Cycles material does the same
at render time (`add_bspline_displacement`, `add_bspline_material`).
"""

import json
import math
import os
import struct
import sys

import bpy
import bmesh

bl_info = {
    "name": "subdfit conversion folder",
    "author": "subdfit",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "File > Import > subdfit conversion folder",
    "description": "Imports a subdfit output folder: control mesh with creases, corners "
    "and UVs, Subdivision Surface and Displace modifiers set to its conventions",
    "category": "Import-Export",
}


def read_control_obj(path):
    """Vertices, faces (vertex indices), per-corner UVs, creases
    {(a, b): sharpness} and corners {v: sharpness} of a control.obj."""
    verts, uvs, faces, face_uvs = [], [], [], []
    creases, corners = {}, {}
    with open(path) as f:
        for line in f:
            t = line.split()
            if not t or t[0].startswith("#"):
                continue
            if t[0] == "v":
                verts.append(tuple(float(x) for x in t[1:4]))
            elif t[0] == "vt":
                uvs.append((float(t[1]), float(t[2])))
            elif t[0] == "f":
                vs, ts = [], []
                for c in t[1:]:
                    parts = c.split("/")
                    vs.append(int(parts[0]) - 1)
                    if len(parts) > 1 and parts[1]:
                        ts.append(int(parts[1]) - 1)
                faces.append(vs)
                face_uvs.append(ts if len(ts) == len(vs) else None)
            elif t[0] == "t":
                # OpenSubdiv shape tags: t NAME nints/nfloats/nstrings ints floats
                ni, nf = (int(x) for x in t[2].split("/")[:2])
                ints = [int(x) for x in t[3:3 + ni]]
                floats = [float(x) for x in t[3 + ni:3 + ni + nf]]
                if t[1] == "crease":
                    for k in range(len(ints) - 1):
                        s = floats[k] if len(floats) == len(ints) - 1 else floats[0]
                        creases[tuple(sorted((ints[k], ints[k + 1])))] = s
                elif t[1] == "corner":
                    for k, v in enumerate(ints):
                        corners[v] = floats[k] if len(floats) == len(ints) else floats[0]
    return verts, faces, uvs, face_uvs, creases, corners


def read_ply_vertices(path):
    """The x, y, z of every vertex of a binary little-endian PLY."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    n, props, in_vertex = 0, [], False
    sizes = {"float": ("f", 4), "double": ("d", 8), "uchar": ("B", 1), "int": ("i", 4)}
    for line in header:
        t = line.split()
        if t[:2] == ["element", "vertex"]:
            n, in_vertex = int(t[2]), True
        elif t and t[0] == "element":
            in_vertex = False
        elif in_vertex and t[0] == "property":
            props.append(sizes[t[1]][0])
    fmt = "<" + "".join(props)
    step = struct.calcsize(fmt)
    out = []
    for k in range(n):
        vals = struct.unpack_from(fmt, data, end + k * step)
        out.append(vals[:3])
    return out


def import_folder(folder, level=None, name=None, maps="displacement"):
    """Builds the object of the module docs from `folder`; returns it.
    `maps`: the stem of the maps to read (`displacement_bilinear`: the
    samples of B-spline maps written for bilinear hosts, read here with
    the Displace modifier as such a host would)."""
    bspline = maps == "displacement"
    verts, faces, uvs, face_uvs, creases, corners = read_control_obj(
        os.path.join(folder, "control.obj"))
    report = {}
    rp = os.path.join(folder, "report.json")
    if os.path.isfile(rp):
        with open(rp) as f:
            report = json.load(f)
    if level is None:
        n = report.get("tessellation", {}).get("segments_per_patch_side", 16)
        level = int(round(math.log2(n))) if n & (n - 1) == 0 and n <= 64 else 4
    name = name or os.path.basename(os.path.normpath(folder))
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    # Layers first: adding one reallocates the elements' data.
    uv_layer = bm.loops.layers.uv.new("st")
    ecrease = bm.edges.layers.crease.verify()
    vcrease = bm.verts.layers.crease.verify()
    bv = [bm.verts.new(p) for p in verts]
    bm.verts.index_update()
    bm.verts.ensure_lookup_table()
    for f, ts in zip(faces, face_uvs):
        face = bm.faces.new([bv[i] for i in f])
        if ts is not None:
            for loop, t in zip(face.loops, ts):
                loop[uv_layer].uv = uvs[t]
    bm.edges.ensure_lookup_table()
    for e in bm.edges:
        key = tuple(sorted((e.verts[0].index, e.verts[1].index)))
        if key in creases:
            e[ecrease] = min(creases[key] / 10.0, 1.0)
    for v, s in corners.items():
        bv[v][vcrease] = min(s / 10.0, 1.0)
    bm.to_mesh(me)
    bm.free()
    obj = bpy.data.objects.new(name, me)
    bpy.context.collection.objects.link(obj)

    sub = obj.modifiers.new("Subdivision", "SUBSURF")
    sub.subdivision_type = "CATMULL_CLARK"
    sub.levels = level
    sub.render_levels = level
    sub.quality = 6
    sub.boundary_smooth = "PRESERVE_CORNERS"
    sub.uv_smooth = "NONE"
    sub.use_limit_surface = True
    sub.use_creases = True

    path, vector = None, False
    for stem, is_vector in ((maps + "_vector", True), (maps, False)):
        for file in (stem + ".1001.exr", stem + ".exr"):
            if path is None and os.path.isfile(os.path.join(folder, file)):
                path, vector = os.path.join(folder, file), is_vector
    if path is not None:
        img = bpy.data.images.load(path, check_existing=False)
        if ".1001." in os.path.basename(path):
            img.source = "TILED"
        img.colorspace_settings.name = "Non-Color"
        if bspline and is_bspline(report):
            add_bspline_displacement(obj, img, tile_images(path), vector, name)
            return obj
        tex = bpy.data.textures.new(name + "_displacement", "IMAGE")
        tex.image = img
        tex.extension = "EXTEND"
        tex.use_clamp = False
        tex.use_interpolation = True
        tex.use_mipmap = False
        tex.filter_type = "BOX"
        dis = obj.modifiers.new("Displace", "DISPLACE")
        dis.texture = tex
        dis.texture_coords = "UV"
        dis.uv_layer = "st"
        dis.mid_level = 0.0
        dis.strength = 1.0
        dis.direction = "RGB_TO_XYZ" if vector else "NORMAL"
        dis.space = "LOCAL"
    return obj


def is_bspline(report):
    """Whether the folder's maps hold B-spline coefficients
    (`--displacement-reconstruction bspline`; absent from report.json for
    the default bilinear samples)."""
    d = report.get("projectability", {}).get("displacement", {})
    return d.get("reconstruction", "bilinear") == "bspline"


def tile_images(path):
    """[(tile index, image)] of the map at `path`: itself as tile 0, or
    each UDIM tile `*.1001.exr`, `*.1002.exr`, ... loaded as an image of
    its own (the Geometry Nodes image lookup of Blender 3.4 reads only the
    first tile of a tiled image)."""
    if ".1001." not in os.path.basename(path):
        return None
    out, k = [], 0
    while True:
        tile = path.replace(".1001.", ".%d." % (1001 + k))
        if not os.path.isfile(tile):
            return out
        img = bpy.data.images.load(tile, check_existing=False)
        img.colorspace_settings.name = "Non-Color"
        out.append((k, img))
        k += 1


def cubic_lookup(nodes, links, uv, img, tile):
    """Image Texture node (Cubic, Extend) reading `img` at `uv` moved into
    UDIM tile `tile`'s unit square; returns its colour socket (times the
    mask of UVs inside that tile when `tile` is given)."""
    tex = nodes.new("GeometryNodeImageTexture")
    tex.interpolation = "Cubic"
    tex.extension = "EXTEND"
    tex.inputs["Image"].default_value = img
    if tile is None:
        links.new(uv, tex.inputs["Vector"])
        return tex.outputs["Color"]
    tu, tv = tile % 10, tile // 10
    shift = nodes.new("ShaderNodeVectorMath")
    shift.operation = "SUBTRACT"
    links.new(uv, shift.inputs[0])
    shift.inputs[1].default_value = (tu, tv, 0.0)
    links.new(shift.outputs["Vector"], tex.inputs["Vector"])
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(uv, sep.inputs["Vector"])
    mask = None
    for axis, t in (("X", tu), ("Y", tv)):
        fl = nodes.new("ShaderNodeMath")
        fl.operation = "FLOOR"
        links.new(sep.outputs[axis], fl.inputs[0])
        eq = nodes.new("ShaderNodeMath")
        eq.operation = "COMPARE"
        links.new(fl.outputs[0], eq.inputs[0])
        eq.inputs[1].default_value = float(t)
        eq.inputs[2].default_value = 0.5
        if mask is None:
            mask = eq.outputs[0]
        else:
            both = nodes.new("ShaderNodeMath")
            both.operation = "MULTIPLY"
            links.new(mask, both.inputs[0])
            links.new(eq.outputs[0], both.inputs[1])
            mask = both.outputs[0]
    scale = nodes.new("ShaderNodeVectorMath")
    scale.operation = "SCALE"
    links.new(tex.outputs["Color"], scale.inputs[0])
    links.new(mask, scale.inputs["Scale"])
    return scale.outputs["Vector"]


def add_bspline_displacement(obj, img, tiles, vector, name):
    """The displacement of B-spline coefficient maps (docs/handoff.md).

    The Displace modifier's image lookup has no cubic filter, so the
    displaced mesh is made by a Geometry Nodes modifier whose Image Texture
    node reads the map with interpolation "Cubic": in Blender 3.4
    (`node_geo_image_texture.cc`, `image_cubic_texture_lookup`) the
    uniform cubic B-spline of the texels, texel centres at
    `(i + 0.5) / width` (it takes `u * width - 0.5`), the convention of
    Cycles' image kernel (`cubic_w0` ... `cubic_w3`) and of the atlas, whose
    samples sit at texel centres. The lookup is evaluated per face corner,
    each corner with its own patch's UV (a vertex on a patch edge has one
    UV per patch), then averaged onto the vertex: the spline is continuous
    across patch edges (src/displace/bspline.rs), so the corners agree to
    float round-off. The map's offsets are in object space: the vector map
    is added as is; the scalar map of older folders goes along Blender's
    normal, as the Displace modifier does. For rendering, the material
    built by `add_bspline_material` does the same in Cycles' shader."""
    group = bpy.data.node_groups.new(name + "_bspline_displacement", "GeometryNodeTree")
    nodes, links = group.nodes, group.links
    group.inputs.new("NodeSocketGeometry", "Geometry")
    group.outputs.new("NodeSocketGeometry", "Geometry")
    gin = nodes.new("NodeGroupInput")
    gout = nodes.new("NodeGroupOutput")
    uv = nodes.new("GeometryNodeInputNamedAttribute")
    uv.data_type = "FLOAT_VECTOR"
    uv.inputs["Name"].default_value = "st"
    if tiles is None:
        value = cubic_lookup(nodes, links, uv.outputs["Attribute"], img, None)
    else:
        # UDIM: one lookup per tile, each masked to its tile's UVs, summed.
        value = None
        for k, tile in tiles:
            part = cubic_lookup(nodes, links, uv.outputs["Attribute"], tile, k)
            if value is not None:
                add = nodes.new("ShaderNodeVectorMath")
                add.operation = "ADD"
                links.new(value, add.inputs[0])
                links.new(part, add.inputs[1])
                part = add.outputs["Vector"]
            value = part
    cap = nodes.new("GeometryNodeCaptureAttribute")
    cap.data_type = "FLOAT_VECTOR"
    cap.domain = "CORNER"
    links.new(gin.outputs["Geometry"], cap.inputs["Geometry"])
    links.new(value, cap.inputs["Value"])
    setp = nodes.new("GeometryNodeSetPosition")
    links.new(cap.outputs["Geometry"], setp.inputs["Geometry"])
    offset = cap.outputs["Attribute"]
    if not vector:
        # One channel of the scalar map, along the (tessellation) normal.
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(offset, sep.inputs["Vector"])
        normal = nodes.new("GeometryNodeInputNormal")
        scale = nodes.new("ShaderNodeVectorMath")
        scale.operation = "SCALE"
        links.new(normal.outputs["Normal"], scale.inputs[0])
        links.new(sep.outputs["X"], scale.inputs["Scale"])
        offset = scale.outputs["Vector"]
    links.new(offset, setp.inputs["Offset"])
    links.new(setp.outputs["Geometry"], gout.inputs["Geometry"])
    mod = obj.modifiers.new("Displace", "NODES")
    mod.node_group = group
    add_bspline_material(obj, img, vector, name)


def add_bspline_material(obj, img, vector, name):
    """A Cycles material displacing by the same spline at render time:
    Image Texture (Non-Color, interpolation "Cubic", the uniform cubic
    B-spline in Cycles' image kernel) on UV map "st", into a Vector
    Displacement node (object space, midlevel 0, scale 1) or, for the
    scalar map, a Displacement node; "Displacement Only" (docs/handoff.md)."""
    mat = bpy.data.materials.new(name + "_subdfit")
    mat.use_nodes = True
    mat.cycles.displacement_method = "DISPLACEMENT"
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    uv = nodes.new("ShaderNodeUVMap")
    uv.uv_map = "st"
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.interpolation = "Cubic"
    tex.extension = "EXTEND"
    links.new(uv.outputs["UV"], tex.inputs["Vector"])
    if vector:
        disp = nodes.new("ShaderNodeVectorDisplacement")
        disp.space = "OBJECT"
        disp.inputs["Midlevel"].default_value = 0.0
        disp.inputs["Scale"].default_value = 1.0
        links.new(tex.outputs["Color"], disp.inputs["Vector"])
    else:
        disp = nodes.new("ShaderNodeDisplacement")
        disp.space = "OBJECT"
        disp.inputs["Midlevel"].default_value = 0.0
        disp.inputs["Scale"].default_value = 1.0
        links.new(tex.outputs["Color"], disp.inputs["Height"])
    links.new(disp.outputs["Displacement"], out.inputs["Displacement"])
    obj.data.materials.append(mat)


def evaluated_vertices(obj, with_resolved=False):
    """The evaluated mesh's vertices (and, with `with_resolved`, whether
    the surface is resolved at each: every face around it within 30° of
    the vertex normal; where the fitted limit surface folds on itself, no
    vertex normal of a tessellation agrees with the exact one)."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    pts = [tuple(v.co) for v in me.vertices]
    resolved = None
    if with_resolved:
        resolved = [True] * len(pts)
        cos30 = math.cos(math.radians(30.0))
        for p in me.polygons:
            for v in p.vertices:
                if p.normal.dot(me.vertices[v].normal) < cos30:
                    resolved[v] = False
    ev.to_mesh_clear()
    return (pts, resolved) if with_resolved else pts


def farthest_from(points, reference):
    """Largest distance from a point of `points` to its nearest in
    `reference`, the reference's bounding-box diagonal, and the RMS of
    those distances."""
    from mathutils import kdtree
    tree = kdtree.KDTree(len(reference))
    for i, p in enumerate(reference):
        tree.insert(p, i)
    tree.balance()
    dists = [tree.find(p)[2] for p in points]
    lo = [min(p[k] for p in reference) for k in range(3)]
    hi = [max(p[k] for p in reference) for k in range(3)]
    rms = math.sqrt(sum(d * d for d in dists) / max(len(dists), 1))
    return max(dists), math.dist(lo, hi), rms


def check(folder, obj):
    out = {"folder": folder, "vertices": 0}
    dis = obj.modifiers.get("Displace")
    if dis is not None:
        dis.show_viewport = False
    pts, resolved = evaluated_vertices(obj, True)
    out["vertices"] = len(pts)
    out["unresolved_vertices"] = resolved.count(False)
    limit = read_ply_vertices(os.path.join(folder, "limit.ply"))
    out["limit_vertices"] = len(limit)
    worst, diag, _ = farthest_from(pts, limit)
    out["limit_max_over_diagonal"] = worst / diag
    if dis is not None:
        dis.show_viewport = True
        pts = evaluated_vertices(obj)
        displaced = read_ply_vertices(os.path.join(folder, "displaced.ply"))
        worst, _, rms = farthest_from(pts, displaced)
        out["displaced_max_over_diagonal"] = worst / diag
        out["displaced_rms_over_diagonal"] = rms / diag
        kept = [p for p, r in zip(pts, resolved) if r]
        worst, _, _ = farthest_from(kept, displaced)
        out["displaced_resolved_max_over_diagonal"] = worst / diag
    return out


class ImportSubdfit(bpy.types.Operator):
    """Import a subdfit conversion folder"""
    bl_idname = "import_scene.subdfit"
    bl_label = "subdfit conversion folder"
    directory: bpy.props.StringProperty(subtype="DIR_PATH")

    def execute(self, context):
        import_folder(self.directory)
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


def menu(self, context):
    self.layout.operator(ImportSubdfit.bl_idname, text="subdfit conversion folder")


def register():
    bpy.utils.register_class(ImportSubdfit)
    bpy.types.TOPBAR_MT_file_import.append(menu)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(menu)
    bpy.utils.unregister_class(ImportSubdfit)


def main(argv):
    args = argv[argv.index("--") + 1:] if "--" in argv else []
    if not args:
        return
    folder, level, do_check = args[0], None, "--check" in args
    if "--level" in args:
        level = int(args[args.index("--level") + 1])
    maps = args[args.index("--maps") + 1] if "--maps" in args else "displacement"
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    obj = import_folder(folder, level, maps=maps)
    if do_check:
        print("SUBDFIT_CHECK " + json.dumps(check(folder, obj)), flush=True)


if __name__ == "__main__":
    main(sys.argv)
