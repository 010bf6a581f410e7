//! `--trace FILE.csv`: the simulated machine's executed path written as it runs, so a
//! test or a user can compare a whole path with the program (truth; the gateway never
//! reads it).
//!
//! Columns `t_s,cmd_x_mm,cmd_y_mm,true_x_mm,true_y_mm`: simulated seconds, the
//! controller's position and where the tool really is, machine coordinates (mm, 6
//! decimals). A row at least every 0.05 mm of motion and at every move's end
//! ([`world::machine::TRACE_STEP_MM`]). The file is flushed every 20 ms of wall time, so
//! killing the emulator loses at most that.

use std::io::{self, BufWriter, Write};
use std::path::Path;
use std::time::Duration;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use world::machine::TraceRow;
use world::{lock, SharedRig};

pub const HEADER: &str = "t_s,cmd_x_mm,cmd_y_mm,true_x_mm,true_y_mm";

/// Rows as CSV lines.
pub fn write_rows(w: &mut impl Write, rows: &[TraceRow]) -> io::Result<()> {
    for r in rows {
        writeln!(
            w,
            "{:.6},{:.6},{:.6},{:.6},{:.6}",
            r.t_s, r.cmd_mm[0], r.cmd_mm[1], r.true_mm[0], r.true_mm[1]
        )?;
    }
    Ok(())
}

/// A trace being written; [`TraceFile::finish`] writes the last rows.
pub struct TraceFile {
    stop: Option<oneshot::Sender<()>>,
    task: JoinHandle<io::Result<u64>>,
}

impl TraceFile {
    /// Create (or truncate) `path`, write the header and start recording the rig's
    /// machine. Must run inside a tokio runtime.
    pub fn start(rig: SharedRig, path: &Path) -> io::Result<TraceFile> {
        let mut out = BufWriter::new(std::fs::File::create(path)?);
        writeln!(out, "{HEADER}")?;
        lock(&rig).machine_mut().start_trace();
        let (tx, mut rx) = oneshot::channel();
        let task = tokio::spawn(async move {
            let mut rows = 0u64;
            let mut tick = tokio::time::interval(Duration::from_millis(20));
            loop {
                let stopping = tokio::select! {
                    _ = tick.tick() => false,
                    _ = &mut rx => true,
                };
                let batch = lock(&rig).machine_mut().take_trace();
                rows += batch.len() as u64;
                write_rows(&mut out, &batch)?;
                out.flush()?;
                if stopping {
                    return Ok(rows);
                }
            }
        });
        Ok(TraceFile {
            stop: Some(tx),
            task,
        })
    }

    /// Write what is left and close the file; the number of rows written.
    pub async fn finish(mut self) -> io::Result<u64> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        self.task.await.map_err(io::Error::other)?
    }
}
