//! Diagnostics of the field layout's adaptivity (issue 40): per relaxation
//! variant, patches, irregular vertices, Spearman(radius, 1/F_S),
//! Spearman(radius, h) and Spearman(h, 1/F_S) at the patch centres, with
//! and without the cleanup.
//!
//! `cargo run --release --example adapt_diag -- MESH VARIANT...` where a
//! VARIANT is a `FIELD_RELAX` value (`uniform`, `none`, `sized:STEPS:POWER`),
//! optionally followed by `/` and a `FIELD_SIZED_RELAX` value
//! (`STEPS:POWER[:GAMMA[:g]]`, the post-extraction relaxation towards the
//! uncapped Fitmap sizes h_r; then ρ(r, h_r) and ρ(h_r, 1/F_S) are printed
//! too).
//! `ADAPT_GAMMA`, `ADAPT_LOOPCAP` and `ADAPT_FACES` override the
//! gradation, the holes' cap slope and the target count;
//! `ADAPT_SWEEPS` sets the position field's sweeps per level;
//! `ADAPT_CLEANUP_ONLY` skips the layouts without the cleanup;
//! `FIELD_GRADING` (`sizing::Grading`) is the graded stage's grading too. h is the
//! sizing before the count loop's uniform scaling (ranks unchanged).

use subdfit::analysis::{compute_fitmap, spearman, FitmapOptions};
use subdfit::mesh::{ControlMesh, Frame, TriMesh};
use subdfit::quad::field::{field_layout, irregular_vertices, sizing, FieldOptions, Surface};
use subdfit::raycast::bvh::BvhCaster;
use subdfit::raycast::{make_raycaster, RayBackend, RayCaster};
use subdfit::DVec3;

/// (ρ(r, 1/F_S), ρ(r, h), ρ(h, 1/F_S)) at the patch centres.
fn rhos(mesh: &TriMesh, fs: &[f64], h: &[f64], k: &ControlMesh) -> (f64, f64, f64) {
    let (mut centres, mut radius) = (Vec::new(), Vec::new());
    for f in k.faces() {
        let q: Vec<DVec3> = k.face_vertices(f).map(|v| k.position(v)).collect();
        let c = q.iter().copied().sum::<DVec3>() / q.len() as f64;
        radius.push(q.iter().map(|p| (*p - c).length()).fold(0.0, f64::max));
        centres.push(c);
    }
    let caster = BvhCaster::new(mesh).unwrap();
    let hits = caster.closest_points(&centres, f64::INFINITY).unwrap();
    let (mut r, mut inv, mut hh) = (Vec::new(), Vec::new(), Vec::new());
    for (c, &rad) in hits.iter().zip(&radius) {
        let Some(c) = c else { continue };
        let t = mesh.triangles[c.triangle as usize];
        let s: Vec<f64> = t
            .iter()
            .map(|&v| fs[v as usize])
            .filter(|s| *s > 0.0 && s.is_finite())
            .collect();
        if s.is_empty() {
            continue;
        }
        r.push(rad);
        inv.push(s.len() as f64 / s.iter().sum::<f64>());
        hh.push(t.iter().map(|&v| h[v as usize]).sum::<f64>() / 3.0);
    }
    (
        spearman(&r, &inv).unwrap_or(f64::NAN),
        spearman(&r, &hh).unwrap_or(f64::NAN),
        spearman(&hh, &inv).unwrap_or(f64::NAN),
    )
}

/// One patch of [`breakdown`]: (radius, √area, 1/F_S at the centre,
/// F_M binds there, an irregular corner).
type PatchRow = (f64, f64, f64, bool, bool);

/// Where ρ(r, 1/F_S) is lost, per patch: ρ over the patches where F_M
/// binds at the centre (β μ h_M < α h_S on the nearest triangle) and where
/// it does not, over patches with / without an irregular corner, ρ with
/// √area instead of the radius (the quads' shape as noise), and ρ over
/// the thirds of 1/F_S (is the spread lost at the small or large end?).
fn breakdown(
    mesh: &TriMesh,
    fitmap: &subdfit::analysis::Fitmap,
    opts: &FieldOptions,
    alpha: f64,
    mu: f64,
    k: &ControlMesh,
) -> anyhow::Result<String> {
    let (hs, hm) = sizing::fitmap_limits(mesh, fitmap, opts.s_fitmap_scale)?;
    let beta = opts.m_fitmap_scale * mu;
    let caster = BvhCaster::new(mesh)?;
    let irregular = |v| {
        let n = k.valence(v);
        if k.is_boundary_vertex(v) {
            n != 3 && n != 2
        } else {
            n != 4
        }
    };
    let mut rows = Vec::new();
    for f in k.faces() {
        let vs: Vec<_> = k.face_vertices(f).collect();
        let q: Vec<DVec3> = vs.iter().map(|&v| k.position(v)).collect();
        let c = q.iter().copied().sum::<DVec3>() / q.len() as f64;
        let rad = q.iter().map(|p| (*p - c).length()).fold(0.0, f64::max);
        let area = if q.len() == 4 {
            0.5 * (q[2] - q[0]).cross(q[3] - q[1]).length()
        } else {
            f64::NAN
        };
        let irr = vs.iter().any(|&v| irregular(v));
        rows.push((c, rad, area.sqrt(), irr));
    }
    let centres: Vec<DVec3> = rows.iter().map(|r| r.0).collect();
    let hits = caster.closest_points(&centres, f64::INFINITY)?;
    let mut p: Vec<PatchRow> = Vec::new();
    for (row, hit) in rows.iter().zip(&hits) {
        let Some(hit) = hit else { continue };
        let t = mesh.triangles[hit.triangle as usize];
        let s: Vec<f64> = t
            .iter()
            .map(|&v| fitmap.s[v as usize])
            .filter(|s| *s > 0.0 && s.is_finite())
            .collect();
        if s.is_empty() {
            continue;
        }
        let binds = t
            .iter()
            .any(|&v| beta * hm[v as usize] < alpha * hs[v as usize]);
        p.push((
            row.1,
            row.2,
            s.len() as f64 / s.iter().sum::<f64>(),
            binds,
            row.3,
        ));
    }
    let rho = |sel: &dyn Fn(&PatchRow) -> bool, area: bool| {
        let (x, y): (Vec<f64>, Vec<f64>) = p
            .iter()
            .filter(|r| sel(r))
            .map(|r| (if area { r.1 } else { r.0 }, r.2))
            .unzip();
        (spearman(&x, &y).unwrap_or(f64::NAN), x.len())
    };
    let mut inv: Vec<f64> = p.iter().map(|r| r.2).collect();
    inv.sort_by(f64::total_cmp);
    let (t1, t2) = (inv[inv.len() / 3], inv[2 * inv.len() / 3]);
    let f = |(r, n): (f64, usize)| format!("{r:.3} ({n})");
    Ok(format!(
        "  per patch: all {} | sqrt(area) {} | F_M binds {} / free {} | irregular corner {} / regular {} | 1/FS thirds {} {} {}",
        f(rho(&|_| true, false)),
        f(rho(&|_| true, true)),
        f(rho(&|r| r.3, false)),
        f(rho(&|r| !r.3, false)),
        f(rho(&|r| r.4, false)),
        f(rho(&|r| !r.4, false)),
        f(rho(&|r| r.2 < t1, false)),
        f(rho(&|r| r.2 >= t1 && r.2 < t2, false)),
        f(rho(&|r| r.2 >= t2, false)),
    ))
}

/// Where the sizing loses 1/F_S, per vertex of M (those with an F_S):
/// ρ(h, 1/F_S) of the ungraded `min(α h_S, μ β h_M)`, graded at γ, then
/// with the holes' caps, and the share of vertices each step lowered.
fn sizing_stages(
    surf: &Surface,
    mesh: &TriMesh,
    fitmap: &subdfit::analysis::Fitmap,
    opts: &FieldOptions,
    alpha: f64,
    mu: f64,
) -> anyhow::Result<()> {
    let (hs, hm) = sizing::fitmap_limits(mesh, fitmap, opts.s_fitmap_scale)?;
    let beta = opts.m_fitmap_scale * mu;
    let raw: Vec<f64> = hs
        .iter()
        .zip(&hm)
        .map(|(&a, &b)| (alpha * a).min(beta * b))
        .collect();
    let hm_mu: Vec<f64> = hm.iter().map(|x| mu * x).collect();
    let graded = sizing::graded_with(surf, &hs, &hm_mu, alpha, opts, opts.grading);
    let mut capped = graded.clone();
    sizing::cap_at_boundaries(surf, &mut capped, opts.gradation, opts.loop_cap_slope);
    let keep: Vec<usize> = (0..hs.len()).filter(|&i| hs[i].is_finite()).collect();
    let inv: Vec<f64> = keep.iter().map(|&i| 1.0 / fitmap.s[i]).collect();
    let rho = |h: &[f64]| {
        let x: Vec<f64> = keep.iter().map(|&i| h[i]).collect();
        spearman(&x, &inv).unwrap_or(f64::NAN)
    };
    let share = |a: &[f64], b: &[f64]| {
        keep.iter().filter(|&&i| b[i] < a[i] * (1.0 - 1e-9)).count() as f64 / keep.len() as f64
    };
    let hsa: Vec<f64> = hs.iter().map(|x| alpha * x).collect();
    let q = |v: &[f64], p: f64| {
        let mut x: Vec<f64> = keep.iter().map(|&i| v[i]).collect();
        x.sort_by(f64::total_cmp);
        x[((x.len() - 1) as f64 * p) as usize]
    };
    println!(
        "sizing: alpha {alpha:.3} mu {mu:.3} | rho(h,1/FS) raw {:.3} graded {:.3} capped {:.3} | lowered by F_M {:.3} grading {:.3} caps {:.3} | h p90/p10 raw {:.2} graded {:.2} capped {:.2} | 1/FS p90/p10 {:.2} | predicted raw {:.0} graded {:.0} capped {:.0}",
        rho(&raw),
        rho(&graded),
        rho(&capped),
        share(&hsa, &raw),
        share(&raw, &graded),
        share(&graded, &capped),
        q(&raw, 0.9) / q(&raw, 0.1),
        q(&graded, 0.9) / q(&graded, 0.1),
        q(&capped, 0.9) / q(&capped, 0.1),
        q(&hs, 0.9) / q(&hs, 0.1),
        sizing::predicted_faces(surf, &raw),
        sizing::predicted_faces(surf, &graded),
        sizing::predicted_faces(surf, &capped),
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    let (lo, hi) = input.mesh.bbox();
    let mut mesh = input.mesh.clone();
    Frame::of_bbox(lo, hi).points_to_unit(&mut mesh.positions);
    let caster = make_raycaster(RayBackend::Embree, &mesh)?;
    let fitmap = compute_fitmap(
        &mesh,
        caster.as_ref(),
        &FitmapOptions::default().with_tolerance(0.01),
    )?;
    let mut opts = FieldOptions::default();
    if std::env::var_os("ADAPT_NATURAL").is_some() {
        opts = opts.with_natural_adaptivity();
    }
    if let Some(g) = std::env::var("ADAPT_GAMMA")
        .ok()
        .and_then(|g| g.parse().ok())
    {
        opts.gradation = g;
    }
    if let Some(g) = std::env::var("ADAPT_LOOPCAP")
        .ok()
        .and_then(|g| g.parse().ok())
    {
        opts.loop_cap_slope = g;
    }
    if let Some(g) = std::env::var("ADAPT_FACES")
        .ok()
        .and_then(|g| g.parse().ok())
    {
        opts.target_faces = Some(g);
    }
    if let Some(g) = std::env::var("ADAPT_SWEEPS")
        .ok()
        .and_then(|g| g.parse().ok())
    {
        opts.position_sweeps = g;
    }
    let cleanups: &[bool] = if std::env::var("ADAPT_CLEANUP_ONLY").is_ok() {
        &[true]
    } else {
        &[false, true]
    };
    let surf = Surface::new(&mesh)?;
    let (mut h, alpha, mu, _) = sizing::sizing_for(&surf, &mesh, &fitmap, &opts)?;
    sizing::cap_at_boundaries(&surf, &mut h, opts.gradation, opts.loop_cap_slope);
    sizing_stages(&surf, &mesh, &fitmap, &opts, alpha, mu)?;
    for v in &args[2..] {
        // `RELAX/SIZED`: FIELD_RELAX, then FIELD_SIZED_RELAX (STEPS:POWER[:GAMMA]).
        let (relax, sized) = v.split_once('/').unwrap_or((v.as_str(), ""));
        std::env::set_var("FIELD_RELAX", relax);
        match subdfit::quad::field::extract::SizedRelax::parse(sized) {
            Some(_) => std::env::set_var("FIELD_SIZED_RELAX", sized),
            None => std::env::remove_var("FIELD_SIZED_RELAX"),
        }
        for &cleanup in cleanups {
            let mut o = opts.clone();
            o.cleanup = cleanup;
            if !sized.is_empty() {
                o.sized_relax = subdfit::quad::field::extract::SizedRelax::parse(sized);
            }
            let laid = field_layout(&mesh, &fitmap, &o)?;
            let (a, b, c) = rhos(&mesh, &fitmap.s, &h, &laid.control);
            let g = subdfit::quad::field::extract::SizedRelax::parse(sized)
                .map_or(f64::INFINITY, |m| m.gamma);
            let hr = sizing::relaxation_sizes(
                &surf,
                &mesh,
                &fitmap,
                &o,
                laid.stats.alpha,
                laid.stats.m_fitmap_relaxed,
                g,
                false,
            )?;
            let (_, d, e) = rhos(&mesh, &fitmap.s, &hr, &laid.control);
            println!(
                "{v:>14} cleanup={cleanup:<5} faces {:4} irr {:3} rho(r,1/FS) {a:.3} rho(r,h) {b:.3} rho(h,1/FS) {c:.3} rho(r,hr) {d:.3} rho(hr,1/FS) {e:.3} rounds {}",
                laid.control.num_faces(),
                irregular_vertices(&laid.control),
                laid.stats.lattice.local_rounds
            );
            println!(
                "{}",
                breakdown(
                    &mesh,
                    &fitmap,
                    &o,
                    laid.stats.alpha,
                    laid.stats.m_fitmap_relaxed,
                    &laid.control
                )?
            );
        }
    }
    Ok(())
}
