//! The service's [`Context`]: the store. The machine's job file and the devices its
//! worker opened through the drivers' factory, the machine's active `error_map` profile
//! with its current reference (a store setting per profile version), the scan journal
//! as the job's measurements, maps and rotary errors as profile versions, the job's
//! sink into the store and the events, the job's stop signal.

use crate::config::MachineConfig;
use crate::sink::{profile_map, ProfileShelf, RotaryShelf, StoreJournal, StoreSink};
use crate::state::{lock, Machine, Shared};
use devices::Devices;
use errormap::reference::MapReference;
use job::rotary::RotaryJob;
use job::Job;
use procedure::context::{ActiveMap, Bench, Context, ContextError, Stop};
use procedure::map::{MapShelf, ScanJournal};
use procedure::rotary::ErrorsShelf;
use procedure::Sink;
use protocol::errormap::Identity;
use serde_json::Value;
use std::sync::Arc;
use std::time::SystemTime;
use store::{JobRecord, ProfileVersion};

/// The store's key of a profile version's current reference record.
pub fn reference_key(machine: &str, profile: &str, version: u32) -> String {
    format!("reference/{machine}/{profile}/v{version}")
}

/// The devices are closed for a kind that opens the machine's link itself.
fn closed() -> ContextError {
    ContextError::Devices(
        "this job's kind opens the machine's link itself; the devices are closed".into(),
    )
}

/// One job's context.
pub struct StoreContext<'a> {
    pub shared: Arc<Shared>,
    pub machine: Arc<Machine>,
    pub config: &'a MachineConfig,
    /// The machine's devices; none for a kind that opens the controller's link itself.
    pub devices: Option<&'a mut Devices>,
    pub record: &'a JobRecord,
    /// The active map profile, resolved when the job started (its record names it).
    pub profile: Option<(ProfileVersion, Value)>,
    pub sink: StoreSink,
    pub stop: Stop,
    job: Option<Job>,
}

impl<'a> StoreContext<'a> {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        shared: &Arc<Shared>,
        machine: &Arc<Machine>,
        config: &'a MachineConfig,
        devices: Option<&'a mut Devices>,
        record: &'a JobRecord,
        profile: Option<(ProfileVersion, Value)>,
        stop: Stop,
    ) -> Self {
        Self {
            shared: shared.clone(),
            machine: machine.clone(),
            config,
            devices,
            record,
            profile,
            sink: StoreSink::new(shared, &machine.id, record.id),
            stop,
            job: None,
        }
    }

    fn loaded_job(&mut self) -> Result<&Job, ContextError> {
        if self.job.is_none() {
            let job = self
                .config
                .job
                .load()
                .map_err(|e| ContextError::Job(format!("job file: {e}")))?;
            self.job = Some(job);
        }
        Ok(self.job.as_ref().expect("loaded"))
    }

    fn devices(&mut self) -> Result<&mut Devices, ContextError> {
        self.devices.as_deref_mut().ok_or_else(closed)
    }

    fn profile(&self) -> Result<&(ProfileVersion, Value), ContextError> {
        self.profile.as_ref().ok_or_else(|| {
            ContextError::NoMap(format!(
                "machine {} has no active error_map profile; activate one first",
                self.machine.id
            ))
        })
    }
}

#[async_trait::async_trait(?Send)]
impl Context for StoreContext<'_> {
    fn job(&mut self) -> Result<Job, ContextError> {
        self.loaded_job().cloned()
    }

    async fn bench(&mut self) -> Result<Bench<'_>, ContextError> {
        self.loaded_job()?;
        Ok(Bench {
            job: self.job.as_ref().expect("loaded"),
            devices: self.devices.as_deref_mut().ok_or_else(closed)?,
            sink: &mut self.sink,
        })
    }

    async fn identity(&mut self) -> Result<Option<Identity>, ContextError> {
        let job = self.loaded_job()?.clone();
        Ok(Some(procedure::identity(&job, self.devices()?)))
    }

    fn sink(&mut self) -> &mut dyn Sink {
        &mut self.sink
    }

    fn stop(&self) -> Stop {
        self.stop.clone()
    }

    fn now(&self) -> SystemTime {
        SystemTime::now()
    }

    fn map(&mut self) -> Result<ActiveMap, ContextError> {
        let (version, body) = self.profile()?;
        let name = format!("error_map profile {} v{}", version.name, version.version);
        let map = profile_map(body)
            .map_err(|e| ContextError::Files(format!("the active {name}: {e}")))?;
        let key = reference_key(&self.machine.id, &version.name, version.version);
        let reference = lock(&self.shared.store)
            .get_setting(&key)
            .map_err(|e| procedure::Error::Input(format!("the reference of {name}: {e}")))
            .and_then(|text| match text {
                None => Ok(None),
                Some(t) => {
                    procedure::reference::parse_record(&t, &format!("the reference of {name}"))
                        .map(Some)
                }
            });
        Ok(ActiveMap {
            name,
            map,
            reference,
        })
    }

    fn keep_reference(&mut self, record: &MapReference) -> Result<String, ContextError> {
        let (version, _) = self.profile()?;
        let key = reference_key(&self.machine.id, &version.name, version.version);
        let text = procedure::reference::record_json(record);
        lock(&self.shared.store)
            .set_setting(&key, &text)
            .map_err(|e| ContextError::Files(e.to_string()))?;
        Ok(format!(
            "the current reference of error_map profile {} v{}",
            version.name, version.version
        ))
    }

    fn scan_journal(&mut self, name: &str) -> Result<Box<dyn ScanJournal>, ContextError> {
        Ok(Box::new(StoreJournal {
            shared: self.shared.clone(),
            machine: self.machine.id.clone(),
            job: self.record.id,
            name: name.to_string(),
            params: self.record.params.clone(),
            resumed_from: None,
        }))
    }

    fn map_shelf(&mut self) -> Result<Box<dyn MapShelf>, ContextError> {
        Ok(Box::new(ProfileShelf {
            shared: self.shared.clone(),
            machine: self.machine.id.clone(),
            job: self.record.id,
        }))
    }

    fn rotary_job(&mut self) -> Result<RotaryJob, ContextError> {
        let source = self.config.rotary.as_ref().ok_or_else(|| {
            ContextError::Job(format!(
                "machine {} has no rotary job file",
                self.machine.id
            ))
        })?;
        source
            .load()
            .map_err(|e| ContextError::Job(format!("rotary job file: {e}")))
    }

    fn errors_shelf(&mut self) -> Result<Box<dyn ErrorsShelf>, ContextError> {
        Ok(Box::new(RotaryShelf {
            shared: self.shared.clone(),
            machine: self.machine.id.clone(),
            job: self.record.id,
        }))
    }
}
