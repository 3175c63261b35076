#!/usr/bin/env python3
"""Surfaces with k x |V(M)| vertices made from M, for bench/floor.sh (issue 37).

Measurement only: needs pymeshlab (`pip install pymeshlab` in a throwaway
venv); subdfit does not depend on it.

    floor_remesh.py MESH NAME OUT_DIR

writes OUT_DIR/NAME-<kind><k>x.ply for k = 1, 2:
  qem      M midpoint-subdivided once (every edge), then quadric edge
           collapse to k|V| vertices, vertices kept on M: can keep all of
           M's own vertices, so at k >= 1 it is ~M itself (a trivial bound).
  iso      isotropic explicit remeshing to about k|V| vertices, vertices
           reprojected on M: uniform density, unrelated to M's vertices.
  qemsub1  QEM of M (free placement) to k|V|/4 vertices, midpoint-subdivided
           once, every vertex moved to its closest point of M: density
           adapted to M's detail at the scale of two samples.
  qemsub2  the same from k|V|/16 vertices subdivided twice: adaptive at the
           scale of a coarse element, uniform inside it (as tiles on patches).
"""
import sys

import pymeshlab as ml

mesh, name, out = sys.argv[1:4]
ms = ml.MeshSet()
ms.load_new_mesh(mesh)
nv = ms.current_mesh().vertex_number()
area = ms.get_geometric_measures()["surface_area"]


def save(tag):
    c = ms.current_mesh()
    ms.save_current_mesh(f"{out}/{name}-{tag}.ply", binary=True, save_vertex_normal=False,
                         save_vertex_color=False, save_face_color=False)
    print(name, tag, "V", c.vertex_number(), "F", c.face_number(), flush=True)


def decimate_to(target, free):
    # A closed triangle mesh has F ~ 2V: aim the face count at the vertex target.
    for _ in range(4):
        c = ms.current_mesh()
        if c.vertex_number() <= target * 1.002:
            return
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=int(c.face_number() - 2 * (c.vertex_number() - target)),
            optimalplacement=free, preservetopology=True, preserveboundary=True,
            qualitythr=0.3, preservenormal=True)


for k in (1, 2):
    target = k * nv
    ms.set_current_mesh(0)
    ms.generate_copy_of_current_mesh()
    ms.meshing_surface_subdivision_midpoint(iterations=1, threshold=ml.PureValue(0.0))
    decimate_to(target, False)
    save(f"qem{k}x")

    # Edge length of an equilateral mesh of this area with `target` vertices.
    l = (2 * area / (3 ** 0.5 * target)) ** 0.5
    for it in range(4):
        ms.set_current_mesh(0)
        ms.generate_copy_of_current_mesh()
        ms.meshing_isotropic_explicit_remeshing(iterations=6, targetlen=ml.PureValue(l),
                                                reprojectflag=True, featuredeg=180)
        got = ms.current_mesh().vertex_number()
        if abs(got - target) <= 0.03 * target or it == 3:
            break
        l *= (got / target) ** 0.5
        ms.delete_current_mesh()
    save(f"iso{k}x")

    for s in (1, 2):
        ms.set_current_mesh(0)
        ms.generate_copy_of_current_mesh()
        sub = ms.current_mesh_id()
        decimate_to(target / 4 ** s, True)
        ms.meshing_surface_subdivision_midpoint(iterations=s, threshold=ml.PureValue(0.0))
        ms.transfer_attributes_per_vertex(sourcemesh=0, targetmesh=sub, geomtransfer=True)
        ms.set_current_mesh(sub)
        save(f"qemsub{s}-{k}x")
