//! The exact mode of the Fitmap ([`super::FitmapOptions::exact`]):
//! Fitmaps §3.1.2–3.1.3 taken literally, one breadth-first ball per
//! radius, every vertex of the ball in the cubic fit and every M-test
//! sample of the ball cast. The reference the fast mode is measured
//! against, and the decision the fast mode's certification takes.

use super::*;

/// The ball of radius `radii[i]` around `p` exactly as §3.1.2–3.1.3 define
/// it (the literal traversal [`bfs_ball`], every vertex in the fit, in
/// traversal order): its cubic, RMS residual and triangles (all three
/// vertices inside), or `None` when the exact mode does not test this
/// radius (fewer than [`MIN_FIT_POINTS`] vertices or no well-posed cubic).
/// The first value says whether a fit was attempted. The exact mode is
/// built on it, and the fast mode's certification
/// ([`FitmapOptions::certify`]) calls it to take one decision exactly as
/// the exact mode takes it.
#[allow(clippy::type_complexity)]
pub(super) fn exact_ball(
    ctx: &Ctx,
    sc: &mut Scratch,
    p: u32,
    frame: &Frame,
    i: usize,
) -> (bool, Option<(Cubic, f64, Vec<u32>)>) {
    let r = ctx.radii[i];
    let stamp = sc.next_stamp();
    let mut ball = std::mem::take(&mut sc.ball);
    bfs_ball(
        &ctx.adj.vv,
        &ctx.mesh.positions,
        p,
        r,
        &mut sc.mark,
        stamp,
        &mut ball,
    );
    sc.pts.clear();
    sc.pts.extend(
        ball.iter()
            .map(|&v| frame.to_local(ctx.mesh.positions[v as usize])),
    );
    let fitted = ball.len() >= MIN_FIT_POINTS;
    let fit = if fitted {
        fit_cubic(&sc.pts, None, r)
    } else {
        None
    };
    let out = fit.map(|CubicFit { cubic, rms }| {
        let mut tris = Vec::new();
        for &v in &ball {
            for &t in ctx.adj.vt.row(v as usize) {
                if sc.tmark[t as usize] != stamp
                    && ctx.mesh.triangles[t as usize]
                        .iter()
                        .all(|&w| sc.mark[w as usize] == stamp)
                {
                    sc.tmark[t as usize] = stamp;
                    tris.push(t);
                }
            }
        }
        (cubic, rms, tris)
    });
    sc.ball = ball;
    (fitted, out)
}

/// The literal flipped fraction of §3.1.3 at every radius `r_0..r_h` for
/// the ball around vertex `v`, exactly as the exact mode computes it
/// (`None` where it tests no cubic). A diagnostic: F_M is the largest
/// radius whose fraction is below τ, so this shows how close to τ the
/// deciding radii of one vertex sit (`fitmap_bench diag` prints it for
/// the vertices where the fast and exact F_M differ by more than a step).
pub fn exact_flip_fractions(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    opts: &FitmapOptions,
    v: u32,
) -> Result<Vec<Option<f64>>> {
    let nv = mesh.positions.len();
    if v as usize >= nv {
        return Err(Error::InvalidArgument(format!(
            "fitmap: vertex {v} out of range ({nv} vertices)"
        )));
    }
    let radii = fitmap_radii(mesh)?;
    let (areas, total_area) = checked_areas(mesh)?;
    let samples = MSamples::new(
        mesh,
        &areas,
        SAMPLES_PER_VERTEX * nv as f64 / total_area,
        opts.seed,
    );
    let ctx = Ctx {
        mesh,
        caster,
        opts,
        areas,
        normals: vertex_normals(mesh),
        adj: Adjacency::new(mesh),
        radii,
        samples,
        level_of: vec![None; RADIUS_STEPS + 1],
        levels: Vec::new(),
        failure: std::sync::Mutex::new(None),
    };
    let n = ctx.normals[v as usize];
    if n == DVec3::ZERO {
        return Ok(vec![None; RADIUS_STEPS + 1]);
    }
    let frame = Frame::from_normal(mesh.positions[v as usize], n);
    let mut sc = Scratch::new(&ctx);
    let mut out = Vec::with_capacity(RADIUS_STEPS + 1);
    for i in 0..=RADIUS_STEPS {
        let (_, ball) = exact_ball(&ctx, &mut sc, v, &frame, i);
        out.push(ball.and_then(|(cubic, _, tris)| {
            flip_fraction_literal(&ctx, &frame, &cubic, ctx.radii[i], &tris, None).0
        }));
    }
    if let Some(e) = ctx.failure.lock().unwrap_or_else(|p| p.into_inner()).take() {
        return Err(e);
    }
    Ok(out)
}

pub(super) fn analyse_vertex_exact(ctx: &Ctx, sc: &mut Scratch, p: u32) -> VertexResult {
    let h = RADIUS_STEPS;
    let mut res = VertexResult {
        m_step: h as u8,
        ..Default::default()
    };
    let n = ctx.normals[p as usize];
    if n == DVec3::ZERO {
        return res;
    }
    let frame = Frame::from_normal(ctx.mesh.positions[p as usize], n);
    let mut errors = Vec::with_capacity(h + 1);
    // Per tested radius: its cubic and the triangles of its ball.
    let mut balls: Vec<Option<(Cubic, Vec<u32>)>> = vec![None; h + 1];
    let mut tested = Vec::with_capacity(h + 1);
    for (i, slot) in balls.iter_mut().enumerate() {
        let (fitted, ball) = exact_ball(ctx, sc, p, &frame, i);
        res.fits += fitted as u64;
        if let Some((cubic, rms, tris)) = ball {
            errors.push((ctx.radii[i], rms));
            *slot = Some((cubic, tris));
            tested.push(i);
        }
    }
    let mut rays = 0;
    m_from_top_down(&mut res, &tested, |i| {
        let (cubic, tris) = balls[i].as_ref()?;
        let (pass, k) = flip_passes_literal(
            ctx,
            &frame,
            cubic,
            ctx.radii[i],
            tris,
            None,
            ctx.opts.tolerance,
        );
        rays += k;
        pass
    });
    res.rays = rays;
    res.defined = !errors.is_empty();
    res.s = s_from_errors(&errors);
    res
}
