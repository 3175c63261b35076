//! Where RMS D's squared error lies by patch (issue 40, gargoyle at the
//! peers' counts): per patch of a pure-quad control mesh, its share of
//! D's squared error in both directions, binned by tile resolution,
//! patch area, irregular corners, ring distance to an irregular vertex
//! and unprojectable samples.
//!
//! `cargo run --release --example d_patches -- MESH CONTROL.obj [DUMP.csv]`

use std::collections::{BTreeMap, VecDeque};
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::report::{evaluate_surfaces, quadrature_points, MetricsOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() >= 3, "usage: d_patches MESH CONTROL.obj [DUMP]");
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    let control = subdfit::io::read_control_mesh(args[2].as_ref())?;
    let mesh = &input.mesh;
    let diag = mesh.bbox_diagonal();
    let caster = make_raycaster(RayBackend::Embree, mesh)?;
    let opts = MetricsOptions::default();
    let s = evaluate_surfaces(mesh, &control, caster.as_ref(), &opts, &mut |_, _| true)?;
    let d = &s.displacement;
    let np = d.grid.num_patches();
    anyhow::ensure!(np == control.num_faces(), "not a pure-quad control mesh");
    println!(
        "D {:.4} (D->M {:.4}, M->D {:.4}) L {:.4} samples {} unproj {}",
        s.metrics.displaced.rms_permille,
        s.metrics.displaced.surface_to_mesh.rms_permille,
        s.metrics.displaced.mesh_to_surface.rms_permille,
        s.metrics.limit.rms_permille,
        d.limit.len(),
        d.stats.unprojectable
    );
    let per = s.displaced.triangles.len() / np;
    // M -> D by the patch of the closest displaced triangle.
    let (mp, mw) = quadrature_points(mesh);
    let dc = make_raycaster(RayBackend::Embree, &s.displaced)?;
    let hits = dc.closest_points(&mp, f64::INFINITY)?;
    if let Ok(path) = std::env::var("D_POINTS") {
        // Per quadrature point of M: weight and distance to D (f64 pairs).
        let mut b = Vec::with_capacity(16 * mw.len());
        for (h, w) in hits.iter().zip(&mw) {
            b.extend_from_slice(&w.to_le_bytes());
            b.extend_from_slice(&h.as_ref().map_or(f64::NAN, |h| h.distance).to_le_bytes());
        }
        std::fs::write(path, b)?;
    }
    let (mut m2d, mut marea) = (vec![0.0; np], vec![0.0; np]);
    for (h, w) in hits.iter().zip(&mw) {
        let Some(h) = h else { continue };
        let f = (h.triangle as usize / per).min(np - 1);
        m2d[f] += w * h.distance * h.distance;
        marea[f] += w;
    }
    // D -> M by the quadrature points of each patch's displaced triangles.
    let (dp, dw) = quadrature_points(&s.displaced);
    let dh = caster.closest_points(&dp, f64::INFINITY)?;
    let (mut d2m, mut darea) = (vec![0.0; np], vec![0.0; np]);
    for (k, (h, w)) in dh.iter().zip(&dw).enumerate() {
        let Some(h) = h else { continue };
        let f = (k / 3 / per).min(np - 1);
        d2m[f] += w * h.distance * h.distance;
        darea[f] += w;
    }
    // Ring distance (in faces) to the nearest face with an irregular corner.
    let irr_v: Vec<bool> = control
        .vertices()
        .map(|v| control.valence(v) != 4 && !control.is_boundary_vertex(v))
        .collect();
    let faces: Vec<_> = control.faces().collect();
    let nirr: Vec<usize> = faces
        .iter()
        .map(|&f| control.face_vertices(f).filter(|v| irr_v[v.idx()]).count())
        .collect();
    let mut ring = vec![usize::MAX; np];
    let mut q = VecDeque::new();
    for f in 0..np {
        if nirr[f] > 0 {
            ring[f] = 0;
            q.push_back(f);
        }
    }
    while let Some(f) = q.pop_front() {
        for v in control.face_vertices(faces[f]) {
            for g in control.vertex_faces(v) {
                if ring[g.idx()] == usize::MAX {
                    ring[g.idx()] = ring[f] + 1;
                    q.push_back(g.idx());
                }
            }
        }
    }
    let unp: Vec<usize> = (0..np)
        .map(|f| {
            let r = d.grid.patch_res(f);
            (0..r * r)
                .filter(|k| !d.projected[d.grid.sample(f, k % r, k / r) as usize])
                .count()
        })
        .collect();
    let (tm, td) = (m2d.iter().sum::<f64>(), d2m.iter().sum::<f64>());
    let wd: f64 = darea.iter().sum();
    let pm = 1000.0 / diag;
    let mut med: Vec<f64> = darea.clone();
    med.sort_by(f64::total_cmp);
    let med = med[np / 2];
    let table = |name: &str, key: &dyn Fn(usize) -> String| {
        let mut b: BTreeMap<String, [f64; 5]> = BTreeMap::new();
        for f in 0..np {
            let e = b.entry(key(f)).or_default();
            e[0] += 1.0;
            e[1] += darea[f];
            e[2] += d2m[f];
            e[3] += m2d[f];
            e[4] += marea[f];
        }
        println!("-- by {name}: n / area% / D->M err% rms / M->D err% rms");
        for (k, e) in b {
            println!(
                "  {k:>10} {:5} {:6.2}% {:6.2}% {:.4} {:6.2}% {:.4}",
                e[0],
                100.0 * e[1] / wd,
                100.0 * e[2] / td,
                pm * (e[2] / e[1].max(1e-300)).sqrt(),
                100.0 * e[3] / tm,
                pm * (e[3] / e[4].max(1e-300)).sqrt()
            );
        }
    };
    table("tile res", &|f| format!("{:02}", d.grid.patch_res(f)));
    table("irregular corners", &|f| nirr[f].to_string());
    table("ring to irregular", &|f| ring[f].min(4).to_string());
    table("area / median", &|f| {
        let r = darea[f] / med;
        (if r < 0.5 {
            "a<0.5"
        } else if r < 1.0 {
            "b<1"
        } else if r < 2.0 {
            "c<2"
        } else if r < 4.0 {
            "d<4"
        } else {
            "e>=4"
        })
        .to_string()
    });
    table("unproj samples", &|f| unp[f].min(3).to_string());
    table("samples/area (x median)", &|f| {
        let r = d.grid.patch_res(f) as f64;
        let dens = r * r / darea[f].max(1e-300);
        let mut v: Vec<f64> = (0..np)
            .map(|g| (d.grid.patch_res(g) as f64).powi(2) / darea[g].max(1e-300))
            .collect();
        v.sort_by(f64::total_cmp);
        let r = dens / v[np / 2];
        format!("{:.2}", 2f64.powf((r.log2() * 2.0).round() / 2.0))
    });
    let mut order: Vec<usize> = (0..np).collect();
    order.sort_by(|&a, &b| (d2m[b] + m2d[b]).total_cmp(&(d2m[a] + m2d[a])));
    let mut cum = 0.0;
    for (i, &f) in order.iter().enumerate() {
        cum += d2m[f] / td + m2d[f] / tm;
        if [4, 9, 19, 49, 99, 199].contains(&i) {
            println!(
                "top {} patches hold {:.1}% (avg of both shares)",
                i + 1,
                50.0 * cum
            );
        }
    }
    for &f in order.iter().take(10) {
        println!(
            "patch {f}: res {} area/med {:.2} D->M {:.1}% rms {:.3} M->D {:.1}% irr {} ring {} unp {}",
            d.grid.patch_res(f),
            darea[f] / med,
            100.0 * d2m[f] / td,
            pm * (d2m[f] / darea[f]).sqrt(),
            100.0 * m2d[f] / tm,
            nirr[f],
            ring[f],
            unp[f]
        );
    }
    if let Some(path) = args.get(3) {
        let mut out = String::from("patch,res,area,d2m,m2d,marea,nirr,ring,unp\n");
        for f in 0..np {
            out += &format!(
                "{f},{},{},{},{},{},{},{},{}\n",
                d.grid.patch_res(f),
                darea[f],
                d2m[f],
                m2d[f],
                marea[f],
                nirr[f],
                ring[f],
                unp[f]
            );
        }
        std::fs::write(path, out)?;
    }
    Ok(())
}
