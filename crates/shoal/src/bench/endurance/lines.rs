//! How the benchmark talks to its two processes: one line on the child's stdin per
//! request, one line back on its stdout, `<word> <field>...`, the request's first word
//! first. Both children (the fleet and the station) speak it.

use std::io::{BufRead as _, Write as _};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tokio::io::{AsyncBufReadExt as _, AsyncWriteExt as _};

use super::super::helpers::{helper, rss_mb_of};
use crate::config::ShoalConfig;

/// The word of a child's first line, once it is up.
pub(super) const READY: &str = "ready";
/// Waits for a child to come up (announce its vehicles, open its history).
const READY_WITHIN: Duration = Duration::from_secs(60);
/// Waits for any other answer. A child answers within milliseconds, or within the
/// request's own bound (the station's `alive` waits up to 60 s), so this only turns a
/// stuck process into an error instead of a hang.
const ANSWER_WITHIN: Duration = Duration::from_secs(90);

/// A child process of the benchmark, driven line by line.
pub(super) struct LineChild {
    name: &'static str,
    /// Every word this child answers with; a line opening with another word is not an
    /// answer (a library printing to stdout) and is skipped.
    words: &'static [&'static str],
    child: tokio::process::Child,
    pub(super) pid: String,
    stdin: tokio::process::ChildStdin,
    lines: tokio::io::Lines<tokio::io::BufReader<tokio::process::ChildStdout>>,
}

impl LineChild {
    /// Starts `shoal bench <args>` and waits for its `ready` line; its fields are returned.
    pub(super) async fn start(
        cfg: &ShoalConfig,
        name: &'static str,
        words: &'static [&'static str],
        args: &[String],
    ) -> Result<(Self, Vec<String>)> {
        let mut child = helper(cfg, args).with_context(|| format!("cannot start the {name}"))?;
        let pid = child
            .id()
            .with_context(|| format!("the {name} ended as it started"))?
            .to_string();
        let stdin = child.stdin.take().context("no child stdin")?;
        let stdout = child.stdout.take().context("no child stdout")?;
        let mut me = Self {
            name,
            words,
            child,
            pid,
            stdin,
            lines: tokio::io::BufReader::new(stdout).lines(),
        };
        let fields = me.answer(READY, READY_WITHIN).await?;
        Ok((me, fields))
    }

    /// Sends `request` and returns the fields of its answer.
    pub(super) async fn ask(&mut self, request: &str) -> Result<Vec<String>> {
        let word = request.split_whitespace().next().unwrap_or_default();
        let line = format!("{request}\n");
        if let Err(e) = self.stdin.write_all(line.as_bytes()).await {
            let ended = self.exit_status().await;
            bail!("cannot ask the {} `{request}` ({e}): it {ended}", self.name);
        }
        self.answer(word, ANSWER_WITHIN).await
    }

    /// The next answer, which must open with `word`.
    async fn answer(&mut self, word: &str, within: Duration) -> Result<Vec<String>> {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            let line = match tokio::time::timeout_at(deadline, self.lines.next_line()).await {
                Err(_) => bail!(
                    "the {} (pid {}) did not answer `{word}` within {} s",
                    self.name,
                    self.pid,
                    within.as_secs()
                ),
                Ok(Ok(Some(line))) => line,
                Ok(Ok(None)) => {
                    let ended = self.exit_status().await;
                    bail!("the {} {ended} before answering `{word}`", self.name);
                }
                Ok(Err(e)) => {
                    return Err(e)
                        .with_context(|| format!("cannot read the {}'s answer", self.name));
                }
            };
            match split_answer(&line, self.words) {
                Some((w, fields)) if w == word => return Ok(fields),
                Some((w, _)) => bail!(
                    "the {} answered `{w}` where `{word}` was due: out of step",
                    self.name
                ),
                None => {}
            }
        }
    }

    /// How the process ended, for an error message ("ended with exit status: 1").
    pub(super) async fn exit_status(&mut self) -> String {
        match tokio::time::timeout(Duration::from_secs(5), self.child.wait()).await {
            Ok(Ok(status)) => format!("ended with {status} (its error, if any, is above)"),
            Ok(Err(e)) => format!("cannot be waited for ({e})"),
            Err(_) => "closed its output but did not end".to_string(),
        }
    }

    /// The child's resident memory, MB.
    pub(super) fn rss_mb(&self) -> f64 {
        rss_mb_of(&self.pid)
    }

    /// Sends `request` (which tells the child to end), waits for the child to end, and
    /// returns the answer's fields.
    pub(super) async fn stop(mut self, request: &str) -> Result<Vec<String>> {
        let last = self.ask(request).await?;
        drop(self.stdin);
        match tokio::time::timeout(Duration::from_secs(30), self.child.wait()).await {
            Ok(Ok(status)) if status.success() => Ok(last),
            Ok(Ok(status)) => bail!("the {} ended with {status}", self.name),
            Ok(Err(e)) => Err(e).with_context(|| format!("cannot wait for the {}", self.name)),
            // Dropping the child kills it.
            Err(_) => bail!(
                "the {} did not end within 30 s of being told to stop",
                self.name
            ),
        }
    }
}

/// `<word> <field>...` with a word of `words`, or `None` for any other line.
pub(super) fn split_answer<'a>(line: &'a str, words: &[&str]) -> Option<(&'a str, Vec<String>)> {
    let mut parts = line.split_whitespace();
    let word = parts.next().filter(|w| words.contains(w))?;
    Some((word, parts.map(str::to_owned).collect()))
}

/// The `i`-th field as a number, or an error naming what was asked.
pub(super) fn field<T: std::str::FromStr>(fields: &[String], i: usize, what: &str) -> Result<T> {
    fields
        .get(i)
        .and_then(|f| f.parse().ok())
        .with_context(|| format!("no {what} in the answer {fields:?}"))
}

/// Lines from stdin until it closes. A plain thread, not `tokio::io::stdin`: that read
/// runs on the runtime's blocking pool, which the runtime waits for when it shuts down, so
/// the process could not end while the parent still held the pipe open.
pub(super) fn stdin_lines() -> Result<tokio::sync::mpsc::UnboundedReceiver<String>> {
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    std::thread::Builder::new()
        .name("bench-commands".into())
        .spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        })
        .context("cannot start the command reader")?;
    Ok(rx)
}

/// Answers the benchmark process with one line.
pub(super) fn tell_parent(line: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")
        .and_then(|()| out.flush())
        .context("cannot answer the benchmark process (has it ended?)")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_open_with_a_word_of_the_protocol_and_anything_else_is_skipped() {
        let words = ["ready", "count", "stop"];
        assert_eq!(
            split_answer("count 12 3", &words),
            Some(("count", vec!["12".to_string(), "3".to_string()]))
        );
        assert_eq!(split_answer("ready", &words), Some(("ready", vec![])));
        for junk in ["", "progress 1 2", "1970-01-01 some library's banner"] {
            assert_eq!(split_answer(junk, &words), None, "{junk:?}");
        }
        let fields = vec!["12".to_string(), "x".to_string()];
        assert_eq!(field::<u64>(&fields, 0, "completed").unwrap(), 12);
        assert!(field::<u64>(&fields, 1, "twice").is_err());
        assert!(field::<u64>(&fields, 2, "twice").is_err());
    }
}
