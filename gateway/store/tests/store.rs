//! Behaviour of the store: every job transition, profile rollback chains, restart
//! recovery on a file, migrations, the outbox.

use std::path::PathBuf;

use serde_json::{json, Map, Value};
use store::{
    JobFilter, JobState, Outcome, ProfileKind, ProfileRef, QueuePlace, Store, StoreError,
    SCHEMA_VERSION,
};

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("store-test-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn metrics(pairs: &[(&str, f64)]) -> Map<String, Value> {
    pairs
        .iter()
        .map(|(k, v)| (k.to_string(), json!(v)))
        .collect()
}

fn running_job(store: &mut Store, machine: &str) -> i64 {
    let job = store
        .enqueue(machine, "verify", &json!({"points": 3}))
        .unwrap();
    store.start(job.id, None).unwrap().id
}

#[test]
fn a_job_goes_queued_running_succeeded_with_result_and_outbox_row() {
    let mut store = Store::open_in_memory().unwrap();
    let queued = store
        .enqueue("demo", "iso230", &json!({"targets": [0, 10]}))
        .unwrap();
    assert_eq!(queued.state, JobState::Queued);
    assert_eq!(queued.params, json!({"targets": [0, 10]}));
    assert!(queued.started_at.is_none() && queued.finished_at.is_none());
    assert!(queued.created_at.ends_with('Z') && queued.created_at.contains('T'));

    let profile = ProfileRef {
        name: "xy".into(),
        version: 2,
    };
    let running = store.start(queued.id, Some(profile.clone())).unwrap();
    assert_eq!(running.state, JobState::Running);
    assert_eq!(running.profile, Some(profile));
    assert!(running.started_at.is_some());

    store.set_progress(queued.id, 1, 2).unwrap();
    store
        .add_measurement(queued.id, &json!({"x": 0.0, "dev_um": 1.5}))
        .unwrap();
    store.set_progress(queued.id, 2, 2).unwrap();
    store
        .add_measurement(queued.id, &json!({"x": 10.0, "dev_um": -0.5}))
        .unwrap();

    let finished = store
        .finish(
            queued.id,
            Outcome::Succeeded {
                result: json!({"A": 2.0}),
                metrics: metrics(&[("A_um", 2.0)]),
            },
        )
        .unwrap();
    assert_eq!(finished.state, JobState::Succeeded);
    assert_eq!(finished.result, Some(json!({"A": 2.0})));
    assert_eq!(finished.progress.map(|p| (p.done, p.total)), Some((2, 2)));
    assert!(finished.finished_at.is_some());
    assert_eq!(
        store.measurements(queued.id).unwrap(),
        vec![
            json!({"x": 0.0, "dev_um": 1.5}),
            json!({"x": 10.0, "dev_um": -0.5})
        ]
    );
    let outbox = store.outbox_pending(10).unwrap();
    assert_eq!(outbox.len(), 1);
    assert_eq!(outbox[0].job_id, Some(queued.id));
    assert_eq!(outbox[0].machine, "demo");
    assert_eq!(outbox[0].metrics, metrics(&[("A_um", 2.0)]));
    assert_eq!(store.job(queued.id).unwrap(), Some(finished));
}

#[test]
fn failed_and_cancelled_running_jobs_keep_error_and_partial_result() {
    let mut store = Store::open_in_memory().unwrap();
    let failed = running_job(&mut store, "demo");
    let job = store
        .finish(
            failed,
            Outcome::Failed {
                error: "camera link lost".into(),
                result: None,
                metrics: Map::new(),
            },
        )
        .unwrap();
    assert_eq!(job.state, JobState::Failed);
    assert_eq!(job.error.as_deref(), Some("camera link lost"));
    assert_eq!(job.result, None);

    let cancelled = running_job(&mut store, "demo");
    let job = store
        .finish(
            cancelled,
            Outcome::Cancelled {
                reason: Some("the service was shut down while it ran".into()),
                result: Some(json!({"points_done": 1})),
                metrics: Map::new(),
            },
        )
        .unwrap();
    assert_eq!(job.state, JobState::Cancelled);
    assert_eq!(
        job.error.as_deref(),
        Some("the service was shut down while it ran")
    );
    assert_eq!(job.result, Some(json!({"points_done": 1})));
    // Every finish writes its outbox row.
    assert_eq!(store.outbox_pending(10).unwrap().len(), 2);
}

#[test]
fn a_queued_job_can_be_cancelled_but_not_a_running_one() {
    let mut store = Store::open_in_memory().unwrap();
    let queued = store.enqueue("demo", "map", &json!({})).unwrap();
    let cancelled = store.cancel_queued(queued.id).unwrap();
    assert_eq!(cancelled.state, JobState::Cancelled);
    assert!(cancelled.finished_at.is_some());
    // No outbox row for a job that never ran.
    assert!(store.outbox_pending(10).unwrap().is_empty());

    let running = running_job(&mut store, "demo");
    match store.cancel_queued(running) {
        Err(StoreError::WrongState { id, state, wanted }) => {
            assert_eq!(
                (id, state, wanted),
                (running, JobState::Running, JobState::Cancelled)
            );
        }
        other => panic!("expected WrongState, got {other:?}"),
    }
}

#[test]
fn wrong_transitions_are_refused_naming_the_state_found() {
    let mut store = Store::open_in_memory().unwrap();
    let queued = store.enqueue("demo", "verify", &json!({})).unwrap().id;
    let ok = || Outcome::Succeeded {
        result: json!({}),
        metrics: Map::new(),
    };

    // Not running yet: no progress, measurement or finish.
    assert!(matches!(
        store.set_progress(queued, 0, 1),
        Err(StoreError::WrongState {
            state: JobState::Queued,
            wanted: JobState::Running,
            ..
        })
    ));
    assert!(matches!(
        store.add_measurement(queued, &json!({})),
        Err(StoreError::WrongState {
            state: JobState::Queued,
            ..
        })
    ));
    assert!(matches!(
        store.finish(queued, ok()),
        Err(StoreError::WrongState {
            state: JobState::Queued,
            wanted: JobState::Succeeded,
            ..
        })
    ));

    store.start(queued, None).unwrap();
    assert!(matches!(
        store.start(queued, None),
        Err(StoreError::WrongState {
            state: JobState::Running,
            wanted: JobState::Running,
            ..
        })
    ));
    store.finish(queued, ok()).unwrap();
    // Finished is final.
    assert!(matches!(
        store.finish(queued, ok()),
        Err(StoreError::WrongState {
            state: JobState::Succeeded,
            ..
        })
    ));
    assert!(matches!(
        store.start(queued, None),
        Err(StoreError::WrongState {
            state: JobState::Succeeded,
            ..
        })
    ));
    assert!(matches!(
        store.cancel_queued(queued),
        Err(StoreError::WrongState {
            state: JobState::Succeeded,
            ..
        })
    ));
    assert!(matches!(
        store.add_measurement(queued, &json!({})),
        Err(StoreError::WrongState {
            state: JobState::Succeeded,
            ..
        })
    ));
    // The failed finish attempts wrote no outbox rows.
    assert_eq!(store.outbox_pending(10).unwrap().len(), 1);
}

#[test]
fn unknown_ids_and_bad_input_are_named() {
    let mut store = Store::open_in_memory().unwrap();
    assert!(matches!(
        store.start(42, None),
        Err(StoreError::UnknownJob(42))
    ));
    assert!(matches!(
        store.cancel_queued(42),
        Err(StoreError::UnknownJob(42))
    ));
    assert!(matches!(
        store.measurements(42),
        Err(StoreError::UnknownJob(42))
    ));
    assert!(matches!(
        store.set_progress(42, 0, 0),
        Err(StoreError::UnknownJob(42))
    ));
    assert_eq!(store.job(42).unwrap(), None);
    assert!(matches!(
        store.outbox_done(7),
        Err(StoreError::UnknownOutboxItem(7))
    ));
    assert!(matches!(
        store.outbox_push("demo", Some(42), &Map::new()),
        Err(StoreError::UnknownJob(42))
    ));
    assert!(matches!(
        store.enqueue("", "verify", &json!({})),
        Err(StoreError::InvalidInput {
            what: "machine",
            ..
        })
    ));
    let running = running_job(&mut store, "demo");
    let error = store.set_progress(running, 3, 2).unwrap_err();
    assert_eq!(
        error.to_string(),
        format!("progress of job {running}: done 3 is more than total 2")
    );
    let error = store.activate("demo", "xy", 1).unwrap_err();
    assert_eq!(error.to_string(), "unknown profile demo/xy version 1");
}

#[test]
fn job_listing_filters_and_pages_newest_first() {
    let mut store = Store::open_in_memory().unwrap();
    let a1 = store.enqueue("a", "verify", &json!({})).unwrap().id;
    let b1 = store.enqueue("b", "verify", &json!({})).unwrap().id;
    let a2 = store.enqueue("a", "map", &json!({})).unwrap().id;
    let a3 = store.enqueue("a", "map", &json!({})).unwrap().id;
    store.start(a1, None).unwrap();

    let ids = |filter: JobFilter| -> Vec<i64> {
        store.jobs(&filter).unwrap().iter().map(|j| j.id).collect()
    };
    assert_eq!(ids(JobFilter::default()), vec![a3, a2, b1, a1]);
    assert_eq!(
        ids(JobFilter {
            machine: Some("a".into()),
            ..Default::default()
        }),
        vec![a3, a2, a1]
    );
    assert_eq!(
        ids(JobFilter {
            state: Some(JobState::Running),
            ..Default::default()
        }),
        vec![a1]
    );
    assert_eq!(
        ids(JobFilter {
            limit: Some(2),
            ..Default::default()
        }),
        vec![a3, a2]
    );
    assert_eq!(
        ids(JobFilter {
            machine: Some("a".into()),
            before_id: Some(a3),
            limit: Some(1),
            ..Default::default()
        }),
        vec![a2]
    );
    let queued: Vec<i64> = store.queued("a").unwrap().iter().map(|j| j.id).collect();
    assert_eq!(queued, vec![a2, a3]);
}

#[test]
fn profile_versions_count_up_and_rollback_walks_the_activation_history_back() {
    let mut store = Store::open_in_memory().unwrap();
    let source = running_job(&mut store, "demo");
    for n in 1..=3 {
        let version = store
            .add_profile(
                "demo",
                "xy",
                ProfileKind::ErrorMap,
                &json!({"n": n}),
                Some(source),
                Some("scan"),
            )
            .unwrap();
        assert_eq!(version.version, n);
        assert!(!version.active);
        assert_eq!(version.source_job, Some(source));
    }
    assert_eq!(
        store.active_profile("demo", ProfileKind::ErrorMap).unwrap(),
        None
    );
    assert!(matches!(
        store.rollback("demo", "xy"),
        Err(StoreError::NothingToRollBack { .. })
    ));

    let active_version = |store: &Store| {
        store
            .active_profile("demo", ProfileKind::ErrorMap)
            .unwrap()
            .map(|(p, body)| (p.version, body))
    };
    store.activate("demo", "xy", 1).unwrap();
    store.activate("demo", "xy", 3).unwrap();
    store.activate("demo", "xy", 2).unwrap();
    // Activating the active version again adds nothing to the history.
    assert!(store.activate("demo", "xy", 2).unwrap().active);
    assert_eq!(active_version(&store), Some((2, json!({"n": 2}))));

    // History 1, 3, 2: rollback gives 3, then 1, then nothing more.
    assert_eq!(store.rollback("demo", "xy").unwrap().version, 3);
    assert_eq!(active_version(&store), Some((3, json!({"n": 3}))));
    let rolled = store.rollback("demo", "xy").unwrap();
    assert_eq!((rolled.version, rolled.active), (1, true));
    assert!(matches!(
        store.rollback("demo", "xy"),
        Err(StoreError::NothingToRollBack { .. })
    ));
    // Exactly one version shows active.
    let actives: Vec<u32> = store
        .profiles("demo")
        .unwrap()
        .iter()
        .filter(|p| p.active)
        .map(|p| p.version)
        .collect();
    assert_eq!(actives, vec![1]);

    // A new activation after rollbacks stacks on what is current: 1 -> 2, rollback -> 1.
    store.activate("demo", "xy", 2).unwrap();
    assert_eq!(store.rollback("demo", "xy").unwrap().version, 1);
}

/// Two error maps of one machine, each with its active version: the one activated last
/// is in use (and only it shows so); activating the other's active version again puts
/// it back in use, and rolling that back returns to the version before it, not to the
/// same version once more.
#[test]
fn of_two_active_maps_the_one_activated_last_is_in_use_and_the_other_can_be_put_back() {
    let mut store = Store::open_in_memory().unwrap();
    for (name, n) in [("demo-map", 1), ("demo-map", 2), ("error_map", 1)] {
        store
            .add_profile(
                "m",
                name,
                ProfileKind::ErrorMap,
                &json!({"n": n}),
                None,
                None,
            )
            .unwrap();
    }
    store
        .add_profile("m", "table", ProfileKind::Rotary, &json!({}), None, None)
        .unwrap();
    let in_use = |store: &Store| -> Vec<(String, u32)> {
        store
            .profiles("m")
            .unwrap()
            .into_iter()
            .filter(|p| p.in_use)
            .map(|p| (p.name, p.version))
            .collect()
    };
    let applied = |store: &Store| {
        let (p, _) = store
            .active_profile("m", ProfileKind::ErrorMap)
            .unwrap()
            .unwrap();
        (p.name, p.version)
    };
    store.activate("m", "demo-map", 1).unwrap();
    store.activate("m", "demo-map", 2).unwrap();
    store.activate("m", "table", 1).unwrap();
    store.activate("m", "error_map", 1).unwrap();
    assert_eq!(applied(&store), ("error_map".into(), 1));
    // Both maps have an active version; one of each kind is in use.
    let active: Vec<(String, u32)> = (store.profiles("m").unwrap().into_iter())
        .filter(|p| p.active)
        .map(|p| (p.name, p.version))
        .collect();
    assert_eq!(active.len(), 3, "{active:?}");
    assert_eq!(
        in_use(&store),
        vec![("error_map".into(), 1), ("table".into(), 1)]
    );

    // demo-map v2 is active but displaced: activating it puts it back in use.
    let again = store.activate("m", "demo-map", 2).unwrap();
    assert!(again.active && again.in_use, "{again:?}");
    assert_eq!(applied(&store), ("demo-map".into(), 2));
    assert_eq!(
        in_use(&store),
        vec![("demo-map".into(), 2), ("table".into(), 1)]
    );
    // Activating what is in use adds nothing: one rollback returns to v1.
    store.activate("m", "demo-map", 2).unwrap();
    let back = store.rollback("m", "demo-map").unwrap();
    assert_eq!((back.version, back.active), (1, true));
    assert!(matches!(
        store.rollback("m", "demo-map"),
        Err(StoreError::NothingToRollBack { .. })
    ));
}

#[test]
fn profiles_are_per_machine_and_name_and_keep_their_kind() {
    let mut store = Store::open_in_memory().unwrap();
    store
        .add_profile("a", "xy", ProfileKind::ErrorMap, &json!({}), None, None)
        .unwrap();
    assert_eq!(
        store
            .add_profile("b", "xy", ProfileKind::ErrorMap, &json!({}), None, None)
            .unwrap()
            .version,
        1
    );
    assert!(matches!(
        store.add_profile("a", "xy", ProfileKind::Rotary, &json!({}), None, None),
        Err(StoreError::ProfileKindMismatch {
            existing: ProfileKind::ErrorMap,
            requested: ProfileKind::Rotary,
            ..
        })
    ));
    store
        .add_profile(
            "a",
            "c",
            ProfileKind::Rotary,
            &json!({"c": 1}),
            None,
            Some("table"),
        )
        .unwrap();
    store.activate("a", "c", 1).unwrap();
    let (rotary, body) = store
        .active_profile("a", ProfileKind::Rotary)
        .unwrap()
        .unwrap();
    assert_eq!(
        (rotary.name.as_str(), rotary.note.as_deref(), body),
        ("c", Some("table"), json!({"c": 1}))
    );
    assert_eq!(
        store.active_profile("a", ProfileKind::ErrorMap).unwrap(),
        None
    );
    assert_eq!(
        store.active_profile("b", ProfileKind::Rotary).unwrap(),
        None
    );
    assert!(matches!(
        store.rollback("a", "nope"),
        Err(StoreError::UnknownProfileName { .. })
    ));
    assert_eq!(store.profile("a", "xy", 2).unwrap(), None);
    assert_eq!(store.profiles("a").unwrap().len(), 2);
    assert!(matches!(
        store.add_profile(
            "a",
            "z",
            ProfileKind::Volumetric,
            &json!({}),
            Some(99),
            None
        ),
        Err(StoreError::UnknownJob(99))
    ));
    // JSON names of the kinds.
    assert_eq!(
        serde_json::to_value(ProfileKind::ErrorMap).unwrap(),
        json!("error_map")
    );
    assert_eq!(
        serde_json::to_value(JobState::Interrupted).unwrap(),
        json!("interrupted")
    );
}

#[test]
fn the_outbox_keeps_order_and_marks_rows_done() {
    let mut store = Store::open_in_memory().unwrap();
    let first = store
        .outbox_push("a", None, &metrics(&[("n", 1.0)]))
        .unwrap();
    let job = running_job(&mut store, "b");
    store
        .finish(
            job,
            Outcome::Succeeded {
                result: json!(1),
                metrics: metrics(&[("n", 2.0)]),
            },
        )
        .unwrap();
    let third = store
        .outbox_push("a", None, &metrics(&[("n", 3.0)]))
        .unwrap();

    let pending = store.outbox_pending(10).unwrap();
    let order: Vec<f64> = pending
        .iter()
        .map(|i| i.metrics["n"].as_f64().unwrap())
        .collect();
    assert_eq!(order, vec![1.0, 2.0, 3.0]);
    assert_eq!(store.outbox_pending(2).unwrap().len(), 2);

    store.outbox_done(pending[1].id).unwrap();
    let left: Vec<i64> = store
        .outbox_pending(10)
        .unwrap()
        .iter()
        .map(|i| i.id)
        .collect();
    assert_eq!(left, vec![first, third]);
    // Done twice is harmless.
    store.outbox_done(pending[1].id).unwrap();
    store.outbox_done(first).unwrap();
    store.outbox_done(third).unwrap();
    assert!(store.outbox_pending(10).unwrap().is_empty());
}

#[test]
fn settings_round_trip_and_replace() {
    let mut store = Store::open_in_memory().unwrap();
    assert_eq!(store.get_setting("sparkplug.bdseq").unwrap(), None);
    store.set_setting("sparkplug.bdseq", "0").unwrap();
    store.set_setting("sparkplug.bdseq", "1").unwrap();
    assert_eq!(
        store.get_setting("sparkplug.bdseq").unwrap().as_deref(),
        Some("1")
    );
}

#[test]
fn restart_turns_running_jobs_into_interrupted_keeping_measurements() {
    let dir = TempDir::new("recover");
    let path = dir.0.join("gateway.sqlite");
    let (running, queued, done) = {
        let mut store = Store::open(&path).unwrap();
        let running = running_job(&mut store, "demo");
        store.set_progress(running, 1, 5).unwrap();
        store.add_measurement(running, &json!({"i": 0})).unwrap();
        store.add_measurement(running, &json!({"i": 1})).unwrap();
        let queued = store.enqueue("demo", "map", &json!({})).unwrap().id;
        let done = running_job(&mut store, "demo");
        store
            .finish(
                done,
                Outcome::Succeeded {
                    result: json!({}),
                    metrics: Map::new(),
                },
            )
            .unwrap();
        store.set_setting("sparkplug.bdseq", "4").unwrap();
        store
            .add_profile(
                "demo",
                "xy",
                ProfileKind::ErrorMap,
                &json!({"g": 1}),
                None,
                None,
            )
            .unwrap();
        store.activate("demo", "xy", 1).unwrap();
        (running, queued, done)
        // dropped here: the process "dies" with a job running
    };
    let mut store = Store::open(&path).unwrap();
    let recovered = store.recover().unwrap();
    assert_eq!(recovered.len(), 1);
    assert_eq!(recovered[0].id, running);
    assert_eq!(recovered[0].state, JobState::Interrupted);
    assert!(recovered[0].finished_at.is_some());
    assert_eq!(
        recovered[0].progress.map(|p| (p.done, p.total)),
        Some((1, 5))
    );
    assert_eq!(
        store.measurements(running).unwrap(),
        vec![json!({"i": 0}), json!({"i": 1})]
    );
    assert_eq!(store.job(queued).unwrap().unwrap().state, JobState::Queued);
    assert_eq!(store.job(done).unwrap().unwrap().state, JobState::Succeeded);
    assert_eq!(
        store.get_setting("sparkplug.bdseq").unwrap().as_deref(),
        Some("4")
    );
    assert_eq!(
        store
            .active_profile("demo", ProfileKind::ErrorMap)
            .unwrap()
            .unwrap()
            .1,
        json!({"g": 1})
    );
    assert_eq!(store.outbox_pending(10).unwrap().len(), 1);
    // Interrupted is final, and a second recover finds nothing.
    assert!(matches!(
        store.finish(
            running,
            Outcome::Cancelled {
                reason: None,
                result: None,
                metrics: Map::new()
            }
        ),
        Err(StoreError::WrongState {
            state: JobState::Interrupted,
            ..
        })
    ));
    assert!(store.recover().unwrap().is_empty());
}

#[test]
fn an_empty_file_is_migrated_and_a_newer_schema_is_refused() {
    let dir = TempDir::new("migrate");
    let path = dir.0.join("empty.sqlite");
    std::fs::write(&path, b"").unwrap();
    let store = Store::open(&path).unwrap();
    assert_eq!(store.schema_version(), SCHEMA_VERSION);
    assert_eq!(SCHEMA_VERSION, 4);
    drop(store);
    // Reopening does not migrate again.
    assert_eq!(Store::open(&path).unwrap().schema_version(), SCHEMA_VERSION);

    // A database from a future program.
    {
        let connection = rusqlite::Connection::open(&path).unwrap();
        connection
            .pragma_update(None, "user_version", SCHEMA_VERSION + 1)
            .unwrap();
    }
    match Store::open(&path) {
        Err(error @ StoreError::SchemaTooNew { .. }) => {
            let text = error.to_string();
            assert!(
                text.contains(&format!("schema version {}", SCHEMA_VERSION + 1)),
                "{text}"
            );
            assert!(text.contains("empty.sqlite"), "{text}");
        }
        Err(other) => panic!("expected SchemaTooNew, got {other}"),
        Ok(_) => panic!("expected SchemaTooNew, the newer database was opened"),
    }
}

#[test]
fn a_file_that_is_not_a_database_is_refused() {
    let dir = TempDir::new("garbage");
    let path = dir.0.join("garbage.sqlite");
    std::fs::write(&path, vec![b'x'; 4096]).unwrap();
    assert!(matches!(Store::open(&path), Err(StoreError::Sqlite(_))));
}

#[test]
fn a_partial_migration_is_rolled_back() {
    // Version 1 applied by hand, and a table of version 2's name already there: the
    // migration to 2 fails, and user_version stays at 1 with nothing half-created.
    let dir = TempDir::new("partial");
    let path = dir.0.join("partial.sqlite");
    drop(Store::open(&path).unwrap());
    {
        let connection = rusqlite::Connection::open(&path).unwrap();
        connection
            .execute_batch(
                "DROP INDEX jobs_by_machine_state; DROP INDEX jobs_by_state; \
                 DROP INDEX measurements_by_job; DROP INDEX activations_by_profile; \
                 DROP INDEX outbox_pending; CREATE TABLE outbox_pending (x); PRAGMA user_version = 1;",
            )
            .unwrap();
    }
    assert!(Store::open(&path).is_err());
    let connection = rusqlite::Connection::open(&path).unwrap();
    let version: u32 = connection
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .unwrap();
    assert_eq!(version, 1);
    let indexes: i64 = connection
        .query_row(
            "SELECT COUNT(*) FROM sqlite_master WHERE type = 'index' AND name = 'jobs_by_state'",
            [],
            |r| r.get(0),
        )
        .unwrap();
    assert_eq!(indexes, 0);
}

#[test]
fn the_database_file_uses_wal() {
    let dir = TempDir::new("pragmas");
    let path = dir.0.join("wal.sqlite");
    drop(Store::open(&path).unwrap());
    let connection = rusqlite::Connection::open(&path).unwrap();
    let mode: String = connection
        .query_row("PRAGMA journal_mode", [], |r| r.get(0))
        .unwrap();
    assert_eq!(mode, "wal");
}

#[test]
fn a_job_keeps_its_files_while_it_runs_and_serves_them_after() {
    let mut store = Store::open_in_memory().unwrap();
    let id = running_job(&mut store, "m1");
    store
        .add_job_file(
            id,
            "deviation_x.svg",
            Some("Deviation X"),
            "image/svg+xml",
            b"<svg/>",
        )
        .unwrap();
    store
        .add_job_file(id, "measurements.csv", None, "text/csv", b"a,b\n")
        .unwrap();
    // The same name again replaces the file.
    store
        .add_job_file(id, "measurements.csv", None, "text/csv", b"a,b\n1,2\n")
        .unwrap();
    for bad in ["", "../x", ".hidden", "a/b.svg", "a b"] {
        let e = store
            .add_job_file(id, bad, None, "text/plain", b"x")
            .unwrap_err();
        assert!(e.to_string().contains("plain file name"), "{bad:?}: {e}");
    }
    let big = vec![0u8; store::MAX_JOB_FILE_BYTES + 1];
    assert!(store
        .add_job_file(id, "big.bin", None, "application/octet-stream", &big)
        .is_err());
    store
        .finish(
            id,
            Outcome::Succeeded {
                result: json!({}),
                metrics: Map::new(),
            },
        )
        .unwrap();
    // A finished job's files are fixed.
    let e = store
        .add_job_file(id, "late.svg", None, "image/svg+xml", b"<svg/>")
        .unwrap_err();
    assert!(matches!(e, StoreError::WrongState { .. }), "{e}");
    let files = store.job_files(id).unwrap();
    let names: Vec<(&str, u64)> = files.iter().map(|f| (f.name.as_str(), f.size)).collect();
    assert_eq!(names, [("deviation_x.svg", 6), ("measurements.csv", 8)]);
    assert_eq!(files[0].title.as_deref(), Some("Deviation X"));
    assert_eq!(
        store.job_file(id, "measurements.csv").unwrap(),
        Some(("text/csv".to_string(), b"a,b\n1,2\n".to_vec()))
    );
    assert_eq!(store.job_file(id, "nothing.svg").unwrap(), None);
}

#[test]
fn a_version_2_database_gains_the_job_files_table() {
    let dir = TempDir::new("v2");
    let path = dir.0.join("v2.sqlite");
    drop(Store::open(&path).unwrap());
    {
        let connection = rusqlite::Connection::open(&path).unwrap();
        connection
            .execute_batch(
                "DROP TABLE job_files; ALTER TABLE jobs DROP COLUMN queue_pos; \
                 PRAGMA user_version = 2;",
            )
            .unwrap();
    }
    let mut store = Store::open(&path).unwrap();
    assert_eq!(store.schema_version(), SCHEMA_VERSION);
    let id = running_job(&mut store, "m1");
    store
        .add_job_file(id, "a.svg", None, "image/svg+xml", b"<svg/>")
        .unwrap();
}

fn queue_ids(store: &Store, machine: &str) -> Vec<i64> {
    store
        .queued(machine)
        .unwrap()
        .iter()
        .map(|j| j.id)
        .collect()
}

#[test]
fn a_queued_job_moves_in_its_machines_queue_and_later_jobs_still_go_last() {
    let mut store = Store::open_in_memory().unwrap();
    let ids: Vec<i64> = (0..4)
        .map(|_| store.enqueue("m1", "verify", &json!({})).unwrap().id)
        .collect();
    let other = store.enqueue("m2", "verify", &json!({})).unwrap().id;
    let [a, b, c, d] = ids[..] else { panic!() };
    // d first, then before b, then last; each answer is the new queue.
    let moved = store.move_queued(d, QueuePlace::Position(0)).unwrap();
    assert_eq!(moved.iter().map(|j| j.id).collect::<Vec<_>>(), [d, a, b, c]);
    store.move_queued(c, QueuePlace::Before(Some(a))).unwrap();
    assert_eq!(queue_ids(&store, "m1"), [d, c, a, b]);
    store.move_queued(d, QueuePlace::Before(None)).unwrap();
    assert_eq!(queue_ids(&store, "m1"), [c, a, b, d]);
    store.move_queued(a, QueuePlace::Position(99)).unwrap();
    assert_eq!(queue_ids(&store, "m1"), [c, b, d, a]);
    // A job queued later goes to the end; the worker takes the queue's first.
    let e = store.enqueue("m1", "verify", &json!({})).unwrap().id;
    assert_eq!(queue_ids(&store, "m1"), [c, b, d, a, e]);
    // Another machine's queue is untouched, and its job is no place to move to.
    assert_eq!(queue_ids(&store, "m2"), [other]);
    let error = store
        .move_queued(b, QueuePlace::Before(Some(other)))
        .unwrap_err();
    assert!(
        matches!(error, StoreError::InvalidInput { what: "before", .. }),
        "{error}"
    );
    // Only a queued job moves.
    store.start(c, None).unwrap();
    let error = store.move_queued(c, QueuePlace::Position(0)).unwrap_err();
    assert!(matches!(error, StoreError::WrongState { .. }), "{error}");
    assert_eq!(queue_ids(&store, "m1"), [b, d, a, e]);
    assert!(matches!(
        store.move_queued(9999, QueuePlace::Position(0)),
        Err(StoreError::UnknownJob(9999))
    ));
}

#[test]
fn a_version_3_database_keeps_its_queue_order_after_the_migration() {
    let dir = TempDir::new("v3");
    let path = dir.0.join("v3.sqlite");
    let ids: Vec<i64> = {
        let mut store = Store::open(&path).unwrap();
        (0..3)
            .map(|_| store.enqueue("m1", "verify", &json!({})).unwrap().id)
            .collect()
    };
    {
        let connection = rusqlite::Connection::open(&path).unwrap();
        connection
            .execute_batch("ALTER TABLE jobs DROP COLUMN queue_pos; PRAGMA user_version = 3;")
            .unwrap();
    }
    let mut store = Store::open(&path).unwrap();
    assert_eq!(store.schema_version(), SCHEMA_VERSION);
    assert_eq!(queue_ids(&store, "m1"), ids);
    store.move_queued(ids[2], QueuePlace::Position(0)).unwrap();
    assert_eq!(queue_ids(&store, "m1"), [ids[2], ids[0], ids[1]]);
}
