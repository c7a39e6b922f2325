//! Progress of a diagnosis, reported through a callback: the library draws nothing, the front
//! ends (the CLI's indicatif bar, the bindings' Python callable or tqdm bar) show it.

use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// One progress report: `done` of `total` model fits finished, in `stage` ("refit nominal",
/// "round 1", …). `total` grows as later search rounds add fits.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Progress {
    /// What is being fitted now.
    pub stage: String,
    /// Fits finished so far.
    pub done: u64,
    /// Fits known so far (finished or to come).
    pub total: u64,
}

/// The caller's progress callback. Called from the fit worker threads (hence `Send + Sync`),
/// once per finished fit and at every change of stage or total; it should return quickly.
#[derive(Clone, Default)]
pub struct ProgressSink(Option<Arc<ProgressFn>>);

/// The callback's type.
pub type ProgressFn = dyn Fn(&Progress) + Send + Sync;

impl ProgressSink {
    /// A sink calling `f` with every report.
    pub fn new(f: impl Fn(&Progress) + Send + Sync + 'static) -> Self {
        Self(Some(Arc::new(f)))
    }

    /// No reports (the default).
    pub fn none() -> Self {
        Self(None)
    }
}

impl fmt::Debug for ProgressSink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(if self.0.is_some() {
            "ProgressSink(callback)"
        } else {
            "ProgressSink(none)"
        })
    }
}

/// The counters of one diagnosis, shared by the fit workers; each change is reported.
pub(crate) struct Tracker {
    sink: ProgressSink,
    done: AtomicU64,
    total: AtomicU64,
    stage: Mutex<String>,
}

impl Tracker {
    pub(crate) fn new(sink: &ProgressSink, total: u64, stage: &str) -> Self {
        let t = Self {
            sink: sink.clone(),
            done: AtomicU64::new(0),
            total: AtomicU64::new(total),
            stage: Mutex::new(stage.to_string()),
        };
        t.report();
        t
    }

    fn report(&self) {
        if let Some(f) = &self.sink.0 {
            let stage = self.stage.lock().map(|s| s.clone()).unwrap_or_default();
            f(&Progress {
                stage,
                done: self.done.load(Ordering::SeqCst),
                total: self.total.load(Ordering::SeqCst),
            });
        }
    }

    /// One more fit finished.
    pub(crate) fn inc(&self) {
        self.done.fetch_add(1, Ordering::SeqCst);
        self.report();
    }

    /// `n` more fits to come, now in `stage`.
    pub(crate) fn add_stage(&self, n: u64, stage: String) {
        self.total.fetch_add(n, Ordering::SeqCst);
        if let Ok(mut s) = self.stage.lock() {
            *s = stage;
        }
        self.report();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_reach_the_callback_in_order() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let s2 = seen.clone();
        let sink = ProgressSink::new(move |p| s2.lock().unwrap().push(p.clone()));
        let t = Tracker::new(&sink, 1, "refit nominal");
        t.inc();
        t.add_stage(3, "round 1".into());
        t.inc();
        let seen = seen.lock().unwrap();
        let got: Vec<(String, u64, u64)> = seen
            .iter()
            .map(|p| (p.stage.clone(), p.done, p.total))
            .collect();
        assert_eq!(
            got,
            vec![
                ("refit nominal".into(), 0, 1),
                ("refit nominal".into(), 1, 1),
                ("round 1".into(), 1, 4),
                ("round 1".into(), 2, 4),
            ]
        );
    }

    #[test]
    fn no_sink_no_calls() {
        let t = Tracker::new(&ProgressSink::none(), 2, "x");
        t.inc();
        assert_eq!(t.done.load(Ordering::SeqCst), 1);
    }
}
