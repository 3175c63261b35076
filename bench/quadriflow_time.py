#!/usr/bin/env python3
"""QuadriFlow's layout-only time on one mesh, for bench/scale.sh's ratio
column: reads a binary or ASCII PLY with trimesh, then times the
pyquadriflow call alone (no reading, no writing) at a target face count.

usage: quadriflow_time.py MESH.ply FACES   (prints: seconds cpu_seconds quads)

CPU seconds are the process's (all threads) over the call alone: on a
loaded machine wall time is not comparable between two runs, CPU time is.
Needs pyquadriflow and trimesh (bench/peers.sh installs them).
"""
import os
import sys
import time


def main():
    path, faces = sys.argv[1], int(sys.argv[2])
    import trimesh
    from pyQuadriFlow.pyQuadriFlow import pyquadriflow

    mesh = trimesh.load(path, process=False)
    v, f = mesh.vertices.tolist(), mesh.faces.tolist()
    # QuadriFlow prints its own progress on stdout: keep it off ours.
    saved = os.dup(1)
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    try:
        t, c = time.perf_counter(), time.process_time()
        r = pyquadriflow(faces, 0, v, f, False, True, False, False, False)
        dt, dc = time.perf_counter() - t, time.process_time() - c
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
    print(f"{dt:.2f} {dc:.2f} {len(r['faces'])}")


if __name__ == "__main__":
    main()
