#!/usr/bin/env python3
"""Size ladder for bench/scale.sh: a shared mesh, 1-to-4 midpoint subdivided
k times, each new vertex moved along its normal by seeded noise of 0.05 of
the rung's mean edge (a scan's fine grain, without changing the shape).

usage: make_ladder.py INPUT.ply OUTDIR LEVEL...   (writes OUTDIR/rungL.ply)
"""
import struct
import sys

import numpy as np


def read_ply(path):
    b = open(path, "rb").read()
    end = b.index(b"end_header\n") + len(b"end_header\n")
    head = b[:end].decode("latin1").split("\n")
    assert "format binary_little_endian 1.0" in head, "binary little-endian PLY only"
    nv = int(next(l for l in head if l.startswith("element vertex")).split()[2])
    nf = int(next(l for l in head if l.startswith("element face")).split()[2])
    v = np.frombuffer(b, "<f4", 3 * nv, end).reshape(nv, 3).astype(np.float64)
    rec = np.dtype([("n", "u1"), ("i", "<i4", 3)])
    f = np.frombuffer(b, rec, nf, end + 12 * nv)
    assert (f["n"] == 3).all(), "triangles only"
    return v, f["i"].astype(np.int64)


def subdivide(v, f, rng):
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    mid = 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])
    # Per-vertex normals of the coarse mesh, averaged onto the edge midpoints.
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    en = vn[uniq[:, 0]] + vn[uniq[:, 1]]
    en /= np.maximum(np.linalg.norm(en, axis=1), 1e-300)[:, None]
    h = 0.5 * np.linalg.norm(v[uniq[:, 0]] - v[uniq[:, 1]], axis=1).mean()
    mid += en * (0.05 * h * rng.standard_normal(len(mid)))[:, None]
    n = len(v)
    nf = len(f)
    a, b, c = inv[:nf] + n, inv[nf : 2 * nf] + n, inv[2 * nf :] + n
    f2 = np.concatenate(
        [
            np.stack([f[:, 0], a, c], 1),
            np.stack([a, f[:, 1], b], 1),
            np.stack([c, b, f[:, 2]], 1),
            np.stack([a, b, c], 1),
        ]
    )
    return np.concatenate([v, mid]), f2


def write_ply(path, v, f):
    with open(path, "wb") as w:
        w.write(
            (
                "ply\nformat binary_little_endian 1.0\n"
                f"element vertex {len(v)}\nproperty double x\nproperty double y\nproperty double z\n"
                f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
            ).encode()
        )
        w.write(v.astype("<f8").tobytes())
        rec = np.zeros(len(f), np.dtype([("n", "u1"), ("i", "<i4", 3)]))
        rec["n"] = 3
        rec["i"] = f
        w.write(rec.tobytes())


def main():
    src, out, levels = sys.argv[1], sys.argv[2], sorted(int(x) for x in sys.argv[3:])
    v, f = read_ply(src)
    rng = np.random.default_rng(20261201)
    done = 0
    for level in levels:
        while done < level:
            v, f = subdivide(v, f, rng)
            done += 1
        write_ply(f"{out}/rung{level}.ply", v, f)
        print(f"{out}/rung{level}.ply: {len(f)} triangles")


if __name__ == "__main__":
    main()
