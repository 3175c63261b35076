"""subdfit inside Blender's own Python (Debian's blender runs the system
Python 3.11): import, convert a Blender mesh, same bytes as here."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np

import subdfit

SCRIPT = """
import sys, json
sys.path.insert(0, {pkg!r})
import bpy, numpy as np, subdfit
bpy.ops.mesh.primitive_monkey_add()
bpy.ops.object.modifier_add(type="SUBSURF")
bpy.context.object.modifiers[0].levels = 2
bpy.ops.object.modifier_apply(modifier=bpy.context.object.modifiers[0].name)
bpy.ops.object.modifier_add(type="TRIANGULATE")
bpy.ops.object.modifier_apply(modifier=bpy.context.object.modifiers[0].name)
me = bpy.context.object.data
v = np.empty(3 * len(me.vertices)); me.vertices.foreach_get("co", v)
s = np.empty(len(me.polygons), np.int32); me.polygons.foreach_get("loop_total", s)
i = np.empty(len(me.loops), np.int32); me.loops.foreach_get("vertex_index", i)
r = subdfit.convert(v.reshape(-1, 3), i, face_sizes=s)
np.savez({npz!r}, v=v.reshape(-1, 3), s=s, i=i)
open({obj!r}, "wb").write(r.control_obj)
print("SUBDFIT", json.dumps({{"file": subdfit.__file__, "faces": int(r.control.face_sizes.size),
      "rms": r.metrics["accuracy.limit.rms_permille"], "python": sys.version}}))
"""


def test_blender_imports_and_converts(blender, tmp_path):
    # The installed package, as an add-on would carry it (a folder on
    # Blender's sys.path): the abi3 extension loads in any CPython >= 3.11.
    pkg = tmp_path / "modules"
    shutil.copytree(Path(subdfit.__file__).parent, pkg / "subdfit")
    npz, obj = tmp_path / "mesh.npz", tmp_path / "control.obj"
    script = SCRIPT.format(pkg=str(pkg), npz=str(npz), obj=str(obj))
    r = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "1",
                        "--python-expr", script], capture_output=True, text=True, timeout=300)
    lines = [l for l in r.stdout.splitlines() if l.startswith("SUBDFIT ")]
    assert r.returncode == 0 and lines, f"blender failed ({r.returncode}):\n{r.stdout}\n{r.stderr}"
    got = json.loads(lines[0].removeprefix("SUBDFIT "))
    assert got["file"].startswith(str(pkg)), got
    assert got["faces"] > 10 and 0 < got["rms"] < 50, got
    # The same arrays converted here give the same control mesh, byte for byte.
    d = np.load(npz)
    here = subdfit.convert(d["v"], d["i"], face_sizes=d["s"])
    assert here.control_obj == obj.read_bytes()
