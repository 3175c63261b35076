//! Where the displacement's unprojectable samples lie and why (issue 37,
//! thin parts): for the patches with the largest share of D's squared
//! error, each unprojectable sample's distance to M, the agreement of its
//! line with M's normal at the closest point, and the line's hits both ways.
//!
//! `cargo run --release --example thin_diag -- MESH CONTROL.obj [MULTIPLE]`

use subdfit::raycast::{make_raycaster, Ray, RayBackend};
use subdfit::report::{distance_stats, evaluate_surfaces, quadrature_points, MetricsOptions};
use subdfit::DVec3;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        args.len() >= 3,
        "usage: thin_diag MESH CONTROL.obj [MULTIPLE]"
    );
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    let control = subdfit::io::read_control_mesh(args[2].as_ref())?;
    let m: f64 = args.get(3).map_or(Ok(1.0), |s| s.parse())?;
    let mesh = &input.mesh;
    let diag = mesh.bbox_diagonal();
    let caster = make_raycaster(RayBackend::Embree, mesh)?;
    let budget = (m * mesh.positions.len() as f64).round() as usize;
    let opts = MetricsOptions::default().with_displacement_samples(Some(budget));
    let s = evaluate_surfaces(mesh, &control, caster.as_ref(), &opts, &mut |_, _| true)?;
    let d = &s.displacement;
    let b = &s.metrics.displaced_breakdown;
    println!(
        "D rms {:.4} s2m {:.4} m2s {:.4}; unproj samples {} (other sheet {}); unproj tri area {:.3}% share {:.1}%",
        s.metrics.displaced.rms_permille,
        s.metrics.displaced.surface_to_mesh.rms_permille,
        s.metrics.displaced.mesh_to_surface.rms_permille,
        d.stats.unprojectable,
        d.stats.other_sheet,
        b.unprojectable_area_percent,
        b.unprojectable_error_share_percent
    );
    let (mp, mw) = quadrature_points(mesh);
    let dc = make_raycaster(RayBackend::Embree, &s.displaced)?;
    let harness = distance_stats(&mp, &mw, dc.as_ref(), diag)?;
    println!(
        "M -> displaced.ply {:.4} max {:.3}; max |offset| {:.2}",
        harness.rms_permille, harness.max_permille, d.stats.max_abs_offset_permille
    );
    // Where M → displaced.ply's squared error lies, by patch: the written
    // tessellation holds the patches in order, the same triangle count
    // each.
    let dhits = dc.closest_points(&mp, f64::INFINITY)?;
    let patches = d.grid.num_patches();
    let per = s.displaced.triangles.len() / patches.max(1);
    let mut by_patch = vec![0.0; patches];
    let mut total = 0.0;
    let wsum: f64 = mw.iter().sum();
    for (h, w) in dhits.iter().zip(&mw) {
        let Some(h) = h else { continue };
        let e = w * h.distance * h.distance;
        by_patch[(h.triangle as usize / per.max(1)).min(patches - 1)] += e;
        total += e;
    }
    let mut order: Vec<usize> = (0..patches).collect();
    order.sort_by(|&a, &b| by_patch[b].total_cmp(&by_patch[a]));
    let pm2 = 1000.0 / diag;
    let mut rest = total;
    for &f in order.iter().take(5) {
        rest -= by_patch[f];
        println!(
            "M -> D patch {f}: share {:.1}%; RMS without it and the ones above {:.4}",
            100.0 * by_patch[f] / total,
            pm2 * (rest / wsum).sqrt()
        );
    }
    // The same by tile resolution: error share against area share.
    let mut by_res: std::collections::BTreeMap<usize, (f64, f64)> = Default::default();
    for (h, w) in dhits.iter().zip(&mw) {
        let Some(h) = h else { continue };
        let f = (h.triangle as usize / per.max(1)).min(patches - 1);
        let e = by_res.entry(d.grid.patch_res(f)).or_default();
        e.0 += w * h.distance * h.distance;
        e.1 += w;
    }
    for (r, (e, a)) in &by_res {
        println!(
            "M -> D tiles {r}x{r}: area {:.1}% error {:.1}% rms {:.4}",
            100.0 * a / wsum,
            100.0 * e / total,
            pm2 * (e / a).sqrt()
        );
    }
    if std::env::var("DIAG_QUIET").is_ok() {
        return Ok(());
    }
    let pm = |x: f64| 1000.0 * x / diag;
    for w in b.worst_patches.iter().take(3) {
        let f = w.patch;
        let r = d.grid.patch_res(f);
        println!(
            "patch {f} res {r} share {:.1}% rms {:.3} unproj {}",
            w.error_share_percent, w.rms_permille, w.unprojectable_samples
        );
        let mut ids = Vec::new();
        for j in 0..r {
            for i in 0..r {
                ids.push((i, j, d.grid.sample(f, i, j) as usize));
            }
        }
        let pts: Vec<DVec3> = ids.iter().map(|&(_, _, s)| d.limit[s].position).collect();
        let dirs: Vec<DVec3> = ids.iter().map(|&(_, _, s)| d.directions[s]).collect();
        let close = caster.closest_points(&pts, f64::INFINITY)?;
        let disp: Vec<DVec3> = ids
            .iter()
            .map(|&(_, _, s)| d.limit[s].position + d.offsets[s] * d.directions[s])
            .collect();
        let dclose = caster.closest_points(&disp, f64::INFINITY)?;
        let mut rays = Vec::new();
        for (&o, &dir) in pts.iter().zip(&dirs) {
            for sgn in [1.0, -1.0] {
                rays.push(Ray {
                    origin: o,
                    dir: sgn * dir,
                    tmin: 0.0,
                    tmax: 0.2 * diag,
                });
            }
        }
        let hits = caster.first_hits(&rays)?;
        for (k, &(i, j, sidx)) in ids.iter().enumerate() {
            let c = close[k].unwrap();
            let [a, bb, cc] = mesh.triangle(c.triangle as usize);
            let nm = (bb - a).cross(cc - a).normalize();
            let cp_off = dirs[k].dot(c.point - pts[k]);
            let f_hit = hits[2 * k].map(|h| pm(h.t));
            let b_hit = hits[2 * k + 1].map(|h| -pm(h.t));
            println!(
                "  ({i:2},{j:2}) {} dM {:7.3} n.nM {:+.2} cpOff {:+7.3} fwd {:?} bwd {:?} off {:+7.3} err {:7.3}",
                if d.projected[sidx] { "P" } else { "U" },
                pm(c.distance),
                dirs[k].dot(nm),
                pm(cp_off),
                f_hit.map(|x| (x * 1000.0).round() / 1000.0),
                b_hit.map(|x| (x * 1000.0).round() / 1000.0),
                pm(d.offsets[sidx]),
                pm(dclose[k].unwrap().distance)
            );
        }
    }
    Ok(())
}
