//! One axis behind a Modbus positioning drive, commanded through its profile.

use super::bus::{exception_error, Failure, Op, SharedBus};
use crate::error::DriverError;
use crate::multi_axis::{AxisDrive, AxisStatus};
use crate::stage::AxisInfo;
use async_trait::async_trait;
pub use link_spec::modbus::ModbusAxisConfig;
use protocol::modbus::profile::{Command, DriveProfile, DriveStatus, Register, Table};
use std::sync::Arc;
use tokio::time::Instant;

/// How the moves of an axis went, for tests and diagnostics.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MoveStats {
    /// Move blocks written (including resends).
    pub writes: u64,
    /// Moves confirmed by their reply.
    pub acknowledged: u64,
    /// Moves whose reply was lost and which the read-back proved received.
    pub proven_by_readback: u64,
    /// Moves whose reply was lost and which the read-back proved NOT received, so
    /// they were sent again.
    pub resent: u64,
}

/// A Modbus drive as an [`AxisDrive`].
///
/// Moves are triggered exactly once: the whole move block (target, speed,
/// acceleration, trigger) is one write-multiple request, which a drive executes
/// entirely or not at all. When its reply is lost (timeout, bad CRC, broken link) the
/// driver does not resend blindly: on the rebuilt connection it reads back the drive's
/// latched target (the profile's `readback`, by default the block's position register)
/// and resends only if the drive provably did not take the block:
/// * the latched target differs from the one sent: not received, send again;
/// * it equals the one sent and differed before: received (only our write sets it);
/// * it was already equal (the same target twice): received if the drive is busy or
///   already there; otherwise not received.
///
/// A drive executes a request when its frame is complete, so by the end of the
/// timeout a request is either executed or lost. Commands (home, stop, alarm reset)
/// set states and may be repeated, so they are retried as plain requests.
pub struct ModbusAxis {
    bus: SharedBus,
    unit: u8,
    profile: Arc<DriveProfile>,
    info: AxisInfo,
    device: String,
    /// The drive's latched target as last known (counts).
    latched: Option<i64>,
    stats: MoveStats,
}

fn range(r: &Register) -> String {
    r.to_string()
}

impl ModbusAxis {
    /// An axis on a (possibly shared) bus. Nothing is sent yet.
    pub async fn new(bus: SharedBus, profile: Arc<DriveProfile>, cfg: &ModbusAxisConfig) -> Self {
        let endpoint = bus.lock().await.endpoint().to_string();
        let device = format!(
            "{endpoint} unit {} (axis {}, {})",
            cfg.unit, cfg.axis, profile.name
        );
        let info = AxisInfo {
            axis: cfg.axis,
            min_mm: cfg.min_mm,
            max_mm: cfg.max_mm,
            resolution_mm: 1.0 / profile.counts_per_mm(),
            max_feed_mm_min: cfg.max_feed_mm_min.unwrap_or(profile.max_speed_mm_min),
        };
        Self {
            bus,
            unit: cfg.unit,
            profile,
            info,
            device,
            latched: None,
            stats: MoveStats::default(),
        }
    }

    pub fn unit(&self) -> u8 {
        self.unit
    }

    pub fn profile(&self) -> &DriveProfile {
        &self.profile
    }

    pub fn move_stats(&self) -> MoveStats {
        self.stats.clone()
    }

    pub fn bus(&self) -> &SharedBus {
        &self.bus
    }

    async fn read(&self, r: &Register) -> Result<i64, DriverError> {
        let op = match r.table {
            Table::Holding => Op::ReadHolding(r.address, r.words()),
            Table::Input => Op::ReadInput(r.address, r.words()),
        };
        let what = format!("read {}", range(r));
        let words = self
            .bus
            .lock()
            .await
            .call(self.unit, &op, &self.device, &what)
            .await?;
        self.expect_words(&words, r.words(), &what)?;
        Ok(r.decode(&words))
    }

    fn expect_words(&self, words: &[u16], n: u16, what: &str) -> Result<(), DriverError> {
        if words.len() != n as usize {
            return Err(DriverError::Protocol {
                device: self.device.clone(),
                message: format!("{what}: {} registers came back, {n} asked for", words.len()),
            });
        }
        Ok(())
    }

    /// Status word, actual position (counts) and alarm code, in one request when the
    /// profile's registers are adjacent.
    async fn poll(&self) -> Result<(DriveStatus, i64, Option<i64>), DriverError> {
        let p = &self.profile;
        if let Some((table, first, n)) = p.poll_span() {
            let op = match table {
                Table::Holding => Op::ReadHolding(first, n),
                Table::Input => Op::ReadInput(first, n),
            };
            let what = format!(
                "read status, position and alarm code ({table} 0x{first:04X}, {n} registers)"
            );
            let words = self
                .bus
                .lock()
                .await
                .call(self.unit, &op, &self.device, &what)
                .await?;
            self.expect_words(&words, n, &what)?;
            let at = |r: &Register| {
                let k = (r.address - first) as usize;
                r.decode(&words[k..k + r.words() as usize])
            };
            let status = p.decode_status(at(&p.status.reg) as u32);
            return Ok((status, at(&p.position), p.alarm_code.as_ref().map(at)));
        }
        let status = p.decode_status(self.read(&p.status.reg).await? as u32);
        let pos = self.read(&p.position).await?;
        let code = match (&p.alarm_code, status.alarm) {
            (Some(r), true) => Some(self.read(r).await?),
            _ => None,
        };
        Ok((status, pos, code))
    }

    fn alarm(&self, code: Option<i64>) -> DriverError {
        let code = code.unwrap_or(0).max(0) as u32;
        let message = match self.profile.alarm_text(code) {
            Some(t) => format!("0x{code:04X}: {t}"),
            None => format!("0x{code:04X} (see the drive's alarm list)"),
        };
        DriverError::Alarm {
            device: self.device.clone(),
            code,
            message,
        }
    }

    async fn write_register(&self, r: &Register, value: i64) -> Result<(), DriverError> {
        let what = format!("write {value} to {}", range(r));
        let words = r.encode(value).map_err(|e| DriverError::Unsupported {
            device: self.device.clone(),
            message: format!("{what}: {e}"),
        })?;
        let op = if words.len() == 1 {
            Op::WriteSingle(r.address, words[0])
        } else {
            Op::WriteMultiple(r.address, &words)
        };
        self.bus
            .lock()
            .await
            .call(self.unit, &op, &self.device, &what)
            .await
            .map(|_| ())
    }

    async fn command(&self, c: &Command) -> Result<(), DriverError> {
        self.write_register(&c.reg, c.value).await?;
        if let Some(r) = c.release {
            self.write_register(&c.reg, r).await?;
        }
        Ok(())
    }

    /// Clear a drive alarm (the profile's `alarm_reset` command).
    pub async fn reset_alarm(&mut self) -> Result<(), DriverError> {
        let Some(c) = self.profile.alarm_reset.clone() else {
            return Err(DriverError::Unsupported {
                device: self.device.clone(),
                message: format!(
                    "the profile {} has no `commands.alarm_reset`",
                    self.profile.file
                ),
            });
        };
        self.command(&c).await
    }

    /// After a lost reply to a move block: did the drive take it?
    async fn was_received(
        &mut self,
        target: i64,
        before: Option<i64>,
    ) -> Result<bool, DriverError> {
        let latched = self.read(&self.profile.readback.clone()).await?;
        if latched != target {
            return Ok(false);
        }
        if before != Some(target) {
            return Ok(true);
        }
        let (st, actual, code) = self.poll().await?;
        if st.alarm {
            return Err(self.alarm(code));
        }
        Ok(st.busy || (actual - target).abs() <= 1)
    }

    async fn wait(&mut self, what: &str, until_homed: bool) -> Result<(), DriverError> {
        let opts = self.bus.lock().await.options().clone();
        let deadline = Instant::now() + opts.motion_timeout;
        loop {
            let (st, _, code) = self.poll().await?;
            if st.alarm {
                return Err(self.alarm(code));
            }
            if !st.busy && (!until_homed || st.home_done != Some(false)) {
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: self.device.clone(),
                    what: what.to_string(),
                    after_ms: opts.motion_timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(opts.poll_interval).await;
        }
    }
}

#[async_trait]
impl AxisDrive for ModbusAxis {
    fn info(&self) -> &AxisInfo {
        &self.info
    }

    fn device(&self) -> &str {
        &self.device
    }

    async fn home(&mut self) -> Result<(), DriverError> {
        let home = self.profile.home.clone();
        self.command(&home).await?;
        self.wait("homing", true).await
    }

    async fn start_move(&mut self, position_mm: f64, speed_mm_min: f64) -> Result<(), DriverError> {
        let i = &self.info;
        if !(position_mm >= i.min_mm && position_mm <= i.max_mm) {
            return Err(DriverError::OutOfLimits {
                axis: i.axis,
                value_mm: position_mm,
                min_mm: i.min_mm,
                max_mm: i.max_mm,
            });
        }
        crate::stage::check_feed(&self.device, speed_mm_min)?;
        let speed = speed_mm_min.min(i.max_feed_mm_min) / 60.0;
        let block = &self.profile.motion;
        let words =
            self.profile
                .move_words(position_mm, speed)
                .map_err(|e| DriverError::Unsupported {
                    device: self.device.clone(),
                    message: format!(
                        "cannot command {position_mm} mm at {speed_mm_min} mm/min: {e}"
                    ),
                })?;
        let target = self.profile.counts(position_mm);
        if self.latched.is_none() {
            // Known before the first move, so a lost reply can be judged.
            self.latched = Some(self.read(&self.profile.readback.clone()).await?);
        }
        let before = self.latched;
        let what = format!(
            "move block (holding 0x{:04X}, {} registers) to {position_mm} mm",
            block.address, block.len
        );
        let op = Op::WriteMultiple(block.address, &words);
        let retries = self.bus.lock().await.options().retries;
        let mut tried = Vec::new();
        for _ in 0..=retries {
            self.stats.writes += 1;
            let r = self.bus.lock().await.attempt(self.unit, &op).await;
            match r {
                Ok(_) => {
                    self.stats.acknowledged += 1;
                    self.latched = Some(target);
                    return Ok(());
                }
                Err(Failure::Exception(e)) => return Err(exception_error(&self.device, &what, e)),
                Err(f) => tried.push(f),
            }
            if self.was_received(target, before).await? {
                self.stats.proven_by_readback += 1;
                self.latched = Some(target);
                return Ok(());
            }
            self.stats.resent += 1;
        }
        self.stats.resent -= 1;
        Err(self.bus.lock().await.gave_up(&self.device, &what, &tried))
    }

    async fn position(&mut self) -> Result<f64, DriverError> {
        let c = self.read(&self.profile.position.clone()).await?;
        Ok(self.profile.mm(c))
    }

    async fn status(&mut self) -> Result<AxisStatus, DriverError> {
        let (st, pos, code) = self.poll().await?;
        let fault = st.alarm.then(|| self.alarm(code).to_string());
        Ok(AxisStatus {
            moving: st.busy,
            homed: st.home_done.unwrap_or(true),
            fault,
            position_mm: self.profile.mm(pos),
        })
    }

    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.wait("end of motion", false).await
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        let stop = self.profile.stop.clone();
        self.command(&stop).await
    }
}
