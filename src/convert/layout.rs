//! The layouts: the control mesh of a conversion, before the tail fits
//! and measures it ([`super::tail`]).
//!
//! - [`Layout::OrganicGreedy`]: the Fitmaps pipeline's layout (§3.1–3.3):
//!   the Fitmap, then the greedy simplification of the quadrangulated
//!   input, on the layout proxy M′ for big inputs (§4).
//! - [`Layout::Mechanical`]: Lavoué et al. 2007's segmentation and
//!   enrichment ([`crate::mechanical`]), which also fits the control mesh
//!   (§7.1's geometry step).
//! - [`Layout::Coarse`]: an input coarser than the Fitmap's radii, its own
//!   faces refined into quads.
//!
//! - [`Layout::OrganicField`]: the same Fitmap, then the field-aligned
//!   layout of [`crate::quad::field`] (`--layout field`): a cross field and
//!   a position field sized by the Fitmap, extracted into a pure-quad mesh
//!   with M's topology. The same tail fits it.

use serde::Serialize;

use crate::analysis::{Fitmap, FitmapOptions};
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, Topology};
use crate::quad::{simplify_prepared, SimplifyOptions, SimplifyStats};
use crate::raycast::{make_raycaster, RayBackend};
use crate::report::StageTimer;

use super::options::{
    adaptive_proxy_triangles, ConvertOptions, Proxy, PROXY_ADAPTIVE_FLOOR,
    PROXY_PATCHES_PER_FM_INTEGRAL, PROXY_PROBE_TRIANGLES,
};
use super::run::Run;
use super::search::ERROR_SEARCH_CHECKPOINTS;

/// Which layout makes the control mesh.
pub enum Layout {
    /// Fitmaps §3.1–3.3 with the Fitmap of `fitmap`; `checkpoints`: keep
    /// the simplification's intermediate meshes for the `--max-error`
    /// search ([`super::search`]).
    OrganicGreedy {
        fitmap: FitmapOptions,
        checkpoints: bool,
    },
    /// The field-aligned layout ([`crate::quad::field::field_layout`])
    /// sized by the Fitmap of `fitmap` (and `--faces` when given).
    OrganicField { fitmap: FitmapOptions },
    /// Lavoué et al. 2007 with these options.
    Mechanical(crate::mechanical::MechanicalOptions),
    /// The input's own faces (no Fitmap: `why`, the error of
    /// [`crate::analysis::fitmap::fitmap_radii`]).
    Coarse { why: Error },
}

/// A layout's control mesh and what made it.
pub struct Laid {
    /// The control mesh: the organic simplification's natural end, the
    /// mechanical mesh (fitted already), or the coarse input refined once.
    pub control: ControlMesh,
    /// Organic with checkpoints: the simplification's intermediate meshes,
    /// fewest faces first (the `--max-error` search's candidates).
    pub checkpoints: Vec<ControlMesh>,
    /// The Fitmap on M's own vertices, when the layout computed one.
    pub fitmap: Option<Fitmap>,
    pub record: LayoutRecord,
}

/// What a layout did, for `report.json`.
pub enum LayoutRecord {
    OrganicGreedy {
        /// `layout_proxy`: the proxy tried and used (see [`Proxy`]).
        proxy: Option<ProxyRecord>,
        simplification: SimplifyStats,
    },
    Mechanical {
        options: crate::mechanical::MechanicalOptions,
        stats: crate::mechanical::MechanicalStats,
    },
    OrganicField {
        /// `layout_proxy`, as for the greedy layout.
        proxy: Option<ProxyRecord>,
        field: crate::quad::field::FieldStats,
        /// The layout mesh and its Fitmap, kept so that `--max-error` can
        /// lay the field out again at another size without a new Fitmap.
        relayout: Box<FieldRelayout>,
    },
    Coarse {
        why: Error,
    },
}

/// What [`Layout::OrganicField`] needs to run the field layout again: the
/// mesh it ran on (M or M′) and the Fitmap on that mesh's vertices.
pub struct FieldRelayout {
    pub mesh: crate::mesh::TriMesh,
    pub fitmap: Fitmap,
    /// The cross field and caster on `mesh`, shared by every relayout.
    pub prepared: crate::quad::field::Prepared,
    /// When `mesh` is M itself renumbered by position (no proxy), a caster
    /// over it: the field's fits then run on it, so that the rounds'
    /// decisions (patches refined at a threshold) do not turn on the float
    /// noise of M's own numbering ([`FieldRelayout::fit_target`]).
    pub fit_caster: Option<Box<dyn crate::raycast::RayCaster>>,
    /// The first layout's other draws (`SUBDFIT_FIELD_THIN_DRAWS`), with
    /// the factor on the sizing each was laid at: each is fitted, given
    /// its own thin round and judged on its final result
    /// ([`super::thin::final_draws`]). Empty without draws.
    pub alternatives: Vec<(f64, crate::mesh::ControlMesh)>,
    /// The factor on the sizing the first layout was laid at (1 without
    /// `SUBDFIT_FIELD_THIN_DRAWS`).
    pub first_scale: f64,
    /// The guarded cancellation of the first layout's own thin round
    /// (`Some(false)`: main's unguarded layout, [`main_candidate`]; `None`:
    /// as the layout options say).
    pub first_guarded: Option<bool>,
    /// The fit that scored the drawn layout of [`main_candidate`] (on M
    /// with the run's caster, no proxy and no renumbering), with its
    /// options and the control mesh it fitted: its carried candidate's
    /// first fit ([`FieldRelayout::scored_fit`]).
    pub scored: Option<ScoredFit>,
}

/// See [`FieldRelayout::scored`]: options, the control mesh fitted, the fit.
pub type ScoredFit = (crate::fit::FitOptions, ControlMesh, crate::fit::Fitted);

/// `SUBDFIT_FIELD_BEST_MAIN`: under `SUBDFIT_FIELD_BEST=1` (on unless `0`),
/// the result of the layout without draws or guard (draw 0, unguarded,
/// with its own fit and thin round: main's) is candidate 0 of the final
/// judgement and the drawn, guarded layout the draws' score ranks first
/// is the alternative ([`super::thin::final_draws`], `Score::Bars` on the
/// final figures, ties to candidate 0). Session 17: the draws' score (a
/// fit to M′) sees neither RMS D nor the final irregular count, and kept
/// gargoyle τ 1 % at 1391 at 1381 / 160 / 1.628‰ / 0.239‰ against
/// main's 1391 / 164 / 1.631‰ / 0.222‰; judged on the final figures
/// against main's own result, the setting never keeps a result the bars
/// score ranks below main's.
pub fn main_candidate() -> bool {
    crate::quad::field::draws::best_enabled()
        && crate::switches::on_off(MAIN_CANDIDATE_ENV).unwrap_or(true)
}

/// See [`main_candidate`].
pub const MAIN_CANDIDATE_ENV: &str = "SUBDFIT_FIELD_BEST_MAIN";

impl FieldRelayout {
    /// The scoring fit of `control` under `fit` ([`FieldRelayout::scored`])
    /// when one was kept: the global fit is a function of the mesh, the
    /// caster, the control mesh and the options, so the carried draw's
    /// first fit on M ([`super::thin::final_draws`]) is the scoring fit bit
    /// for bit (issue 40's speed point, session 21: ~1 s of gargoyle 402).
    /// The control mesh is compared by its bits too (`==` takes −0 for 0).
    pub fn scored_fit(
        &self,
        control: &ControlMesh,
        fit: &crate::fit::FitOptions,
    ) -> Option<crate::fit::Fitted> {
        let (o, c, f) = self.scored.as_ref()?;
        let bits = |k: &ControlMesh| -> Vec<[u64; 3]> {
            k.positions()
                .iter()
                .map(|p| p.to_array().map(f64::to_bits))
                .collect()
        };
        (o == fit && c == control && bits(c) == bits(control)).then(|| f.clone())
    }

    /// The mesh and caster the field layout's fits run on: `mesh` with
    /// [`FieldRelayout::fit_caster`] when it is M renumbered, else M
    /// (`m`, `caster`).
    pub fn fit_target<'a>(
        &'a self,
        m: &'a crate::mesh::TriMesh,
        caster: &'a dyn crate::raycast::RayCaster,
    ) -> (&'a crate::mesh::TriMesh, &'a dyn crate::raycast::RayCaster) {
        match &self.fit_caster {
            Some(c) => (&self.mesh, c.as_ref()),
            None => (m, caster),
        }
    }
}

impl Layout {
    /// Runs the layout on `run`'s input (stages into `run.timer`).
    pub fn lay(self, run: &mut Run<'_, '_>, opts: &ConvertOptions) -> Result<Laid> {
        match self {
            Layout::OrganicGreedy {
                fitmap,
                checkpoints,
            } => organic_greedy(run, opts, &fitmap, checkpoints),
            Layout::OrganicField { fitmap } => organic_field(run, opts, &fitmap),
            Layout::Mechanical(mo) => mechanical(run, mo),
            Layout::Coarse { why } => {
                let mesh = run.mesh();
                if !(mesh.bbox_diagonal().is_finite() && mesh.bbox_diagonal() > 0.0) {
                    return Err(why);
                }
                let control = run.timer.run("control", || coarse_control(mesh))?;
                Ok(Laid {
                    control,
                    checkpoints: Vec::new(),
                    fitmap: None,
                    record: LayoutRecord::Coarse { why },
                })
            }
        }
    }
}

/// The organic layout (Fitmaps §3.1–3.3): the Fitmap and the simplified
/// control mesh, on the layout proxy M′ when there is one (§4; the Fitmap
/// then transferred to M's vertices for fitmap.ply and the pictures), with
/// the proxy's record for the report.
fn organic_greedy(
    run: &mut Run<'_, '_>,
    opts: &ConvertOptions,
    fo: &FitmapOptions,
    checkpoints: bool,
) -> Result<Laid> {
    let mesh = run.mesh();
    let (proxy, proxy_stats) = layout_proxy(mesh, opts.proxy, fo, &mut run.timer, run.progress)?;
    let (layout, layout_caster) = match &proxy {
        Some((m, c)) => (m, c.as_ref()),
        None => (mesh, run.caster.as_ref()),
    };
    let run_caster = run.caster.as_ref();
    let (timer, progress) = (&mut run.timer, &mut *run.progress);
    let stage = crate::fit::report_progress;
    // The quadrangulation and interpolation read M′ only: they run on a
    // thread of their own beside the Fitmap, whose two rayon workers they
    // share the cores with (their ~0.3 s on bunny is mostly sequential, so
    // after the Fitmap it left a core idle). A plain scoped thread, since
    // the Fitmap's progress callback is not `Send`; neither result depends
    // on the other or on the thread count. Their parallel loops run in a
    // one-thread pool of their own: in the global pool they queued behind
    // the Fitmap's jobs, so `seconds_quadrangulate` was about the Fitmap's
    // whole time and the rest of the start (interpolation) ran after it,
    // on the critical path.
    let (fitmap, start) = std::thread::scope(|s| {
        let start = s.spawn(
            || match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
                Ok(pool) => pool.install(|| crate::quad::prepare(layout)),
                // No thread to spare: as before, in the global pool.
                Err(_) => crate::quad::prepare(layout),
            },
        );
        let fitmap = match (&proxy, fitmap_on_m_env()) {
            // §4's split: the Fitmap on M, carried to M′ (diagnostic).
            (Some((m, _)), true) => {
                layout_fitmap(mesh, run_caster, fo, timer, progress).and_then(|on_m| {
                    let on_proxy =
                        timer.run("fitmap transfer", || on_m.transferred(mesh, run_caster, m))?;
                    Ok((on_proxy, Some(on_m)))
                })
            }
            _ => layout_fitmap(layout, layout_caster, fo, timer, progress).map(|f| (f, None)),
        };
        // A panic there is re-raised here, as if it had run inline.
        let start = start
            .join()
            .unwrap_or_else(|e| std::panic::resume_unwind(e));
        (fitmap, start)
    });
    let ((fitmap, fitmap_m), start) = (fitmap?, start?);
    let so = SimplifyOptions::default()
        .with_target_faces(opts.target_faces)
        .with_m_fitmap(!opts.no_m_fitmap)
        .with_checkpoints(if checkpoints {
            ERROR_SEARCH_CHECKPOINTS
        } else {
            0
        });
    stage(progress, "simplify", 0.0)?;
    let simplified = timer.run("simplify", || {
        simplify_prepared(layout, &fitmap, layout_caster, &so, start, &mut |p| {
            let goal = p
                .initial_faces
                .saturating_sub(opts.target_faces.unwrap_or(0))
                .max(1);
            let done = p.initial_faces.saturating_sub(p.faces) as f64 / goal as f64;
            progress("simplify", done.min(0.99))
        })
    })?;
    stage(progress, "simplify", 1.0)?;
    let fitmap = match fitmap_m {
        Some(f) => f,
        None => fitmap_on_m(&proxy, fitmap, mesh, timer)?,
    };
    Ok(Laid {
        control: simplified.mesh,
        checkpoints: simplified.checkpoints,
        fitmap: Some(fitmap),
        record: LayoutRecord::OrganicGreedy {
            proxy: proxy_stats,
            simplification: simplified.stats,
        },
    })
}

/// The field-aligned organic layout: the layout proxy and the Fitmap as in
/// [`organic_greedy`], then [`crate::quad::field::field_layout`] on the
/// same mesh, aiming at `--faces` when given (the sizing field's scale is
/// set before meshing, issue 40), else at the sizes the Fitmap's tests
/// accept.
fn organic_field(run: &mut Run<'_, '_>, opts: &ConvertOptions, fo: &FitmapOptions) -> Result<Laid> {
    let mesh = run.mesh();
    // With `SUBDFIT_FIELD_ORDER` set, the layout side (proxy, Fitmap,
    // field) runs on M renumbered by position (issue 40 item 4): the
    // Fitmap's seeds and random streams go by vertex index, and spot
    // renumbered laid 188 → 239 patches at the defaults through a Fitmap
    // that differed on every vertex. Off by default (session 13): the
    // fixed order is one more draw of the lattice, and on the shared
    // meshes it drew worse (homer 318 → 499 patches, bunny 409 → 652,
    // gargoyle τ 1 % RMS D ×3.5; docs/status.md "Field-aligned layout").
    let canonical = crate::quad::field::parts::Order::from_env()
        .map(|o| crate::quad::field::parts::canonical_mesh_in(mesh, o));
    let canon = canonical.as_ref().map_or(mesh, |c| &c.0);
    let (proxy, proxy_stats) = layout_proxy(canon, opts.proxy, fo, &mut run.timer, run.progress)?;
    let canon_caster = match (&proxy, &canonical) {
        (None, Some(_)) => Some(make_raycaster(RayBackend::Embree, canon)?),
        _ => None,
    };
    let (layout, layout_caster) = match (&proxy, &canon_caster) {
        (Some((m, c)), _) => (m, c.as_ref()),
        (None, Some(c)) => (canon, c.as_ref()),
        (None, None) => (mesh, run.caster.as_ref()),
    };
    let (timer, progress) = (&mut run.timer, &mut *run.progress);
    let stage = crate::fit::report_progress;
    let fitmap = layout_fitmap(layout, layout_caster, fo, timer, progress)?;
    let field_opts =
        crate::quad::field::FieldOptions::for_convert(opts.target_faces, opts.field_adapt);
    stage(progress, "field layout", 0.0)?;
    // Best of `SUBDFIT_FIELD_DRAWS` lattices (one unless set), ranked by
    // [`super::field::draw_score`], at a face target only: at the natural
    // size the draws' counts differ, the score prefers the finer one, and
    // the `--max-error` rounds lay the field out again anyway (session 14,
    // homer defaults 318 → 421 patches, cheburashka RMS D 0.35 → 0.79‰).
    let draw_set = match opts.target_faces {
        Some(_) => crate::quad::field::draws::first_draws_from_env(),
        None => vec![0],
    };
    let draws = draw_set.len();
    // With `SUBDFIT_FIELD_THIN_DRAWS=K` (session 15, face target only),
    // every draw the guard leaves is carried on: the first is laid out as
    // the layout, the others as `alternatives`, each judged on its final
    // result after its own fit and thin round ([`super::thin::final_draws`]).
    let final_draws = match opts.target_faces {
        Some(_) => crate::quad::field::draws::thin_draws_from_env(),
        None => 1,
    };
    let fit_opts = super::field::field_fit_options(opts.objective);
    // On M itself (no proxy, no renumbering), the draws' scoring fits are
    // the fits `super::thin::final_draws` gives the drawn candidate
    // ([`FieldRelayout::scored_fit`]): kept until the choice.
    let keep_fits = proxy.is_none() && canon_caster.is_none();
    let fits: std::sync::Mutex<Vec<(ControlMesh, crate::fit::Fitted)>> = Default::default();
    let (laid, prepared, alternatives) = timer.run("field layout", || {
        let prep = crate::quad::field::Prepared::new(layout, &field_opts)?;
        if final_draws > 1 {
            let all = crate::quad::field::field_layout_draws(
                &prep,
                layout,
                &fitmap,
                &field_opts,
                final_draws,
            )?;
            let scale = |i: usize| crate::quad::field::draws::SCALES[i];
            let mut all = all.into_iter();
            let (i, laid) = all.next().expect("at least one eligible draw");
            let alternatives = all.map(|(i, l)| (scale(i), l.control)).collect();
            return Ok((laid, prep, (scale(i), alternatives)));
        }
        let score = |l: &crate::quad::field::FieldLayout| {
            let (s, fitted) = super::field::draw_score_fitted(layout, layout_caster, &fit_opts, l)?;
            if let Some(f) = fitted.filter(|_| keep_fits) {
                let mut fits = fits.lock().unwrap_or_else(|e| e.into_inner());
                fits.push((l.control.clone(), f));
            }
            Ok(s)
        };
        // Main's layout (draw 0 unguarded, [`main_candidate`]) is laid
        // beside the draws and their scores: neither reads the other.
        let fo_main = (draws > 1 && main_candidate()).then(|| crate::quad::field::FieldOptions {
            cleanup_guarded: Some(false),
            ..field_opts.clone()
        });
        // One sizing for both ([`crate::quad::field::field_layout_drawn_with_main`]).
        let (laid, main) = crate::quad::field::field_layout_drawn_at_with_main(
            &prep,
            layout,
            &fitmap,
            &field_opts,
            fo_main.as_ref(),
            &draw_set,
            score,
        )?;
        if let Some(main) = main {
            // Main's layout first, the drawn one as the alternative
            // ([`main_candidate`]).
            let mut main = main?;
            let scale = laid
                .stats
                .draws
                .as_ref()
                .map_or(1.0, |d| crate::quad::field::draws::SCALES[d.chosen]);
            main.stats.draws = laid.stats.draws.clone();
            return Ok((main, prep, (1.0, vec![(scale, laid.control)])));
        }
        Ok((laid, prep, (1.0, Vec::new())))
    })?;
    let first_guarded = (!alternatives.1.is_empty() && final_draws == 1).then_some(false);
    // The drawn candidate's scoring fit (main's branch above: one
    // alternative, the chosen draw).
    let fits = fits.into_inner().unwrap_or_else(|e| e.into_inner());
    let scored = match (first_guarded, alternatives.1.as_slice()) {
        (Some(_), [(_, drawn)]) => fits
            .into_iter()
            .find(|(c, _)| c == drawn)
            .map(|(c, f)| (fit_opts.clone(), c, f)),
        _ => None,
    };
    stage(progress, "field layout", 1.0)?;
    let on_canon = fitmap_on_m(&proxy, fitmap.clone(), canon, timer)?;
    let on_m = match &canonical {
        Some((_, order)) => {
            let mut back = vec![0u32; order.len()];
            for (i, &v) in order.iter().enumerate() {
                back[v as usize] = i as u32;
            }
            on_canon.permuted(&back)
        }
        None => on_canon,
    };
    Ok(Laid {
        control: laid.control,
        checkpoints: Vec::new(),
        fitmap: Some(on_m),
        record: LayoutRecord::OrganicField {
            proxy: proxy_stats,
            field: laid.stats,
            relayout: Box::new(FieldRelayout {
                mesh: layout.clone(),
                fitmap,
                prepared,
                fit_caster: canon_caster,
                first_scale: alternatives.0,
                first_guarded,
                alternatives: alternatives.1,
                scored,
            }),
        },
    })
}

/// `SUBDFIT_PROXY_FITMAP_ON_M=1`: with a layout proxy, compute the Fitmap
/// on M and carry it to M′ (Fitmaps §4: "all computation, including
/// fitting and mapping, is referred to the original mesh M"), so that only
/// the quadrangulation and simplification run on M′. A measuring switch.
fn fitmap_on_m_env() -> bool {
    crate::switches::on("SUBDFIT_PROXY_FITMAP_ON_M")
}

/// The Fitmap (§3.1) of the mesh the organic layouts run on (M or M′), as
/// the `"fitmap"` stage.
fn layout_fitmap(
    layout: &crate::mesh::TriMesh,
    caster: &dyn crate::raycast::RayCaster,
    fo: &FitmapOptions,
    timer: &mut StageTimer,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Fitmap> {
    let stage = crate::fit::report_progress;
    stage(progress, "fitmap", 0.0)?;
    let fitmap = timer.run("fitmap", || {
        fitmap_reporting(layout, caster, fo, &mut *progress)
    })?;
    stage(progress, "fitmap", 1.0)?;
    Ok(fitmap)
}

/// `fitmap` (on the layout mesh) on M's own vertices, which fitmap.ply and
/// the pictures show: carried over from M′ when the layout ran there.
fn fitmap_on_m(
    proxy: &Option<LayoutProxy>,
    fitmap: Fitmap,
    mesh: &crate::mesh::TriMesh,
    timer: &mut StageTimer,
) -> Result<Fitmap> {
    match proxy {
        Some((m, c)) => timer.run("fitmap transfer", || {
            fitmap.transferred(m, c.as_ref(), mesh)
        }),
        None => Ok(fitmap),
    }
}

/// The mechanical layout (Lavoué et al. 2007, see [`crate::mechanical`]):
/// segmentation, enrichment and its own fit (§7.1's geometry step).
fn mechanical(run: &mut Run<'_, '_>, mo: crate::mechanical::MechanicalOptions) -> Result<Laid> {
    let (mesh, caster) = (run.mesh(), run.caster.as_ref());
    crate::fit::report_progress(run.progress, "mechanical", 0.0)?;
    let built = run.timer.run("mechanical", || {
        crate::mechanical::build_control(mesh, caster, &mo)
    })?;
    crate::fit::report_progress(run.progress, "mechanical", 1.0)?;
    Ok(Laid {
        control: built.control,
        checkpoints: Vec::new(),
        fitmap: None,
        record: LayoutRecord::Mechanical {
            options: mo,
            stats: built.stats,
        },
    })
}

/// The layout proxy M′ for `proxy` (see [`Proxy`]) with an Embree caster
/// over it, or `None` when the layout runs on M; and what was done, for
/// the report. M′ is used only when it has M's [`Topology`] (components,
/// boundary loops, Euler characteristic): the control mesh inherits the
/// layout mesh's topology, so a decimation that closed a handle or pinched
/// a part off would give a wrong surface, not just a coarser one. A failed
/// check retries at twice the triangles, up to [`PROXY_ATTEMPTS`] times,
/// then falls back to M (the report says why). [`Proxy::Adaptive`] then
/// sizes M′ by the output ([`adaptive_size`], with `fo`'s τ), decimating
/// the first M′ (inputs above `auto`'s bound) or M.
pub(super) fn layout_proxy(
    mesh: &crate::mesh::TriMesh,
    proxy: Proxy,
    fo: &FitmapOptions,
    timer: &mut StageTimer,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<(Option<LayoutProxy>, Option<ProxyRecord>)> {
    let adaptive = proxy == Proxy::Adaptive;
    let first = proxy.target(mesh.triangles.len());
    if first.is_none() && !adaptive {
        return Ok((None, None));
    }
    crate::fit::report_progress(progress, "proxy", 0.0)?;
    let found = timer.run("proxy", || -> Result<_> {
        let want = Topology::of(mesh);
        let mut tried = Vec::new();
        let mut m = match first {
            Some(t) => decimate_keeping(mesh, t, want, &mut tried)?,
            None => None,
        };
        let mut sizing = None;
        if adaptive {
            let base = m.as_ref().map_or(mesh, |(b, _)| b);
            let (target, record) = adaptive_size(base, fo, want)?;
            if let Some(t) = target {
                if let Some(smaller) = decimate_keeping(base, t, want, &mut tried)? {
                    m = Some(smaller);
                }
            }
            sizing = Some(record);
        }
        Ok((m, tried, want, sizing))
    })?;
    crate::fit::report_progress(progress, "proxy", 1.0)?;
    let (m, tried, want, adaptive) = found;
    let record = ProxyRecord {
        used: m.is_some(),
        input_triangles: mesh.triangles.len(),
        input_topology: want,
        attempts: tried,
        adaptive,
    };
    Ok((m, Some(record)))
}

/// A decimation of `base` to about `triangles` with the topology `want`
/// (retried at twice the triangles up to [`PROXY_ATTEMPTS`] times, never
/// above half of `base`), each attempt pushed onto `tried`; `None` when
/// none kept it.
fn decimate_keeping(
    base: &crate::mesh::TriMesh,
    mut triangles: usize,
    want: Topology,
    tried: &mut Vec<ProxyAttempt>,
) -> Result<Option<LayoutProxy>> {
    for _ in 0..PROXY_ATTEMPTS {
        if triangles.saturating_mul(2) > base.triangles.len() {
            break;
        }
        let (m, stats) = crate::mesh::decimate(base, triangles)?;
        let got = Topology::of(&m);
        tried.push(ProxyAttempt {
            target_triangles: triangles,
            triangles: m.triangles.len(),
            topology: got,
            decimation: stats,
        });
        if got == want {
            let c = make_raycaster(RayBackend::Embree, &m)?;
            return Ok(Some((m, c)));
        }
        triangles *= 2;
    }
    Ok(None)
}

/// [`Proxy::Adaptive`]'s size of M′ for the layout mesh `base` (M, or the
/// first M′ of a big input), or `None` when the layout should run on
/// `base` itself.
///
/// Fitmaps §4 lays out on a simplified M′ because the layout needs far
/// fewer vertices than M has; what it needs grows with the *output*
/// (dozens of M′ vertices per patch), not with M. The patch count is
/// predicted before the layout from a probe, a [`PROXY_PROBE_TRIANGLES`]
/// decimation with `base`'s topology, and the Fitmap on it at `fo`'s τ:
/// the radius field F_M asks for ∝ ∫ F_M⁻² dA patches (the count
/// [`crate::quad::s_fitmap_kappa`] equates the S-fitmap test's with). M′
/// gets [`super::options::PROXY_TRIANGLES_PER_PATCH`] triangles per predicted patch
/// ([`adaptive_proxy_triangles`]); when that is more than half of `base`
/// (a detailed surface whose patches already see only dozens of its
/// vertices, gargoyle) the layout stays on `base`, as it does when no
/// probe keeps the topology. Inputs under twice [`PROXY_ADAPTIVE_FLOOR`]
/// triangles are not probed.
fn adaptive_size(
    base: &crate::mesh::TriMesh,
    fo: &FitmapOptions,
    want: Topology,
) -> Result<(Option<usize>, AdaptiveRecord)> {
    let mut record = AdaptiveRecord::default();
    if base.triangles.len() < 2 * PROXY_ADAPTIVE_FLOOR {
        return Ok((None, record));
    }
    let Some((probe, caster)) =
        decimate_keeping(base, PROXY_PROBE_TRIANGLES, want, &mut record.probe)?
    else {
        return Ok((None, record));
    };
    let fitmap = crate::analysis::compute_fitmap(&probe, caster.as_ref(), fo)?;
    record.fm_integral = fm_patch_integral(&probe, &fitmap);
    record.predicted_patches = PROXY_PATCHES_PER_FM_INTEGRAL * record.fm_integral;
    let target = adaptive_proxy_triangles(record.fm_integral);
    record.target_triangles = target;
    let fits = target.saturating_mul(2) <= base.triangles.len();
    Ok((fits.then_some(target), record))
}

/// [`Proxy::Adaptive`]'s decision for a layout on `mesh` at `fo`'s τ (the
/// probe, its prediction and the M′ size, `None` when the layout would
/// stay on `mesh`); what [`layout_proxy`] does before decimating M′.
pub fn adaptive_proxy_size(
    mesh: &crate::mesh::TriMesh,
    fo: &FitmapOptions,
) -> Result<(Option<usize>, AdaptiveRecord)> {
    adaptive_size(mesh, fo, Topology::of(mesh))
}

/// `∫ F_M⁻² dA` over `mesh` (vertex areas a third of the incident
/// triangles', vertices without a positive finite F_M left out): ∝ the
/// patch count of the radius field F_M, see [`adaptive_size`].
pub fn fm_patch_integral(mesh: &crate::mesh::TriMesh, fitmap: &Fitmap) -> f64 {
    let areas = crate::analysis::normals::triangle_areas(mesh);
    let mut va = vec![0.0; mesh.positions.len()];
    for (t, a) in mesh.triangles.iter().zip(&areas) {
        for &v in t {
            va[v as usize] += a / 3.0;
        }
    }
    va.iter()
        .zip(&fitmap.m)
        .filter(|(_, &m)| m > 0.0 && m.is_finite())
        .map(|(&a, &m)| a / (m * m))
        .sum()
}

/// What [`adaptive_size`] measured (`report.json`'s
/// `layout_proxy.adaptive`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct AdaptiveRecord {
    /// The probe's decimations (empty: the input was under twice the floor).
    pub probe: Vec<ProxyAttempt>,
    /// `∫ F_M⁻² dA` over the probe (scale-invariant).
    pub fm_integral: f64,
    pub predicted_patches: f64,
    /// The M′ size asked for (0: no probe); used when at most half of the
    /// layout mesh.
    pub target_triangles: usize,
}

/// What [`layout_proxy`] tried (`report.json`'s `layout_proxy`, and `fit`'s
/// `fitmap_proxy`).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct ProxyRecord {
    /// Whether the layout ran on M′ (one attempt kept M's topology).
    pub used: bool,
    pub input_triangles: usize,
    pub input_topology: Topology,
    pub attempts: Vec<ProxyAttempt>,
    /// [`Proxy::Adaptive`]'s probe and the size it chose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<AdaptiveRecord>,
}

/// One decimation [`layout_proxy`] tried.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct ProxyAttempt {
    pub target_triangles: usize,
    pub triangles: usize,
    pub topology: Topology,
    pub decimation: crate::mesh::DecimateStats,
}

/// The host-surface least-squares rounds of the displacement
/// ([`crate::report::MetricsOptions::host_lsq_rounds`]) for a greedy
/// layout with this proxy record: one when [`Proxy::Adaptive`] laid out on
/// an M′, else the report's default (`None`).
///
/// Why (session 15, issue 39): on the adaptive M′ the first round's
/// update is kept (bunny defaults: 0.2595 → 0.2387‰ on its objective),
/// so the default's second round runs in full and then its check round
/// rejects its step and all three halvings (0.2792, 0.2597, 0.2461,
/// 0.2376‰ against 0.2368‰) and undoes it: bunny's displacement+metrics
/// took 3.47 CPU s against 1.82 with one round, for the same bytes. On M
/// the first round's step is already rejected (bunny defaults), so only
/// the adaptive M′ pays for the idle round. Bunny τ 1 % at one round:
/// RMS D 0.454 → 0.450‰, 3.05 → 2.37 CPU s. Gargoyle, which the rule
/// keeps on M, keeps the default (its τ 1 % gains from the second round,
/// `report`'s `HOST_LSQ_ROUNDS`).
pub fn adaptive_lsq_rounds(proxy: Option<&ProxyRecord>) -> Option<usize> {
    proxy
        .filter(|p| p.used && p.adaptive.is_some())
        .map(|_| ADAPTIVE_PROXY_LSQ_ROUNDS)
}

/// [`adaptive_lsq_rounds`]'s rounds on an adaptive M′.
const ADAPTIVE_PROXY_LSQ_ROUNDS: usize = 1;

/// M′ and a ray caster over it.
type LayoutProxy = (crate::mesh::TriMesh, Box<dyn crate::raycast::RayCaster>);

/// Decimations tried for a layout proxy with M's topology (targets 1×, 2×,
/// 4× the bound) before the layout runs on M.
const PROXY_ATTEMPTS: usize = 3;

/// [`Layout::Coarse`]'s control mesh: M's triangles with its sharp edges
/// as infinitely sharp creases and the vertices where three or more meet
/// as corners (so a tetrahedron or a box is reproduced exactly: each face's
/// limit patch is the planar face), refined once into quads.
fn coarse_control(mesh: &crate::mesh::TriMesh) -> Result<crate::mesh::ControlMesh> {
    use crate::mesh::{ControlMesh, VertexId, INFINITELY_SHARP};
    let mut base = ControlMesh::from_polygons(mesh.positions.clone(), &mesh.triangles)?;
    let topo = crate::mechanical::Topology::new(mesh);
    let mut sharp_degree = vec![0u32; mesh.positions.len()];
    for (e, sharp) in topo.edges.iter().zip(topo.sharp_edges()) {
        if sharp {
            base.set_crease(VertexId(e.v[0]), VertexId(e.v[1]), INFINITELY_SHARP)?;
            for v in e.v {
                sharp_degree[v as usize] += 1;
            }
        }
    }
    for (v, &d) in sharp_degree.iter().enumerate() {
        if d >= 3 {
            base.set_corner(VertexId(v as u32), INFINITELY_SHARP)?;
        }
    }
    crate::subdiv::refine::refine_once_keeping_infinite(&base)
}

/// The Fitmap (§3.1) with progress and cancellation, watched
/// ([`crate::watch::watched`]): the workers count their analysed vertices
/// and stop within one vertex each once the host said stop.
pub(super) fn fitmap_reporting(
    mesh: &crate::mesh::TriMesh,
    caster: &dyn crate::raycast::RayCaster,
    fo: &FitmapOptions,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<crate::analysis::Fitmap> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let done = AtomicUsize::new(0);
    let total = mesh.positions.len().max(1) as f64;
    crate::watch::watched(progress, |w| {
        w.report("fitmap", 0.0)?;
        crate::analysis::compute_fitmap_cancellable(mesh, caster, fo, &|k| {
            let d = done.fetch_add(k, Ordering::Relaxed) + k;
            w.report("fitmap", (d as f64 / total).min(0.99)).is_ok()
        })
    })
}
