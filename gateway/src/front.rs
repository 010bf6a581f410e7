//! What the command line does around a procedure: the runtime, Ctrl-C as the stop
//! signal, a progress bar, artifacts written atomically into the output folder (never
//! over an input), and the outcome printed (`--json`: the procedure's result object, the
//! same one the service stores).

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use procedure::files::Files;
use procedure::{Artifact, LogRow, Outcome, Sink, Stop};
use serde_json::Value;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// A runtime for one command: two workers, so bus tasks (heartbeats, status polling,
/// emulators in-process) keep running while a frame is localized on the other.
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?)
}

/// Completes on Ctrl-C (never where signals cannot be handled).
pub async fn ctrl_c() {
    if tokio::signal::ctrl_c().await.is_err() {
        std::future::pending::<()>().await;
    }
}

/// Writes `bytes` to `path` atomically, never over one of `inputs`
/// (`protocol::config::write_output`).
pub fn write_atomic(path: &Path, bytes: &[u8], inputs: &[PathBuf]) -> anyhow::Result<()> {
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    protocol::config::write_output(path, bytes, &inputs)
        .with_context(|| format!("writing {}", path.display()))
}

/// The command line's sink.
pub struct CliSink {
    bar: ProgressBar,
    /// Where artifacts go (none: not written), and under which names.
    out: Option<PathBuf>,
    rename: Vec<(String, PathBuf)>,
    inputs: Vec<PathBuf>,
    /// The logs being grown ([`Sink::log_row`]), open for appending.
    logs: Vec<(String, std::fs::File)>,
    /// What was written where: `(artifact name, path)`.
    written: Vec<(String, PathBuf)>,
    /// How a partial result is printed as it comes: `--json` (one object a line), else
    /// the kind's summary.
    partial: Option<(bool, &'static procedure::registry::Kind)>,
}

impl CliSink {
    /// `what` names the steps on the bar ("targets", "frames"); hidden with `--json`.
    pub fn new(what: &str, json: bool) -> Self {
        let bar = if json {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(0)
        };
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{{spinner}} [{{bar:30}}] {{pos}}/{{len}} {what}, {{elapsed}} so far, about {{eta}} left"
            ))
            .expect("valid template")
            .progress_chars("=> "),
        );
        Self {
            bar,
            out: None,
            rename: Vec::new(),
            inputs: Vec::new(),
            logs: Vec::new(),
            written: Vec::new(),
            partial: None,
        }
    }

    /// Artifacts are written into `dir`, created with the first thing written into it
    /// (a run refused before that leaves no folder behind).
    pub fn into_folder(mut self, dir: &Path) -> Self {
        self.out = Some(dir.to_path_buf());
        self
    }

    /// The output folder, created when it is not there yet.
    fn folder(&self) -> Result<Option<&Path>, procedure::Error> {
        let Some(dir) = &self.out else {
            return Ok(None);
        };
        std::fs::create_dir_all(dir)
            .map_err(|e| procedure::Error::Output(format!("creating {}: {e}", dir.display())))?;
        Ok(Some(dir))
    }

    /// Where the artifact `name` goes (none: it is not written).
    fn path_of(&self, name: &str) -> Result<Option<PathBuf>, procedure::Error> {
        Ok(match self.rename.iter().find(|(n, _)| *n == name) {
            Some((_, p)) => Some(p.clone()),
            None => self.folder()?.map(|dir| dir.join(name)),
        })
    }

    /// The artifact `name` is written to `path` instead (only those named, when no
    /// folder is given).
    pub fn artifact_to(mut self, name: &str, path: PathBuf) -> Self {
        self.rename.push((name.to_string(), path));
        self
    }

    /// Files the command reads: never written over.
    pub fn inputs(mut self, inputs: &[&Path]) -> Self {
        self.inputs = inputs.iter().map(|p| p.to_path_buf()).collect();
        self
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }

    /// Partial results ([`Sink::partial_result`]) printed as they come.
    pub fn print_partials(mut self, json: bool, kind: &'static procedure::registry::Kind) -> Self {
        self.partial = Some((json, kind));
        self
    }

    /// What was written where, `(artifact name, path)`, in order.
    pub fn written(&self) -> Vec<(String, PathBuf)> {
        self.written.clone()
    }

    fn wrote(&mut self, name: &str, path: &Path) {
        if !self.written.iter().any(|(n, _)| n == name) {
            self.written.push((name.to_string(), path.to_path_buf()));
        }
    }
}

impl Sink for CliSink {
    fn progress(&mut self, done: u64, total: u64) {
        self.bar.set_position(done);
        // A new total (the first call, or a resumed scan's start) restarts the estimate.
        if self.bar.length() != Some(total) {
            self.bar.set_length(total);
            self.bar.reset_eta();
        }
    }

    fn measurement(&mut self, _: &Value) -> Result<(), procedure::Error> {
        Ok(())
    }

    fn log_row(&mut self, row: &LogRow) -> Result<(), procedure::Error> {
        if let Some((_, file)) = self.logs.iter_mut().find(|(n, _)| n == row.log) {
            return file
                .write_all(row.row.as_bytes())
                .and_then(|()| file.sync_data())
                .map_err(|e| procedure::Error::Output(format!("{}: {e}", row.log)));
        }
        // The header and the first row written whole (never over an input), then the
        // file opened for the rows to come.
        let Some(path) = self.path_of(row.log)? else {
            return Ok(());
        };
        let first = format!("{}{}", row.header, row.row);
        write_atomic(&path, first.as_bytes(), &self.inputs).map_err(not_written)?;
        self.wrote(row.log, &path);
        let file = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .map_err(|e| procedure::Error::Output(format!("opening {}: {e}", path.display())))?;
        self.logs.push((row.log.to_string(), file));
        Ok(())
    }

    fn artifact(&mut self, artifact: Artifact) -> Result<(), procedure::Error> {
        let Some(path) = self.path_of(&artifact.name)? else {
            return Ok(());
        };
        // A log grown so far is replaced whole.
        self.logs.retain(|(n, _)| *n != artifact.name);
        write_atomic(&path, &artifact.bytes, &self.inputs).map_err(not_written)?;
        self.wrote(&artifact.name, &path);
        Ok(())
    }

    fn partial_result(&mut self, result: &Value) {
        let Some((json, kind)) = self.partial else {
            return;
        };
        let mut text = if json {
            result.to_string()
        } else {
            kind.summary(result)
        };
        if !text.ends_with('\n') {
            text.push('\n');
        }
        self.bar.suspend(|| {
            let _ = emit(&text);
        });
    }

    fn check_outputs(&mut self, names: &[String]) -> Result<(), procedure::Error> {
        let inputs: Vec<&Path> = self.inputs.iter().map(PathBuf::as_path).collect();
        for name in names {
            let Some(path) = self.path_of(name)? else {
                continue;
            };
            protocol::config::check_output(&path, &inputs).map_err(|e| {
                procedure::Error::Output(format!("writing {}: {e}", path.display()))
            })?;
        }
        Ok(())
    }

    fn artifact_streamed(
        &mut self,
        name: String,
        _: &'static str,
        write: &mut dyn FnMut(&mut dyn Write) -> std::io::Result<()>,
    ) -> Result<(), procedure::Error> {
        let Some(path) = self.path_of(&name)? else {
            return Ok(());
        };
        let inputs: Vec<&Path> = self.inputs.iter().map(PathBuf::as_path).collect();
        protocol::config::write_output_with(&path, &inputs, write)
            .map_err(|e| procedure::Error::Output(format!("writing {}: {e}", path.display())))?;
        self.wrote(&name, &path);
        Ok(())
    }
}

/// An output the command could not write.
fn not_written(e: anyhow::Error) -> procedure::Error {
    procedure::Error::Output(format!("{e:#}"))
}

/// Writes `text` to stdout; a reader that has gone (`| head -1`) ends the output
/// quietly instead of panicking as `println!` does on a closed pipe.
pub fn emit(text: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}

/// Prints an outcome: `--json` the result object (the service's too), else `text` of
/// it; a failure's message goes to stderr and the exit code is 1. A failure with
/// nothing to show is returned as the error (main prints it, as JSON with `--json`).
pub fn print(
    outcome: &Outcome,
    json: bool,
    text: impl FnOnce(&Value) -> String,
) -> anyhow::Result<ExitCode> {
    let Some(result) = &outcome.result else {
        anyhow::bail!("{}", outcome.error().unwrap_or("cancelled"));
    };
    let mut shown = if json {
        json_shown(outcome, result)
    } else {
        text(result)
    };
    if !shown.ends_with('\n') {
        shown.push('\n');
    }
    emit(&shown)?;
    match &outcome.end {
        procedure::End::Succeeded => Ok(ExitCode::SUCCESS),
        procedure::End::Failed { error } => {
            eprintln!("error: {error}");
            Ok(ExitCode::FAILURE)
        }
        procedure::End::Cancelled => {
            eprintln!("cancelled: the stage was told to stop; what was measured is kept");
            Ok(ExitCode::FAILURE)
        }
    }
}

/// The `--json` result of an outcome: a failure's object carries its `error` (issue 38:
/// a failed spot check printed a result with zero points and no error); a result that
/// names its own error (a compensation report) keeps it.
fn json_shown(outcome: &Outcome, result: &Value) -> String {
    let mut shown = result.clone();
    if let (Some(object), Some(error)) = (shown.as_object_mut(), outcome.error()) {
        object.entry("error").or_insert_with(|| error.into());
    }
    shown.to_string()
}

/// Runs the registered procedure `kind` on `request` (checked once here: an error names
/// the flag) in the files context `configure` makes of the command's files, with Ctrl-C
/// as the stop signal: its outcome.
pub fn run_outcome(
    kind: &procedure::registry::Kind,
    request: &impl serde::Serialize,
    sink: &mut CliSink,
    configure: impl for<'s> FnOnce(Files<'s>) -> Files<'s>,
) -> anyhow::Result<Outcome> {
    let params = serde_json::to_value(request)?;
    let params = kind
        .parse(&params)
        .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let rt = runtime()?;
    let (raise, stop) = Stop::new();
    let outcome = rt.block_on(async {
        // Ctrl-C raises the stop: the procedure stops the stage and ends with what it
        // measured so far.
        let watcher = tokio::spawn(async move {
            ctrl_c().await;
            let _ = raise.send(true);
        });
        let mut files = configure(Files::new(&mut *sink, stop));
        let outcome = kind.run(params, &mut files).await;
        watcher.abort();
        outcome
    });
    sink.finish();
    Ok(outcome)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A log grows row by row under one header (a stopped run keeps its rows), is
    /// replaced whole by the artifact of its name, and is never written over an input.
    #[test]
    fn a_log_grows_a_row_at_a_time_and_the_artifact_replaces_it() {
        let dir = std::env::temp_dir().join(format!("gateway-front-log-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut sink = CliSink::new("", true).into_folder(&dir);
        let row = |row| LogRow {
            log: "m.csv",
            header: "a,b\n",
            row,
        };
        sink.log_row(&row("1,2\n")).unwrap();
        sink.log_row(&row("3,4\n")).unwrap();
        let text = std::fs::read_to_string(dir.join("m.csv")).unwrap();
        assert_eq!(text, "a,b\n1,2\n3,4\n");
        let whole = Artifact {
            name: "m.csv".into(),
            title: None,
            media_type: "text/csv",
            bytes: b"a,b\n9,9\n".to_vec(),
        };
        sink.artifact(whole).unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.join("m.csv")).unwrap(),
            "a,b\n9,9\n"
        );
        let input = dir.join("in.csv");
        std::fs::write(&input, "keep").unwrap();
        let mut sink = CliSink::new("", true).artifact_to("m.csv", input.clone());
        sink.inputs = vec![input.clone()];
        assert!(sink.log_row(&row("1,2\n")).is_err());
        assert_eq!(std::fs::read_to_string(&input).unwrap(), "keep");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failed_outcomes_json_names_its_error() {
        let mut failed = Outcome::failed("the spot check found no dot");
        failed.result = Some(serde_json::json!({"points": []}));
        let shown: Value =
            serde_json::from_str(&json_shown(&failed, failed.result.as_ref().unwrap())).unwrap();
        assert_eq!(shown["error"], "the spot check found no dot");
        assert_eq!(shown["points"], serde_json::json!([]));
        let ok = Outcome::succeeded(serde_json::json!({"points": [1]}), Default::default());
        let shown: Value =
            serde_json::from_str(&json_shown(&ok, ok.result.as_ref().unwrap())).unwrap();
        assert!(shown.get("error").is_none(), "{shown}");
        let mut own = Outcome::failed("stopped at target #1");
        own.result = Some(serde_json::json!({"error": "target #1: the board was not found"}));
        let shown: Value =
            serde_json::from_str(&json_shown(&own, own.result.as_ref().unwrap())).unwrap();
        assert_eq!(shown["error"], "target #1: the board was not found");
    }
}
