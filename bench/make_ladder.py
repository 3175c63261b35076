#!/usr/bin/env python3
"""Size ladder for bench/scale.sh: a shared mesh, 1-to-4 midpoint subdivided
k times, each new vertex moved along its normal by seeded noise of 0.05 of
the rung's mean edge (a scan's fine grain, without changing the shape).

usage: make_ladder.py INPUT.ply OUTDIR LEVEL...   (writes OUTDIR/rungL.ply)

LEVEL is a number of 1-to-4 steps, or `10m`: level 2 split once more 1-to-9
(every edge in thirds, one point inside each face), 144x the input's
triangles (bunny: 10.0M), written as OUTDIR/rung10m.ply.
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


def trisect(v, f, rng):
    """1-to-9 split: two points on every edge (at a third and two thirds),
    one at each face's centroid, the new points moved along the normal by
    the same seeded noise as `subdivide` (0.05 of the new mean edge)."""
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    lo, hi = e.min(axis=1), e.max(axis=1)
    uniq, inv = np.unique(np.stack([lo, hi], 1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    vn /= np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]
    a, b = v[uniq[:, 0]], v[uniq[:, 1]]
    en = vn[uniq[:, 0]] + vn[uniq[:, 1]]
    en /= np.maximum(np.linalg.norm(en, axis=1), 1e-300)[:, None]
    h = np.linalg.norm(b - a, axis=1).mean() / 3.0
    p1 = (2.0 * a + b) / 3.0 + en * (0.05 * h * rng.standard_normal(len(a)))[:, None]
    p2 = (a + 2.0 * b) / 3.0 + en * (0.05 * h * rng.standard_normal(len(a)))[:, None]
    fc = (v[f[:, 0]] + v[f[:, 1]] + v[f[:, 2]]) / 3.0
    cn = vn[f[:, 0]] + vn[f[:, 1]] + vn[f[:, 2]]
    cn /= np.maximum(np.linalg.norm(cn, axis=1), 1e-300)[:, None]
    fc += cn * (0.05 * h * rng.standard_normal(len(f)))[:, None]
    n, ne, nf = len(v), len(uniq), len(f)
    # The point of edge k (k = 0: v0v1, 1: v1v2, 2: v2v0) nearer its first
    # corner, and the one nearer its second: p1 lies at a third from the
    # edge's smaller vertex id.
    near = []
    for k in range(3):
        idx = inv[k * nf : (k + 1) * nf]
        first_is_lo = e[k * nf : (k + 1) * nf, 0] == lo[k * nf : (k + 1) * nf]
        i1, i2 = n + idx, n + ne + idx
        near.append((np.where(first_is_lo, i1, i2), np.where(first_is_lo, i2, i1)))
    (x, y), (z, w), (s, t) = near
    c = n + 2 * ne + np.arange(nf)
    v0, v1, v2 = f[:, 0], f[:, 1], f[:, 2]
    tris = [
        (v0, x, t), (x, y, c), (y, v1, z), (t, c, s), (c, z, w), (s, w, v2),
        (x, c, t), (y, z, c), (c, w, s),
    ]
    f2 = np.concatenate([np.stack(tr, 1) for tr in tris])
    return np.concatenate([v, p1, p2, fc]), f2


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
    src, out = sys.argv[1], sys.argv[2]
    ten_m = "10m" in sys.argv[3:]
    levels = sorted(int(x) for x in sys.argv[3:] if x != "10m")
    v, f = read_ply(src)
    rng = np.random.default_rng(20261201)
    done = 0
    level2 = None
    for level in sorted(set(levels + ([2] if ten_m else []))):
        while done < level:
            v, f = subdivide(v, f, rng)
            done += 1
            if done == 2 and ten_m:
                level2 = (v, f)
        if level in levels:
            write_ply(f"{out}/rung{level}.ply", v, f)
            print(f"{out}/rung{level}.ply: {len(f)} triangles")
    if ten_m:
        # A seed of its own: the other rungs are the same with or without it.
        v, f = trisect(*level2, np.random.default_rng(20261205))
        write_ply(f"{out}/rung10m.ply", v, f)
        print(f"{out}/rung10m.ply: {len(f)} triangles")


if __name__ == "__main__":
    main()
