//! The experiment switches: the `SUBDFIT_*` environment variables (and
//! the field layout's older `FIELD_*` ones), read here only.
//!
//! Each turns on a variant that was measured and left off by default (the
//! session that measured it is in docs/status.md), sets a constant of one
//! for a measurement, or asks for a trace on stderr. None is an option of
//! the product: without them every command does what its flags say, and
//! the outputs do not depend on them unless one is set. The crate reads
//! them only through the functions below, so that one value reads the
//! same way everywhere: white space around a value is ignored, and a
//! value that does not parse is as if the switch were unset.
//!
//! | switch | read by | what |
//! |---|---|---|
//! | `SUBDFIT_THIN_ROUND` | `convert::thin` | `0` turns the thin second round off, `1` on (on by default) |
//! | `SUBDFIT_THIN_SHARE`, `_DFACTOR`, `_DROUNDS`, `_LCAP`, `_LCAP_REAL`, `_TOP_SHARE` | `convert::thin` | its constants |
//! | `SUBDFIT_THIN_JUDGE` | `convert::thin` | what the chain's rounds are judged by (`mprime`, `m`, `displaced`) |
//! | `SUBDFIT_THIN_SPLIT` | `convert::thin` | `1`: the split round |
//! | `SUBDFIT_FIELD_THIN_DRAWS`, `SUBDFIT_FIELD_THIN_RELAYOUT_DRAWS` | `quad::field::draws` | draws of the final result and of the thin round's re-layouts |
//! | `SUBDFIT_FIELD_THIN_GUARD_KEPT` | `convert::thin` | `1`: the guarded cancellation on the kept draw |
//! | `SUBDFIT_FIELD_DRAWS` | `quad::field::draws` | draws of the first layout |
//! | `SUBDFIT_FIELD_DRAW_SCORE` | `convert::field` | what the first layout's draws are ranked by (`irr`, `fit`, `unproj`) |
//! | `SUBDFIT_FIELD_DRAW_LOG` | `convert::field`, `convert::thin` | each draw's figures on stderr |
//! | `SUBDFIT_FIELD_BRACKET` | `convert::field` | `0` turns the bracket off, `1` on (on by default) |
//! | `SUBDFIT_FIELD_NEAR_D` | `convert::field` | with `SUBDFIT_FIELD_ADAPT=1`, the share of RMS L a near miss's RMS D may reach to be judged on M (`NEAR_D_SHARE`, off by default; `0.15` measured) |
//! | `SUBDFIT_FIELD_ORDER` | `quad::field::parts` | the parts' order (`lex`, `bfs`, another value Morton) |
//! | `SUBDFIT_FACES_PROJ` | `convert::faces_proj` | `1`: the projectability rounds at `--faces` |
//! | `SUBDFIT_FACES_PROJ_F`, `_ROUNDS`, `_LCAP` | `convert::faces_proj` | their constants |
//! | `SUBDFIT_FACES_PROJ_LOG` | `convert::faces_proj` | each round on stderr |
//! | `SUBDFIT_FACES_PROJ_STOP` | `convert::faces_proj` | `0`: the judged rounds do not stop once the choice meets the unprojectable bar |
//! | `SUBDFIT_FACES_PROJ_LOCAL` | `convert::faces_local` | `1`: when the incoming result misses narrowly, the projectability rounds first move the last round's control vertices towards the unprojectable spots (a lens, same topology), then re-lay |
//! | `SUBDFIT_FACES_PROJ_LOCAL_S`, `_RINGS`, `_ROUNDS`, `_GATE` | `convert::faces_local` | the lens's scale at its centre (`LENS`), the rings it may move (`RINGS`), the local rounds before the re-laid ones (`ROUNDS`) and the incoming M′ unprojectable % above which none is tried (`GATE_PERCENT`) |
//! | `SUBDFIT_FACES_PROJ_LOCAL_CHAIN` | `convert::faces_local` | `start`: each local round moves the last round's start, not its fit put back on M′ |
//! | `SUBDFIT_FACES_PROJ_TUBE` | `convert::faces_proj` (`tube_round_marks`), `quad::field` (`FieldOptions::local_caps`) | `k > 0`: when a first fit at `--faces` leaves > 0.1 % of M′ unprojectable, one re-laid round whose sizes are capped at `k` × the tube thickness on the M′ vertices under and around those patches (held at any count scale, graded at γ), the factor `_F` where no tube is found; kept by the rounds' rule (off by default, session 26) |
//! | `SUBDFIT_FACES_PROJ_TUBE_ROUNDS` | `convert::faces_proj` | the tube rounds laid at most (`TUBE_ROUNDS`, 1) |
//! | `SUBDFIT_SEARCH_FULL_MEASURE` | `convert::search` | `1`: the full measure on every step (same bytes) |
//! | `SUBDFIT_PROXY_FITMAP_ON_M` | `convert::layout` | `1`: the proxy's Fitmap computed on M |
//! | `SUBDFIT_CLEANUP_GUARDED` | `quad::field::cleanup` | set and not `0`: the guarded cancellation |
//! | `SUBDFIT_CLEANUP_MOVES`, `_RISE`, `_SHARE` | `quad::field` | the cleanup's moves' constants |
//! | `SUBDFIT_CLEANUP_LATE`, `_EXACT` | `quad::field` | set: moves after the count, exact undo |
//! | `SUBDFIT_CLEANUP_FITMAP_MOVES` | `quad::field::cleanup` | set and not `0`: one round of multi-rotation moves before the count phase under the fitmap tests, no region-fit guard (`CleanupOptions::with_fitmap_moves_env`; session 25); `shape`: the fitmap-load and shear proxies too; `local`: `shape` with the locality gate (a move whose support is more than `LOCAL_SHARE` of the control surface's area is refused; session 26); `local-fit`: such moves judged by the region fit instead |
//! | `SUBDFIT_CLEANUP_LOCAL_SHARE` | `quad::field::cleanup` | the locality gate's share under `SUBDFIT_CLEANUP_FITMAP_MOVES=local` / `local-fit` (default 0.2, `CleanupOptions::move_local_share`) |
//! | `SUBDFIT_FIELD_COUNT_TRIM_CAP` | `quad::field` | `c > 0`: the count passes compare a pass the cleanup trimmed by more than `c · N` faces as outside the window (session 25) |
//! | `SUBDFIT_FIELD_COUNT_STEER` | `quad::field::count` | `1`: the count passes steered: each pass's sizes from the pooled h⁻² predictions of every sound pass (not the kept pass's factor on the last pass's sizes), a degenerate lattice (the field's own offsets with > 10 % raw non-quads) ranked behind every other pass and its scale not laid again; `kept`: the same with the kept pass's own prediction alone (session 26) |
//! | `SUBDFIT_FIELD_COUNT_SWEEP` | `quad::field::count` | `lo,hi,k`: a diagnostic; before the count passes, the lattice alone laid at k + 1 factors lo..hi on the sizes, faces and defects per factor on stderr (session 26) |
//! | `SUBDFIT_CLEANUP_GEO` | `quad::field` | set and `0`: no geometric ties |
//! | `SUBDFIT_CLEANUP_TRACE` | `quad::field::cleanup` | each trial on stderr |
//! | `SUBDFIT_CROSS_R`, `SUBDFIT_CROSS_P` | `quad::field::cross` | the guide smoothing's radius and power |
//! | `SUBDFIT_CROSS_ALIGN`, `SUBDFIT_CROSS_ALEN` | `quad::field` | the curvature guide's weight and length (`FieldOptions::alignment_weight`, `_length`) |
//! | `SUBDFIT_CROSS_HIER` | `quad::field` | `1`: the hierarchical orientation smoothing (`FieldOptions::orientation_hierarchy`) |
//! | `SUBDFIT_FLOW_RESTARTED` | `quad::field::flow` | set: the restarted search |
//! | `SUBDFIT_SIMPLIFY_SPLIT` | `quad::simplify_split` | `1`: the simplification's split |
//! | `SUBDFIT_SIMPLIFY_FORK` | `quad::simplify` | `N`: a step's φ batches split in two over the pool from `N` lines on (default off, `DEFAULT_STEP_FORK`: no wall gain measured on quiet cores; `0`: never; same bytes) |
//! | `SUBDFIT_FIT_START_PICK` | `fit` | `K[:M]`: the fit's start picked after K iterations |
//! | `SUBDFIT_FITTRACE` | `fit` | each fit iteration on stderr |
//! | `SUBDFIT_FITMAP_SPARSE`, `SUBDFIT_FITMAP_SPARSE_POWER`, `SUBDFIT_FITMAP_SEED` | `analysis::fitmap` | the sparse rule, its mean's power, the sampling seed |
//! | `SUBDFIT_LSQ_HALVINGS` | `displace::lsq` | the full step's halvings |
//! | `SUBDFIT_LSQ_CG_TOL` | `displace::lsq` | the least squares' conjugate-gradient tolerance (default 1e-10) |
//! | `SUBDFIT_TAIL_SAMPLES` | `report` | `N`: the least squares' M-side fitting points a stratified draw of `N` when M has more edges |
//! | `SUBDFIT_EMBREE_POINT_BUILD` | `raycast::embree` | `low`, `medium` or `high`: Embree's build quality of the scenes asked only for closest points (D, L's tessellation, the fit's sample grids; `EmbreeCaster::for_points`, default `POINT_BUILD_QUALITY`); the same answers bit for bit at any |
//! | `SUBDFIT_FIT_FACTOR_REUSE` | `fit` | `0`: each point-objective round factors every patch afresh instead of reusing the start's last factor of a patch with the same samples (`compress::FactorCache`; the same bytes either way, a measurement switch) |
//! | `SUBDFIT_LSQTRACE` | `displace::lsq` | the solves on stderr |
//! | `SUBDFIT_MEMTRACE` | `watch` | memory per stage on stderr |
//! | `SUBDFIT_TEST_PAUSE_BEFORE_SWAP_MS` | `report::output` | a test hook: a pause before the output swap |
//! | `SUBDFIT_FIELD_BEST` | `quad::field::draws`, `quad::field::cleanup`, `convert::faces_proj`, `convert::layout` | `1`: 4 first-layout draws, the guarded cleanup, the projectability rounds judged on final figures and main's result as a candidate (each part overridden by its own switch when that is set); `lean`: the same with the draws at scales 1 and 0.97 only (`draws::LEAN_DRAWS`, session 23) |
//! | `SUBDFIT_FIELD_BARS_D` | `quad::field::draws` | `w ≥ 1`: RMS D's term in the bars score (`Score::Bars`) weighted `w` times |
//! | `SUBDFIT_DISP_REFINE` | `convert::tail`, `convert::thin`, `convert::search` | `1`: an all-quad layout's displacement atlas (and metrics) on its refinement by one level, as a non-quad layout's always is |
//! | `SUBDFIT_DISP_LEVEL0` | `displace::alloc`, `convert::tail` | `1`: where the level-1 floor takes over 4/5 of the budget, the adaptive allocation may leave a patch at its corners (`R = 2`); `SUBDFIT_DISP_REFINE` also refines where that holds on the refinement and its vertices take at most half the budget |
//! | `SUBDFIT_DISP_SHEET` | `displace::sheet`, `displace::lsq`, `report` | `1`: a displacement sample the same-sheet test rejects takes its line's nearest hit whose M normal faces the limit normal's way (cosine ≥ 0.5) within 6 distances to M, and counts as projected; `fixed`: the same, and the samples still unprojectable keep their inpainted offsets through the least squares |
//! | `SUBDFIT_FIELD_BEST_MAIN` | `convert::layout` | under `SUBDFIT_FIELD_BEST=1`, `0`: no main's-result candidate in the final judgement (on otherwise) |
//! | `SUBDFIT_FIELD_ADAPT` | `convert::options` (`ConvertOptions::field_adapt`'s default) | `1`: the natural-size adaptivity (caps, grading, relaxation towards F_S's sizes) without `--faces`; with a finite `--max-error`, the rounds' relaxation follows the first sizing, a projectability near miss is judged on M, the bracket lays the kept sizing scaled once |
//! | `SUBDFIT_FIELD_ADAPT_CHECK` | `convert::adapt` | with `SUBDFIT_FIELD_ADAPT=1` at a finite `--max-error`: `0` turns off the switch-off conversion beside a result whose RMS D > 0.15 RMS L (on otherwise) |
//! | `SUBDFIT_FIELD_ADAPT_CARRY` | `convert::field` | with `SUBDFIT_FIELD_ADAPT=1` at a finite `--max-error`: the share of the limit's area (%) whose samples the displacement cannot carry onto M′ above which a round fails projectability, those patches refined as unprojectable (`ADAPT_CARRY_PERCENT`, off by default) |
//! | `SUBDFIT_FIELD_FIT_ITERS` | `convert::field` (`fit_iterations`), `convert`, `convert::layout` | `N`: the field layout's fits run at most `N` iterations (8 unset; session 24: `12` meets spot 85's RMS L bar on the single draw) |
//! | `FIELD_GRADING`, `FIELD_LOOP_CAP_SLOPE` | `quad::field` | the sizing's grading and its loops' cap |
//! | `FIELD_RELAX`, `FIELD_SIZED_RELAX`, `FIELD_POSITION_OWN_SCALE` | `quad::field` | the extraction's relaxation, the positions' scale |
//! | `FIELD_DEBUG` | `quad::field` | the layout's steps on stderr |
//! | `SUBDFIT_FIELD_TUBE_CAP` | `quad::field` (`FieldOptions::tube_cap`, `tube`) | `k > 0`: sizes capped at `k` × the thickness where M is a tube thinner than the lattice step (homer's fingers; off by default, session 25); `SUBDFIT_FIELD_TUBE_SKIP`: only where the tube is thinner than this share of h (`tube::TUBE_SKIP`) |
//! | `FIELD_DUMP` | `quad::field::extract`, `quad::field::tube` | `DIR`: each lattice's clusters and extracted quads, and the tube caps, written to `DIR` (a trace) |

use std::str::FromStr;

/// Whether the switch `name` is set, whatever its value (the traces).
pub fn set(name: &str) -> bool {
    std::env::var_os(name).is_some()
}

/// Whether the switch `name` is `1` (the variants off by default).
pub fn on(name: &str) -> bool {
    text(name).is_some_and(|v| v == "1")
}

/// The switch `name`: `Some(false)` at `0`, `Some(true)` at `1`, `None`
/// unset or at another value (the variants on by default).
pub fn on_off(name: &str) -> Option<bool> {
    match text(name)?.as_str() {
        "0" => Some(false),
        "1" => Some(true),
        _ => None,
    }
}

/// Whether the switch `name` is set to anything but `0` (`None` unset).
pub fn not_zero(name: &str) -> Option<bool> {
    text(name).map(|v| v != "0")
}

/// The switch `name`'s value parsed as a `T` (`None` unset, or when it
/// does not parse).
pub fn parsed<T: FromStr>(name: &str) -> Option<T> {
    text(name)?.parse().ok()
}

/// The switch `name`'s number, `default` when unset or when it does not
/// parse (the constants of a variant).
pub fn number(name: &str, default: f64) -> f64 {
    parsed(name).unwrap_or(default)
}

/// The switch `name`'s value, white space around it removed (`None`
/// unset, or not UTF-8).
pub fn text(name: &str) -> Option<String> {
    std::env::var(name).ok().map(|v| v.trim().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every reader on one variable set to each value: white space is
    /// ignored, and a value that does not parse is as if unset. (A
    /// variable name of this test's own, so that no other test sees it.)
    #[test]
    fn one_value_reads_the_same_way_everywhere() {
        let name = "SUBDFIT_SWITCHES_UNIT_TEST";
        std::env::remove_var(name);
        assert!(!set(name) && !on(name));
        assert_eq!((on_off(name), not_zero(name)), (None, None));
        assert_eq!((parsed::<f64>(name), number(name, 0.5)), (None, 0.5));
        std::env::set_var(name, " 1 ");
        assert!(set(name) && on(name));
        assert_eq!((on_off(name), not_zero(name)), (Some(true), Some(true)));
        assert_eq!((parsed::<usize>(name), number(name, 0.5)), (Some(1), 1.0));
        std::env::set_var(name, "0");
        assert!(set(name) && !on(name));
        assert_eq!((on_off(name), not_zero(name)), (Some(false), Some(false)));
        std::env::set_var(name, "0.6x");
        assert_eq!((parsed::<f64>(name), number(name, 0.5)), (None, 0.5));
        assert_eq!((on_off(name), not_zero(name)), (None, Some(true)));
        std::env::remove_var(name);
    }
}
