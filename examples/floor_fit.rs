//! How close to M a piecewise-linear surface with a given vertex budget can
//! get when its vertices may move along their normals by least squares, as
//! the displacement's offsets do (issue 37; Fitmaps §3.5/§4). Measurement
//! only: `bench/floor.sh` feeds it surfaces remeshed from M at k × |V(M)|
//! vertices (isotropic, or QEM of M subdivided), made outside the crate.
//!
//! `cargo run --release --example floor_fit -- MESH SURFACE [ROUNDS] [BACK_WEIGHT]`
//!
//! Prints one JSON line per round (round 0: SURFACE as given, its vertices
//! on M, i.e. interpolation): RMS M → surface (the figure of
//! `bench/density.sh`'s "M→ply", M's 3-point quadrature, ‰ of M's diagonal)
//! and surface → M. Each round is one Gauss–Newton step of scalar offsets
//! `t_k` along the surface's vertex normals `n_k`, point-to-plane rows from
//! both sides (M's quadrature points to their closest surface point, the
//! surface's quadrature points to their closest point of M; one row per
//! point, weighted by its area), solved by conjugate gradients on the
//! normal equations. Both sides, as the displacement least squares
//! (`displace`) has both: M → surface alone lets the surface fold away
//! from M where no point of M is closest to it. `BACK_WEIGHT` (default 1)
//! scales the surface → M rows; 0 fits M → surface alone, the issue's
//! figure, as a more generous bound.

use subdfit::mesh::TriMesh;
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::report::{distance_stats, quadrature_points};
use subdfit::DVec3;

/// One point-to-plane row: up to three vertices, their coefficients, the
/// right-hand side and the row's weight.
struct Row {
    v: [u32; 3],
    c: [f64; 3],
    rhs: f64,
    w: f64,
}

fn vertex_normals(m: &TriMesh) -> Vec<DVec3> {
    let mut n = vec![DVec3::ZERO; m.positions.len()];
    for (t, tri) in m.triangles.iter().enumerate() {
        let [a, b, c] = m.triangle(t);
        let f = (b - a).cross(c - a); // area-weighted
        for &v in tri {
            n[v as usize] += f;
        }
    }
    n.iter().map(|x| x.normalize_or_zero()).collect()
}

/// Barycentric coordinates of `p` (on or near triangle `t`) in `m`.
fn barycentric(m: &TriMesh, t: usize, p: DVec3) -> [f64; 3] {
    let [a, b, c] = m.triangle(t);
    let (e0, e1, d) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (e0.dot(e0), e0.dot(e1), e1.dot(e1));
    let (d20, d21) = (d.dot(e0), d.dot(e1));
    let den = d00 * d11 - d01 * d01;
    if den.abs() < 1e-300 {
        return [1.0 / 3.0; 3];
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    [1.0 - v - w, v, w]
}

fn face_normal(m: &TriMesh, t: usize) -> DVec3 {
    let [a, b, c] = m.triangle(t);
    (b - a).cross(c - a).normalize_or_zero()
}

/// The rows of one Gauss–Newton step of `s` towards `m` (module docs).
fn rows(m: &TriMesh, s: &TriMesh, normals: &[DVec3], back: f64) -> anyhow::Result<Vec<Row>> {
    let mut out = Vec::new();
    let row = |t: usize, q: DVec3, p: DVec3, w: f64, beta: [f64; 3]| {
        let nt = face_normal(s, t);
        let tri = s.triangles[t];
        let c = [0, 1, 2].map(|k| beta[k] * nt.dot(normals[tri[k] as usize]));
        Row {
            v: tri,
            c,
            rhs: nt.dot(p - q),
            w,
        }
    };
    // M → surface.
    let (mp, mw) = quadrature_points(m);
    let sc = make_raycaster(RayBackend::Embree, s)?;
    for ((p, w), cp) in mp
        .iter()
        .zip(&mw)
        .zip(sc.closest_points(&mp, f64::INFINITY)?)
    {
        let cp = cp.ok_or_else(|| anyhow::anyhow!("no closest point"))?;
        let t = cp.triangle as usize;
        out.push(row(t, cp.point, *p, *w, barycentric(s, t, cp.point)));
    }
    // Surface → M: the 3-point rule's points, barycentrics (4, 1, 1)/6.
    let (sp, sw) = quadrature_points(s);
    let mc = make_raycaster(RayBackend::Embree, m)?;
    for (i, cp) in mc
        .closest_points(&sp, f64::INFINITY)?
        .into_iter()
        .enumerate()
    {
        let cp = cp.ok_or_else(|| anyhow::anyhow!("no closest point"))?;
        let mut beta = [1.0 / 6.0; 3];
        beta[i % 3] = 4.0 / 6.0;
        out.push(row(i / 3, sp[i], cp.point, back * sw[i], beta));
    }
    Ok(out)
}

/// `AᵀW A x + λ x` for the rows.
fn apply(rows: &[Row], lambda: f64, x: &[f64]) -> Vec<f64> {
    let mut y: Vec<f64> = x.iter().map(|v| lambda * v).collect();
    for r in rows {
        let ax: f64 = (0..3).map(|k| r.c[k] * x[r.v[k] as usize]).sum();
        for k in 0..3 {
            y[r.v[k] as usize] += r.w * r.c[k] * ax;
        }
    }
    y
}

/// Offsets minimising the rows' weighted squares (+ λ|t|², which only pins
/// vertices no row reaches), by Jacobi-preconditioned conjugate gradients.
fn solve(rows: &[Row], n: usize) -> Vec<f64> {
    let wsum: f64 = rows.iter().map(|r| r.w).sum();
    let lambda = 1e-6 * wsum / n as f64;
    let mut diag = vec![lambda; n];
    let mut b = vec![0.0; n];
    for r in rows {
        for k in 0..3 {
            diag[r.v[k] as usize] += r.w * r.c[k] * r.c[k];
            b[r.v[k] as usize] += r.w * r.c[k] * r.rhs;
        }
    }
    let mut x = vec![0.0; n];
    let mut r = b.clone();
    let mut z: Vec<f64> = r.iter().zip(&diag).map(|(a, d)| a / d).collect();
    let mut p = z.clone();
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    let r0 = rz;
    for _ in 0..400 {
        let ap = apply(rows, lambda, &p);
        let alpha = rz / p.iter().zip(&ap).map(|(a, b)| a * b).sum::<f64>();
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        z = r.iter().zip(&diag).map(|(a, d)| a / d).collect();
        let rz1: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        if rz1 <= 1e-16 * r0 {
            break;
        }
        let beta = rz1 / rz;
        rz = rz1;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    x
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        (3..=5).contains(&args.len()),
        "usage: floor_fit MESH SURFACE [ROUNDS] [BACK_WEIGHT]"
    );
    let m = subdfit::io::read_mesh(args[1].as_ref())?.mesh;
    let mut s = subdfit::io::read_mesh(args[2].as_ref())?.mesh;
    let rounds: usize = args.get(3).map_or(Ok(4), |a| a.parse())?;
    let back: f64 = args.get(4).map_or(Ok(1.0), |a| a.parse())?;
    let diag = m.bbox_diagonal();
    let (mp, mw) = quadrature_points(&m);
    let mc = make_raycaster(RayBackend::Embree, &m)?;
    for round in 0..=rounds {
        if round > 0 {
            let normals = vertex_normals(&s);
            let t = solve(&rows(&m, &s, &normals, back)?, s.positions.len());
            for (k, p) in s.positions.iter_mut().enumerate() {
                *p += t[k] * normals[k];
            }
        }
        let sc = make_raycaster(RayBackend::Embree, &s)?;
        let m2s = distance_stats(&mp, &mw, sc.as_ref(), diag)?;
        let (sp, sw) = quadrature_points(&s);
        let s2m = distance_stats(&sp, &sw, mc.as_ref(), diag)?;
        println!(
            "{}",
            serde_json::json!({
                "surface": args[2],
                "vertices": s.positions.len(),
                "m_vertices": m.positions.len(),
                "round": round,
                "back_weight": back,
                "m_to_surface": m2s.rms_permille,
                "surface_to_m": s2m.rms_permille,
            })
        );
    }
    Ok(())
}
