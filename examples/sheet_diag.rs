//! The displacement samples whose normal line meets M only on another
//! sheet (issue 40, gargoyle 421): per unprojectable sample, its place, the
//! line's hits both ways, M's closest point (distance, normal against the
//! line), the offset the pipeline gives it and the distance of the
//! displaced point to M, and the offset along the line nearest to M.
//!
//! `cargo run --release --example sheet_diag -- MESH CONTROL.obj [OUT.csv]`

use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::report::{evaluate_surfaces, MetricsOptions};
use subdfit::DVec3;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        args.len() >= 3,
        "usage: sheet_diag MESH CONTROL.obj [OUT.csv]"
    );
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    let control = subdfit::io::read_control_mesh(args[2].as_ref())?;
    let mesh = &input.mesh;
    let diag = mesh.bbox_diagonal();
    let k = 1000.0 / diag;
    let caster = make_raycaster(RayBackend::Embree, mesh)?;
    let opts = MetricsOptions::default();
    let s = evaluate_surfaces(mesh, &control, caster.as_ref(), &opts, &mut |_, _| true)?;
    let d = &s.displacement;
    let m = &s.metrics;
    println!(
        "D {:.4} (D->M {:.4}, M->D {:.4}) unproj {} other {} area% {:.3} share% {:.1} proj-rms {:.4}",
        m.displaced.rms_permille,
        m.displaced.surface_to_mesh.rms_permille,
        m.displaced.mesh_to_surface.rms_permille,
        d.stats.unprojectable,
        d.stats.other_sheet,
        m.displaced_breakdown.unprojectable_area_percent,
        m.displaced_breakdown.unprojectable_error_share_percent,
        m.displaced_breakdown.surface_to_mesh_projected.rms_permille,
    );
    println!(
        "sheet_resolved {:?} lsq {:?}",
        d.stats.sheet_resolved, d.stats.least_squares
    );
    // D → M by region: displaced.ply's vertices (a third of their
    // triangles' area each) within 8 units of the clusters' centres
    // given in SHEET_CENTRES ("x,y,z;x,y,z"), and the rest.
    let centres: Vec<DVec3> = std::env::var("SHEET_CENTRES")
        .unwrap_or_default()
        .split(';')
        .filter(|c| !c.is_empty())
        .map(|c| {
            let v: Vec<f64> = c.split(',').map(|x| x.parse().unwrap()).collect();
            DVec3::new(v[0], v[1], v[2])
        })
        .collect();
    let area = subdfit::report::vertex_areas(&s.displaced);
    let dv = caster.closest_points(&s.displaced.positions, f64::INFINITY)?;
    let total: f64 = area.iter().sum();
    let mut region = vec![0.0; centres.len() + 1];
    for ((p, a), c) in s.displaced.positions.iter().zip(&area).zip(&dv) {
        let e = a * c.unwrap().distance.powi(2);
        let r = centres
            .iter()
            .position(|q| q.distance(*p) < 8.0)
            .unwrap_or(centres.len());
        region[r] += e;
    }
    if let Ok(path) = std::env::var("SHEET_DUMP") {
        // displaced.ply's vertices: x y z area distance projected.
        let mut o = String::new();
        for (((p, a), c), pr) in s
            .displaced
            .positions
            .iter()
            .zip(&area)
            .zip(&dv)
            .zip(&s.displaced_projected)
        {
            o += &format!(
                "{:.3} {:.3} {:.3} {:.5} {:.5} {}\n",
                p.x,
                p.y,
                p.z,
                a,
                c.unwrap().distance,
                *pr as u8
            );
        }
        std::fs::write(path, o)?;
    }
    let rms: Vec<String> = region
        .iter()
        .map(|e| format!("{:.4}", k * (e / total).sqrt()))
        .collect();
    println!(
        "D->M of displaced.ply vertices by region (last: rest): {}",
        rms.join(" ")
    );
    let idx: Vec<usize> = (0..d.offsets.len()).filter(|&i| !d.projected[i]).collect();
    let pos: Vec<DVec3> = idx.iter().map(|&i| d.limit[i].position).collect();
    let dir: Vec<DVec3> = idx.iter().map(|&i| d.directions[i]).collect();
    let mk = |sign: f64| -> Vec<subdfit::raycast::Ray> {
        pos.iter()
            .zip(&dir)
            .map(|(&o, &n)| subdfit::raycast::Ray::new(o, sign * n))
            .collect()
    };
    let fwd = caster.first_hits(&mk(1.0))?;
    let bwd = caster.first_hits(&mk(-1.0))?;
    let cl = caster.closest_points(&pos, f64::INFINITY)?;
    let disp: Vec<DVec3> = idx
        .iter()
        .map(|&i| d.limit[i].position + d.offsets[i] * d.directions[i])
        .collect();
    let dcl = caster.closest_points(&disp, f64::INFINITY)?;
    // The offset along the line nearest to M: a scan of t over ±(4·d_M + 2
    // edges), then the best one.
    let edge = mesh.mean_edge_length();
    let mut out =
        String::from("i,x,y,z,fwd,bwd,dM,cos_n,along,final,final_dist,best_t,best_dist,nx,ny,nz\n");
    let mut sum_final = 0.0;
    let mut sum_best = 0.0;
    for (j, &i) in idx.iter().enumerate() {
        let c = cl[j].unwrap();
        let tri = mesh.triangle(c.triangle as usize);
        let mn = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
        let cosn = mn.dot(dir[j]);
        let along = (c.point - pos[j]).dot(dir[j]);
        let r = 4.0 * c.distance + 2.0 * edge;
        let ts: Vec<f64> = (0..=400).map(|q| -r + 2.0 * r * q as f64 / 400.0).collect();
        let pts: Vec<DVec3> = ts.iter().map(|&t| pos[j] + t * dir[j]).collect();
        let dd = caster.closest_points(&pts, f64::INFINITY)?;
        let (bt, bd) = ts
            .iter()
            .zip(&dd)
            .map(|(&t, c)| (t, c.unwrap().distance))
            .fold((0.0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
        let fd = dcl[j].unwrap().distance;
        sum_final += fd * fd;
        sum_best += bd * bd;
        let f = |h: Option<subdfit::raycast::Hit>| h.map_or(f64::NAN, |h| h.t * k);
        out += &format!(
            "{i},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}\n",
            pos[j].x,
            pos[j].y,
            pos[j].z,
            f(fwd[j]),
            f(bwd[j]),
            c.distance * k,
            cosn,
            along * k,
            d.offsets[i] * k,
            fd * k,
            bt * k,
            bd * k,
            dir[j].x,
            dir[j].y,
            dir[j].z
        );
    }
    let n = idx.len().max(1) as f64;
    println!(
        "unprojectable samples {}: rms dist of displaced point {:.3}‰, best along the line {:.3}‰",
        idx.len(),
        k * (sum_final / n).sqrt(),
        k * (sum_best / n).sqrt()
    );
    if let Some(p) = args.get(3) {
        std::fs::write(p, out)?;
    }
    Ok(())
}
