//! [`Run`]: what every stage of one conversion shares.

use crate::error::Result;
use crate::mesh::{Frame, TriMesh, ValidatedMesh};
use crate::raycast::{make_raycaster, RayBackend, RayCaster};
use crate::report::StageTimer;
use crate::watch::Progress;

/// One conversion under way: the input in its working frame, the ray
/// caster over it, the stage timer whose stages go into `report.json`, and
/// the host's progress callback (returning `false` cancels).
///
/// Every conversion runs in a working frame ([`Frame`]: centred, unit
/// diagonal, snapped), so that every threshold of the pipeline, a fraction
/// of the diagonal, means the same at 1e-3 and at 1e20; the result is mapped
/// back by [`super::Converted::map_from_unit`].
pub struct Run<'a, 'p> {
    /// The input, in `frame`'s unit coordinates.
    pub input: &'a ValidatedMesh,
    /// The working frame `input` was mapped into.
    pub frame: Frame,
    /// Embree over `input`'s triangles (every fit, projection and
    /// measurement refers to M, whatever mesh the layout ran on).
    pub caster: Box<dyn RayCaster>,
    /// The stages run so far; a branch takes them for its report
    /// ([`Run::take_timer`]).
    pub timer: StageTimer,
    pub progress: &'a mut Progress<'p>,
}

impl<'a, 'p> Run<'a, 'p> {
    /// Starts a run on `input` (in the working `frame` already): builds the
    /// ray caster as the stage `"raycaster"` of `timer`.
    pub fn start(
        input: &'a ValidatedMesh,
        frame: Frame,
        mut timer: StageTimer,
        progress: &'a mut Progress<'p>,
    ) -> Result<Self> {
        let caster = timer.run("raycaster", || {
            make_raycaster(RayBackend::Embree, &input.mesh)
        })?;
        Ok(Run {
            input,
            frame,
            caster,
            timer,
            progress,
        })
    }

    pub fn mesh(&self) -> &'a TriMesh {
        &self.input.mesh
    }

    /// The stages so far, leaving an empty timer: a branch's report carries
    /// them, and a second branch (`--mode auto`'s second opinion) starts
    /// its own count.
    pub fn take_timer(&mut self) -> StageTimer {
        std::mem::take(&mut self.timer)
    }

    /// Reports `stage` at `fraction` to the host; `Err(Cancelled)` once it
    /// said stop.
    pub fn report(&mut self, stage: &str, fraction: f64) -> Result<()> {
        crate::watch::report_progress(self.progress, stage, fraction)
    }
}
