//! `report.json` read back from disk, by the readers of a finished output
//! folder (`report.html`, `subdfit render`, batch runs that skip a
//! finished asset): the few figures they use, typed, every one optional
//! (a folder written by another version may lack it), and the file's
//! numeric leaves under dotted keys, for hosts without a JSON parser.
//!
//! A run in progress has its typed [`super::Report`] and never reads this.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The parts of a written `report.json` its readers use.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenReport {
    pub input: WrittenInput,
    pub control: WrittenControl,
    pub projectability: WrittenProjectability,
    pub accuracy: WrittenAccuracy,
    pub options: WrittenOptions,
    /// Every numeric leaf of the file, under dotted keys (see
    /// [`flat_numbers`]).
    #[serde(skip)]
    pub figures: Vec<(String, f64)>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenInput {
    pub triangles: Option<u64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenControl {
    pub faces: Option<u64>,
    pub irregular_vertices: Option<u64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenProjectability {
    pub unprojectable_area_percent: Option<f64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenAccuracy {
    pub limit: WrittenRms,
    pub displaced: WrittenRms,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenRms {
    /// ‰ of the input's diagonal (`null` when it was not finite).
    pub rms_permille: Option<f64>,
}

/// `options`: a fitted run's `{pipeline, run}` or a mechanical run's own
/// record (`{mode, convert, run, mechanical}`).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenOptions {
    pub pipeline: Option<WrittenPipeline>,
    pub run: Option<WrittenRun>,
    pub mode: Option<WrittenMode>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenPipeline {
    pub fitmap: Option<WrittenFitmap>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenFitmap {
    /// τ, a fraction of the diagonal.
    pub tolerance: Option<f64>,
}

/// `options.run`: the host's record (`fit`, mechanical) or an organic
/// branch's, with the host's record below it as `run`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenRun {
    pub mesh: Option<String>,
    pub run: Option<Box<WrittenRun>>,
    pub convert: Option<WrittenConvert>,
    pub mode: Option<WrittenMode>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenConvert {
    pub target_faces: Option<u64>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenMode {
    pub mode: Option<String>,
    pub second_opinion: Option<WrittenSecondOpinion>,
}

#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default)]
pub struct WrittenSecondOpinion {
    pub kept: Option<String>,
}

impl WrittenReport {
    /// Reads `path` (a `report.json`).
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let parse =
            |e: serde_json::Error| Error::parse(path, format!("line {}", e.line()), e.to_string());
        let value: serde_json::Value = serde_json::from_str(&text).map_err(parse)?;
        let mut report = WrittenReport::deserialize(&value).map_err(parse)?;
        report.figures = flat_numbers(&value);
        Ok(report)
    }

    /// The input mesh the run named: `convert` stores
    /// `{run: {run: {mesh}}}`, `fit` `{run: {mesh}}`.
    pub fn input_mesh(&self) -> Option<&str> {
        let run = self.options.run.as_ref()?;
        run.run
            .as_ref()
            .and_then(|r| r.mesh.as_deref())
            .or(run.mesh.as_deref())
    }

    /// The pipeline that made the result (`"organic"`, `"mechanical"`):
    /// an organic branch nests its choice under `options.run`, a
    /// mechanical one does not; `--mode auto`'s second opinion says which
    /// of the two was kept.
    pub fn mode(&self) -> Option<&str> {
        let o = &self.options;
        let mode = o
            .run
            .as_ref()
            .and_then(|r| r.mode.as_ref())
            .or(o.mode.as_ref())?;
        mode.second_opinion
            .as_ref()
            .and_then(|s| s.kept.as_deref())
            .or(mode.mode.as_deref())
    }

    /// Whether the run was given `--faces`.
    pub fn had_target_faces(&self) -> bool {
        let run = self.options.run.as_ref();
        run.and_then(|r| r.convert.as_ref())
            .is_some_and(|c| c.target_faces.is_some())
    }
}

impl<O: Serialize> super::Report<O> {
    /// Every numeric leaf of `report.json` under dotted keys
    /// (`accuracy.limit.rms_permille`, `stages[2].seconds`, …), in key
    /// order, so a C++ host gets the figures without a JSON parser.
    pub fn figures(&self) -> Result<Vec<(String, f64)>> {
        let value =
            serde_json::to_value(self).map_err(|e| Error::internal(format!("report.json: {e}")))?;
        Ok(flat_numbers(&value))
    }
}

/// The numeric leaves of a JSON value under dotted keys; array elements
/// as `[i]`.
fn flat_numbers(report: &serde_json::Value) -> Vec<(String, f64)> {
    fn walk(v: &serde_json::Value, key: &mut String, out: &mut Vec<(String, f64)>) {
        match v {
            serde_json::Value::Number(n) => {
                if let Some(x) = n.as_f64() {
                    out.push((key.clone(), x));
                }
            }
            serde_json::Value::Object(m) => {
                for (k, v) in m {
                    let len = key.len();
                    if !key.is_empty() {
                        key.push('.');
                    }
                    key.push_str(k);
                    walk(v, key, out);
                    key.truncate(len);
                }
            }
            serde_json::Value::Array(a) => {
                for (i, v) in a.iter().enumerate() {
                    let len = key.len();
                    key.push_str(&format!("[{i}]"));
                    walk(v, key, out);
                    key.truncate(len);
                }
            }
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(report, &mut String::new(), &mut out);
    out
}
