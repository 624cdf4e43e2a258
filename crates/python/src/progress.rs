//! A Python callable as the pipeline's [`Progress`]: `callback(step, done, total)`, called from
//! whichever thread advances, with the GIL taken for the call only, at most every 100 ms for one
//! step (and always at its start and end). An exception in the callback does not stop the run (the
//! pipeline cannot be interrupted half-way); the first one is raised when the call returns.

use std::sync::Mutex;
use std::time::{Duration, Instant};

use handheld_core::Progress;
use pyo3::prelude::*;

const EVERY: Duration = Duration::from_millis(100);

struct Step {
    label: String,
    done: u64,
    total: u64,
    last: Instant,
}

pub struct PyProgress {
    callback: Option<Py<PyAny>>,
    step: Mutex<Step>,
    error: Mutex<Option<PyErr>>,
}

impl PyProgress {
    pub fn new(callback: Option<Py<PyAny>>) -> Self {
        Self {
            callback,
            step: Mutex::new(Step {
                label: String::new(),
                done: 0,
                total: 0,
                last: Instant::now(),
            }),
            error: Mutex::new(None),
        }
    }

    /// Raises the first exception the callback raised, if any.
    pub fn raise_callback_error(&self) -> PyResult<()> {
        match self.error.lock().map(|mut e| e.take()) {
            Ok(Some(e)) => Err(e),
            _ => Ok(()),
        }
    }

    /// Updates the step under its lock; calls back (outside the lock) when `update` says so.
    fn update(&self, update: impl FnOnce(&mut Step) -> bool) {
        let Some(cb) = &self.callback else { return };
        let call = {
            let Ok(mut s) = self.step.lock() else { return };
            if !update(&mut s) {
                return;
            }
            s.last = Instant::now();
            (s.label.clone(), s.done, s.total)
        };
        Python::attach(|py| {
            if let Err(e) = cb.call1(py, call) {
                if let Ok(mut slot) = self.error.lock() {
                    slot.get_or_insert(e);
                }
            }
        });
    }
}

impl Progress for PyProgress {
    fn start(&self, label: &str, len: u64) {
        self.update(|s| {
            s.label = label.to_string();
            s.done = 0;
            s.total = len;
            true
        });
    }

    fn inc(&self, n: u64) {
        self.update(|s| {
            s.done += n;
            s.last.elapsed() >= EVERY || (s.total > 0 && s.done >= s.total)
        });
    }

    fn finish(&self) {
        self.update(|s| {
            s.done = s.done.max(s.total);
            true
        });
    }
}
