//! Progress of runs (`run`, `sweep`): one overall line (runs done of total, elapsed, time left)
//! above one line per run in progress. On a terminal these are bars redrawn in place (a few
//! times a second, only the running runs' lines, so the output stays small however long the
//! sweep); otherwise (a pipe, CI) plain lines: one per finished run, and at most one status line
//! every [`STATUS_EVERY`] naming what the running runs are doing.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Least time between two status lines when stderr is not a terminal.
const STATUS_EVERY: Duration = Duration::from_secs(30);
/// Running runs named on one status line; the rest are counted.
const STATUS_RUNS: usize = 4;
/// Redraws per second on a terminal.
const DRAWS_PER_SECOND: u8 = 4;

/// The progress of a set of runs, updated from any thread.
pub(super) struct StageBars {
    names: Vec<String>,
    start: Instant,
    state: Mutex<State>,
    terminal: Option<Terminal>,
}

struct State {
    finished: usize,
    /// Per run: when it started and what it is doing (`None` before it starts and once done).
    running: Vec<Option<(Instant, String)>>,
    last_status: Instant,
}

struct Terminal {
    multi: MultiProgress,
    overall: ProgressBar,
    /// Per run: its line while it runs.
    lines: Mutex<Vec<Option<ProgressBar>>>,
}

/// What a run is doing: the stage and its counter (`track gp 120/200`); a stage without frames
/// (a fit reports 0 of 1) has none, and the counter never shows more done than its total.
pub(super) fn stage_text(stage: &str, done: usize, total: usize) -> String {
    if total <= 1 {
        stage.to_string()
    } else {
        format!("{stage} {}/{total}", done.min(total))
    }
}

/// `seconds` as `1h02m`, `3m05s`, `42s` or `0.4s`.
fn duration_text(seconds: f64) -> String {
    if seconds < 9.95 {
        return format!("{:.1}s", seconds.max(0.0));
    }
    let s = seconds.round() as u64;
    match s {
        0..=59 => format!("{s}s"),
        60..=3599 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, (s % 3600) / 60),
    }
}

impl StageBars {
    /// Progress of the runs `names`, in the order their indices refer to.
    pub(super) fn new(names: &[String]) -> Self {
        let now = Instant::now();
        let terminal = std::io::stderr().is_terminal().then(|| {
            let multi = MultiProgress::with_draw_target(ProgressDrawTarget::stderr_with_hz(
                DRAWS_PER_SECOND,
            ));
            let overall = multi.add(ProgressBar::new(names.len() as u64));
            overall.set_style(
                ProgressStyle::with_template("[{bar:30}] {pos}/{len} runs, {elapsed} elapsed{msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
            );
            overall.set_message(", time left unknown");
            // Its clock moves between finished runs.
            overall.enable_steady_tick(Duration::from_secs(1));
            Terminal {
                multi,
                overall,
                lines: Mutex::new(vec![None; names.len()]),
            }
        });
        Self {
            names: names.to_vec(),
            start: now,
            state: Mutex::new(State {
                finished: 0,
                running: vec![None; names.len()],
                last_status: now,
            }),
            terminal,
        }
    }

    /// Run `run` is at `stage`, `done` of `total` frames.
    pub(super) fn update(&self, run: usize, stage: &str, done: usize, total: usize) {
        let text = stage_text(stage, done, total);
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let Some(slot) = state.running.get_mut(run) else {
            return;
        };
        let started = slot.as_ref().map_or_else(Instant::now, |s| s.0);
        *slot = Some((started, text.clone()));
        match &self.terminal {
            Some(t) => {
                let mut lines = t.lines.lock().unwrap_or_else(|e| e.into_inner());
                let line = lines[run].get_or_insert_with(|| {
                    let bar = t.multi.add(ProgressBar::new_spinner());
                    bar.set_style(
                        ProgressStyle::with_template("{prefix:>24} {spinner} {msg} {elapsed}")
                            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
                    );
                    bar.set_prefix(self.names[run].clone());
                    bar.enable_steady_tick(Duration::from_millis(250));
                    bar
                });
                line.set_message(text);
            }
            None if state.last_status.elapsed() >= STATUS_EVERY => {
                state.last_status = Instant::now();
                eprintln!("{}", self.status_line(&state));
            }
            None => {}
        }
    }

    /// The plain status line: runs done, then what the running runs are doing.
    fn status_line(&self, state: &State) -> String {
        let running: Vec<String> = state
            .running
            .iter()
            .enumerate()
            .filter_map(|(k, r)| r.as_ref().map(|(_, s)| format!("{}: {s}", self.names[k])))
            .collect();
        let more = running.len().saturating_sub(STATUS_RUNS);
        let mut line = format!(
            "[{}/{} runs, {} elapsed] {}",
            state.finished,
            self.names.len(),
            duration_text(self.start.elapsed().as_secs_f64()),
            running[..running.len().min(STATUS_RUNS)].join("; ")
        );
        if more > 0 {
            line.push_str(&format!("; and {more} more"));
        }
        line
    }

    /// The estimated time left: the sweep's pace so far (runs finished per second, whatever
    /// the parallelism) over the runs left.
    fn time_left(&self, finished: usize) -> String {
        let left = self.names.len() - finished;
        match (finished, left) {
            (_, 0) => "finished".into(),
            (0, _) => "time left unknown".into(),
            _ => {
                let pace = self.start.elapsed().as_secs_f64() / finished as f64;
                format!("about {} left", duration_text(pace * left as f64))
            }
        }
    }

    /// Run `run` is over: its line goes, the overall count moves (and, without a terminal, one
    /// line says so).
    pub(super) fn done(&self, run: usize, failed: bool) {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let Some(slot) = state.running.get_mut(run) else {
            return;
        };
        let took = slot.take().map_or(0.0, |s| s.0.elapsed().as_secs_f64());
        state.finished += 1;
        let left = self.time_left(state.finished);
        match &self.terminal {
            Some(t) => {
                let mut lines = t.lines.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(line) = lines[run].take() {
                    line.finish_and_clear();
                    t.multi.remove(&line);
                }
                t.overall.set_position(state.finished as u64);
                t.overall.set_message(format!(", {left}"));
                if failed {
                    t.overall.println(format!(
                        "{} failed after {}",
                        self.names[run],
                        duration_text(took)
                    ));
                }
            }
            None => eprintln!(
                "[{}/{} runs] {} {} after {}; {} elapsed, {left}",
                state.finished,
                self.names.len(),
                self.names[run],
                if failed { "failed" } else { "done" },
                duration_text(took),
                duration_text(self.start.elapsed().as_secs_f64()),
            ),
        }
    }

    /// Clears the terminal lines (the plain lines stay in the log).
    pub(super) fn finish(&self) {
        if let Some(t) = &self.terminal {
            let lines = t.lines.lock().unwrap_or_else(|e| e.into_inner());
            for line in lines.iter().flatten() {
                line.finish_and_clear();
            }
            t.overall.finish_and_clear();
            let _ = t.multi.clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_shows_its_own_counter_never_past_its_total() {
        assert_eq!(stage_text("fit gp", 0, 1), "fit gp");
        assert_eq!(stage_text("track gp", 120, 200), "track gp 120/200");
        assert_eq!(
            stage_text("validation features", 400, 100),
            "validation features 100/100"
        );
    }

    #[test]
    fn durations_read_as_a_person_would_say_them() {
        assert_eq!(duration_text(42.4), "42s");
        assert_eq!(duration_text(0.44), "0.4s");
        assert_eq!(duration_text(185.0), "3m05s");
        assert_eq!(duration_text(3720.0), "1h02m");
    }
}
