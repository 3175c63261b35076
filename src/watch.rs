//! Progress and cancellation for the long stages, reaching their inner
//! loops on every worker thread.
//!
//! The pipeline's progress callback ([`Progress`]) is an `FnMut`: one
//! caller at a time. A stage that runs on the rayon pool cannot call it from
//! its workers, so before this module a stage could only report (and learn
//! of a cancellation) between its parallel steps, which on a large mesh are
//! seconds apart. [`watched`] runs a stage with a [`Watch`] instead: a
//! `Sync` handle whose [`Watch::report`] and [`Watch::check`] cost an atomic
//! load (and, for a report, an uncontended lock), callable from any thread,
//! while a watcher thread forwards the latest report to the callback every
//! [`Watch::INTERVAL`] and raises the stop flag when the callback says stop.
//! A cancelled stage thus ends within one inner step (a chunk of ray queries,
//! see [`crate::raycast::Watched`]), not one parallel phase.
//!
//! The callback still never runs on two threads at once: during a watched
//! stage the watcher thread is its only caller.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use crate::error::{Error, Result};

/// A progress callback: `(stage, fraction in [0, 1])`; returning `false`
/// cancels the run with [`Error::Cancelled`]. `Send`, because a watched
/// stage calls it from its watcher thread.
pub type Progress<'a> = dyn FnMut(&str, f64) -> bool + Send + 'a;

/// Calls `progress` and turns a `false` into [`Error::Cancelled`].
pub fn report_progress(progress: &mut Progress<'_>, stage: &str, fraction: f64) -> Result<()> {
    if progress(stage, fraction.clamp(0.0, 1.0)) {
        Ok(())
    } else {
        Err(Error::Cancelled {
            stage: stage.to_string(),
        })
    }
}

/// What a watched stage said last, and the boundaries (stage starts and
/// ends) the watcher has not forwarded yet: those are never dropped, so the
/// callback sees every stage begin and end in order.
#[derive(Default)]
struct Said {
    boundaries: Vec<(String, f64)>,
    latest: Option<(String, f64)>,
}

/// The handle a watched stage reports through and polls; see the module doc.
pub struct Watch {
    stop: AtomicBool,
    finished: AtomicBool,
    said: Mutex<Said>,
    stage: Mutex<String>,
    /// What the watcher forwarded last (its thread only).
    last_sent: Mutex<Option<(String, f64)>>,
}

impl Default for Watch {
    fn default() -> Self {
        Self::new()
    }
}

impl Watch {
    /// How often the watcher forwards the latest report (and so the longest
    /// a cancellation waits for it, beside the stage's own inner step).
    pub const INTERVAL: Duration = Duration::from_millis(10);

    /// A watch nobody watches: reports are dropped and nothing stops it
    /// (for library calls without a callback).
    pub fn new() -> Self {
        Watch {
            stop: AtomicBool::new(false),
            finished: AtomicBool::new(false),
            said: Mutex::new(Said::default()),
            stage: Mutex::new(String::new()),
            last_sent: Mutex::new(None),
        }
    }

    /// Records that `stage` is `fraction` done (forwarded by the watcher)
    /// and returns [`Error::Cancelled`] once the callback said stop.
    pub fn report(&self, stage: &str, fraction: f64) -> Result<()> {
        let fraction = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        {
            let mut current = self.stage.lock().unwrap_or_else(|p| p.into_inner());
            let mut said = self.said.lock().unwrap_or_else(|p| p.into_inner());
            if *current != stage || fraction == 0.0 || fraction == 1.0 {
                if *current != stage {
                    *current = stage.to_owned();
                }
                said.boundaries.push((stage.to_owned(), fraction));
                said.latest = None;
            } else {
                said.latest = Some((stage.to_owned(), fraction));
            }
        }
        self.check()
    }

    /// The cheap poll for inner loops: one atomic load while nothing stops.
    pub fn check(&self) -> Result<()> {
        if self.is_stopped() {
            Err(Error::Cancelled {
                stage: self.stage.lock().unwrap_or_else(|p| p.into_inner()).clone(),
            })
        } else {
            Ok(())
        }
    }

    pub fn is_stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// Forwards what was said since the last call; `false` once the
    /// callback said stop (or had said it before).
    fn forward(&self, progress: &mut Progress<'_>) -> bool {
        let said = {
            let mut said = self.said.lock().unwrap_or_else(|p| p.into_inner());
            let said = std::mem::take(&mut *said);
            (said.boundaries, said.latest)
        };
        let mut sent = false;
        for (stage, f) in said.0.iter().chain(said.1.iter()) {
            if self.is_stopped() {
                break;
            }
            sent = true;
            if !progress(stage, *f) {
                self.stop.store(true, Ordering::Relaxed);
            }
        }
        // Nothing new: the last report again, which is how a host that wants
        // to stop gets asked (hosts rate limit repeats).
        if !sent && !self.is_stopped() {
            let last = self
                .last_sent
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone();
            if let Some((stage, f)) = last {
                if !progress(&stage, f) {
                    self.stop.store(true, Ordering::Relaxed);
                }
            }
        } else if let Some(last) = said.1.or_else(|| said.0.last().cloned()) {
            *self.last_sent.lock().unwrap_or_else(|p| p.into_inner()) = Some(last);
        }
        !self.is_stopped()
    }
}

/// Runs `work` on the calling thread (so on the caller's rayon pool, with
/// all of its threads) with a [`Watch`], while a watcher thread forwards the
/// watch's reports to `progress` every [`Watch::INTERVAL`] — including one
/// forward when nothing new was said, which is how a host that wants to
/// stop is asked. `work` should report its stages through the watch and
/// poll [`Watch::check`] in its inner loops; a cancellation it did not see
/// is still returned once it ends.
pub fn watched<T>(
    progress: &mut Progress<'_>,
    work: impl FnOnce(&Watch) -> Result<T>,
) -> Result<T> {
    let watch = Watch::new();
    let result = std::thread::scope(|s| {
        let watcher = s.spawn(|| {
            while !watch.finished.load(Ordering::Acquire) {
                std::thread::park_timeout(Watch::INTERVAL);
                if !watch.is_stopped() {
                    watch.forward(progress);
                }
            }
            // The last boundaries (a stage's 1.0) reach the host too.
            if !watch.is_stopped() {
                watch.forward(progress);
            }
        });
        let r = work(&watch);
        watch.finished.store(true, Ordering::Release);
        watcher.thread().unpark();
        // The watcher only calls `progress`; a panic there is the host's and
        // comes back to it.
        if let Err(p) = watcher.join() {
            std::panic::resume_unwind(p);
        }
        r
    });
    if watch.is_stopped() {
        if let Ok(_) | Err(Error::Cancelled { .. }) = &result {
            return Err(Error::Cancelled {
                stage: watch
                    .stage
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .clone(),
            });
        }
    }
    result
}

/// Scale work's probe (issue 39): with `SUBDFIT_MEMTRACE` set, prints the
/// process's resident and peak memory (`VmRSS`, `VmHWM` of
/// `/proc/self/status`, MiB) at `label` on stderr; otherwise nothing. A
/// stage's peak in `report.json` says which stage holds the most; this
/// says which step within it.
pub fn memtrace(label: &str) {
    if !crate::switches::set("SUBDFIT_MEMTRACE") {
        return;
    }
    let Ok(s) = std::fs::read_to_string("/proc/self/status") else {
        return;
    };
    let field = |name: &str| {
        s.lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|k| k.parse::<f64>().ok())
            .map_or(f64::NAN, |kb| kb / 1024.0)
    };
    eprintln!(
        "memtrace {label}: rss {:.0} MiB, peak {:.0} MiB, process cpu {:.2} s",
        field("VmRSS:"),
        field("VmHWM:"),
        process_cpu_seconds()
    );
}

/// CPU seconds spent by the whole process so far (every thread; 0 if the
/// clock cannot be read): `SUBDFIT_MEMTRACE`'s per-step CPU, the figure
/// that stays comparable on a loaded machine.
pub fn process_cpu_seconds() -> f64 {
    cpu_seconds(libc::CLOCK_PROCESS_CPUTIME_ID)
}

/// CPU seconds spent by the calling thread so far (0 if the clock cannot be
/// read). For diagnostics that time one thread's share of a parallel step
/// (the split simplification's halves, the field's flow search): on a shared
/// machine wall time says little about the work done.
pub fn thread_cpu_seconds() -> f64 {
    cpu_seconds(libc::CLOCK_THREAD_CPUTIME_ID)
}

/// The CPU seconds `clock` reads (0 if it cannot be read).
fn cpu_seconds(clock: libc::clockid_t) -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec for the call's duration.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    if rc == 0 {
        ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn boundaries_reach_the_callback_in_order() {
        let mut seen = Vec::new();
        let r = watched(
            &mut |s: &str, f: f64| {
                seen.push((s.to_owned(), f));
                true
            },
            |w| {
                for s in ["a", "b", "c"] {
                    w.report(s, 0.0)?;
                    w.report(s, 0.5)?;
                    w.report(s, 1.0)?;
                }
                Ok(7)
            },
        );
        assert_eq!(r.unwrap(), 7);
        // The watcher repeats its last report while nothing new is said
        // (how a host is asked whether to go on): repeats are dropped.
        let mut bounds: Vec<_> = seen
            .iter()
            .filter(|(_, f)| *f == 0.0 || *f == 1.0)
            .cloned()
            .collect();
        bounds.dedup();
        let want: Vec<_> = ["a", "b", "c"]
            .iter()
            .flat_map(|s| [(s.to_string(), 0.0), (s.to_string(), 1.0)])
            .collect();
        assert_eq!(bounds, want);
    }

    #[test]
    fn a_stop_reaches_a_polling_loop_within_a_few_intervals() {
        let asked = std::sync::atomic::AtomicBool::new(false);
        let t = Instant::now();
        let r: Result<()> = watched(&mut |_, _| !asked.load(Ordering::Relaxed), |w| {
            w.report("loop", 0.0)?;
            let start = Instant::now();
            loop {
                if start.elapsed() > Duration::from_millis(50) {
                    asked.store(true, Ordering::Relaxed);
                }
                w.check()?;
                assert!(start.elapsed() < Duration::from_secs(5), "never stopped");
            }
        });
        assert!(
            matches!(r, Err(Error::Cancelled { ref stage }) if stage == "loop"),
            "{r:?}"
        );
        // 50 ms of work, then a few watcher intervals (generous: the test
        // binary runs its tests in parallel on a 2-core machine).
        assert!(t.elapsed() < Duration::from_millis(50) + 50 * Watch::INTERVAL);
    }

    #[test]
    fn a_stop_the_work_did_not_see_still_cancels() {
        let r = watched(&mut |_, _| false, |w| {
            w.report("quick", 0.0).ok();
            std::thread::sleep(5 * Watch::INTERVAL);
            Ok(1)
        });
        assert!(matches!(r, Err(Error::Cancelled { .. })), "{r:?}");
    }
}
