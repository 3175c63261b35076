"""Layouts of the peers (QuadriFlow, Instant Meshes) at a given patch count,
fitted by `subdfit fit` and measured like subdfit's own (issue 17; the
Fitmaps paper's protocol, §4.1: the same fitter and metric on every
layout). Called by bench/peers.sh; needs `pyquadriflow`, `pyinstantmeshes`
and `trimesh` (bench/peers.sh installs them into .venv-peers).

    python bench/peers.py MESH PATCHES OUTDIR SUBDFIT

Prints one JSON line per peer: tool, requested and obtained ptex patch
count (a quad is one patch, an n-gon n), irregular vertices, RMS L and D
(‰ of the diagonal), unprojectable area (%), whether the layout kept the
input's genus and boundary count, layout and fit seconds, or the error.
"""

import contextlib
import json
import os
import subprocess
import sys
import time

import numpy as np
import trimesh


def ptex_patches(faces):
    return sum(1 if len(f) == 4 else len(f) for f in faces)


def read_obj_faces(path):
    faces = []
    with open(path) as f:
        for line in f:
            if line.startswith("f "):
                faces.append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
    return faces


def write_obj(path, vertices, faces):
    with open(path, "w") as f:
        for v in vertices:
            f.write("v %.9g %.9g %.9g\n" % tuple(v))
        for face in faces:
            f.write("f " + " ".join(str(int(i) + 1) for i in face) + "\n")


@contextlib.contextmanager
def stdout_to_stderr():
    """The peers' C++ code prints progress on stdout (file descriptor 1):
    send it to stderr, so that stdout carries only this script's JSON."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def quadriflow(mesh, n, out):
    from pyQuadriFlow.pyQuadriFlow import pyquadriflow
    r = pyquadriflow(n, 0, mesh.vertices.tolist(), mesh.faces.tolist(),
                     False, True, False, False, False)
    write_obj(out, r["vertices"], r["faces"])


def instant_meshes(path, n, out):
    import pyinstantmeshes
    # The file it writes is its quad-dominant mesh (quads, a few triangles
    # and pentagons, and unreferenced vertices); the arrays it returns are
    # triangulated.
    pyinstantmeshes.remesh_file(path, out, target_face_count=n, deterministic=True)


def euler_and_boundaries(vertices, faces):
    edges = {}
    for f in faces:
        for k in range(len(f)):
            a, b = f[k], f[(k + 1) % len(f)]
            edges[(min(a, b), max(a, b))] = edges.get((min(a, b), max(a, b)), 0) + 1
    used = {v for f in faces for v in f}
    boundary = sum(1 for c in edges.values() if c == 1)
    return len(used) - len(edges) + len(faces), boundary > 0


def run(tool, mesh_path, target, outdir, subdfit):
    mesh = trimesh.load(mesh_path, process=False)
    name = os.path.splitext(os.path.basename(mesh_path))[0]
    layout = os.path.join(outdir, f"{name}-{tool}.obj")
    row = {"mesh": name, "tool": tool, "requested": target}
    n = target
    t0 = time.time()
    try:
        # Up to four tries: the tools land near, not on, the count they
        # are given.
        for _ in range(4):
            with stdout_to_stderr():
                if tool == "quadriflow":
                    quadriflow(mesh, n, layout)
                else:
                    instant_meshes(mesh_path, n, layout)
            got = ptex_patches(read_obj_faces(layout))
            if abs(got - target) <= 0.05 * target:
                break
            n = max(8, int(round(n * target / max(got, 1))))
    except Exception as e:  # the peer failed: report it, go on
        row["error"] = f"layout: {e}"
        return row
    row["layout_seconds"] = round(time.time() - t0, 2)
    faces = read_obj_faces(layout)
    row["patches"] = ptex_patches(faces)
    chi_in, _ = euler_and_boundaries(mesh.vertices, mesh.faces.tolist())
    chi_out, _ = euler_and_boundaries(None, faces)
    row["topology_kept"] = chi_in == chi_out
    fit_dir = os.path.join(outdir, f"{name}-{tool}-fit")
    t0 = time.time()
    p = subprocess.run([subdfit, "fit", mesh_path, layout, "-o", fit_dir, "--quiet"],
                       capture_output=True, text=True)
    row["fit_seconds"] = round(time.time() - t0, 2)
    if p.returncode != 0:
        row["error"] = "fit: " + p.stderr.strip().splitlines()[-1]
        return row
    with open(os.path.join(fit_dir, "report.json")) as f:
        r = json.load(f)
    row.update({
        "irregular": r["control"]["irregular_vertices"],
        "rms_l": round(r["accuracy"]["limit"]["rms_permille"], 3),
        "rms_d": round(r["accuracy"]["displaced"]["rms_permille"], 3),
        "unprojectable": round(r["projectability"]["unprojectable_area_percent"], 3),
        "notes": r["input"].get("notes", []),
    })
    return row


def main():
    mesh_path, target, outdir, subdfit = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
    os.makedirs(outdir, exist_ok=True)
    for tool in ("quadriflow", "instant-meshes"):
        print(json.dumps(run(tool, mesh_path, target, outdir, subdfit)), flush=True)


if __name__ == "__main__":
    np.random.seed(0)
    main()
