//! One CiA 402 drive as an [`AxisDrive`]: start-up over SDO, PDO mapping, heartbeat
//! supervision, bring-up to "Operation enabled", profile-position moves with the
//! set-point handshake, homing, EMCY and fault handling, counts-per-mm scaling.
//!
//! Process data the driver maps on every node (by SDO, in Pre-operational):
//!
//! | PDO | COB-ID | content | why |
//! |---|---|---|---|
//! | RPDO1 | 0x200+id | controlword, target position | a set-point and its bit 4 edge arrive together |
//! | RPDO2 | 0x300+id | profile velocity | each move's speed, sent just before it |
//! | TPDO1 | 0x180+id | statusword, mode display | on change, no inhibit: no state change is missed (handshake, homing) |
//! | TPDO2 | 0x280+id | statusword, position actual | on change with an inhibit time, plus an event timer: positions without flooding the bus, each paired with its statusword |
//!
//! Other PDOs are disabled. Position units are encoder counts, scaled by the
//! configured counts per mm.

use super::network::{Network, NodeView};
use crate::error::DriverError;
use crate::multi_axis::{AxisDrive, AxisStatus};
use crate::stage::AxisInfo;
use async_trait::async_trait;
pub use link_spec::canopen::{AxisConfig, CanopenOptions};
use protocol::can::CanFrame;
use protocol::canopen::emcy;
use protocol::canopen::nmt::NmtCommand;
use protocol::canopen::pdo::{self, MapEntry, COB_INVALID};
use protocol::canopen::NodeId;
use protocol::cia402::{self, cw, obj, sw, HomingStatus, Mode, Scaling, State};
use std::time::Duration;
use tokio::time::Instant;

/// A CiA 402 drive on a CANopen network.
pub struct Cia402Axis {
    net: Network,
    node: NodeId,
    cfg: AxisConfig,
    opts: CanopenOptions,
    info: AxisInfo,
    device: String,
    scaling: Scaling,
    /// Target in the last RPDO1 (resent with every controlword).
    target: i32,
    /// A move was started and not yet waited for: TPDO2 count at its acknowledge.
    moving_since: Option<u64>,
    homed: bool,
    boot_ups: u64,
}

fn device_name(node: NodeId) -> String {
    format!("CANopen node {}", node.get())
}

impl Cia402Axis {
    /// Bring a node up: check it is a CiA 402 drive with profile position and homing,
    /// set its heartbeat, map its PDOs, set accelerations and the homing method, start
    /// it (NMT) and enable it (Operation enabled).
    pub async fn connect(
        net: &Network,
        cfg: AxisConfig,
        opts: CanopenOptions,
    ) -> Result<Self, DriverError> {
        let node = NodeId::new(cfg.node).ok_or_else(|| DriverError::Unsupported {
            device: net.name().to_string(),
            message: format!("node id {} is outside 1..127", cfg.node),
        })?;
        let device = device_name(node);
        let scaling = Scaling::new(cfg.counts_per_mm);
        let info = AxisInfo {
            axis: cfg.axis,
            min_mm: cfg.min_mm,
            max_mm: cfg.max_mm,
            resolution_mm: 1.0 / cfg.counts_per_mm,
            max_feed_mm_min: cfg.max_feed_mm_min,
        };
        let mut a = Cia402Axis {
            net: net.clone(),
            node,
            cfg,
            opts,
            info,
            device,
            scaling,
            target: 0,
            moving_since: None,
            homed: false,
            boot_ups: 0,
        };
        a.start_up().await?;
        Ok(a)
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    async fn read(&self, index: u16, sub: u8) -> Result<Vec<u8>, DriverError> {
        match self.net.sdo_read(self.node, index, sub).await {
            Ok(v) => Ok(v),
            // A node that is gone is reported as such, not as an unanswered SDO.
            Err(e) => Err(self.check_alive().err().unwrap_or(e)),
        }
    }

    async fn read_u32(&self, index: u16, sub: u8) -> Result<u32, DriverError> {
        let v = self.read(index, sub).await?;
        let mut b = [0u8; 4];
        if v.is_empty() || v.len() > 4 {
            return Err(DriverError::Protocol {
                device: self.device.clone(),
                message: format!(
                    "0x{index:04X}:{sub:02X} is {} bytes, expected 1 to 4",
                    v.len()
                ),
            });
        }
        b[..v.len()].copy_from_slice(&v);
        Ok(u32::from_le_bytes(b))
    }

    async fn write(&self, index: u16, sub: u8, data: &[u8]) -> Result<(), DriverError> {
        match self.net.sdo_write(self.node, index, sub, data).await {
            Ok(()) => Ok(()),
            Err(e) => Err(self.check_alive().err().unwrap_or(e)),
        }
    }

    async fn start_up(&mut self) -> Result<(), DriverError> {
        let node = self.node;
        // Pre-operational: SDO works, PDOs are off while they are re-mapped.
        self.net
            .nmt(NmtCommand::EnterPreOperational, Some(node))
            .await?;
        let device_type = self.read_u32(0x1000, 0).await?;
        if device_type & 0xFFFF != 402 {
            return Err(DriverError::Protocol {
                device: self.device.clone(),
                message: format!(
                    "device type 0x{device_type:08X} is not a CiA 402 drive (profile {})",
                    device_type & 0xFFFF
                ),
            });
        }
        let modes = self.read_u32(obj::SUPPORTED_MODES, 0).await?;
        for m in [Mode::ProfilePosition, Mode::Homing] {
            if modes & m.supported_bit() == 0 {
                return Err(DriverError::Unsupported {
                    device: self.device.clone(),
                    message: format!(
                        "the drive does not support {m:?} mode (0x6502 = 0x{modes:08X})"
                    ),
                });
            }
        }
        if let Ok(name) = self.read(0x1008, 0).await {
            let name = String::from_utf8_lossy(&name)
                .trim_end_matches('\0')
                .to_string();
            if !name.is_empty() {
                self.device = format!("{} ({name})", device_name(node));
            }
        }
        self.write(0x1017, 0, &self.opts.heartbeat_ms.to_le_bytes())
            .await?;
        self.map_pdos().await?;
        let accel = self.scaling.accel_to_counts_s2(self.cfg.accel_mm_s2);
        self.write(obj::PROFILE_ACCELERATION, 0, &accel.to_le_bytes())
            .await?;
        self.write(obj::PROFILE_DECELERATION, 0, &accel.to_le_bytes())
            .await?;
        self.write(obj::HOMING_METHOD, 0, &[self.cfg.homing_method as u8])
            .await?;
        self.write(obj::MODES_OF_OPERATION, 0, &[Mode::ProfilePosition as u8])
            .await?;
        self.net
            .set_stop_frame(node, self.rpdo1(cw::QUICK_STOP_CMD, 0))?;
        if self.opts.heartbeat_ms > 0 {
            self.net
                .watch_heartbeat(node, self.opts.heartbeat_timeout)?;
        }
        self.boot_ups = self.net.view(node, |v| v.boot_ups);
        self.net.nmt(NmtCommand::Start, Some(node)).await?;
        // Seed the process image by SDO: a drive need not send its TPDOs on start.
        let sw = self.read(obj::STATUSWORD, 0).await?;
        let pos = self.read(obj::POSITION_ACTUAL, 0).await?;
        self.target = i32::from_le_bytes(
            pos.get(..4)
                .and_then(|b| b.try_into().ok())
                .unwrap_or([0; 4]),
        );
        self.net.seed_value(node, obj::STATUSWORD, 0, sw);
        self.net.seed_value(node, obj::POSITION_ACTUAL, 0, pos);
        self.enable(true).await
    }

    async fn map_pdos(&self) -> Result<(), DriverError> {
        let id = self.node;
        // Disable everything first (bit 31), then map what we use.
        for (comm, n) in [
            (pdo::RPDO_COMM, 0u16),
            (pdo::RPDO_COMM, 1),
            (pdo::RPDO_COMM, 2),
            (pdo::RPDO_COMM, 3),
        ]
        .into_iter()
        .chain((0..4).map(|n| (pdo::TPDO_COMM, n)))
        {
            let base = if comm == pdo::RPDO_COMM {
                id.rpdo(usize::from(n) + 1)
            } else {
                id.tpdo(usize::from(n) + 1)
            };
            self.write(comm + n, 1, &(COB_INVALID | u32::from(base)).to_le_bytes())
                .await?;
        }
        let cwm = MapEntry::new(obj::CONTROLWORD, 0, 16);
        let tpm = MapEntry::new(obj::TARGET_POSITION, 0, 32);
        let pvm = MapEntry::new(obj::PROFILE_VELOCITY, 0, 32);
        let swm = MapEntry::new(obj::STATUSWORD, 0, 16);
        let mdm = MapEntry::new(obj::MODES_DISPLAY, 0, 8);
        let pam = MapEntry::new(obj::POSITION_ACTUAL, 0, 32);
        self.map(pdo::RPDO_COMM, 0, id.rpdo(1), &[cwm, tpm], 0, 0)
            .await?;
        self.map(pdo::RPDO_COMM, 1, id.rpdo(2), &[pvm], 0, 0)
            .await?;
        self.map(pdo::TPDO_COMM, 0, id.tpdo(1), &[swm, mdm], 0, 0)
            .await?;
        self.map(
            pdo::TPDO_COMM,
            1,
            id.tpdo(2),
            &[swm, pam],
            self.opts.position_inhibit_100us,
            self.opts.position_event_ms,
        )
        .await?;
        self.net.map_tpdo(id, 1, id.tpdo(1), vec![swm, mdm])?;
        self.net.map_tpdo(id, 2, id.tpdo(2), vec![swm, pam])?;
        Ok(())
    }

    /// Map one PDO (CiA 301 order: disabled, type, timing, sub 0 = 0, entries, count,
    /// enabled).
    async fn map(
        &self,
        comm: u16,
        n: u16,
        cob: u16,
        entries: &[MapEntry],
        inhibit: u16,
        timer: u16,
    ) -> Result<(), DriverError> {
        let c = comm + n;
        let m = c + 0x200;
        self.write(c, 2, &[pdo::TT_EVENT_PROFILE]).await?;
        if comm == pdo::TPDO_COMM {
            self.write(c, 3, &inhibit.to_le_bytes()).await?;
            self.write(c, 5, &timer.to_le_bytes()).await?;
        }
        self.write(m, 0, &[0]).await?;
        for (k, e) in entries.iter().enumerate() {
            self.write(m, k as u8 + 1, &e.to_u32().to_le_bytes())
                .await?;
        }
        self.write(m, 0, &[entries.len() as u8]).await?;
        self.write(c, 1, &u32::from(cob).to_le_bytes()).await
    }

    fn rpdo1(&self, word: u16, target: i32) -> CanFrame {
        let mut d = [0u8; 6];
        d[..2].copy_from_slice(&word.to_le_bytes());
        d[2..].copy_from_slice(&target.to_le_bytes());
        CanFrame::std(self.node.rpdo(1), &d)
    }

    async fn controlword(&self, word: u16) -> Result<(), DriverError> {
        self.net.send(self.rpdo1(word, self.target)).await
    }

    fn statusword(&self) -> Option<u16> {
        self.net.view(self.node, |v| v.u16(obj::STATUSWORD, 0))
    }

    /// Fail if the node (or any node of the bus) lost its heartbeat, or rebooted.
    fn check_alive(&self) -> Result<(), DriverError> {
        self.net.check_open()?;
        if let Some((n, l)) = self.net.lost_nodes().into_iter().next() {
            return Err(DriverError::Alarm {
                device: self.device.clone(),
                code: u32::from(emcy::codes::HEARTBEAT_ERROR),
                message: format!(
                    "node {n} heartbeat lost (silent for {:.0} ms, timeout {:.0} ms): motion on the bus was stopped",
                    l.silent_for_s * 1000.0,
                    l.timeout_s * 1000.0
                ),
            });
        }
        if self.net.view(self.node, |v| v.boot_ups) > self.boot_ups {
            return Err(DriverError::Alarm {
                device: self.device.clone(),
                code: u32::from(emcy::codes::DEVICE_SOFTWARE),
                message: "the node rebooted (boot-up seen): its configuration is lost; reconnect"
                    .into(),
            });
        }
        Ok(())
    }

    /// The drive's fault as an error with its code (last EMCY, else 0x603F).
    async fn fault_error(&self, what: &str) -> DriverError {
        let e = self.net.view(self.node, NodeView::last_error);
        let (code, desc) = match e {
            Some(e) => (e.code, e.describe().to_string()),
            None => match self.read(obj::ERROR_CODE, 0).await {
                Ok(v) if v.len() >= 2 => {
                    let c = u16::from_le_bytes([v[0], v[1]]);
                    (c, emcy::describe(c).to_string())
                }
                _ => (0, "fault (no error code)".into()),
            },
        };
        DriverError::Alarm {
            device: self.device.clone(),
            code: u32::from(code),
            message: format!("{what}: drive fault 0x{code:04X} ({desc})"),
        }
    }

    /// Wait for a statusword (from a TPDO) that satisfies `f`.
    async fn wait_status(
        &self,
        timeout: Duration,
        what: &str,
        mut f: impl FnMut(u16, &NodeView) -> bool,
    ) -> Result<u16, DriverError> {
        let deadline = Instant::now() + timeout;
        // Any node's heartbeat loss ends the wait too (the whole stage was stopped).
        let r = self
            .net
            .wait_for_or_loss(self.node, deadline, |v| {
                let s = v.u16(obj::STATUSWORD, 0)?;
                (f(s, v) || State::from_statusword(s) == State::Fault).then_some(s)
            })
            .await?;
        self.check_alive()?;
        match r {
            Some(s) => Ok(s),
            None => Err(DriverError::Timeout {
                device: self.device.clone(),
                what: what.to_string(),
                after_ms: timeout.as_millis() as u64,
            }),
        }
    }

    /// Walk the power state machine to Operation enabled (resetting a fault if
    /// `reset_fault`).
    async fn enable(&mut self, reset_fault: bool) -> Result<(), DriverError> {
        let mut last = None;
        for _ in 0..12 {
            self.check_alive()?;
            let s = match self.statusword() {
                Some(s) => s,
                None => {
                    let v = self.read(obj::STATUSWORD, 0).await?;
                    u16::from_le_bytes([v[0], *v.get(1).unwrap_or(&0)])
                }
            };
            let state = State::from_statusword(s);
            if state == State::OperationEnabled {
                return Ok(());
            }
            if state == State::Fault && !reset_fault {
                return Err(self.fault_error("cannot enable").await);
            }
            let Some(word) = cia402::next_controlword_to_enable(state) else {
                // Not ready yet or reacting to a fault: wait for the drive.
                self.wait_status(
                    self.opts.state_timeout,
                    "the drive to leave a transient state",
                    |x, _| State::from_statusword(x) != state,
                )
                .await?;
                continue;
            };
            if word & cw::FAULT_RESET != 0 {
                // A reset needs a rising edge of bit 7.
                self.controlword(0).await?;
            }
            self.controlword(word).await?;
            last = Some(state);
            let what = format!("{} -> next state (controlword 0x{word:04X})", state.name());
            self.wait_status(self.opts.state_timeout, &what, |x, _| {
                State::from_statusword(x) != state
            })
            .await?;
        }
        Err(DriverError::InvalidState {
            device: self.device.clone(),
            message: format!(
                "could not reach OPERATION ENABLED (last state {})",
                last.map_or("unknown", State::name)
            ),
        })
    }

    /// Make sure the drive is enabled and not faulted before a command.
    async fn ready(&mut self, what: &str) -> Result<(), DriverError> {
        self.check_alive()?;
        match self.statusword().map(State::from_statusword) {
            Some(State::OperationEnabled) => Ok(()),
            Some(State::Fault) | Some(State::FaultReactionActive) => {
                Err(self.fault_error(what).await)
            }
            _ => self.enable(false).await,
        }
    }

    async fn set_mode(&self, mode: Mode) -> Result<(), DriverError> {
        self.write(obj::MODES_OF_OPERATION, 0, &[mode as u8])
            .await?;
        let deadline = Instant::now() + self.opts.state_timeout;
        let shown = self
            .net
            .wait_for(self.node, deadline, |v| {
                (v.i8(obj::MODES_DISPLAY, 0) == Some(mode as i8)).then_some(())
            })
            .await?;
        if shown.is_none() {
            // The display may not have changed in a TPDO yet: ask.
            let v = self.read(obj::MODES_DISPLAY, 0).await?;
            if v.first().copied() != Some(mode as u8) {
                return Err(DriverError::InvalidState {
                    device: self.device.clone(),
                    message: format!(
                        "mode display is {:?} after setting mode {}",
                        v.first(),
                        mode as u8
                    ),
                });
            }
        }
        Ok(())
    }

    /// Reset a fault and enable again.
    pub async fn reset_fault(&mut self) -> Result<(), DriverError> {
        self.moving_since = None;
        self.enable(true).await
    }

    fn counts(&self) -> Option<i32> {
        self.net.view(self.node, |v| v.i32(obj::POSITION_ACTUAL, 0))
    }
}

#[async_trait]
impl AxisDrive for Cia402Axis {
    fn info(&self) -> &AxisInfo {
        &self.info
    }

    fn device(&self) -> &str {
        &self.device
    }

    async fn home(&mut self) -> Result<(), DriverError> {
        // Homing is the way back after a fault: reset it first.
        self.check_alive()?;
        self.enable(true).await?;
        self.set_mode(Mode::Homing).await?;
        self.controlword(cw::ENABLE_OPERATION_CMD).await?;
        let before = self.net.view(self.node, NodeView::tpdo_total);
        self.controlword(cw::ENABLE_OPERATION_CMD | cw::HOMING_START)
            .await?;
        // Completed counts only after the drive showed the homing running (a status
        // left over from an earlier homing must not end this one).
        let s = self
            .wait_status(self.opts.homing_timeout, "homing", |_, v| {
                let mut started = false;
                for s in v.statuswords_since(before) {
                    match cia402::homing_status(s) {
                        HomingStatus::InProgress | HomingStatus::AttainedNotReached => {
                            started = true
                        }
                        HomingStatus::Completed if started => return true,
                        HomingStatus::Error => return true,
                        _ => {}
                    }
                }
                false
            })
            .await?;
        let s = self
            .net
            .view(self.node, |v| {
                v.statuswords_since(before)
                    .find(|&x| matches!(cia402::homing_status(x), HomingStatus::Error))
            })
            .unwrap_or(s);
        self.controlword(cw::ENABLE_OPERATION_CMD).await?;
        if State::from_statusword(s) == State::Fault {
            return Err(self.fault_error("homing").await);
        }
        if cia402::homing_status(s) == HomingStatus::Error {
            return Err(DriverError::Refused {
                device: self.device.clone(),
                what: format!("homing (method {})", self.cfg.homing_method),
                code: u32::from(s),
                message: "the drive reports a homing error".into(),
            });
        }
        self.set_mode(Mode::ProfilePosition).await?;
        self.target = self.counts().unwrap_or(0);
        self.homed = true;
        self.moving_since = None;
        Ok(())
    }

    async fn start_move(&mut self, position_mm: f64, speed_mm_min: f64) -> Result<(), DriverError> {
        if !(position_mm >= self.info.min_mm && position_mm <= self.info.max_mm) {
            return Err(DriverError::OutOfLimits {
                axis: self.info.axis,
                value_mm: position_mm,
                min_mm: self.info.min_mm,
                max_mm: self.info.max_mm,
            });
        }
        let target = self
            .scaling
            .to_counts(position_mm)
            .map_err(|e| DriverError::Unsupported {
                device: self.device.clone(),
                message: e.to_string(),
            })?;
        crate::stage::check_feed(&self.device, speed_mm_min)?;
        self.ready("move").await?;
        let speed = self
            .scaling
            .speed_to_counts_s(speed_mm_min.min(self.info.max_feed_mm_min));
        self.net
            .send(CanFrame::std(self.node.rpdo(2), &speed.to_le_bytes()))
            .await?;
        // The previous set-point's acknowledge must be down before a new edge counts.
        if self
            .statusword()
            .is_some_and(|s| s & sw::SET_POINT_ACK != 0)
        {
            self.controlword(cw::ENABLE_OPERATION_CMD).await?;
            self.wait_status(
                self.opts.state_timeout,
                "set-point acknowledge to drop",
                |s, _| s & sw::SET_POINT_ACK == 0,
            )
            .await?;
        }
        self.target = target;
        let before = self
            .net
            .view(self.node, |v| v.tpdo_count[0] + v.tpdo_count[1]);
        self.controlword(cw::ENABLE_OPERATION_CMD | cw::NEW_SET_POINT | cw::CHANGE_IMMEDIATELY)
            .await?;
        let mut ack_seq = 0;
        let s = self
            .wait_status(
                self.opts.state_timeout,
                "set-point acknowledge (statusword bit 12)",
                |_, v| {
                    // Every statusword is looked at, not only the latest: several may have
                    // arrived together.
                    match v
                        .statuswords
                        .iter()
                        .find(|(k, x)| *k > before && x & sw::SET_POINT_ACK != 0)
                    {
                        Some((k, _)) => {
                            ack_seq = *k;
                            true
                        }
                        None => false,
                    }
                },
            )
            .await?;
        if State::from_statusword(s) == State::Fault {
            self.controlword(cw::ENABLE_OPERATION_CMD).await?;
            return Err(self.fault_error("move").await);
        }
        self.controlword(cw::ENABLE_OPERATION_CMD).await?;
        self.moving_since = Some(ack_seq);
        Ok(())
    }

    async fn position(&mut self) -> Result<f64, DriverError> {
        self.check_alive()?;
        let c = match self.counts() {
            Some(c) => c,
            None => {
                let v = self.read(obj::POSITION_ACTUAL, 0).await?;
                i32::from_le_bytes(v.get(..4).and_then(|b| b.try_into().ok()).unwrap_or([0; 4]))
            }
        };
        Ok(self.scaling.to_mm(c))
    }

    async fn status(&mut self) -> Result<AxisStatus, DriverError> {
        self.check_alive()?;
        let s = self.statusword().unwrap_or(0);
        let state = State::from_statusword(s);
        let fault = match state {
            State::Fault | State::FaultReactionActive => {
                let e = self.fault_error("status").await;
                Some(e.to_string())
            }
            State::OperationEnabled => None,
            other => Some(format!("drive not enabled ({})", other.name())),
        };
        Ok(AxisStatus {
            moving: state == State::OperationEnabled && s & sw::TARGET_REACHED == 0,
            homed: self.homed,
            fault,
            position_mm: self.scaling.to_mm(self.counts().unwrap_or(0)),
        })
    }

    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        let Some(since) = self.moving_since else {
            self.check_alive()?;
            return Ok(());
        };
        // "Target reached" in a statusword that came after the acknowledge belongs to
        // this set-point (the drive clears it when it takes one, and only a new one
        // clears it again).
        let s = self
            .wait_status(
                self.opts.motion_timeout,
                "target reached (statusword bit 10)",
                |_, v| {
                    v.statuswords
                        .back()
                        .is_some_and(|(k, x)| *k >= since && x & sw::TARGET_REACHED != 0)
                },
            )
            .await?;
        self.moving_since = None;
        if State::from_statusword(s) == State::Fault {
            return Err(self.fault_error("move").await);
        }
        // The final position, asked for: a TPDO2 may still wait out its inhibit time,
        // or not come at all when nothing it carries changed.
        let pos = self.read(obj::POSITION_ACTUAL, 0).await?;
        self.net
            .store_value(self.node, obj::POSITION_ACTUAL, 0, pos);
        Ok(())
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        self.net.check_open()?;
        self.moving_since = None;
        self.controlword(cw::ENABLE_OPERATION_CMD | cw::HALT).await
    }
}
