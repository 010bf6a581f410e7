//! SQLite persistence of the service (issue 15): jobs and their life cycle, the
//! measurements of a job (one row each, written as they come), results, compensation
//! profiles with versions and an activation history, settings, and the outbox of summary
//! metrics for the plant (written in the same transaction as a job's finish).
//!
//! Blocking calls, no tokio: the service shares one `Store` behind a `Mutex` and every
//! call is one short transaction.
//!
//! Conventions:
//! - Timestamps are RFC 3339 UTC with milliseconds, e.g. `2026-11-23T03:20:01.123Z`,
//!   taken from SQLite's clock when the row is written.
//! - A profile is identified by (machine, name); its versions count 1, 2, 3, ... Each
//!   (machine, name) has at most one active version. Activations form a stack: activating
//!   v1, then v2, then v3 and rolling back twice gives v2 then v1 (each rollback pops the
//!   current activation, which stays in the history marked as rolled back).
//! - `active_profile(machine, kind)` is the active version of the profile of that kind
//!   that was activated most recently on that machine.

mod schema;

use std::path::Path;

use rusqlite::{params, Connection, OptionalExtension, Transaction};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

pub use schema::SCHEMA_VERSION;

/// A job's id (SQLite rowid, increasing).
pub type JobId = i64;

/// Where a job is in its life: queued -> running -> succeeded | failed | cancelled, or
/// queued -> cancelled, or running -> interrupted (the service stopped under it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
    Interrupted,
}

impl JobState {
    /// The lowercase name used in the database and in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
            JobState::Interrupted => "interrupted",
        }
    }

    /// Parses the lowercase name.
    pub fn parse(text: &str) -> Option<JobState> {
        Some(match text {
            "queued" => JobState::Queued,
            "running" => JobState::Running,
            "succeeded" => JobState::Succeeded,
            "failed" => JobState::Failed,
            "cancelled" => JobState::Cancelled,
            "interrupted" => JobState::Interrupted,
            _ => return None,
        })
    }

    /// True once the job can no longer change.
    pub fn is_final(self) -> bool {
        !matches!(self, JobState::Queued | JobState::Running)
    }
}

impl std::fmt::Display for JobState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How far a running job is: `done` of `total` steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Progress {
    pub done: u64,
    pub total: u64,
}

/// The profile version a job used.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProfileRef {
    pub name: String,
    pub version: u32,
}

/// One job as stored; the API returns it as is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    pub id: JobId,
    pub machine: String,
    /// "compensate", "verify", "map", "iso230", "rotary", "layout" (checked by the service).
    pub kind: String,
    pub params: Value,
    pub state: JobState,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    pub progress: Option<Progress>,
    pub profile: Option<ProfileRef>,
    pub error: Option<String>,
    pub result: Option<Value>,
}

/// What a profile body is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProfileKind {
    ErrorMap,
    Volumetric,
    Rotary,
}

impl ProfileKind {
    /// The snake_case name used in the database and in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            ProfileKind::ErrorMap => "error_map",
            ProfileKind::Volumetric => "volumetric",
            ProfileKind::Rotary => "rotary",
        }
    }

    /// Parses the snake_case name.
    pub fn parse(text: &str) -> Option<ProfileKind> {
        Some(match text {
            "error_map" => ProfileKind::ErrorMap,
            "volumetric" => ProfileKind::Volumetric,
            "rotary" => ProfileKind::Rotary,
            _ => return None,
        })
    }
}

impl std::fmt::Display for ProfileKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One version of a profile (the body is fetched separately).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProfileVersion {
    pub machine: String,
    pub name: String,
    pub kind: ProfileKind,
    pub version: u32,
    /// The active version of its name (each name has at most one).
    pub active: bool,
    /// The version jobs use: of the active versions of its kind on the machine, the one
    /// activated last ([`Store::active_profile`]).
    pub in_use: bool,
    pub created_at: String,
    pub source_job: Option<JobId>,
    pub note: Option<String>,
}

/// A file a job wrote (its body is read on its own: `Store::job_file`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobFile {
    pub name: String,
    /// A chart's caption.
    pub title: Option<String>,
    pub media_type: String,
    pub size: u64,
}

/// The largest file a job may keep (a map's heat map or report is well under 1 MiB).
pub const MAX_JOB_FILE_BYTES: usize = 32 << 20;

/// One row of metrics waiting to be published to the plant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutboxItem {
    pub id: i64,
    pub machine: String,
    pub job_id: Option<JobId>,
    pub created_at: String,
    pub metrics: Map<String, Value>,
}

/// How a running job ended; `metrics` go to the outbox in the same transaction.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Succeeded {
        result: Value,
        metrics: Map<String, Value>,
    },
    Failed {
        error: String,
        result: Option<Value>,
        metrics: Map<String, Value>,
    },
    Cancelled {
        /// Why it was stopped, kept as the job's `error` ("the service was shut down
        /// while it ran"); None: on request.
        reason: Option<String>,
        result: Option<Value>,
        metrics: Map<String, Value>,
    },
}

/// Which jobs `Store::jobs` lists (newest first).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JobFilter {
    pub machine: Option<String>,
    pub state: Option<JobState>,
    pub limit: Option<usize>,
    /// Only jobs with an id below this one (paging backwards).
    pub before_id: Option<JobId>,
}

/// What went wrong, naming the job, profile or row concerned.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("unknown job {0}")]
    UnknownJob(JobId),
    #[error("unknown profile {machine}/{name} version {version}")]
    UnknownProfile {
        machine: String,
        name: String,
        version: u32,
    },
    #[error("no profile named {name} on machine {machine}")]
    UnknownProfileName { machine: String, name: String },
    #[error("job {id} is {state}, but this needs it {wanted}")]
    WrongState {
        id: JobId,
        state: JobState,
        wanted: JobState,
    },
    #[error("profile {machine}/{name} is of kind {existing}, a new version cannot be {requested}")]
    ProfileKindMismatch {
        machine: String,
        name: String,
        existing: ProfileKind,
        requested: ProfileKind,
    },
    #[error("profile {machine}/{name} has no earlier activation to roll back to")]
    NothingToRollBack { machine: String, name: String },
    #[error("unknown outbox row {0}")]
    UnknownOutboxItem(i64),
    #[error("progress of job {id}: done {done} is more than total {total}")]
    InvalidProgress { id: JobId, done: u64, total: u64 },
    #[error("invalid {what}: {why}")]
    InvalidInput { what: &'static str, why: String },
    #[error(
        "the database {path} has schema version {found}, newer than this program's {supported}; \
         use a newer gateway or another data directory"
    )]
    SchemaTooNew {
        path: String,
        found: u32,
        supported: u32,
    },
    #[error("corrupt row in {table}: {why}")]
    Corrupt { table: &'static str, why: String },
    #[error("SQLite: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// The service's database.
pub struct Store {
    connection: Connection,
    schema_version: u32,
}

/// The order a machine's queue runs in.
const QUEUE_ORDER: &str = "ORDER BY COALESCE(j.queue_pos, j.id), j.id";

/// Where `Store::move_queued` puts a job in its machine's queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QueuePlace {
    /// Before that queued job of the same machine; `None`: last.
    Before(Option<JobId>),
    /// At this index of the queue (0: next to run); past the end: last.
    Position(usize),
}

/// SQL expression for "now" as RFC 3339 UTC with milliseconds.
const NOW: &str = "strftime('%Y-%m-%dT%H:%M:%fZ','now')";

const JOB_COLUMNS: &str =
    "j.id, j.machine, j.kind, j.params, j.state, j.created_at, j.started_at, \
     j.finished_at, j.progress_done, j.progress_total, j.profile_name, j.profile_version, \
     j.error, r.body";

/// A profile's columns, then whether the version is its name's active one, then whether it
/// is the one in use: of the active versions of its kind, the one activated last.
const PROFILE_COLUMNS: &str =
    "p.machine, p.name, p.kind, p.version, p.created_at, p.source_job, p.note, \
     (SELECT a.version FROM profile_activations a \
      WHERE a.machine = p.machine AND a.name = p.name AND a.rolled_back_at IS NULL \
      ORDER BY a.id DESC LIMIT 1) = p.version, \
     (SELECT a.name = p.name AND a.version = p.version FROM profile_activations a \
      JOIN profiles q ON q.machine = a.machine AND q.name = a.name AND q.version = a.version \
      WHERE a.machine = p.machine AND q.kind = p.kind AND a.rolled_back_at IS NULL \
      AND a.id = (SELECT MAX(b.id) FROM profile_activations b WHERE b.machine = a.machine \
                  AND b.name = a.name AND b.rolled_back_at IS NULL) \
      ORDER BY a.id DESC LIMIT 1)";

impl Store {
    /// Opens (creating if needed) the database file, migrates it to the current schema,
    /// and switches it to WAL. Refuses a database written by a newer program.
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        let connection = Connection::open(path)?;
        // WAL: readers do not block the writer, and a crash loses at most the last commit.
        let mode: String = connection.query_row("PRAGMA journal_mode=WAL", [], |row| row.get(0))?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(StoreError::InvalidInput {
                what: "database",
                why: format!("{} cannot use WAL (journal mode {mode})", path.display()),
            });
        }
        connection.pragma_update(None, "synchronous", "NORMAL")?;
        Store::prepare(connection, &path.display().to_string())
    }

    /// A fresh database in memory (tests, demos).
    pub fn open_in_memory() -> Result<Store, StoreError> {
        Store::prepare(Connection::open_in_memory()?, ":memory:")
    }

    fn prepare(mut connection: Connection, name: &str) -> Result<Store, StoreError> {
        connection.pragma_update(None, "foreign_keys", "ON")?;
        connection.busy_timeout(std::time::Duration::from_secs(5))?;
        let schema_version = schema::migrate(&mut connection, name)?;
        Ok(Store {
            connection,
            schema_version,
        })
    }

    /// The schema version of the open database (PRAGMA user_version).
    pub fn schema_version(&self) -> u32 {
        self.schema_version
    }

    /// At service start: every `running` job becomes `interrupted` (its measurements
    /// kept); returns them, oldest first.
    pub fn recover(&mut self) -> Result<Vec<JobRecord>, StoreError> {
        let tx = self.connection.transaction()?;
        let ids: Vec<JobId> = {
            let mut statement =
                tx.prepare("SELECT id FROM jobs WHERE state = 'running' ORDER BY id")?;
            let rows = statement.query_map([], |row| row.get(0))?;
            rows.collect::<Result<_, _>>()?
        };
        tx.execute(
            &format!(
                "UPDATE jobs SET state = 'interrupted', finished_at = {NOW} WHERE state = 'running'"
            ),
            [],
        )?;
        let jobs = ids
            .iter()
            .map(|&id| load_job(&tx, id))
            .collect::<Result<Vec<_>, _>>()?;
        tx.commit()?;
        Ok(jobs)
    }

    /// Queues a job.
    pub fn enqueue(
        &mut self,
        machine: &str,
        kind: &str,
        params: &Value,
    ) -> Result<JobRecord, StoreError> {
        non_empty("machine", machine)?;
        non_empty("job kind", kind)?;
        let tx = self.connection.transaction()?;
        tx.execute(
            &format!(
                "INSERT INTO jobs (machine, kind, params, state, created_at) \
                 VALUES (?1, ?2, ?3, 'queued', {NOW})"
            ),
            params![machine, kind, serde_json::to_string(params)?],
        )?;
        let id = tx.last_insert_rowid();
        let job = load_job(&tx, id)?;
        tx.commit()?;
        Ok(job)
    }

    /// queued -> running, recording the profile version the job uses.
    pub fn start(
        &mut self,
        id: JobId,
        profile: Option<ProfileRef>,
    ) -> Result<JobRecord, StoreError> {
        let tx = self.connection.transaction()?;
        expect_state(&tx, id, JobState::Queued, JobState::Running)?;
        tx.execute(
            &format!(
                "UPDATE jobs SET state = 'running', started_at = {NOW}, \
                 profile_name = ?2, profile_version = ?3 WHERE id = ?1"
            ),
            params![
                id,
                profile.as_ref().map(|p| p.name.as_str()),
                profile.as_ref().map(|p| p.version)
            ],
        )?;
        let job = load_job(&tx, id)?;
        tx.commit()?;
        Ok(job)
    }

    /// Records a running job's progress.
    pub fn set_progress(&mut self, id: JobId, done: u64, total: u64) -> Result<(), StoreError> {
        if done > total {
            return Err(StoreError::InvalidProgress { id, done, total });
        }
        let tx = self.connection.transaction()?;
        expect_state(&tx, id, JobState::Running, JobState::Running)?;
        tx.execute(
            "UPDATE jobs SET progress_done = ?2, progress_total = ?3 WHERE id = ?1",
            params![id, to_sql_count(done)?, to_sql_count(total)?],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// Appends one measurement to a running job (one row, committed at once, so a crash
    /// keeps every measurement taken before it). Returns the row's id.
    pub fn add_measurement(&mut self, id: JobId, measurement: &Value) -> Result<i64, StoreError> {
        let tx = self.connection.transaction()?;
        expect_state(&tx, id, JobState::Running, JobState::Running)?;
        tx.execute(
            &format!("INSERT INTO measurements (job_id, taken_at, body) VALUES (?1, {NOW}, ?2)"),
            params![id, serde_json::to_string(measurement)?],
        )?;
        let row = tx.last_insert_rowid();
        tx.commit()?;
        Ok(row)
    }

    /// Keeps a file of a running job (a chart, a table, a report), replacing one of the
    /// same name. The name is a plain file name.
    pub fn add_job_file(
        &mut self,
        id: JobId,
        name: &str,
        title: Option<&str>,
        media_type: &str,
        body: &[u8],
    ) -> Result<(), StoreError> {
        let plain = !name.is_empty()
            && name.len() <= 128
            && name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b))
            && !name.starts_with('.');
        if !plain {
            return Err(StoreError::InvalidInput {
                what: "job file name",
                why: format!("{name:?} is not a plain file name"),
            });
        }
        if body.len() > MAX_JOB_FILE_BYTES {
            return Err(StoreError::InvalidInput {
                what: "job file",
                why: format!(
                    "{name} is {} bytes; at most {MAX_JOB_FILE_BYTES} are kept",
                    body.len()
                ),
            });
        }
        let tx = self.connection.transaction()?;
        expect_state(&tx, id, JobState::Running, JobState::Running)?;
        tx.execute(
            "INSERT OR REPLACE INTO job_files (job_id, name, title, media_type, body) \
             VALUES (?1, ?2, ?3, ?4, ?5)",
            params![id, name, title, media_type, body],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// The files a job wrote, in name order (without their bodies).
    pub fn job_files(&self, id: JobId) -> Result<Vec<JobFile>, StoreError> {
        let mut statement = self.connection.prepare(
            "SELECT name, title, media_type, length(body) FROM job_files \
             WHERE job_id = ?1 ORDER BY name",
        )?;
        let rows = statement.query_map(params![id], |row| {
            Ok(JobFile {
                name: row.get(0)?,
                title: row.get(1)?,
                media_type: row.get(2)?,
                size: row.get::<_, i64>(3)? as u64,
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// One file of a job: its media type and body.
    pub fn job_file(&self, id: JobId, name: &str) -> Result<Option<(String, Vec<u8>)>, StoreError> {
        Ok(self
            .connection
            .query_row(
                "SELECT media_type, body FROM job_files WHERE job_id = ?1 AND name = ?2",
                params![id, name],
                |row| Ok((row.get(0)?, row.get(1)?)),
            )
            .optional()?)
    }

    /// running -> succeeded/failed/cancelled, and in the same transaction an outbox row
    /// with the job's summary metrics (so a result is never lost for the plant).
    pub fn finish(&mut self, id: JobId, outcome: Outcome) -> Result<JobRecord, StoreError> {
        let (state, error, result, metrics) = match outcome {
            Outcome::Succeeded { result, metrics } => {
                (JobState::Succeeded, None, Some(result), metrics)
            }
            Outcome::Failed {
                error,
                result,
                metrics,
            } => (JobState::Failed, Some(error), result, metrics),
            Outcome::Cancelled {
                reason,
                result,
                metrics,
            } => (JobState::Cancelled, reason, result, metrics),
        };
        let tx = self.connection.transaction()?;
        let machine = expect_state(&tx, id, JobState::Running, state)?;
        tx.execute(
            &format!("UPDATE jobs SET state = ?2, finished_at = {NOW}, error = ?3 WHERE id = ?1"),
            params![id, state.as_str(), error],
        )?;
        if let Some(result) = &result {
            tx.execute(
                "INSERT INTO results (job_id, body) VALUES (?1, ?2)",
                params![id, serde_json::to_string(result)?],
            )?;
        }
        push_outbox(&tx, &machine, Some(id), &metrics)?;
        let job = load_job(&tx, id)?;
        tx.commit()?;
        Ok(job)
    }

    /// queued -> cancelled; refused for a job in any other state.
    pub fn cancel_queued(&mut self, id: JobId) -> Result<JobRecord, StoreError> {
        let tx = self.connection.transaction()?;
        expect_state(&tx, id, JobState::Queued, JobState::Cancelled)?;
        tx.execute(
            &format!("UPDATE jobs SET state = 'cancelled', finished_at = {NOW} WHERE id = ?1"),
            params![id],
        )?;
        let job = load_job(&tx, id)?;
        tx.commit()?;
        Ok(job)
    }

    /// One job, or None if there is no job with that id.
    pub fn job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        match load_job(&self.connection, id) {
            Ok(job) => Ok(Some(job)),
            Err(StoreError::UnknownJob(_)) => Ok(None),
            Err(other) => Err(other),
        }
    }

    /// Jobs matching the filter, newest first.
    pub fn jobs(&self, filter: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        let mut sql = format!(
            "SELECT {JOB_COLUMNS} FROM jobs j LEFT JOIN results r ON r.job_id = j.id WHERE 1"
        );
        let mut values: Vec<Box<dyn rusqlite::ToSql>> = Vec::new();
        if let Some(machine) = &filter.machine {
            values.push(Box::new(machine.clone()));
            sql.push_str(&format!(" AND j.machine = ?{}", values.len()));
        }
        if let Some(state) = filter.state {
            values.push(Box::new(state.as_str()));
            sql.push_str(&format!(" AND j.state = ?{}", values.len()));
        }
        if let Some(before) = filter.before_id {
            values.push(Box::new(before));
            sql.push_str(&format!(" AND j.id < ?{}", values.len()));
        }
        sql.push_str(" ORDER BY j.id DESC");
        if let Some(limit) = filter.limit {
            values.push(Box::new(i64::try_from(limit).unwrap_or(i64::MAX)));
            sql.push_str(&format!(" LIMIT ?{}", values.len()));
        }
        query_jobs(
            &self.connection,
            &sql,
            rusqlite::params_from_iter(values.iter()),
        )
    }

    /// The queued jobs of a machine in the order they run in: oldest first, unless an
    /// operator moved one (`move_queued`).
    pub fn queued(&self, machine: &str) -> Result<Vec<JobRecord>, StoreError> {
        query_jobs(
            &self.connection,
            &format!(
                "SELECT {JOB_COLUMNS} FROM jobs j LEFT JOIN results r ON r.job_id = j.id \
                 WHERE j.machine = ?1 AND j.state = 'queued' {QUEUE_ORDER}"
            ),
            params![machine],
        )
    }

    /// Moves a queued job to another place in its machine's queue; returns the queue in
    /// its new order. Refused for a job that is not queued (`WrongState`) and for a
    /// `Before` job that is not queued on the same machine (`InvalidInput` naming it).
    pub fn move_queued(
        &mut self,
        id: JobId,
        place: QueuePlace,
    ) -> Result<Vec<JobRecord>, StoreError> {
        let tx = self.connection.transaction()?;
        let machine = expect_state(&tx, id, JobState::Queued, JobState::Queued)?;
        // The queue's keys in run order; the moved job takes a new place and the keys
        // are handed out again in the new order (no key above the largest id, so a job
        // queued later still goes to the end).
        let queue: Vec<(JobId, i64)> = {
            let mut statement = tx.prepare(&format!(
                "SELECT j.id, COALESCE(j.queue_pos, j.id) FROM jobs j \
                 WHERE j.machine = ?1 AND j.state = 'queued' {QUEUE_ORDER}"
            ))?;
            let rows =
                statement.query_map(params![machine], |row| Ok((row.get(0)?, row.get(1)?)))?;
            rows.collect::<Result<_, _>>()?
        };
        let mut keys: Vec<i64> = queue.iter().map(|(_, key)| *key).collect();
        keys.sort_unstable();
        let mut order: Vec<JobId> = queue
            .iter()
            .map(|(job, _)| *job)
            .filter(|j| *j != id)
            .collect();
        let at = match place {
            QueuePlace::Position(p) => p.min(order.len()),
            QueuePlace::Before(None) => order.len(),
            QueuePlace::Before(Some(before)) => order
                .iter()
                .position(|j| *j == before)
                .ok_or_else(|| StoreError::InvalidInput {
                    what: "before",
                    why: format!(
                        "job {before} is not queued on machine {machine} (or is the job moved)"
                    ),
                })?,
        };
        order.insert(at, id);
        for (job, key) in order.iter().zip(&keys) {
            tx.execute(
                "UPDATE jobs SET queue_pos = ?2 WHERE id = ?1",
                params![job, key],
            )?;
        }
        let jobs = query_jobs(
            &tx,
            &format!(
                "SELECT {JOB_COLUMNS} FROM jobs j LEFT JOIN results r ON r.job_id = j.id \
                 WHERE j.machine = ?1 AND j.state = 'queued' {QUEUE_ORDER}"
            ),
            params![machine],
        )?;
        tx.commit()?;
        Ok(jobs)
    }

    /// A job's measurements in the order they were added.
    pub fn measurements(&self, id: JobId) -> Result<Vec<Value>, StoreError> {
        job_exists(&self.connection, id)?;
        let mut statement = self
            .connection
            .prepare("SELECT body FROM measurements WHERE job_id = ?1 ORDER BY id")?;
        let rows = statement.query_map(params![id], |row| row.get::<_, String>(0))?;
        rows.map(|body| Ok(serde_json::from_str(&body?)?)).collect()
    }

    /// The row id of a job's newest measurement (the `row` of its event), if it has one.
    pub fn last_measurement_row(&self, id: JobId) -> Result<Option<i64>, StoreError> {
        job_exists(&self.connection, id)?;
        Ok(self.connection.query_row(
            "SELECT MAX(id) FROM measurements WHERE job_id = ?1",
            params![id],
            |row| row.get(0),
        )?)
    }

    /// Adds a new version (previous + 1, starting at 1) of a profile, not active.
    pub fn add_profile(
        &mut self,
        machine: &str,
        name: &str,
        kind: ProfileKind,
        body: &Value,
        source_job: Option<JobId>,
        note: Option<&str>,
    ) -> Result<ProfileVersion, StoreError> {
        non_empty("machine", machine)?;
        non_empty("profile name", name)?;
        let tx = self.connection.transaction()?;
        if let Some(job) = source_job {
            job_exists(&tx, job)?;
        }
        let existing: Option<String> = tx
            .query_row(
                "SELECT kind FROM profiles WHERE machine = ?1 AND name = ?2 LIMIT 1",
                params![machine, name],
                |row| row.get(0),
            )
            .optional()?;
        if let Some(existing) = existing {
            let existing = parse_kind(&existing)?;
            if existing != kind {
                return Err(StoreError::ProfileKindMismatch {
                    machine: machine.into(),
                    name: name.into(),
                    existing,
                    requested: kind,
                });
            }
        }
        let version: u32 = tx.query_row(
            "SELECT COALESCE(MAX(version), 0) + 1 FROM profiles WHERE machine = ?1 AND name = ?2",
            params![machine, name],
            |row| row.get(0),
        )?;
        tx.execute(
            &format!(
                "INSERT INTO profiles (machine, name, version, kind, body, created_at, source_job, note) \
                 VALUES (?1, ?2, ?3, ?4, ?5, {NOW}, ?6, ?7)"
            ),
            params![
                machine,
                name,
                version,
                kind.as_str(),
                serde_json::to_string(body)?,
                source_job,
                note
            ],
        )?;
        let profile = load_profile(&tx, machine, name, version)?.0;
        tx.commit()?;
        Ok(profile)
    }

    /// Makes a version the active one of its profile and the one in use for its kind.
    /// Activating the version that is already in use changes nothing (no new history
    /// entry); activating the active version of a name that another profile of the kind
    /// has displaced puts it back in use (a new history entry).
    pub fn activate(
        &mut self,
        machine: &str,
        name: &str,
        version: u32,
    ) -> Result<ProfileVersion, StoreError> {
        let tx = self.connection.transaction()?;
        if !load_profile(&tx, machine, name, version)?.0.in_use {
            tx.execute(
                &format!(
                    "INSERT INTO profile_activations (machine, name, version, activated_at) \
                     VALUES (?1, ?2, ?3, {NOW})"
                ),
                params![machine, name, version],
            )?;
        }
        let profile = load_profile(&tx, machine, name, version)?.0;
        tx.commit()?;
        Ok(profile)
    }

    /// Goes back to the version that was active before the current one: the current
    /// activation is marked rolled back and the one under it becomes current again.
    pub fn rollback(&mut self, machine: &str, name: &str) -> Result<ProfileVersion, StoreError> {
        let tx = self.connection.transaction()?;
        let exists: bool = tx.query_row(
            "SELECT EXISTS (SELECT 1 FROM profiles WHERE machine = ?1 AND name = ?2)",
            params![machine, name],
            |row| row.get(0),
        )?;
        if !exists {
            return Err(StoreError::UnknownProfileName {
                machine: machine.into(),
                name: name.into(),
            });
        }
        let nothing = || StoreError::NothingToRollBack {
            machine: machine.into(),
            name: name.into(),
        };
        let (current_row, current_version) =
            current_activation(&tx, machine, name)?.ok_or_else(nothing)?;
        // The version active before the current one (a version activated again to put it
        // back in use counts once: its earlier rows are rolled back with it).
        let previous: Option<(i64, u32)> = tx
            .query_row(
                "SELECT id, version FROM profile_activations \
                 WHERE machine = ?1 AND name = ?2 AND rolled_back_at IS NULL AND id < ?3 \
                 AND version != ?4 ORDER BY id DESC LIMIT 1",
                params![machine, name, current_row, current_version],
                |row| Ok((row.get(0)?, row.get(1)?)),
            )
            .optional()?;
        let (previous_row, previous) = previous.ok_or_else(nothing)?;
        tx.execute(
            &format!(
                "UPDATE profile_activations SET rolled_back_at = {NOW} \
                 WHERE machine = ?1 AND name = ?2 AND rolled_back_at IS NULL AND id > ?3"
            ),
            params![machine, name, previous_row],
        )?;
        let profile = load_profile(&tx, machine, name, previous)?.0;
        tx.commit()?;
        Ok(profile)
    }

    /// The active profile of a kind on a machine (if several profiles of that kind have
    /// an active version, the one activated most recently) with its body.
    pub fn active_profile(
        &self,
        machine: &str,
        kind: ProfileKind,
    ) -> Result<Option<(ProfileVersion, Value)>, StoreError> {
        // The current activation of each name is its newest row not rolled back; pick
        // among those the newest whose profile has the wanted kind.
        let found: Option<(String, u32)> = self
            .connection
            .query_row(
                "SELECT a.name, a.version FROM profile_activations a \
                 JOIN profiles p ON p.machine = a.machine AND p.name = a.name AND p.version = a.version \
                 WHERE a.machine = ?1 AND p.kind = ?2 AND a.rolled_back_at IS NULL \
                 AND a.id = (SELECT MAX(b.id) FROM profile_activations b \
                             WHERE b.machine = a.machine AND b.name = a.name AND b.rolled_back_at IS NULL) \
                 ORDER BY a.id DESC LIMIT 1",
                params![machine, kind.as_str()],
                |row| Ok((row.get(0)?, row.get(1)?)),
            )
            .optional()?;
        match found {
            Some((name, version)) => Ok(Some(load_profile(
                &self.connection,
                machine,
                &name,
                version,
            )?)),
            None => Ok(None),
        }
    }

    /// Every version of every profile of a machine, by name then version.
    pub fn profiles(&self, machine: &str) -> Result<Vec<ProfileVersion>, StoreError> {
        let mut statement = self.connection.prepare(&format!(
            "SELECT {PROFILE_COLUMNS} FROM profiles p WHERE p.machine = ?1 ORDER BY p.name, p.version"
        ))?;
        let rows = statement.query_map(params![machine], profile_from_row)?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// One version of a profile with its body, or None.
    pub fn profile(
        &self,
        machine: &str,
        name: &str,
        version: u32,
    ) -> Result<Option<(ProfileVersion, Value)>, StoreError> {
        match load_profile(&self.connection, machine, name, version) {
            Ok(found) => Ok(Some(found)),
            Err(StoreError::UnknownProfile { .. }) => Ok(None),
            Err(other) => Err(other),
        }
    }

    /// Queues metrics for the plant that do not come from a job's finish.
    pub fn outbox_push(
        &mut self,
        machine: &str,
        job_id: Option<JobId>,
        metrics: &Map<String, Value>,
    ) -> Result<i64, StoreError> {
        let tx = self.connection.transaction()?;
        if let Some(job) = job_id {
            job_exists(&tx, job)?;
        }
        let id = push_outbox(&tx, machine, job_id, metrics)?;
        tx.commit()?;
        Ok(id)
    }

    /// Outbox rows not yet published, oldest first.
    pub fn outbox_pending(&self, limit: usize) -> Result<Vec<OutboxItem>, StoreError> {
        let mut statement = self.connection.prepare(
            "SELECT id, machine, job_id, created_at, metrics FROM outbox \
             WHERE done_at IS NULL ORDER BY id LIMIT ?1",
        )?;
        let rows =
            statement.query_map(params![i64::try_from(limit).unwrap_or(i64::MAX)], |row| {
                Ok((
                    row.get::<_, i64>(0)?,
                    row.get::<_, String>(1)?,
                    row.get::<_, Option<JobId>>(2)?,
                    row.get::<_, String>(3)?,
                    row.get::<_, String>(4)?,
                ))
            })?;
        rows.map(|row| {
            let (id, machine, job_id, created_at, metrics) = row?;
            Ok(OutboxItem {
                id,
                machine,
                job_id,
                created_at,
                metrics: serde_json::from_str(&metrics)?,
            })
        })
        .collect()
    }

    /// Marks an outbox row published. Marking it twice is harmless (a publish retried
    /// after a lost acknowledgement); an unknown id is an error.
    pub fn outbox_done(&mut self, id: i64) -> Result<(), StoreError> {
        let changed = self.connection.execute(
            &format!("UPDATE outbox SET done_at = COALESCE(done_at, {NOW}) WHERE id = ?1"),
            params![id],
        )?;
        if changed == 0 {
            return Err(StoreError::UnknownOutboxItem(id));
        }
        Ok(())
    }

    /// A setting (e.g. "sparkplug.bdseq"), or None if never set.
    pub fn get_setting(&self, key: &str) -> Result<Option<String>, StoreError> {
        Ok(self
            .connection
            .query_row(
                "SELECT value FROM settings WHERE key = ?1",
                params![key],
                |row| row.get(0),
            )
            .optional()?)
    }

    /// Sets (or replaces) a setting.
    pub fn set_setting(&mut self, key: &str, value: &str) -> Result<(), StoreError> {
        non_empty("setting key", key)?;
        self.connection.execute(
            "INSERT INTO settings (key, value) VALUES (?1, ?2) \
             ON CONFLICT (key) DO UPDATE SET value = excluded.value",
            params![key, value],
        )?;
        Ok(())
    }
}

fn non_empty(what: &'static str, value: &str) -> Result<(), StoreError> {
    if value.trim().is_empty() {
        return Err(StoreError::InvalidInput {
            what,
            why: "empty".into(),
        });
    }
    Ok(())
}

fn to_sql_count(value: u64) -> Result<i64, StoreError> {
    i64::try_from(value).map_err(|_| StoreError::InvalidInput {
        what: "progress count",
        why: format!("{value} does not fit in SQLite's 64-bit signed integer"),
    })
}

fn parse_kind(text: &str) -> Result<ProfileKind, StoreError> {
    ProfileKind::parse(text).ok_or_else(|| StoreError::Corrupt {
        table: "profiles",
        why: format!("unknown profile kind {text:?}"),
    })
}

fn job_exists(connection: &Connection, id: JobId) -> Result<(), StoreError> {
    let exists: bool = connection.query_row(
        "SELECT EXISTS (SELECT 1 FROM jobs WHERE id = ?1)",
        params![id],
        |row| row.get(0),
    )?;
    if exists {
        Ok(())
    } else {
        Err(StoreError::UnknownJob(id))
    }
}

/// Checks that job `id` is in state `needed` (for a move to `wanted`); returns its machine.
fn expect_state(
    tx: &Transaction<'_>,
    id: JobId,
    needed: JobState,
    wanted: JobState,
) -> Result<String, StoreError> {
    let (machine, state): (String, String) = tx
        .query_row(
            "SELECT machine, state FROM jobs WHERE id = ?1",
            params![id],
            |row| Ok((row.get(0)?, row.get(1)?)),
        )
        .optional()?
        .ok_or(StoreError::UnknownJob(id))?;
    let state = JobState::parse(&state).ok_or_else(|| StoreError::Corrupt {
        table: "jobs",
        why: format!("job {id} has unknown state {state:?}"),
    })?;
    if state != needed {
        return Err(StoreError::WrongState { id, state, wanted });
    }
    Ok(machine)
}

fn push_outbox(
    tx: &Connection,
    machine: &str,
    job_id: Option<JobId>,
    metrics: &Map<String, Value>,
) -> Result<i64, StoreError> {
    non_empty("machine", machine)?;
    tx.execute(
        &format!(
            "INSERT INTO outbox (machine, job_id, created_at, metrics) VALUES (?1, ?2, {NOW}, ?3)"
        ),
        params![machine, job_id, serde_json::to_string(metrics)?],
    )?;
    Ok(tx.last_insert_rowid())
}

type RawJob = (
    JobId,
    String,
    String,
    String,
    String,
    String,
    Option<String>,
    Option<String>,
    Option<i64>,
    Option<i64>,
    Option<String>,
    Option<u32>,
    Option<String>,
    Option<String>,
);

fn raw_job(row: &rusqlite::Row<'_>) -> rusqlite::Result<RawJob> {
    Ok((
        row.get(0)?,
        row.get(1)?,
        row.get(2)?,
        row.get(3)?,
        row.get(4)?,
        row.get(5)?,
        row.get(6)?,
        row.get(7)?,
        row.get(8)?,
        row.get(9)?,
        row.get(10)?,
        row.get(11)?,
        row.get(12)?,
        row.get(13)?,
    ))
}

fn job_from_raw(raw: RawJob) -> Result<JobRecord, StoreError> {
    let (
        id,
        machine,
        kind,
        params,
        state,
        created_at,
        started_at,
        finished_at,
        done,
        total,
        profile_name,
        profile_version,
        error,
        result,
    ) = raw;
    let corrupt = |why: String| StoreError::Corrupt {
        table: "jobs",
        why: format!("job {id}: {why}"),
    };
    let state = JobState::parse(&state).ok_or_else(|| corrupt(format!("state {state:?}")))?;
    let progress = match (done, total) {
        (Some(done), Some(total)) => Some(Progress {
            done: u64::try_from(done).map_err(|_| corrupt(format!("progress {done}")))?,
            total: u64::try_from(total).map_err(|_| corrupt(format!("progress {total}")))?,
        }),
        _ => None,
    };
    let profile = match (profile_name, profile_version) {
        (Some(name), Some(version)) => Some(ProfileRef { name, version }),
        _ => None,
    };
    Ok(JobRecord {
        id,
        machine,
        kind,
        params: serde_json::from_str(&params)?,
        state,
        created_at,
        started_at,
        finished_at,
        progress,
        profile,
        error,
        result: result.map(|body| serde_json::from_str(&body)).transpose()?,
    })
}

fn query_jobs<P: rusqlite::Params>(
    connection: &Connection,
    sql: &str,
    params: P,
) -> Result<Vec<JobRecord>, StoreError> {
    let mut statement = connection.prepare(sql)?;
    let rows = statement.query_map(params, raw_job)?;
    rows.map(|raw| job_from_raw(raw?)).collect()
}

fn load_job(connection: &Connection, id: JobId) -> Result<JobRecord, StoreError> {
    query_jobs(
        connection,
        &format!(
            "SELECT {JOB_COLUMNS} FROM jobs j LEFT JOIN results r ON r.job_id = j.id WHERE j.id = ?1"
        ),
        params![id],
    )?
    .pop()
    .ok_or(StoreError::UnknownJob(id))
}

fn profile_from_row(row: &rusqlite::Row<'_>) -> rusqlite::Result<ProfileVersion> {
    let kind: String = row.get(2)?;
    let kind = ProfileKind::parse(&kind).ok_or_else(|| {
        rusqlite::Error::FromSqlConversionFailure(
            2,
            rusqlite::types::Type::Text,
            format!("unknown profile kind {kind:?}").into(),
        )
    })?;
    Ok(ProfileVersion {
        machine: row.get(0)?,
        name: row.get(1)?,
        kind,
        version: row.get(3)?,
        active: row.get::<_, Option<bool>>(7)?.unwrap_or(false),
        in_use: row.get::<_, Option<bool>>(8)?.unwrap_or(false),
        created_at: row.get(4)?,
        source_job: row.get(5)?,
        note: row.get(6)?,
    })
}

fn load_profile(
    connection: &Connection,
    machine: &str,
    name: &str,
    version: u32,
) -> Result<(ProfileVersion, Value), StoreError> {
    let found = connection
        .query_row(
            &format!(
                "SELECT {PROFILE_COLUMNS}, p.body FROM profiles p \
                 WHERE p.machine = ?1 AND p.name = ?2 AND p.version = ?3"
            ),
            params![machine, name, version],
            |row| Ok((profile_from_row(row)?, row.get::<_, String>(9)?)),
        )
        .optional()?;
    let (profile, body) = found.ok_or_else(|| StoreError::UnknownProfile {
        machine: machine.into(),
        name: name.into(),
        version,
    })?;
    Ok((profile, serde_json::from_str(&body)?))
}

/// The current activation of a profile: (row id, version), or None if never activated
/// (or rolled back to nothing, which `rollback` does not allow).
fn current_activation(
    connection: &Connection,
    machine: &str,
    name: &str,
) -> Result<Option<(i64, u32)>, StoreError> {
    Ok(connection
        .query_row(
            "SELECT id, version FROM profile_activations \
             WHERE machine = ?1 AND name = ?2 AND rolled_back_at IS NULL \
             ORDER BY id DESC LIMIT 1",
            params![machine, name],
            |row| Ok((row.get(0)?, row.get(1)?)),
        )
        .optional()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn foreign_keys_are_enforced() {
        let store = Store::open_in_memory().unwrap();
        let on: bool = store
            .connection
            .query_row("PRAGMA foreign_keys", [], |row| row.get(0))
            .unwrap();
        assert!(on);
        // A measurement of a job that does not exist is refused by the database itself.
        let refused = store.connection.execute(
            "INSERT INTO measurements (job_id, taken_at, body) VALUES (99, 'x', '{}')",
            [],
        );
        assert!(refused.is_err());
    }
}
