//! Step 1: a smooth, curvature-aligned cross field (4-RoSy) on the vertices
//! of M, after Knöppel, Crane, Pinkall, Schröder, "Globally optimal
//! direction fields" (SIGGRAPH 2013).
//!
//! Each vertex i has a tangent basis (e1, e2) and the field is one complex
//! number u_i per vertex, the cross's angle times 4 (§4: "n-direction
//! fields as complex numbers", n = 4), so the four arms are one value. The
//! energy is the connection Laplacian's `Σ_ij w_ij |u_i − r_ij u_j|²`
//! (§5.1), r_ij = e^{4iφ_ji} carrying j's basis into i's (the discrete
//! Levi-Civita transport: the rotation taking n_j to n_i, then the angle
//! of j's e1 in i's basis), plus the alignment term of §6.1 ("curvature
//! aligned fields"), `t Σ_i A_i |u_i − q_i|²` with q_i the principal
//! direction to the 4th power weighted by the anisotropy |κ₁ − κ₂|: where
//! the surface is umbilic or flat q ≈ 0 and the smoothest field wins. It is
//! one sparse SPD solve, `(L + t M) u = t M q`, realified to 2n unknowns and
//! solved by [`crate::solve::NormalEquations`] (Eigen's CG; its shape fits
//! exactly: every row couples a vertex with a neighbour). Boundary vertices
//! are held to the boundary tangent (§6.2's Dirichlet condition) by a stiff
//! row.

use crate::error::{Error, Result};
use crate::solve::NormalEquations;
use crate::DVec3;

use super::{FieldOptions, Surface};

/// Per-vertex tangent basis: e1 from the first neighbour's edge projected
/// onto the tangent plane, e2 = n × e1.
pub fn tangent_bases(s: &Surface) -> Vec<(DVec3, DVec3)> {
    (0..s.len())
        .map(|i| {
            let n = s.normals[i];
            let e = s
                .neighbours(i)
                .first()
                .map(|&j| s.positions[j as usize] - s.positions[i])
                .unwrap_or(DVec3::X);
            let e1 = (e - n * n.dot(e)).normalize_or_zero();
            let e1 = if e1 == DVec3::ZERO {
                n.any_orthonormal_vector()
            } else {
                e1
            };
            (e1, n.cross(e1))
        })
        .collect()
}

/// `v` rotated by the smallest rotation taking unit `from` to unit `to`
/// (Rodrigues; antipodal normals fall back to no rotation).
pub fn transport(v: DVec3, from: DVec3, to: DVec3) -> DVec3 {
    let axis = from.cross(to);
    let c = from.dot(to);
    if c <= -1.0 + 1e-12 {
        return v;
    }
    v * c + axis.cross(v) + axis * (axis.dot(v) / (1.0 + c))
}

/// The principal curvature directions' guide per vertex,
/// `|κ₁ − κ₂| / (|κ₁| + |κ₂| + floor) e^{4iθ}` in the vertex basis (θ:
/// angle of κ₁'s direction), from a least-squares
/// quadric `h = a u² + b uv + c v² + d u + e v` over the 2-ring in the
/// tangent frame (the second fundamental form is `[[2a, b], [b, 2c]]`).
pub fn curvature_guide(s: &Surface, bases: &[(DVec3, DVec3)], floor: f64) -> Vec<[f64; 2]> {
    let mut out = vec![[0.0; 2]; s.len()];
    let mut ring: Vec<u32> = Vec::new();
    for (i, o) in out.iter_mut().enumerate() {
        ring.clear();
        for &j in s.neighbours(i) {
            ring.push(j);
            ring.extend_from_slice(s.neighbours(j as usize));
        }
        ring.sort_unstable();
        ring.dedup();
        let (e1, e2) = bases[i];
        let n = s.normals[i];
        let mut ata = [[0.0f64; 5]; 5];
        let mut atb = [0.0f64; 5];
        let mut m = 0;
        for &j in &ring {
            if j as usize == i {
                continue;
            }
            let d = s.positions[j as usize] - s.positions[i];
            let (u, v, h) = (d.dot(e1), d.dot(e2), d.dot(n));
            let row = [u * u, u * v, v * v, u, v];
            for a in 0..5 {
                for b in 0..5 {
                    ata[a][b] += row[a] * row[b];
                }
                atb[a] += row[a] * h;
            }
            m += 1;
        }
        if m < 5 {
            continue;
        }
        let Some(x) = solve5(ata, atb) else { continue };
        let (aa, bb, cc) = (2.0 * x[0], x[1], 2.0 * x[2]);
        let diff = ((aa - cc).powi(2) + 4.0 * bb * bb).sqrt();
        // |κ₁| + |κ₂| = max(|tr|, |κ₁ − κ₂|) for the eigenvalues of II.
        let aniso = diff / ((aa + cc).abs().max(diff) + floor);
        // Principal angle θ = ½ atan2(2B, A − C); the 4-RoSy value is 4θ.
        let phi = 2.0 * (2.0 * bb).atan2(aa - cc);
        *o = [aniso * phi.cos(), aniso * phi.sin()];
    }
    out
}

/// Gaussian elimination with partial pivoting on a 5×5 system; `None` when
/// a pivot vanishes (too few or collinear neighbours).
fn solve5(mut a: [[f64; 5]; 5], mut b: [f64; 5]) -> Option<[f64; 5]> {
    let scale = (0..5).map(|k| a[k][k].abs()).fold(0.0, f64::max);
    for c in 0..5 {
        let p = (c..5).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[p][c].abs() <= 1e-14 * scale.max(1e-300) {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..5 {
            let f = a[r][c] / a[c][c];
            let pivot = a[c];
            for (x, p) in a[r][c..].iter_mut().zip(&pivot[c..]) {
                *x -= f * p;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 5];
    for c in (0..5).rev() {
        let mut v = b[c];
        for k in c + 1..5 {
            v -= a[c][k] * x[k];
        }
        x[c] = v / a[c][c];
    }
    Some(x)
}

/// Relative anisotropy below which [`smooth_hierarchical`] lets the
/// linear solve's cross go (only [`FieldOptions::orientation_hierarchy`]):
/// on gargoyle at τ 1 % a threshold of 0.3 or 0.7 gave 191 / 189
/// irregular vertices at 1391 patches, 0.5 gave 152 (docs/status.md).
const GUIDE_THRESHOLD: f64 = 0.5;

/// Inverse-power steps after the first solve (see [`cross_field`]).
const POWER_STEPS: usize = 3;

/// The cross field: one unit tangent vector per vertex (any of the four
/// arms), see the module docs.
///
/// The guide is the *relative* anisotropy `|κ₁ − κ₂| / (|κ₁| + |κ₂| + 1/diag)`
/// (in [0, 1], so the guide is strong on a cylinder and fades on umbilic or
/// flat parts whatever the mesh's scale). The first solve is
/// `(L + tM) u = M q`; each of [`POWER_STEPS`] more solves adds the
/// previous field, normalised to unit RMS, to the right-hand side: an
/// inverse-power step toward the smoothest field (Knöppel et al. §5.2,
/// which is the lowest eigenvector of L) where the guide is weak, while a
/// strong guide keeps its direction. With t ≪ L's smallest eigenvalue
/// (t = 1/(alignment_length · diag)²) the first solve alone leaves the
/// higher modes of a weak, noisy guide only ~3× damped (measured on an
/// icosphere: 20 + 12 − singularities instead of 8).
pub fn cross_field(s: &Surface, opts: &FieldOptions) -> Result<Vec<DVec3>> {
    cross_field_with(s, opts, GuideSmoothing::from_env())
}

/// Smoothing of the curvature guide before the solve (off by default, see
/// [`GuideSmoothing::from_env`]): the guide `q` (the principal direction's
/// 4th power times the relative anisotropy) is replaced by its screened
/// Poisson smoothing at radius r, `(L + M/r²) q̃ = M q / r²`, with the
/// same connection Laplacian as the field (Knöppel et al. 2013 §6.1 use
/// the field solve itself as such a filter; here it is applied to the
/// guide at a short radius). Where the principal directions are coherent
/// over the ball of radius ~r the smoothed guide keeps its magnitude;
/// where they are noise (the 2-ring quadric of a scanned surface) the
/// transported values cancel and |q̃| falls, so the field there follows
/// its own smoothness. The magnitude is then raised to `power` (p > 1
/// lowers incoherent parts further).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuideSmoothing {
    /// Radius in mean edge lengths of M.
    pub radius: f64,
    /// Exponent on the smoothed guide's magnitude (itself in [0, 1]).
    pub power: f64,
}

impl GuideSmoothing {
    /// `SUBDFIT_CROSS_R` (radius in mean edges) and `SUBDFIT_CROSS_P`
    /// (power, default 1); `None` (the default layout) when the radius is
    /// unset or not a positive number. An experiment switch: it lowered
    /// the cross field's singularities by 0–20 % (docs/status.md,
    /// "Field-aligned layout", 2026-12-05 guide smoothing).
    pub fn from_env() -> Option<GuideSmoothing> {
        let get = crate::switches::parsed::<f64>;
        let radius = get("SUBDFIT_CROSS_R").filter(|r| *r > 0.0 && r.is_finite())?;
        let power = get("SUBDFIT_CROSS_P")
            .filter(|p| *p > 0.0 && p.is_finite())
            .unwrap_or(1.0);
        Some(GuideSmoothing { radius, power })
    }
}

/// [`cross_field`] with an explicit guide smoothing (`None`: the guide as
/// fitted).
pub fn cross_field_with(
    s: &Surface,
    opts: &FieldOptions,
    smoothing: Option<GuideSmoothing>,
) -> Result<Vec<DVec3>> {
    let n = s.len();
    let bases = tangent_bases(s);
    let mut guide = curvature_guide(s, &bases, 1.0 / s.diagonal.max(1e-300));
    for g in &mut guide {
        g[0] *= opts.alignment_weight;
        g[1] *= opts.alignment_weight;
    }
    let ell = (opts.alignment_length * s.diagonal).max(s.mean_edge);
    let t = 1.0 / (ell * ell);
    let weights = cotan_weights(s);
    let debug = crate::switches::set("FIELD_DEBUG");
    if let Some(sm) = smoothing {
        let r = sm.radius * s.mean_edge;
        // The boundary held at a fully anisotropic guide (magnitude 1).
        let filter = FieldSystem::new(s, &bases, &weights, 1.0 / (r * r), 1.0)?;
        let g = filter.solve(&guide)?;
        for (i, gi) in guide.iter_mut().enumerate() {
            let (x, y) = (g[2 * i], g[2 * i + 1]);
            let m = (x * x + y * y).sqrt();
            let f = if m > 0.0 { m.powf(sm.power) / m } else { 0.0 };
            *gi = [x * f, y * f];
        }
    }
    // One matrix for the first solve and the power steps: only the
    // right-hand side changes between them.
    let system = FieldSystem::new(s, &bases, &weights, t, 2.0 / t)?;
    let mut target: Vec<[f64; 2]> = guide.iter().map(|g| [g[0] / t, g[1] / t]).collect();
    let mut u = system.solve(&target)?;
    for _ in 0..POWER_STEPS {
        let (mut ms, mut area) = (0.0, 0.0);
        for i in 0..n {
            ms += s.areas[i] * (u[2 * i].powi(2) + u[2 * i + 1].powi(2));
            area += s.areas[i];
        }
        let rms = (ms / area.max(1e-300)).sqrt();
        if !(rms > 0.0 && rms.is_finite()) {
            break;
        }
        for i in 0..n {
            target[i] = [
                (guide[i][0] + u[2 * i] / rms) / t,
                (guide[i][1] + u[2 * i + 1] / rms) / t,
            ];
        }
        u = system.solve(&target)?;
    }
    let mut dirs = Vec::with_capacity(n);
    for i in 0..n {
        let (x, y) = (u[2 * i], u[2 * i + 1]);
        if !(x.is_finite() && y.is_finite()) {
            return Err(Error::Backend {
                backend: "Eigen",
                msg: format!("cross field: non-finite value at vertex {i}"),
            });
        }
        let a = y.atan2(x) / 4.0;
        let (e1, e2) = bases[i];
        dirs.push(e1 * a.cos() + e2 * a.sin());
    }
    if debug {
        debug_count(s, &dirs, "after solve");
    }
    let sweeps = opts.orientation_sweeps;
    if opts.orientation_hierarchy {
        // The linear solve's cross is the guide where the relative
        // anisotropy is above GUIDE_THRESHOLD (ramping to full weight at 1).
        let weights: Vec<f64> = guide
            .iter()
            .map(|g| {
                let a = (g[0] * g[0] + g[1] * g[1]).sqrt() / opts.alignment_weight.max(1e-300);
                opts.alignment_weight * ((a - GUIDE_THRESHOLD) / (1.0 - GUIDE_THRESHOLD)).max(0.0)
            })
            .collect();
        smooth_hierarchical(s, &mut dirs, &weights, sweeps);
    } else {
        smooth_extrinsic(s, &mut dirs, sweeps);
    }
    if debug {
        debug_count(s, &dirs, "after sweeps");
    }
    Ok(dirs)
}

/// `FIELD_DEBUG`: the field's +¼ / −¼ singularities at a step.
fn debug_count(s: &Surface, dirs: &[DVec3], step: &str) {
    let sing = singularities(s, dirs);
    let p = sing.iter().filter(|x| x.1 == 1).count();
    let m = sing.iter().filter(|x| x.1 == 3).count();
    eprintln!("cross: {step} {p}+{m} singularities");
}

/// Gauss–Seidel sweeps of Instant Meshes' orientation rule (Jakob et al.
/// 2015, §4: each cross moved to the mean of its neighbours' arms nearest
/// its own, projected on its tangent plane) over M's vertices, boundary
/// vertices held. The curvature guide of [`curvature_guide`] is read per
/// vertex from a 2-ring quadric and is noisy on scanned surfaces: the
/// linear solve keeps pairs of ±¼ singularities a few triangles apart
/// (spot: 36 + 28), which this local smoothing lets annihilate while the
/// field's large-scale alignment stays. Sequential in vertex order, so
/// the result does not depend on the thread count.
pub fn smooth_extrinsic(s: &Surface, dirs: &mut [DVec3], sweeps: usize) {
    for _ in 0..sweeps {
        for i in 0..s.len() {
            if s.boundary_tangent[i].is_some() {
                continue;
            }
            let ni = s.normals[i];
            let mut acc = dirs[i];
            for &j in s.neighbours(i) {
                let j = j as usize;
                let cur = (acc - ni * ni.dot(acc)).normalize_or(dirs[i]);
                acc += match_arm(cur, dirs[j], s.normals[j]).0;
            }
            let q = (acc - ni * ni.dot(acc)).normalize_or_zero();
            if q != DVec3::ZERO {
                dirs[i] = q;
            }
        }
    }
}

/// Instant Meshes' multiresolution orientation smoothing (Jakob et al.
/// 2015, §4 with the hierarchy of §5.3, as QuadriFlow runs it): the field
/// is restricted up the pairwise-merge hierarchy of [`super::position`]
/// (each coarse cross the area-weighted mean of its children's matched
/// arms), smoothed from the coarsest level down, each level starting from
/// its parent's cross, by Gauss–Seidel sweeps of the extrinsic rule as
/// Instant Meshes runs it: each neighbour matched to the running mean as a
/// pair of arms ([`match_pair`]) and the mean renormalised after each one.
/// With the one-sided [`match_arm`] and a plain mean instead (the rule of
/// [`smooth_extrinsic`]) the field's 8 singularities on the jittered
/// sphere were the same, but its uniform lattice had 10–13 valence-3
/// vertices at every sweep count tried (the flow left 2–6 triangle
/// equations); with this rule 8 (docs/status.md, 2026-12-05). A sweep
/// on M's vertices alone moves a cross by
/// its one-ring only, so ±¼ pairs the noisy curvature guide leaves a few
/// lattice cells apart never meet (gargoyle at τ 1 %: 133 + 125
/// singularities against QuadriFlow's 124 irregular vertices); on the
/// coarse levels they do. Where the surface is strongly anisotropic the
/// linear solve's (curvature-aligned) cross is kept as a guide: vertex i
/// pulls toward it with `weight[i]` times its neighbours' weight, summed
/// up the hierarchy by area. Boundary vertices are held to the boundary
/// tangent. Sequential, so the result does not depend on the thread count.
pub fn smooth_hierarchical(s: &Surface, dirs: &mut [DVec3], weight: &[f64], sweeps: usize) {
    use super::position::{hierarchy, Level};
    let levels = hierarchy(Level::finest(s, dirs, &vec![1.0; s.len()]));
    // The guide (the restricted linear solve's cross) and its weight per level.
    let mut w = vec![weight.to_vec()];
    for l in 1..levels.len() {
        let fine = &levels[l - 1];
        let mut acc = vec![0.0; levels[l].p.len()];
        for (i, &pa) in fine.parent.iter().enumerate() {
            acc[pa as usize] += fine.area[i] * w[l - 1][i];
        }
        for (a, &area) in acc.iter_mut().zip(&levels[l].area) {
            *a /= area.max(1e-300);
        }
        w.push(acc);
    }
    let top = levels.len() - 1;
    let mut q = levels[top].q.clone();
    for l in (0..=top).rev() {
        let lv = &levels[l];
        if l < top {
            let coarse = q;
            q = (0..lv.p.len())
                .map(|i| {
                    let c = coarse[lv.parent[i] as usize];
                    let ni = lv.n[i];
                    (c - ni * ni.dot(c)).normalize_or(lv.q[i])
                })
                .collect();
        }
        for _ in 0..sweeps.max(1) {
            for i in 0..lv.p.len() {
                let ni = lv.n[i];
                if let Some((_, t)) = lv.constraint[i] {
                    q[i] = (t - ni * ni.dot(t)).normalize_or(q[i]);
                    continue;
                }
                let nb = lv.neighbours(i);
                let mut sum = q[i];
                let mut total = 0.0;
                let guide = w[l][i] * nb.len() as f64;
                if guide > 0.0 {
                    sum = match_arm(q[i], lv.q[i], ni).0 * guide;
                    total = guide;
                }
                // Instant Meshes' running mean: the unit mean so far
                // (weight `total`) and the neighbour, matched as a pair of
                // arms in 3D, renormalised after each neighbour.
                for &j in nb {
                    let j = j as usize;
                    let cur = (sum - ni * ni.dot(sum)).normalize_or(q[i]);
                    let (a, b) = match_pair(cur, ni, q[j], lv.n[j]);
                    sum = (a * total + b - ni * ni.dot(a * total + b)).normalize_or(cur);
                    total += 1.0;
                }
                let v = (sum - ni * ni.dot(sum)).normalize_or_zero();
                if v != DVec3::ZERO {
                    q[i] = v;
                }
            }
        }
    }
    dirs.copy_from_slice(&q);
}

/// The system `(L + tM) u = tM target` with the boundary rows
/// (realified: `u_i = (x, y)` at unknowns `2i`, `2i + 1`), assembled once
/// for every right-hand side of [`cross_field`].
struct FieldSystem {
    ne: NormalEquations,
    /// Per vertex the square root of its data row's weight and, on M's
    /// boundary, the goal held there (else the target's).
    rows: Vec<(f64, Option<[f64; 2]>)>,
}

impl FieldSystem {
    fn new(
        s: &Surface,
        bases: &[(DVec3, DVec3)],
        weights: &[f64],
        t: f64,
        boundary_goal: f64,
    ) -> Result<FieldSystem> {
        let n = s.len();
        let own = (0..n as u32).map(|i| [2 * i, 2 * i + 1]);
        let pairs = own.chain(s.edges.iter().flat_map(|&[a, b]| {
            let (a, b) = (2 * a, 2 * b);
            [[a, b], [a, b + 1], [a + 1, b], [a + 1, b + 1]]
        }));
        let mut ne = NormalEquations::with_pairs(2 * n, pairs)?;
        let mut stiff = 0.0f64;
        for (k, &[a, b]) in s.edges.iter().enumerate() {
            let (ai, bi) = (a as usize, b as usize);
            // r = e^{4iφ}: b's e1 carried to a's tangent plane, at angle φ in a's basis.
            let e1b = transport(bases[bi].0, s.normals[bi], s.normals[ai]);
            let phi = e1b.dot(bases[ai].1).atan2(e1b.dot(bases[ai].0));
            let (c, sn) = ((4.0 * phi).cos(), (4.0 * phi).sin());
            let w = weights[k].sqrt();
            stiff = stiff.max(weights[k]);
            let (xa, ya, xb, yb) = (2 * a, 2 * a + 1, 2 * b, 2 * b + 1);
            // Re(u_a − r u_b) and Im(u_a − r u_b).
            ne.add_row(&[(xa, w), (xb, -w * c), (yb, w * sn)], 0.0)?;
            ne.add_row(&[(ya, w), (xb, -w * sn), (yb, -w * c)], 0.0)?;
        }
        let mut rows = Vec::with_capacity(n);
        for (i, &(e1, e2)) in bases.iter().enumerate() {
            let (xi, yi) = (2 * i as u32, 2 * i as u32 + 1);
            let (wt, goal) = match s.boundary_tangent[i] {
                // §6.2: the boundary tangent is one arm of the cross, held by
                // a row 10³ times stiffer than any smoothness row (its
                // magnitude that of the largest target, so that it also
                // dominates the power steps' right-hand side).
                Some(tb) => {
                    let phi = 4.0 * tb.dot(e2).atan2(tb.dot(e1));
                    let m = boundary_goal;
                    (1e3 * stiff.max(1e-12), Some([m * phi.cos(), m * phi.sin()]))
                }
                None => (t * s.areas[i], None),
            };
            let w = wt.sqrt();
            // The data rows' right-hand sides are [`Self::solve`]'s.
            ne.add_row(&[(xi, w)], 0.0)?;
            ne.add_row(&[(yi, w)], 0.0)?;
            // A small ridge keeps vertices without area or neighbours definite.
            ne.add_diagonal(xi as usize, 1e-12 * (1.0 + stiff))?;
            ne.add_diagonal(yi as usize, 1e-12 * (1.0 + stiff))?;
            rows.push((w, goal));
        }
        Ok(FieldSystem { ne, rows })
    }

    /// `u` for `target`: the right-hand side `Aᵀ b` written directly (the
    /// smoothness rows' b is 0, so each unknown's entry is its data row's
    /// `w · (w · goal)`, the same value the rows would sum to).
    fn solve(&self, target: &[[f64; 2]]) -> Result<Vec<f64>> {
        let mut rhs = vec![0.0; 2 * self.rows.len()];
        for (i, &(w, fixed)) in self.rows.iter().enumerate() {
            let goal = fixed.unwrap_or(target[i]);
            rhs[2 * i] += w * (w * goal[0]);
            rhs[2 * i + 1] += w * (w * goal[1]);
        }
        self.ne.solve_cg_for(&rhs, 1e-8)
    }
}

/// Cotangent weights of the edges (in `s.edges` order), clamped below at a
/// small positive value: obtuse triangles of scanned meshes give negative
/// cotangents, which would make the energy indefinite.
fn cotan_weights(s: &Surface) -> Vec<f64> {
    let mut w = vec![0.0; s.edges.len()];
    let index = |a: u32, b: u32| {
        let key = [a.min(b), a.max(b)];
        s.edges.binary_search(&key).ok()
    };
    for t in &s.triangles {
        for k in 0..3 {
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (pa, pb, pc) = (
                s.positions[a as usize],
                s.positions[b as usize],
                s.positions[c as usize],
            );
            let (u, v) = (pa - pc, pb - pc);
            let cot = u.dot(v) / u.cross(v).length().max(1e-300);
            if let Some(e) = index(a, b) {
                w[e] += 0.5 * cot;
            }
        }
    }
    for x in &mut w {
        *x = x.max(0.05);
    }
    w
}

/// The arm of `q1` (rotations by 90° about `n1`) closest in direction to
/// `q0`, and its index k (arm = q1 rotated by k·90°).
#[inline]
pub fn match_arm(q0: DVec3, q1: DVec3, n1: DVec3) -> (DVec3, u8) {
    let t1 = n1.cross(q1);
    let (a, b) = (q0.dot(q1), q0.dot(t1));
    if a.abs() >= b.abs() {
        if a >= 0.0 {
            (q1, 0)
        } else {
            (-q1, 2)
        }
    } else if b >= 0.0 {
        (t1, 1)
    } else {
        (-t1, 3)
    }
}

/// Extrinsic matching of two crosses (Jakob et al. 2015, §4, the
/// extrinsic 4-RoSy rule; Instant Meshes' `compat_orientation_extrinsic_4`):
/// among the arms `q0`, `n0 × q0` and `q1`, `n1 × q1` the pair most nearly
/// parallel in 3D, the second's sign flipped to agree. Unlike
/// [`match_arm`] (the arm of `q1` nearest `q0`) it lets `q0`'s own arm
/// change too, which matters where the normals differ: on the coarse
/// levels of [`smooth_hierarchical`].
pub fn match_pair(q0: DVec3, n0: DVec3, q1: DVec3, n1: DVec3) -> (DVec3, DVec3) {
    let a = [q0, n0.cross(q0)];
    let b = [q1, n1.cross(q1)];
    let mut best = (f64::NEG_INFINITY, 0, 0);
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            let sc = x.dot(*y).abs();
            if sc > best.0 {
                best = (sc, i, j);
            }
        }
    }
    let (x, y) = (a[best.1], b[best.2]);
    (x, if x.dot(y) < 0.0 { -y } else { y })
}

/// Triangles where the cross field has a singularity, with the turn
/// `k ∈ {1, 2, 3}` (index k/4 mod 1): the arm matched along the three
/// edges, summed mod 4 (Instant Meshes' combinatorial index, after
/// Ray et al. 2008's matching). k = 1 is index +¼ (a valence-3 vertex of
/// the quad mesh), k = 3 is −¼ (valence 5).
pub fn singularities(s: &Surface, dirs: &[DVec3]) -> Vec<(u32, u8)> {
    let mut out = Vec::new();
    for (t, tri) in s.triangles.iter().enumerate() {
        let mut turn = 0u32;
        for k in 0..3 {
            let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
            // Carry a's arm into b's tangent plane, find b's matching arm.
            let qa = transport(dirs[a], s.normals[a], s.normals[b]);
            let (_, kb) = match_arm(qa, dirs[b], s.normals[b]);
            // b's arm kb matches a's arm 0: the arm followed turns by kb
            // quarter turns (counter-clockwise about the normal).
            turn += u32::from(kb);
        }
        let k = (turn % 4) as u8;
        if k != 0 {
            out.push((t as u32, k));
        }
    }
    out
}
