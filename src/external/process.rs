//! Running a feature program on a folder: its output collected, its time limited.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use super::ExternalError;
use crate::features::ExternalFeatureConfig;

/// Lines of a failed program's stderr its error quotes.
const STDERR_LINES: usize = 10;

/// Runs `program` with `folder` appended to its arguments and returns its standard output.
///
/// # Errors
/// It cannot start, exits with a failure (quoting the end of its stderr), or runs past its
/// `timeout_seconds` (it is then killed).
pub(super) fn run(
    program: &ExternalFeatureConfig,
    folder: &Path,
) -> Result<Vec<u8>, ExternalError> {
    let label = program.label();
    let mut child = Command::new(&program.command[0])
        .args(&program.command[1..])
        .arg(folder)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|source| ExternalError::Start {
            program: label.clone(),
            source,
        })?;
    let stdout = drain(child.stdout.take());
    let stderr = drain(child.stderr.take());
    let limit = Duration::from_secs_f64(program.timeout_seconds);
    let clock = Instant::now();
    let timeout = || ExternalError::Timeout {
        program: label.clone(),
        seconds: program.timeout_seconds,
    };
    let mut pause = Duration::from_millis(1);
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) if clock.elapsed() >= limit => {
                // Stopped, then reaped so that no zombie is left behind.
                let _ = child.kill();
                let _ = child.wait();
                return Err(timeout());
            }
            Ok(None) => {
                std::thread::sleep(pause.min(limit.saturating_sub(clock.elapsed())));
                pause = (pause * 2).min(Duration::from_millis(50));
            }
            Err(source) => {
                let _ = child.kill();
                return Err(ExternalError::Start {
                    program: label.clone(),
                    source,
                });
            }
        }
    };
    // A child of the program may still hold the pipes open: wait for them within the limit.
    let left = |clock: Instant| limit.saturating_sub(clock.elapsed());
    let out = stdout.recv_timeout(left(clock)).map_err(|_| timeout())?;
    let err = stderr.recv_timeout(left(clock)).unwrap_or_default();
    if !status.success() {
        return Err(ExternalError::Failed {
            program: label,
            status: status.to_string(),
            stderr: tail(&err),
        });
    }
    Ok(out)
}

/// Reads a pipe to its end on a thread of its own, so that neither pipe can fill and block the
/// program.
fn drain(pipe: Option<impl Read + Send + 'static>) -> mpsc::Receiver<Vec<u8>> {
    let (send, receive) = mpsc::channel();
    std::thread::spawn(move || {
        let mut bytes = Vec::new();
        if let Some(mut pipe) = pipe {
            let _ = pipe.read_to_end(&mut bytes);
        }
        let _ = send.send(bytes);
    });
    receive
}

/// The last lines of a program's stderr, or a note that it wrote none.
fn tail(stderr: &[u8]) -> String {
    let text = String::from_utf8_lossy(stderr);
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    if lines.is_empty() {
        return "(its stderr is empty)".into();
    }
    lines[lines.len().saturating_sub(STDERR_LINES)..].join("\n")
}
