//! Ctrl-C (SIGINT, and SIGTERM and SIGHUP) as a request to stop at the next safe point: the running fit
//! saves its state and `run` returns `Interrupted`, which the CLI prints as one line and exits
//! with 130. A second Ctrl-C quits at once (what was saved stays valid: every file and
//! checkpoint folder appears atomically).
//!
//! Owns: the stop flag and its signal handler. Must not touch: what is saved.

use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);

/// The error a stage returns when it stopped on request; its text is the one line to print.
#[derive(Debug)]
pub struct Interrupted(pub String);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Interrupted {}

/// Installs the handler (once per process; later calls do nothing).
pub fn install() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = ctrlc::set_handler(|| {
            if STOP.swap(true, Ordering::SeqCst) {
                eprintln!("\ninterrupted again: quitting now");
                std::process::exit(130);
            }
            // A person at a terminal hears at once; a script gets only the final line.
            if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
                eprintln!("\nstopping at the next safe point (Ctrl-C again quits at once)");
            }
        });
    });
}

/// Installs a handler for commands with no safe point to stop at (every file they write
/// appears atomically): the first Ctrl-C prints one line and exits with 130 at once.
pub fn install_quit() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = ctrlc::set_handler(|| {
            eprintln!("interrupted");
            std::process::exit(130);
        });
    });
}

/// Whether a stop was requested.
pub fn requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

/// `Err(Interrupted(msg()))` when a stop was requested.
pub fn check(msg: impl FnOnce() -> String) -> anyhow::Result<()> {
    if requested() {
        return Err(Interrupted(msg()).into());
    }
    Ok(())
}

/// `e` with its message replaced by `msg()` when it is an `Interrupted` (a stage that stopped
/// says where in the pipeline it was); other errors unchanged.
pub fn reword(e: anyhow::Error, msg: impl FnOnce() -> String) -> anyhow::Error {
    if e.is::<Interrupted>() {
        Interrupted(msg()).into()
    } else {
        e
    }
}
