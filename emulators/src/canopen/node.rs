//! One CiA 402 drive node's communication side: its object dictionary values, NMT
//! state, SDO server, PDOs, heartbeat producer, EMCY producer and the power state
//! machine. Motion is not here: the node reports what it is asked to do as
//! [`Effect`]s and the [`super::DriveSet`] that owns the shared machine carries them
//! out, because every node of a set moves the same simulated machine.

use protocol::can::CanFrame;
use protocol::canopen::emcy::{self, Emcy};
use protocol::canopen::nmt::{heartbeat_frame, NmtCommand, NmtState};
use protocol::canopen::od::{decode_int, encode_int, DataType, ObjectDictionary};
use protocol::canopen::pdo::{self, MapEntry, PdoComm, COB_INVALID};
use protocol::canopen::sdo::{AbortCode, ObjectAccess, SdoServer};
use protocol::canopen::NodeId;
use protocol::cia402::{self, obj, sw, HomingStatus, PpHandshake, State};
use std::collections::BTreeMap;
use std::sync::Arc;

/// Homing methods the emulated drive supports: it homes on the negative limit switch,
/// with (1) or without (17) the encoder index pulse. Others are refused when written.
pub const HOMING_METHODS: [i8; 2] = [1, 17];

/// Modes the drive runs: profile position and homing (0x6502 = 0x21); 0 = no mode.
const MODES: [i8; 3] = [0, 1, 6];

/// What a write or a command asks of the motion side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Effect {
    /// A controlword arrived (via SDO or RPDO); `prev` was the one before.
    Controlword { prev: u16 },
    /// The mode of operation changed.
    Mode,
}

/// Homing as the statusword shows it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Homing {
    Idle,
    /// Running; done when the set's clock passes the remaining time.
    Running {
        left_s: f64,
    },
    Attained,
    Error,
}

/// Live values the set computes from the machine before the node answers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Live {
    pub position: i32,
    pub demand: i32,
    pub following_error: i32,
    /// A motion of this axis is in progress.
    pub moving: bool,
}

#[derive(Clone, Debug, Default)]
struct TpdoRun {
    last: Option<Vec<u8>>,
    last_sent: Option<f64>,
    syncs: u32,
}

/// One drive node.
pub struct Node {
    pub id: NodeId,
    /// Machine axis (0 = X, 1 = Y).
    pub axis: usize,
    od: Arc<ObjectDictionary>,
    values: BTreeMap<(u16, u8), Vec<u8>>,
    /// Values the node powers up with (EDS defaults plus commissioning).
    commissioned: BTreeMap<(u16, u8), Vec<u8>>,
    pub nmt: NmtState,
    sdo: SdoServer,
    pub state: State,
    pub cw: u16,
    pub pp: PpHandshake,
    pub homing: Homing,
    pub homed: bool,
    pub target_reached: bool,
    pub following_error: bool,
    pub internal_limit: bool,
    pub live: Live,
    effects: Vec<Effect>,
    tpdo: [TpdoRun; 4],
    hb_next: Option<f64>,
    /// Fault injection: the node neither answers nor sends anything (power lost).
    pub silent: bool,
    pub emcys_sent: u64,
    pub sdo_requests: u64,
}

fn key_int(t: DataType, v: i64) -> Vec<u8> {
    encode_int(t, v)
}

impl Node {
    /// A node powered on with `od`'s defaults, overridden by `commissioning` (values a
    /// commissioning tool stored in the drive: software limits, feed constant...).
    pub fn new(
        id: NodeId,
        axis: usize,
        od: Arc<ObjectDictionary>,
        commissioning: &[((u16, u8), Vec<u8>)],
    ) -> Self {
        let mut values: BTreeMap<(u16, u8), Vec<u8>> = od
            .variables()
            .map(|v| ((v.index, v.sub), v.default.clone()))
            .collect();
        for (k, v) in commissioning {
            if values.contains_key(k) {
                values.insert(*k, v.clone());
            }
        }
        Self {
            id,
            axis,
            od,
            commissioned: values.clone(),
            values,
            nmt: NmtState::BootUp,
            sdo: SdoServer::new(),
            state: State::NotReadyToSwitchOn,
            cw: 0,
            pp: PpHandshake::default(),
            homing: Homing::Idle,
            homed: false,
            target_reached: true,
            following_error: false,
            internal_limit: false,
            live: Live::default(),
            effects: Vec::new(),
            tpdo: Default::default(),
            hb_next: None,
            silent: false,
            emcys_sent: 0,
            sdo_requests: 0,
        }
    }

    // -------------------------------------------------------------------- values

    pub fn int(&self, index: u16, sub: u8) -> i64 {
        let Ok(v) = self.od.variable(index, sub) else {
            return 0;
        };
        self.values
            .get(&(index, sub))
            .and_then(|b| decode_int(v.data_type, b))
            .unwrap_or(0)
    }

    fn set_int(&mut self, index: u16, sub: u8, x: i64) {
        if let Ok(v) = self.od.variable(index, sub) {
            let t = v.data_type;
            self.values.insert((index, sub), key_int(t, x));
        }
    }

    pub fn mode(&self) -> i8 {
        self.int(obj::MODES_OF_OPERATION, 0) as i8
    }

    pub fn error_code(&self) -> u16 {
        self.int(obj::ERROR_CODE, 0) as u16
    }

    pub fn statusword(&self) -> u16 {
        let mut s = self.state.statusword_bits() | sw::REMOTE;
        if self.internal_limit {
            s |= sw::INTERNAL_LIMIT;
        }
        match self.mode() {
            1 => {
                if self.target_reached {
                    s |= sw::TARGET_REACHED;
                }
                if self.pp.ack() {
                    s |= sw::SET_POINT_ACK;
                }
                if self.following_error {
                    s |= sw::FOLLOWING_ERROR;
                }
            }
            6 => match self.homing {
                Homing::Idle => s |= sw::TARGET_REACHED,
                Homing::Running { .. } => {}
                Homing::Attained => s |= sw::TARGET_REACHED | sw::HOMING_ATTAINED,
                Homing::Error => s |= sw::HOMING_ERROR | sw::TARGET_REACHED,
            },
            _ => {
                if self.target_reached {
                    s |= sw::TARGET_REACHED;
                }
            }
        }
        s
    }

    pub fn homing_status(&self) -> HomingStatus {
        cia402::homing_status(self.statusword())
    }

    fn dynamic(&self, index: u16, sub: u8) -> Option<Vec<u8>> {
        Some(match (index, sub) {
            (obj::STATUSWORD, 0) => self.statusword().to_le_bytes().to_vec(),
            (obj::MODES_DISPLAY, 0) => vec![self.mode() as u8],
            (obj::POSITION_ACTUAL, 0) => self.live.position.to_le_bytes().to_vec(),
            (obj::POSITION_DEMAND, 0) => self.live.demand.to_le_bytes().to_vec(),
            (obj::FOLLOWING_ERROR_ACTUAL, 0) => self.live.following_error.to_le_bytes().to_vec(),
            _ => return None,
        })
    }

    /// Current bytes of an entry (as a PDO or an SDO upload would carry them).
    pub fn value(&self, index: u16, sub: u8) -> Option<Vec<u8>> {
        self.dynamic(index, sub)
            .or_else(|| self.values.get(&(index, sub)).cloned())
    }

    pub fn take_effects(&mut self) -> Vec<Effect> {
        std::mem::take(&mut self.effects)
    }

    /// Store a value without any check (internal use: the set writes demands, limits).
    pub fn store(&mut self, index: u16, sub: u8, x: i64) {
        self.set_int(index, sub, x);
    }

    // ----------------------------------------------------------------------- NMT

    /// Power-on / reset node: every value back to what the drive powers up with.
    pub fn reset_node(&mut self, now: f64, out: &mut Vec<CanFrame>) {
        self.values = self.commissioned.clone();
        self.state = State::SwitchOnDisabled;
        self.cw = 0;
        self.pp.reset();
        self.homing = Homing::Idle;
        self.following_error = false;
        self.internal_limit = false;
        self.reset_communication(now, out);
    }

    /// Reset communication: communication objects (0x1000-0x1FFF) back, boot-up sent.
    pub fn reset_communication(&mut self, now: f64, out: &mut Vec<CanFrame>) {
        let keys: Vec<(u16, u8)> = self
            .commissioned
            .keys()
            .filter(|(i, _)| (0x1000..0x2000).contains(i))
            .copied()
            .collect();
        for k in keys {
            let v = self.commissioned[&k].clone();
            self.values.insert(k, v);
        }
        self.sdo = SdoServer::new();
        self.tpdo = Default::default();
        self.nmt = NmtState::PreOperational;
        if !self.silent {
            out.push(heartbeat_frame(self.id, NmtState::BootUp));
        }
        self.restart_heartbeat(now);
    }

    fn restart_heartbeat(&mut self, now: f64) {
        let ms = self.int(0x1017, 0);
        self.hb_next = (ms > 0).then(|| now + ms as f64 / 1000.0);
    }

    pub fn nmt_command(&mut self, cmd: NmtCommand, now: f64, out: &mut Vec<CanFrame>) {
        if self.silent {
            return;
        }
        match cmd {
            NmtCommand::Start => {
                if self.nmt != NmtState::Operational {
                    // Every event-driven TPDO is sent once on entering Operational.
                    self.tpdo = Default::default();
                }
                self.nmt = NmtState::Operational;
            }
            NmtCommand::Stop => self.nmt = NmtState::Stopped,
            NmtCommand::EnterPreOperational => self.nmt = NmtState::PreOperational,
            NmtCommand::ResetNode => self.reset_node(now, out),
            NmtCommand::ResetCommunication => self.reset_communication(now, out),
        }
    }

    /// Heartbeats due by `now`.
    pub fn poll_heartbeat(&mut self, now: f64, out: &mut Vec<CanFrame>) {
        let Some(t) = self.hb_next else { return };
        if now < t {
            return;
        }
        let period = self.int(0x1017, 0) as f64 / 1000.0;
        if !self.silent {
            out.push(heartbeat_frame(self.id, self.nmt));
        }
        // Keep the cadence; after a long gap, restart from now.
        let next = t + period;
        self.hb_next = Some(if next < now { now + period } else { next });
    }

    // ----------------------------------------------------------------------- EMCY

    /// Enter Fault with an error code: EMCY, error register, 0x603F.
    pub fn fault(&mut self, code: u16, out: &mut Vec<CanFrame>) {
        self.state = State::Fault;
        self.pp.reset();
        self.set_int(obj::ERROR_CODE, 0, i64::from(code));
        let register = emcy::register::GENERIC
            | if code & 0xF000 == 0x8000 {
                0
            } else {
                emcy::register::PROFILE
            };
        self.set_int(0x1001, 0, i64::from(register));
        self.emcy(Emcy::new(code, register), out);
    }

    fn emcy(&mut self, e: Emcy, out: &mut Vec<CanFrame>) {
        if !self.silent && self.nmt != NmtState::Stopped {
            out.push(e.frame(self.id));
            self.emcys_sent += 1;
        }
    }

    /// Fault reset done: clear the error and tell the bus (EMCY 0x0000).
    pub fn clear_fault(&mut self, out: &mut Vec<CanFrame>) {
        self.set_int(obj::ERROR_CODE, 0, 0);
        self.set_int(0x1001, 0, 0);
        self.following_error = false;
        self.internal_limit = false;
        self.emcy(Emcy::new(emcy::codes::NO_ERROR, 0), out);
    }

    // ----------------------------------------------------------------------- SDO

    /// An SDO request (COB-ID 0x600 + id); returns the response frame.
    pub fn sdo_request(&mut self, data: &[u8]) -> Option<CanFrame> {
        if self.silent || self.nmt == NmtState::Stopped {
            return None;
        }
        self.sdo_requests += 1;
        let mut server = std::mem::take(&mut self.sdo);
        let r = server.on_request(data, self);
        self.sdo = server;
        r.map(|d| CanFrame::std(self.id.sdo_tx(), &d))
    }

    // ----------------------------------------------------------------------- PDO

    fn comm(&self, base: u16, n: u16) -> PdoComm {
        let i = base + n;
        PdoComm {
            cob_id: self.int(i, 1) as u32,
            transmission_type: self.int(i, 2) as u8,
            inhibit_100us: self.int(i, 3) as u16,
            event_timer_ms: self.int(i, 5) as u16,
            sync_start: self.int(i, 6) as u8,
        }
    }

    fn mapping(&self, base: u16, n: u16) -> Vec<MapEntry> {
        let i = base + n;
        let count = self.int(i, 0).clamp(0, 8) as u8;
        (1..=count)
            .map(|s| MapEntry::from_u32(self.int(i, s) as u32))
            .collect()
    }

    fn tpdo_data(&self, n: u16) -> Vec<u8> {
        let map = self.mapping(pdo::TPDO_MAP, n);
        pdo::pack(&map, |e| self.value(e.index, e.sub).unwrap_or_default())
    }

    /// A frame on the bus that may be one of this node's RPDOs (or an RTR for a TPDO).
    /// Returns true if it was.
    pub fn pdo_frame(&mut self, frame: &CanFrame, now: f64, out: &mut Vec<CanFrame>) -> bool {
        if self.silent || self.nmt != NmtState::Operational {
            return false;
        }
        let Some(id) = frame.id().as_standard() else {
            return false;
        };
        if frame.is_remote() {
            for n in 0..4u16 {
                let c = self.comm(pdo::TPDO_COMM, n);
                if c.valid() && c.can_id() == id && c.cob_id & pdo::COB_NO_RTR == 0 {
                    let data = self.tpdo_data(n);
                    out.push(CanFrame::std(id, &data));
                    let run = &mut self.tpdo[usize::from(n)];
                    run.last = Some(data);
                    run.last_sent = Some(now);
                    return true;
                }
            }
            return false;
        }
        for n in 0..4u16 {
            let c = self.comm(pdo::RPDO_COMM, n);
            if !c.valid() || c.can_id() != id {
                continue;
            }
            let map = self.mapping(pdo::RPDO_MAP, n);
            match pdo::unpack(&map, frame.data()) {
                Ok(parts) => {
                    let prev = self.cw;
                    let mut cw = None;
                    for (e, bytes) in parts {
                        if (e.index, e.sub) == (obj::CONTROLWORD, 0) {
                            cw = Some(u16::from_le_bytes([bytes[0], bytes[1]]));
                            continue;
                        }
                        // An RPDO cannot be refused; invalid values are ignored.
                        let _ = self.write_checked(e.index, e.sub, bytes, true);
                    }
                    if let Some(c) = cw {
                        self.cw = c;
                        self.values
                            .insert((obj::CONTROLWORD, 0), c.to_le_bytes().to_vec());
                        self.effects.push(Effect::Controlword { prev });
                    }
                }
                Err(_) => {
                    let reg = emcy::register::COMMUNICATION | emcy::register::GENERIC;
                    self.emcy(Emcy::new(emcy::codes::PDO_LENGTH, reg), out);
                }
            }
            return true;
        }
        false
    }

    /// SYNC: synchronous TPDOs.
    pub fn sync(&mut self, now: f64, out: &mut Vec<CanFrame>) {
        if self.silent || self.nmt != NmtState::Operational {
            return;
        }
        for n in 0..4u16 {
            let c = self.comm(pdo::TPDO_COMM, n);
            if !c.valid() || !c.is_synchronous() {
                continue;
            }
            let data = self.tpdo_data(n);
            let run = &mut self.tpdo[usize::from(n)];
            run.syncs += 1;
            let due = if c.transmission_type == 0 {
                run.last.as_ref() != Some(&data)
            } else {
                run.syncs.is_multiple_of(u32::from(c.transmission_type))
            };
            if due {
                out.push(CanFrame::std(c.can_id(), &data));
                run.last = Some(data);
                run.last_sent = Some(now);
            }
        }
    }

    /// Event-driven TPDOs due now (mapped data changed, inhibit time passed; or the
    /// event timer ran out). Returns the earliest time one may become due.
    pub fn emit_tpdos(&mut self, now: f64, out: &mut Vec<CanFrame>) -> Option<f64> {
        if self.silent || self.nmt != NmtState::Operational {
            return None;
        }
        let mut next: Option<f64> = None;
        for n in 0..4u16 {
            let c = self.comm(pdo::TPDO_COMM, n);
            if !c.valid() || !c.is_event_driven() {
                continue;
            }
            let data = self.tpdo_data(n);
            let run = &mut self.tpdo[usize::from(n)];
            let changed = run.last.as_ref() != Some(&data);
            let timer = f64::from(c.event_timer_ms) / 1000.0;
            let inhibit = f64::from(c.inhibit_100us) * 1e-4;
            let timer_due = c.event_timer_ms > 0 && run.last_sent.is_none_or(|t| now >= t + timer);
            let inhibit_ok = run.last_sent.is_none_or(|t| now >= t + inhibit);
            if (changed || timer_due) && inhibit_ok {
                out.push(CanFrame::std(c.can_id(), &data));
                run.last = Some(data);
                run.last_sent = Some(now);
            } else if changed {
                let t = run.last_sent.unwrap_or(now) + inhibit;
                next = Some(next.map_or(t, |x: f64| x.min(t)));
            }
            if c.event_timer_ms > 0 {
                let t = run.last_sent.unwrap_or(now) + timer;
                next = Some(next.map_or(t, |x: f64| x.min(t)));
            }
        }
        next
    }

    pub fn heartbeat_deadline(&self) -> Option<f64> {
        self.hb_next
    }

    // ----------------------------------------------------------------- writes

    /// A write with the checks a node makes (`internal` skips the access check, for
    /// RPDO-mapped objects written by a PDO).
    fn write_checked(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        internal: bool,
    ) -> Result<(), AbortCode> {
        let v = self.od.variable(index, sub)?;
        if internal {
            if v.data_type.size().is_some_and(|n| n != data.len()) {
                return Err(AbortCode::LENGTH_MISMATCH);
            }
        } else {
            v.check_write(data)?;
        }
        let t = v.data_type;
        let x = decode_int(t, data);
        match (index, sub) {
            (obj::MODES_OF_OPERATION, 0) => {
                let m = x.unwrap_or(-1) as i8;
                if !MODES.contains(&m) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                let changed = m != self.mode();
                self.values.insert((index, sub), data.to_vec());
                if changed {
                    self.effects.push(Effect::Mode);
                }
                return Ok(());
            }
            (obj::CONTROLWORD, 0) => {
                let prev = self.cw;
                self.cw = x.unwrap_or(0) as u16;
                self.values.insert((index, sub), data.to_vec());
                self.effects.push(Effect::Controlword { prev });
                return Ok(());
            }
            (obj::HOMING_METHOD, 0) if !HOMING_METHODS.contains(&(x.unwrap_or(0) as i8)) => {
                return Err(AbortCode::INVALID_VALUE);
            }
            // The emulated drive takes the switch as zero: an offset is not applied, so
            // it is refused rather than silently ignored.
            (obj::HOME_OFFSET, 0) if x != Some(0) => return Err(AbortCode::INVALID_VALUE),
            (0x1017, 0) => {
                self.values.insert((index, sub), data.to_vec());
                // The new period counts from now; the set passes `now` on its next poll.
                self.hb_next = Some(f64::NEG_INFINITY);
                if x == Some(0) {
                    self.hb_next = None;
                }
                return Ok(());
            }
            _ => {}
        }
        if !internal {
            self.check_pdo_write(index, sub, x.unwrap_or(0))?;
        }
        self.values.insert((index, sub), data.to_vec());
        Ok(())
    }

    /// CiA 301 rules for PDO records: a valid PDO's COB-ID and type cannot change, and
    /// a mapping changes only while disabled (sub 0 = 0); enabling checks it.
    fn check_pdo_write(&self, index: u16, sub: u8, x: i64) -> Result<(), AbortCode> {
        let comm = matches!(index, 0x1400..=0x1403 | 0x1800..=0x1803);
        let map = matches!(index, 0x1600..=0x1603 | 0x1A00..=0x1A03);
        if comm && sub == 1 {
            let cur = self.int(index, 1) as u32;
            let new = x as u32;
            let valid_now = cur & COB_INVALID == 0;
            let valid_new = new & COB_INVALID == 0;
            if valid_now && valid_new && (cur & 0x7FF) != (new & 0x7FF) {
                return Err(AbortCode::INVALID_VALUE);
            }
            if new & pdo::COB_FRAME_29BIT != 0 {
                return Err(AbortCode::INVALID_VALUE);
            }
        }
        if comm && sub == 2 && !(x as u8 <= 240 || x as u8 >= 252) {
            return Err(AbortCode::INVALID_VALUE);
        }
        if map {
            let comm_index = index - 0x200;
            let pdo_valid = self.int(comm_index, 1) as u32 & COB_INVALID == 0;
            if pdo_valid {
                return Err(AbortCode::DEVICE_STATE);
            }
            if sub == 0 {
                let n = x.clamp(0, 8) as u8;
                if x > 8 {
                    return Err(AbortCode::VALUE_TOO_HIGH);
                }
                let rx = index < 0x1A00;
                let mut entries = Vec::new();
                for s in 1..=n {
                    let e = MapEntry::from_u32(self.int(index, s) as u32);
                    let v = self
                        .od
                        .variable(e.index, e.sub)
                        .map_err(|_| AbortCode::NOT_MAPPABLE)?;
                    let ok_dir = if rx {
                        v.access.writable()
                    } else {
                        v.access.readable()
                    };
                    if !v.pdo_mappable || !ok_dir || v.bits() != Some(e.bits) {
                        return Err(AbortCode::NOT_MAPPABLE);
                    }
                    entries.push(e);
                }
                pdo::check_mapping(&entries)?;
            } else if self.int(index, 0) != 0 {
                return Err(AbortCode::DEVICE_STATE);
            }
        }
        Ok(())
    }
}

impl ObjectAccess for Node {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        let v = self.od.variable(index, sub)?;
        v.check_read()?;
        Ok(self.value(index, sub).unwrap_or_else(|| v.default.clone()))
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        self.write_checked(index, sub, data, false)
    }
}
