//! Meshes as the readers hand them over, before any validation: a
//! polygon soup ([`PolySoup`]) and the all-triangle mesh M ([`TriMesh`]),
//! with the edge keys and counts the validation and the layers above use
//! (one `u64` per undirected edge, so edges sort and compare as integers).

use crate::DVec3;

/// Polygons exactly as a reader found them: positions and faces of any size,
/// indices into `positions`, nothing validated yet.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PolySoup {
    pub positions: Vec<DVec3>,
    /// `face_offsets[f]..face_offsets[f + 1]` indexes `face_indices`; its
    /// length is `num_faces() + 1` and it starts with 0.
    pub face_offsets: Vec<u32>,
    pub face_indices: Vec<u32>,
}

impl PolySoup {
    pub fn new() -> Self {
        PolySoup {
            positions: Vec::new(),
            face_offsets: vec![0],
            face_indices: Vec::new(),
        }
    }

    pub fn from_faces<F: AsRef<[u32]>>(positions: Vec<DVec3>, faces: &[F]) -> Self {
        let mut s = PolySoup {
            positions,
            ..PolySoup::new()
        };
        for f in faces {
            s.push_face(f.as_ref());
        }
        s
    }

    pub fn push_face(&mut self, idx: &[u32]) {
        if self.face_offsets.is_empty() {
            self.face_offsets.push(0);
        }
        self.face_indices.extend_from_slice(idx);
        self.face_offsets.push(self.face_indices.len() as u32);
    }

    pub fn num_faces(&self) -> usize {
        self.face_offsets.len().saturating_sub(1)
    }

    pub fn face(&self, f: usize) -> &[u32] {
        &self.face_indices[self.face_offsets[f] as usize..self.face_offsets[f + 1] as usize]
    }

    pub fn faces(&self) -> impl Iterator<Item = &[u32]> + '_ {
        (0..self.num_faces()).map(move |f| self.face(f))
    }

    /// Face sizes, OpenSubdiv-descriptor style.
    pub fn face_sizes(&self) -> Vec<u32> {
        self.face_offsets.windows(2).map(|w| w[1] - w[0]).collect()
    }
}

/// A triangle mesh (the input M of the papers), positions in double precision.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// The key of the undirected edge (a, b): `(min << 32) | max`.
pub fn edge_key(a: u32, b: u32) -> u64 {
    (u64::from(a.min(b)) << 32) | u64::from(a.max(b))
}

impl TriMesh {
    /// The mean length of the triangles' sides (an interior edge counted
    /// from both of its triangles, a boundary edge once): the scale the
    /// report's reach tolerance, the field cleanup's projectability guard,
    /// the thin rounds' same-sheet slack and the renderer's offsets use.
    /// Summed in triangle order, so every caller gets the same bits.
    pub fn mean_edge_length(&self) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
                sum += (self.positions[a] - self.positions[b]).length();
                n += 1;
            }
        }
        sum / n.max(1) as f64
    }

    /// Every undirected edge once, by [`edge_key`] in increasing order,
    /// with the number of triangles that use it. A sort, not a hash map:
    /// the fit, the boundary loops and the proxy's topology check all ask
    /// on the full input (~10× faster on a million triangles).
    pub fn edge_counts(&self) -> Vec<(u64, u32)> {
        let sides = self.sorted_sides();
        let mut out: Vec<(u64, u32)> = Vec::with_capacity(sides.len() / 2 + 1);
        for (k, _) in sides {
            match out.last_mut() {
                Some(l) if l.0 == k => l.1 += 1,
                _ => out.push((k, 1)),
            }
        }
        out
    }

    /// Every triangle side as `(edge_key, triangle)`, sorted: the sides of
    /// one edge are adjacent, in triangle order, so whatever is summed or
    /// compared per edge along this list comes out the same on every run
    /// and thread count. Both cores (16 bytes per side).
    pub fn sorted_sides(&self) -> Vec<(u64, u32)> {
        use rayon::prelude::*;
        let mut sides: Vec<(u64, u32)> = self
            .triangles
            .par_iter()
            .enumerate()
            .flat_map_iter(|(i, t)| {
                let i = i as u32;
                [
                    (edge_key(t[0], t[1]), i),
                    (edge_key(t[1], t[2]), i),
                    (edge_key(t[2], t[0]), i),
                ]
            })
            .collect();
        sides.par_sort_unstable();
        sides
    }

    /// Per triangle, which of its edges are boundary edges (used by one
    /// triangle only): bit 0 edge (a, b), bit 1 (b, c), bit 2 (c, a).
    ///
    /// One pass over [`Self::sorted_sides`]: a side alone in its run is a
    /// boundary edge of its triangle (the fit asks this of the whole input
    /// for every start; a binary search per side was ~10× slower).
    pub fn boundary_edge_masks(&self) -> Vec<u8> {
        let mut masks = vec![0u8; self.triangles.len()];
        for run in self.sorted_sides().chunk_by(|a, b| a.0 == b.0) {
            if let [(key, t)] = run {
                let tri = self.triangles[*t as usize];
                // The first side of the triangle on this edge (a triangle
                // with a repeated vertex has the same key on two sides, and
                // then it is not alone in its run).
                if let Some(k) = (0..3).find(|&k| edge_key(tri[k], tri[(k + 1) % 3]) == *key) {
                    masks[*t as usize] |= 1 << k;
                }
            }
        }
        masks
    }

    pub fn bbox(&self) -> (DVec3, DVec3) {
        bbox(&self.positions)
    }

    /// Length of the bounding-box diagonal: the unit of every relative error.
    pub fn bbox_diagonal(&self) -> f64 {
        let (lo, hi) = self.bbox();
        (hi - lo).length()
    }

    /// Centroid of every triangle, in triangle order.
    pub fn centroids(&self) -> Vec<DVec3> {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.triangle(t);
                (a + b + c) / 3.0
            })
            .collect()
    }

    pub fn triangle(&self, t: usize) -> [DVec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }
}

pub(crate) fn bbox(p: &[DVec3]) -> (DVec3, DVec3) {
    if p.is_empty() {
        return (DVec3::ZERO, DVec3::ZERO);
    }
    p.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &q| (lo.min(q), hi.max(q)),
    )
}

/// Points at bit-identical positions merged into one: the shared weld of
/// every reader path (STL's corners, and [`crate::mesh::validate_soup`] for
/// OBJ, PLY, OFF and meshes handed over in memory).
///
/// Only *identical* coordinates are merged (`-0` and `+0` count as one),
/// never merely close ones: scans and CAD exports hold vertices that are
/// legitimately a hair apart across thin parts (the two faces of a sheet,
/// the lips of a slot, a crack that is really there), and any tolerance
/// would fuse them into one surface and change the topology. A writer that
/// split a vertex along a UV or normal seam, or wrote a triangle soup,
/// copied the coordinates verbatim, so equality finds every such copy.
#[derive(Clone, Debug, PartialEq)]
pub struct Weld {
    /// The distinct positions, in the order of their first occurrence.
    pub positions: Vec<DVec3>,
    /// For each input point, the index of its position in `positions`.
    pub remap: Vec<u32>,
}

impl Weld {
    /// Input points merged into an earlier one.
    pub fn merged(&self) -> usize {
        self.remap.len() - self.positions.len()
    }
}

/// Welds `points` (see [`Weld`]). A sort of the coordinate bits, not a
/// hash map: O(n log n) on both cores, the same numbering at any thread
/// count (the keys are unique once the index is part of them), and
/// positions numbered in order of first occurrence so that a mesh without
/// copies keeps its numbering.
pub fn weld_identical(points: &[DVec3]) -> Weld {
    use rayon::prelude::*;
    // `+ 0.0` turns -0 into +0 so that both weld (they are one point).
    let key = |p: DVec3| {
        [
            (p.x + 0.0).to_bits(),
            (p.y + 0.0).to_bits(),
            (p.z + 0.0).to_bits(),
        ]
    };
    let mut order: Vec<([u64; 3], u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, &p)| (key(p), i as u32))
        .collect();
    order.par_sort_unstable();
    // Each run of equal keys starts with its smallest index: every member
    // points at that first occurrence.
    let mut first = vec![0u32; points.len()];
    for run in order.chunk_by(|a, b| a.0 == b.0) {
        for &(_, i) in run {
            first[i as usize] = run[0].1;
        }
    }
    drop(order);
    let mut positions = Vec::with_capacity(points.len());
    let mut remap = vec![0u32; points.len()];
    for i in 0..points.len() {
        let f = first[i] as usize;
        remap[i] = if f == i {
            positions.push(points[i]);
            (positions.len() - 1) as u32
        } else {
            // `f < i`, so its new index is already set.
            remap[f]
        };
    }
    Weld { positions, remap }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weld_keeps_first_occurrence_order_and_is_idempotent() {
        let (a, b) = (DVec3::new(1.0, 2.0, 3.0), DVec3::new(-1.0, 0.5, 0.0));
        let w = weld_identical(&[b, a, b, a, DVec3::new(-1.0, 0.5, -0.0)]);
        assert_eq!(w.positions, vec![b, a]);
        assert_eq!(w.remap, vec![0, 1, 0, 1, 0]);
        assert_eq!(w.merged(), 3);
        let again = weld_identical(&w.positions);
        assert_eq!(again.merged(), 0);
        assert_eq!(again.remap, vec![0, 1]);
    }
}
