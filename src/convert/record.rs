//! `report.json`'s `options`: the typed record of what a run was given and
//! what its layout did, so that the compiler checks what the file promises
//! (its keys are pinned by `tests/report_keys.rs`) and hosts read the run's
//! results from these values instead of from the JSON.
//!
//! Two shapes, as the file always had them:
//! - a fitted run (organic, coarse, `subdfit fit`):
//!   `{pipeline, run}`, the tail's options beside the run's record;
//! - a mechanical run (Lavoué et al. 2007 fit their own control mesh):
//!   the branch's record itself, `{mode, convert, run, mechanical}`.

use serde::Serialize;

use crate::mechanical::{MechanicalOptions, MechanicalStats, ModeChoice};
use crate::mesh::ForeignRepairs;
use crate::quad::SimplifyStats;

use super::auto::SecondOpinion;
use super::field::FieldRecord;
use super::layout::ProxyRecord;
use super::search::ErrorSearch;
use super::tail::PipelineOptions;
use super::ConvertOptions;

/// `report.json`'s `options`.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum RunOptions {
    /// A run whose control mesh went through the global fit (organic,
    /// coarse, `subdfit fit`).
    Fitted {
        /// The tail's fit, metrics and Fitmap options.
        pipeline: Box<PipelineOptions>,
        run: FittedRun,
        /// `--mode auto` kept the organic result of its second opinion:
        /// what it compared, at `options.mode.second_opinion` as for a
        /// mechanical result (the organic branch's own choice stays in
        /// `options.run.mode`).
        #[serde(skip_serializing_if = "Option::is_none")]
        mode: Option<Box<SecondOpinionNote>>,
    },
    /// A mechanical run: its branch record at the top.
    Mechanical(Box<BranchRecord>),
}

/// `options.run` of a fitted run.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum FittedRun {
    /// A conversion's branch (`convert`, and the hosts' `convert`).
    Convert(Box<BranchRecord>),
    /// `subdfit fit` and the hosts' `fit`: the host's record alone.
    Host(HostRecord),
}

/// `{"second_opinion": …}` of a [`RunOptions::Fitted`] result that
/// `--mode auto` kept.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct SecondOpinionNote {
    pub second_opinion: SecondOpinion,
}

/// The host's record of a run (`options.run` of `fit`, `options.run.run`
/// of `convert`, `options.run` of a mechanical run): which command, on
/// which file, and for `fit` the control mesh given.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct HostRecord {
    /// `"convert"` or `"fit"`.
    pub command: String,
    /// The input mesh as the host names it (its path for the CLI).
    pub mesh: String,
    /// `subdfit fit`: the control mesh given and what reading it repaired.
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub fit: Option<FitInputs>,
    /// `subdfit fit` on a mesh above the proxy bound: what the Fitmap's
    /// layout proxy tried (`options.run.fitmap_proxy`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fitmap_proxy: Option<Box<super::layout::ProxyRecord>>,
}

impl HostRecord {
    /// A `convert` of the mesh called `mesh`.
    pub fn convert(mesh: impl Into<String>) -> Self {
        HostRecord {
            command: "convert".into(),
            mesh: mesh.into(),
            fit: None,
            fitmap_proxy: None,
        }
    }

    /// A `fit` of the mesh called `mesh` (`fit`: the control mesh given,
    /// when the host names one).
    pub fn fit(mesh: impl Into<String>, fit: Option<FitInputs>) -> Self {
        HostRecord {
            command: "fit".into(),
            mesh: mesh.into(),
            fit,
            fitmap_proxy: None,
        }
    }
}

/// The control mesh `subdfit fit` was given.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct FitInputs {
    /// Its path.
    pub control: String,
    /// What reading it repaired, and the same said in words.
    pub control_repairs: ForeignRepairs,
    pub control_notes: Vec<String>,
}

/// One branch of a conversion: `--mode`'s choice, the options, the host's
/// record and what the layout did.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct BranchRecord {
    pub mode: ModeRecord,
    pub convert: ConvertOptions,
    pub run: HostRecord,
    #[serde(flatten)]
    pub layout: BranchLayout,
}

/// `--mode`'s choice and why, with `--mode auto`'s second opinion when it
/// ran one and kept this branch.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ModeRecord {
    #[serde(flatten)]
    pub choice: ModeChoice,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub second_opinion: Option<SecondOpinion>,
}

/// The layout's keys of a [`BranchRecord`].
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum BranchLayout {
    OrganicGreedy {
        layout_proxy: Option<ProxyRecord>,
        simplification: SimplifyStats,
        max_error_search: Option<ErrorSearch>,
    },
    OrganicField {
        layout_proxy: Option<ProxyRecord>,
        field_layout: FieldRecord,
    },
    Mechanical {
        mechanical: MechanicalRecord,
    },
    Coarse {
        coarse_input: String,
    },
}

/// Lavoué et al.'s options and statistics of a mechanical branch.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct MechanicalRecord {
    pub options: MechanicalOptions,
    pub stats: MechanicalStats,
}

impl RunOptions {
    /// A mechanical run's polyhedron face count before enrichment (§7),
    /// `None` for any other run.
    pub fn mechanical_initial_faces(&self) -> Option<usize> {
        match self {
            RunOptions::Mechanical(b) => match &b.layout {
                BranchLayout::Mechanical { mechanical } => Some(mechanical.stats.initial_faces),
                _ => None,
            },
            RunOptions::Fitted { .. } => None,
        }
    }

    /// The pipeline whose result this is: `"organic"` or `"mechanical"`
    /// (the one `--mode auto`'s second opinion kept, when it ran one);
    /// `None` for `fit`, which has no mode.
    pub fn mode(&self) -> Option<&'static str> {
        match self {
            RunOptions::Mechanical(b) => Some(b.mode.kept()),
            RunOptions::Fitted { mode: Some(n), .. } => Some(n.second_opinion.kept),
            RunOptions::Fitted {
                run: FittedRun::Convert(b),
                ..
            } => Some(b.mode.kept()),
            RunOptions::Fitted { .. } => None,
        }
    }

    /// Records `--mode auto`'s second opinion on the result kept.
    pub(super) fn note_second_opinion(&mut self, note: SecondOpinion) {
        match self {
            RunOptions::Mechanical(b) => b.mode.second_opinion = Some(note),
            RunOptions::Fitted { mode, .. } => {
                *mode = Some(Box::new(SecondOpinionNote {
                    second_opinion: note,
                }))
            }
        }
    }

    /// The host's record of the run.
    pub fn host(&self) -> &HostRecord {
        match self {
            RunOptions::Mechanical(b) => &b.run,
            RunOptions::Fitted {
                run: FittedRun::Convert(b),
                ..
            } => &b.run,
            RunOptions::Fitted {
                run: FittedRun::Host(h),
                ..
            } => h,
        }
    }
}

impl ModeRecord {
    /// The pipeline whose result the branch holds.
    fn kept(&self) -> &'static str {
        self.second_opinion
            .as_ref()
            .map_or(self.choice.mode, |s| s.kept)
    }
}
