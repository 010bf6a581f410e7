//! Versioned schema migrations. `PRAGMA user_version` holds the number of migrations
//! applied; each migration runs in its own transaction together with the version bump,
//! so a crash leaves the database at the old or the new version, never in between.
//! Never edit a released migration: append a new one.

use rusqlite::Connection;

use crate::StoreError;

const MIGRATIONS: &[&str] = &[
    // 1: the tables.
    "CREATE TABLE jobs (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        machine TEXT NOT NULL,
        kind TEXT NOT NULL,
        params TEXT NOT NULL,
        state TEXT NOT NULL CHECK (state IN
            ('queued', 'running', 'succeeded', 'failed', 'cancelled', 'interrupted')),
        created_at TEXT NOT NULL,
        started_at TEXT,
        finished_at TEXT,
        progress_done INTEGER,
        progress_total INTEGER,
        profile_name TEXT,
        profile_version INTEGER,
        error TEXT
    );
    CREATE TABLE measurements (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        job_id INTEGER NOT NULL REFERENCES jobs (id),
        taken_at TEXT NOT NULL,
        body TEXT NOT NULL
    );
    CREATE TABLE results (
        job_id INTEGER PRIMARY KEY REFERENCES jobs (id),
        body TEXT NOT NULL
    );
    CREATE TABLE profiles (
        machine TEXT NOT NULL,
        name TEXT NOT NULL,
        version INTEGER NOT NULL CHECK (version >= 1),
        kind TEXT NOT NULL CHECK (kind IN ('error_map', 'volumetric', 'rotary')),
        body TEXT NOT NULL,
        created_at TEXT NOT NULL,
        source_job INTEGER REFERENCES jobs (id),
        note TEXT,
        PRIMARY KEY (machine, name, version)
    );
    CREATE TABLE profile_activations (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        machine TEXT NOT NULL,
        name TEXT NOT NULL,
        version INTEGER NOT NULL,
        activated_at TEXT NOT NULL,
        rolled_back_at TEXT,
        FOREIGN KEY (machine, name, version) REFERENCES profiles (machine, name, version)
    );
    CREATE TABLE settings (
        key TEXT PRIMARY KEY,
        value TEXT NOT NULL
    );
    CREATE TABLE outbox (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        machine TEXT NOT NULL,
        job_id INTEGER REFERENCES jobs (id),
        created_at TEXT NOT NULL,
        metrics TEXT NOT NULL,
        done_at TEXT
    );",
    // 2: the indexes the service's queries use.
    "CREATE INDEX jobs_by_machine_state ON jobs (machine, state, id);
    CREATE INDEX jobs_by_state ON jobs (state, id);
    CREATE INDEX measurements_by_job ON measurements (job_id, id);
    CREATE INDEX activations_by_profile ON profile_activations (machine, name, id);
    CREATE INDEX outbox_pending ON outbox (id) WHERE done_at IS NULL;",
    // 3: the files a job wrote (charts, tables, reports), served on their own instead of
    // inside its result.
    "CREATE TABLE job_files (
        job_id INTEGER NOT NULL REFERENCES jobs (id),
        name TEXT NOT NULL,
        title TEXT,
        media_type TEXT NOT NULL,
        body BLOB NOT NULL,
        PRIMARY KEY (job_id, name)
    );",
    // 4: a queued job's place in its machine's queue, when an operator moved it; a job
    // never moved runs in its id's place (`COALESCE(queue_pos, id)`), so older stores keep
    // their order.
    "ALTER TABLE jobs ADD COLUMN queue_pos INTEGER;",
];

/// The schema version this program writes (the number of migrations).
pub const SCHEMA_VERSION: u32 = MIGRATIONS.len() as u32;

/// Brings the database to `SCHEMA_VERSION`; refuses a newer one. Returns the version.
pub(crate) fn migrate(connection: &mut Connection, name: &str) -> Result<u32, StoreError> {
    let found: u32 = connection.query_row("PRAGMA user_version", [], |row| row.get(0))?;
    if found > SCHEMA_VERSION {
        return Err(StoreError::SchemaTooNew {
            path: name.into(),
            found,
            supported: SCHEMA_VERSION,
        });
    }
    for (index, sql) in MIGRATIONS.iter().enumerate().skip(found as usize) {
        let version = index + 1;
        let tx = connection.transaction()?;
        tx.execute_batch(sql)?;
        // user_version lives in the database header, which the transaction covers.
        tx.pragma_update(None, "user_version", version)?;
        tx.commit()?;
    }
    Ok(SCHEMA_VERSION)
}
