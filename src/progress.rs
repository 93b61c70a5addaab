//! Progress of the library's long jobs (training), reported through a trait object so that the
//! library needs no terminal crate: the command-line tool draws a bar from it, a library user
//! logs it or passes [`Silent`] (issue 33 item 4).

/// What a long job reports as it goes. Every method has an empty default.
pub trait Progress {
    /// The job runs to step `total` and starts at `position` (past 0 when it resumes).
    fn start(&mut self, _total: u64, _position: u64) {}
    /// It reached `position`; `message` is a short status (the smoothed loss, the last validation).
    fn update(&mut self, _position: u64, _message: &str) {}
    /// A line worth keeping (a validation result), printed above any bar.
    fn line(&mut self, _line: &str) {}
    /// The job is done.
    fn finish(&mut self) {}
}

/// Reports nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {}
