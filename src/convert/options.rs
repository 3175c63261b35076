//! [`ConvertOptions`]: every choice of a conversion, one type for every host
//! (the CLI's flags, [`crate::embed::Options`], the C++ and Python APIs).

use serde::Serialize;

use crate::error::{Error, Result};
use crate::fit::Objective;

/// Options of [`convert`], mirroring `subdfit convert`.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct ConvertOptions {
    /// τ of the M-fitmap (§3.1.3), a fraction: the only parameter of the
    /// method. `None`: the Fitmap's default.
    pub tolerance: Option<f64>,
    /// Stop the simplification at this many faces (the paper's "*" rows).
    pub target_faces: Option<usize>,
    /// Lift the projectability test (the paper's Fig. 7 experiment).
    pub no_m_fitmap: bool,
    pub objective: Objective,
    /// Displacement samples per patch side; `None`: total ≈ M's vertices.
    pub displacement_res: Option<usize>,
    /// Per-patch displacement resolution under this many samples in all
    /// (`--displacement-samples`, [`crate::displace`]'s adaptive grid);
    /// `None`: M's vertex count. Left out of `report.json`'s options when
    /// `None`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub displacement_samples: Option<usize>,
    /// `--displacement-allocation`: per patch under the budget (the
    /// default) or the uniform grid of before issue 37.
    pub displacement_allocation: crate::displace::SampleAllocation,
    /// `--displacement-reconstruction`: how hosts read the maps, bilinear
    /// (the default) or the cubic B-spline of the texels (Blender's
    /// "Cubic"; docs/handoff.md). Left out of `report.json` when bilinear.
    #[serde(
        default,
        skip_serializing_if = "crate::displace::Reconstruction::is_bilinear"
    )]
    pub displacement_reconstruction: crate::displace::Reconstruction,
    /// Which pipeline: Fitmaps (organic), Lavoué et al. (mechanical), or
    /// chosen from the share of sharp edges (auto, the default).
    pub mode: Mode,
    /// An RMS distance bound, fraction of the diagonal. Mechanical mode:
    /// Lavoué et al.'s `E_limit` per control face; `None`:
    /// [`crate::mechanical::DEFAULT_MAX_ERROR`]. Organic mode: RMS L of
    /// the whole surface, met with the fewest patches the simplification
    /// passed through (see [`DEFAULT_ORGANIC_MAX_ERROR`]); `None`: that
    /// default, unless `target_faces` is given; infinity: the natural end.
    pub max_error: Option<f64>,
    /// Cells per patch side of `limit.ply` / `displaced.ply`; `None`: the
    /// default of [`crate::report::tessellate`].
    pub tessellation: Option<usize>,
    /// The mesh the layout stages (Fitmap, quadrangulation,
    /// simplification) run on; see [`Proxy`].
    pub proxy: Proxy,
    /// Organic mode's layout: the greedy simplification of the
    /// quadrangulated input (Fitmaps §3.2–3.3, the default) or the
    /// field-aligned layout ([`crate::quad::field`], issue 40).
    pub layout: LayoutKind,
    /// Measure every point of every direction of the metrics
    /// (`--exact-metrics`); off: D's directions of more than
    /// [`crate::report::METRIC_SAMPLES`] points, and L's and the
    /// projectability's of more than [`crate::report::DECISION_SAMPLES`],
    /// are measured on a stratified draw of that many, with the confidence
    /// intervals in `report.json`. Left out of
    /// `report.json`'s options when off.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub exact_metrics: bool,
    /// The field layout's natural-size adaptivity (issue 40; off by
    /// default, an experiment): without `target_faces`, the layout's
    /// sizes follow the S-fitmap
    /// ([`crate::quad::field::FieldOptions::with_natural_adaptivity`]),
    /// and at a finite `max_error` the rounds' relaxation follows the
    /// first sizing, a projectability near miss is judged on M, and a
    /// doubted result is checked against the conversion with this off
    /// (`convert::adapt`). [`ConvertOptions::default`] sets it from
    /// [`FIELD_ADAPT_ENV`]: an experiment switch's value, not a product
    /// option, so not public and not among the hosts' options
    /// (`tests/host_options.rs`); hosts take it from the environment
    /// through the default. Left out of `report.json`'s options when off.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub(crate) field_adapt: bool,
}

/// `SUBDFIT_FIELD_ADAPT=1`: [`ConvertOptions::field_adapt()`] on in
/// [`ConvertOptions::default`] (docs/status.md "Field-aligned layout",
/// sessions 16–21). Read there only, so that a conversion's options say
/// whether it is adaptive and the check's switch-off conversion is the
/// same options with it off.
pub const FIELD_ADAPT_ENV: &str = "SUBDFIT_FIELD_ADAPT";

/// `convert --layout`: which organic layout makes the control mesh.
#[derive(
    Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum LayoutKind {
    /// Fitmaps §3.2–3.3: M′'s triangle pairs, then diagonal collapses,
    /// edge rotations and doublet removals under the Fitmap's tests.
    #[default]
    Greedy,
    /// A cross field and a position field sized by the Fitmap, extracted
    /// into a pure-quad mesh with M's topology ([`crate::quad::field`]).
    Field,
}

/// `convert --proxy`: the layout proxy M′ of the Fitmaps paper's §4 (its
/// Armadillo runs compute the control mesh from a simplified copy of the
/// input while every fit, projection and measurement refers to M). The
/// Fitmap, the quadrangulation and the simplification cost ~50 and ~150 µs
/// per vertex they see, the fit and the metrics scale with M's size
/// only through ray casting; so the layout runs on M′ (meshoptimizer's quadric
/// simplification, [`crate::mesh::decimate`]) and the rest on M.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Proxy {
    /// M′ of [`PROXY_AUTO_TRIANGLES`] triangles when M has more than
    /// [`PROXY_AUTO_ABOVE`].
    #[default]
    Auto,
    /// The layout runs on M itself.
    None,
    /// M′ of about this many triangles when M has more.
    Triangles(usize),
    /// M′ sized by the *output* rather than the input (§4: the layout
    /// needs only "dozens of M′ vertices" per patch): a cheap probe
    /// Fitmap predicts the patch count, M′ gets
    /// [`PROXY_TRIANGLES_PER_PATCH`] triangles per predicted patch (at
    /// least [`PROXY_ADAPTIVE_FLOOR`]), and the layout runs on M when that
    /// is more than half of M ([`adaptive_proxy_triangles`]).
    Adaptive,
}

/// The size of [`Proxy::Auto`]'s M′, in triangles: the final control
/// meshes of the paper's τ range have 10²–10³ patches, and 50k triangles
/// still give every patch dozens of M′ vertices to choose its corners from,
/// while the layout stages (Fitmap, quadrangulation, simplification: ~200
/// µs per triangle they see on this 2-core machine) then cost ~10 s
/// whatever the size of M.
pub const PROXY_AUTO_TRIANGLES: usize = 50_000;

/// [`Proxy::Auto`] decimates only inputs above this many triangles: below
/// it the full-resolution layout costs under ~20 s and stays the reference
/// (the papers' meshes, 50–70k triangles, convert as before).
pub const PROXY_AUTO_ABOVE: usize = 100_000;

/// Triangles of [`Proxy::Adaptive`]'s probe: the decimation whose Fitmap
/// predicts the patch count. Probe and Fitmap cost 0.3–0.6 CPU s (bunny,
/// gargoyle), a tenth of a full-resolution Fitmap.
pub const PROXY_PROBE_TRIANGLES: usize = 4_000;

/// Patches per unit of `∫ F_M⁻² dA` over the probe (a patch of radius r
/// covers ∝ r², so the patch count of the radius field F_M is ∝ ∫ F_M⁻² dA,
/// the denominator of [`crate::quad::s_fitmap_kappa`]; scale-invariant).
/// Measured 2026-12-06 (docs/status.md, "Scale"), natural-end patches of
/// the full-resolution layout over the probe's integral: bunny τ 1 / 5 /
/// 10 % 1.61 / 1.61 / 1.48, gargoyle 1.64 / 1.52 / 1.22. The probe's F_M is
/// coarser than M's (its r_0 is larger and its small folds are decimated
/// away), which this constant absorbs.
pub const PROXY_PATCHES_PER_FM_INTEGRAL: f64 = 1.6;

/// M′ triangles per predicted patch of [`Proxy::Adaptive`]. The greedy
/// simplification's natural end moves when M′ is coarse *for the output*:
/// measured on bunny and gargoyle (docs/status.md, "Scale"), the end keeps
/// its patch count while the quadrangulated start has ≳ 25 faces (50
/// triangles) per final patch and loses 10–20 % below ~15 (gargoyle at
/// 24k and 15k triangles, bunny at 10k), with M's own Fitmap carried to M′
/// as well as with M′'s: it is the coarse start, not the Fitmap. 58 (~29
/// vertices, Fitmaps §4's "dozens") leaves a margin for a prediction up
/// to 15 % high.
pub const PROXY_TRIANGLES_PER_PATCH: f64 = 58.0;

/// The smallest M′ of [`Proxy::Adaptive`]; inputs under twice this many
/// triangles are laid out on M without a probe.
pub const PROXY_ADAPTIVE_FLOOR: usize = 10_000;

/// [`Proxy::Adaptive`]'s M′ size for a probe whose `∫ F_M⁻² dA` is
/// `fm_integral`: [`PROXY_TRIANGLES_PER_PATCH`] per predicted patch, at
/// least [`PROXY_ADAPTIVE_FLOOR`]. Grows with the predicted output, never
/// with M's own triangle count.
pub fn adaptive_proxy_triangles(fm_integral: f64) -> usize {
    let patches = PROXY_PATCHES_PER_FM_INTEGRAL * fm_integral.max(0.0);
    let t = (PROXY_TRIANGLES_PER_PATCH * patches).ceil();
    if t.is_finite() && t < usize::MAX as f64 {
        (t as usize).max(PROXY_ADAPTIVE_FLOOR)
    } else {
        usize::MAX
    }
}

/// `auto`, `none`, `adaptive` or a triangle count of at least 100:
/// `--proxy`, and the same words in every host.
impl std::str::FromStr for Proxy {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Proxy, String> {
        match s {
            "auto" => Ok(Proxy::Auto),
            "none" => Ok(Proxy::None),
            "adaptive" => Ok(Proxy::Adaptive),
            n => match n.parse::<usize>() {
                Ok(n) if n >= 100 => Ok(Proxy::Triangles(n)),
                _ => Err(format!(
                    "expected auto, none, adaptive or a triangle count of at least 100, got '{n}'"
                )),
            },
        }
    }
}

impl Proxy {
    /// The triangle count M′ should have for a mesh of `triangles`, or
    /// `None` when the layout runs on M. [`Proxy::Adaptive`] answers as
    /// `auto` here (its first decimation for inputs above
    /// [`PROXY_AUTO_ABOVE`]); its own size comes from the probe
    /// ([`adaptive_proxy_triangles`]).
    pub fn target(self, triangles: usize) -> Option<usize> {
        let (above, size) = match self {
            Proxy::Auto | Proxy::Adaptive => (PROXY_AUTO_ABOVE, PROXY_AUTO_TRIANGLES),
            Proxy::None => return None,
            Proxy::Triangles(n) => (n, n),
        };
        (triangles > above).then_some(size)
    }
}

/// Organic mode's default RMS L bound (5‰ of the diagonal; issue 17: "no
/// input ends above RMS L 5‰ unless asked"). The simplification's natural
/// end is set by projectability and the Fitmap's predicted error
/// (§3.3.1), which ends small, smooth inputs coarser than that (spot at
/// τ = 5 %: 79 patches, 6.7‰); the bound then takes the fewest patches
/// along the simplification's own path that meet it ([`super::search`]).
pub const DEFAULT_ORGANIC_MAX_ERROR: f64 = 5e-3;

/// Which pipeline a conversion runs: `convert --mode`, and the same enum
/// in every host (`embed`, C++, Python). The CLI parses it by clap's
/// derive; `report.json` writes it in lower case.
#[derive(
    Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Picks one from the share of sharp feature edges
    /// ([`crate::mechanical::choose_mode`]).
    #[default]
    Auto,
    /// Smooth organic shapes (Fitmaps, Panozzo et al.).
    Organic,
    /// CAD-like shapes with sharp features kept as creases (Lavoué et al.).
    Mechanical,
}

/// The CLI's words (`auto`, `organic`, `mechanical`), for hosts that take
/// the mode as a string.
impl std::str::FromStr for Mode {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Mode, String> {
        <Mode as clap::ValueEnum>::from_str(s, false)
    }
}

/// The CLI's words (`greedy`, `field`), for hosts that take the layout as
/// a string.
impl std::str::FromStr for LayoutKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<LayoutKind, String> {
        <LayoutKind as clap::ValueEnum>::from_str(s, false)
    }
}

impl Default for ConvertOptions {
    fn default() -> Self {
        ConvertOptions {
            tolerance: None,
            target_faces: None,
            no_m_fitmap: false,
            objective: Objective::Point,
            displacement_res: None,
            displacement_samples: None,
            displacement_allocation: Default::default(),
            displacement_reconstruction: Default::default(),
            mode: Mode::Auto,
            max_error: None,
            tessellation: None,
            proxy: Proxy::Auto,
            layout: LayoutKind::Greedy,
            exact_metrics: false,
            field_adapt: crate::switches::on(FIELD_ADAPT_ENV),
        }
    }
}

impl ConvertOptions {
    /// Rejects values no stage could use, before any work starts: τ out of
    /// its range ([`crate::analysis::fitmap::check_tolerance`]), a
    /// non-positive `max_error`, more than 4096 displacement samples per
    /// patch side, a tessellation outside 1–1024 cells, a proxy below 100
    /// triangles (the ranges the CLI's parsers enforce).
    pub fn check(&self) -> Result<()> {
        let bad = |option: &str, m: String| Err(Error::option(option, m));
        if let Some(t) = self.tolerance {
            crate::analysis::fitmap::check_tolerance(t)
                .map_err(|m| Error::option("tolerance", m))?;
        }
        if let Some(e) = self.max_error {
            if e.is_nan() || e <= 0.0 {
                return bad("max_error", format!(
                    "max error {e} out of range: it is a positive fraction of the diagonal, e.g. 3e-3 (or infinity)"
                ));
            }
        }
        if let Some(r) = self.displacement_res.filter(|&r| r > 4096) {
            return bad(
                "displacement_res",
                format!(
                    "displacement resolution {r} too large (at most 4096 samples per patch side)"
                ),
            );
        }
        if let Some(n) = self.tessellation.filter(|n| !(1..=1024).contains(n)) {
            return bad(
                "tessellation",
                format!("tessellation {n} out of range: 1 to 1024 cells per patch side"),
            );
        }
        if let Proxy::Triangles(n) = self.proxy {
            if n < 100 {
                return bad(
                    "proxy",
                    format!("proxy of {n} triangles: give at least 100 (or auto, none)"),
                );
            }
        }
        Ok(())
    }

    pub fn with_tolerance(mut self, t: Option<f64>) -> Self {
        self.tolerance = t;
        self
    }
    pub fn with_target_faces(mut self, n: Option<usize>) -> Self {
        self.target_faces = n;
        self
    }
    pub fn with_m_fitmap(mut self, on: bool) -> Self {
        self.no_m_fitmap = !on;
        self
    }
    pub fn with_objective(mut self, o: Objective) -> Self {
        self.objective = o;
        self
    }
    pub fn with_displacement_res(mut self, r: Option<usize>) -> Self {
        self.displacement_res = r;
        self
    }
    pub fn with_displacement_samples(mut self, n: Option<usize>) -> Self {
        self.displacement_samples = n;
        self
    }
    pub fn with_displacement_allocation(mut self, a: crate::displace::SampleAllocation) -> Self {
        self.displacement_allocation = a;
        self
    }
    pub fn with_displacement_reconstruction(mut self, r: crate::displace::Reconstruction) -> Self {
        self.displacement_reconstruction = r;
        self
    }
    pub fn with_mode(mut self, m: Mode) -> Self {
        self.mode = m;
        self
    }
    pub fn with_tessellation(mut self, n: Option<usize>) -> Self {
        self.tessellation = n;
        self
    }
    pub fn with_max_error(mut self, e: Option<f64>) -> Self {
        self.max_error = e;
        self
    }
    pub fn with_proxy(mut self, p: Proxy) -> Self {
        self.proxy = p;
        self
    }
    pub fn with_exact_metrics(mut self, on: bool) -> Self {
        self.exact_metrics = on;
        self
    }
    /// Whether the field layout takes its natural-size adaptivity (the
    /// field `field_adapt`, from `SUBDFIT_FIELD_ADAPT`).
    pub fn field_adapt(&self) -> bool {
        self.field_adapt
    }
    pub fn with_field_adapt(mut self, on: bool) -> Self {
        self.field_adapt = on;
        self
    }
    pub fn with_layout(mut self, l: LayoutKind) -> Self {
        self.layout = l;
        self
    }
}
