//! Modbus positioning drives on the simulated machine, sans-IO: a request PDU and the
//! wall time go in, a response PDU comes out, and moves happen on the shared
//! [`SimMachine`](world::machine::SimMachine).
//!
//! Several unit ids (one per drive) share one machine; each unit is mapped to machine
//! axis X or Y. The registers are the ones a [`DriveProfile`] names, with the profile's
//! types and word order:
//! * a read of any address the profile does not name is answered with exception 02
//!   (illegal data address), as is a write to a register that is not writable (status,
//!   position, alarm code) or a write that splits a 32-bit register;
//! * functions other than 3, 4, 6 and 16 get exception 01 (illegal function); bad
//!   quantities, a trigger or command value the profile does not know, or a move with
//!   no speed get exception 03 (illegal data value), and nothing is written;
//! * each unit is an independent drive of its own axis: writing the move block's
//!   trigger value starts an absolute move of the unit's axis alone, on the axis's own
//!   profile (speed, and the gentler of acceleration and deceleration, from the block,
//!   bounded by the machine axis's limits), counted in [`ModbusStats`]; home, stop and
//!   alarms act on the unit's own axis, and the other axis carries on;
//! * commands act on their rising edge (profiles with `release`) or on every write of
//!   their value (trigger-register style);
//! * a move before homing or beyond the travel puts the unit in alarm with the
//!   profile's codes, until an alarm reset.
//!
//! Time: [`Clock::Scaled`] runs motion at a multiple of the wall clock;
//! [`Clock::Unconstrained`] completes motion and homing right after a read of a
//! status or position register has been answered (so the first poll after a start
//! sees the drive busy, the next sees it arrived), and tests never wait on wall time.

use protocol::modbus::frame::{Exception, Request, Response};
use protocol::modbus::profile::{DriveProfile, Register, Table};
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use world::lock;
use world::machine::MachineRefusal;
use world::{Clock, SharedRig};

/// Which machine axis a unit drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MachineAxis {
    X,
    Y,
}

impl MachineAxis {
    fn index(self) -> usize {
        match self {
            MachineAxis::X => 0,
            MachineAxis::Y => 1,
        }
    }
}

/// Counters for tests, benchmarks and the stand-alone binary.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ModbusStats {
    /// Requests addressed to a served unit (or broadcast).
    pub requests: u64,
    pub exceptions: u64,
    /// Moves started, per unit id: a duplicated or lost trigger shows here.
    pub triggers: BTreeMap<u8, u64>,
    pub homings: u64,
    pub stops: u64,
    pub alarm_resets: u64,
    /// Frames dropped by the RTU server for a bad CRC.
    pub crc_errors: u64,
    /// Replies dropped, corrupted or delayed by fault injection.
    pub faults_applied: u64,
}

impl ModbusStats {
    pub fn triggers_of(&self, unit: u8) -> u64 {
        self.triggers.get(&unit).copied().unwrap_or(0)
    }
}

#[derive(Clone, Debug)]
struct Unit {
    id: u8,
    axis: MachineAxis,
    /// Contents of the writable registers (move block and command registers).
    memory: HashMap<u16, u16>,
    alarm: Option<u32>,
    /// Moving on its own command (cleared when the machine stops).
    active: bool,
    /// Latched target, drive counts.
    target: Option<i64>,
    /// Simulated seconds of homing left (busy meanwhile).
    homing_left_s: f64,
}

/// The drives of one bus (or one TCP gateway) on one simulated machine.
pub struct DriveSet {
    rig: SharedRig,
    profile: Arc<DriveProfile>,
    clock: Clock,
    units: Vec<Unit>,
    last_wall: Option<f64>,
    stats: ModbusStats,
}

enum Action {
    Home,
    Stop,
    AlarmReset,
}

/// What a read of one register returns, for the status registers that are computed.
enum Source {
    Memory,
    Status,
    Actual,
    AlarmCode,
    Readback,
}

impl DriveSet {
    /// Drives with these unit ids (1..=247) on these axes. Panics on a duplicate or
    /// out-of-range unit id (a configuration error of the caller, checked by the CLI).
    pub fn new(
        rig: SharedRig,
        profile: Arc<DriveProfile>,
        units: &[(u8, MachineAxis)],
        clock: Clock,
    ) -> Self {
        let mut seen = Vec::new();
        for (id, _) in units {
            assert!((1..=247).contains(id), "unit id {id} is outside 1..=247");
            assert!(!seen.contains(id), "unit id {id} given twice");
            seen.push(*id);
        }
        let units = units
            .iter()
            .map(|&(id, axis)| Unit {
                id,
                axis,
                memory: HashMap::new(),
                alarm: None,
                active: false,
                target: None,
                homing_left_s: 0.0,
            })
            .collect();
        Self {
            rig,
            profile,
            clock,
            units,
            last_wall: None,
            stats: ModbusStats::default(),
        }
    }

    pub fn profile(&self) -> &DriveProfile {
        &self.profile
    }

    pub fn unit_ids(&self) -> Vec<u8> {
        self.units.iter().map(|u| u.id).collect()
    }

    pub fn serves(&self, unit: u8) -> bool {
        self.units.iter().any(|u| u.id == unit)
    }

    pub fn stats(&self) -> &ModbusStats {
        &self.stats
    }

    pub fn stats_mut(&mut self) -> &mut ModbusStats {
        &mut self.stats
    }

    /// Answer one request PDU addressed to `unit` at wall time `now` (seconds, any
    /// origin). `None`: no reply (a unit not served here, or a broadcast, which the
    /// served units execute silently).
    pub fn handle(&mut self, unit: u8, pdu: &[u8], now: f64) -> Option<Vec<u8>> {
        self.tick(now);
        if unit == 0 {
            // Broadcast: writes act on every unit, nothing is answered.
            self.stats.requests += 1;
            if let Ok(req @ (Request::WriteSingle { .. } | Request::WriteMultiple { .. })) =
                Request::parse(pdu)
            {
                for k in 0..self.units.len() {
                    let _ = self.execute(k, &req);
                }
            }
            return None;
        }
        let k = self.units.iter().position(|u| u.id == unit)?;
        self.stats.requests += 1;
        let response = match Request::parse(pdu) {
            Err((function, exception)) => Response::Exception {
                function,
                exception,
            },
            Ok(req) => match self.execute(k, &req) {
                Ok(r) => r,
                Err(exception) => Response::Exception {
                    function: req.function(),
                    exception,
                },
            },
        };
        if matches!(response, Response::Exception { .. }) {
            self.stats.exceptions += 1;
        }
        Some(response.encode())
    }

    fn tick(&mut self, now: f64) {
        let dt = self.last_wall.map_or(0.0, |t| (now - t).max(0.0));
        self.last_wall = Some(now);
        if let Clock::Scaled(k) = self.clock {
            let dt = dt * k;
            lock(&self.rig).machine_mut().advance(dt);
            for u in &mut self.units {
                u.homing_left_s = (u.homing_left_s - dt).max(0.0);
            }
        }
        let r = lock(&self.rig);
        for u in &mut self.units {
            if !r.machine().is_axis_moving(u.axis.index()) {
                u.active = false;
            }
        }
    }

    /// Unconstrained clock: run motion and homing to their end.
    fn complete(&mut self) {
        if self.clock == Clock::Unconstrained {
            lock(&self.rig).machine_mut().finish_motion();
            for u in &mut self.units {
                u.active = false;
                u.homing_left_s = 0.0;
            }
        }
    }

    fn source(&self, r: &Register) -> Source {
        let p = &self.profile;
        if *r == p.status.reg {
            Source::Status
        } else if *r == p.position {
            Source::Actual
        } else if p.alarm_code.as_ref() == Some(r) {
            Source::AlarmCode
        } else if *r == p.readback && p.readback != p.motion.position {
            Source::Readback
        } else {
            Source::Memory
        }
    }

    fn find(&self, table: Table, address: u16) -> Option<&Register> {
        self.profile
            .registers()
            .into_iter()
            .find(|r| r.contains(table, address))
    }

    fn execute(&mut self, k: usize, req: &Request) -> Result<Response, Exception> {
        match req {
            Request::ReadHolding { address, count } => {
                self.read(k, Table::Holding, *address, *count, 3)
            }
            Request::ReadInput { address, count } => {
                self.read(k, Table::Input, *address, *count, 4)
            }
            Request::WriteSingle { address, value } => {
                self.write(k, *address, &[*value])?;
                Ok(Response::WroteSingle {
                    address: *address,
                    value: *value,
                })
            }
            Request::WriteMultiple { address, values } => {
                self.write(k, *address, values)?;
                Ok(Response::WroteMultiple {
                    address: *address,
                    count: values.len() as u16,
                })
            }
            Request::Other { .. } => Err(Exception::IllegalFunction),
        }
    }

    fn read(
        &mut self,
        k: usize,
        table: Table,
        address: u16,
        count: u16,
        function: u8,
    ) -> Result<Response, Exception> {
        if address as u32 + count as u32 > 0x1_0000 {
            return Err(Exception::IllegalDataAddress);
        }
        let mut values = Vec::with_capacity(count as usize);
        let mut live = false;
        let mut a = address as u32;
        let end = address as u32 + count as u32;
        while a < end {
            let r = self
                .find(table, a as u16)
                .ok_or(Exception::IllegalDataAddress)?
                .clone();
            let source = self.source(&r);
            live |= matches!(source, Source::Status | Source::Actual);
            let words = self.register_words(k, &r, source);
            for (i, w) in words.iter().enumerate() {
                let at = r.address as u32 + i as u32;
                if at >= a && at < end {
                    values.push(*w);
                }
            }
            a = r.last() as u32 + 1;
        }
        let response = Response::Registers { function, values };
        if live {
            self.complete();
        }
        Ok(response)
    }

    fn register_words(&self, k: usize, r: &Register, source: Source) -> Vec<u16> {
        let u = &self.units[k];
        let p = &self.profile;
        let value: i64 = match source {
            Source::Memory => {
                return (0..r.words())
                    .map(|i| u.memory.get(&(r.address + i)).copied().unwrap_or(0))
                    .collect();
            }
            Source::Status => self.status_word(k) as i64,
            Source::Actual => {
                let mm = lock(&self.rig).machine().position_mm()[u.axis.index()];
                p.counts(mm)
            }
            Source::AlarmCode => u.alarm.unwrap_or(0) as i64,
            Source::Readback => u.target.unwrap_or(0),
        };
        // Values that do not fit (a position beyond an i16 register) wrap as a
        // drive's own counter would.
        let (min, max) = r.ty.range();
        let span = max - min + 1;
        let v = (value - min).rem_euclid(span) + min;
        r.encode(v).unwrap_or_else(|_| vec![0; r.words() as usize])
    }

    fn status_word(&self, k: usize) -> u32 {
        let u = &self.units[k];
        let s = &self.profile.status;
        let (homed, counts) = {
            let r = lock(&self.rig);
            (
                r.machine().is_axis_homed(u.axis.index()),
                self.profile
                    .counts(r.machine().position_mm()[u.axis.index()]),
            )
        };
        let busy = u.active || u.homing_left_s > 0.0;
        let in_pos = !busy && u.target.is_none_or(|t| (t - counts).abs() <= 1);
        let mut w = 0;
        let mut set = |m: Option<u32>, on: bool| {
            if let (Some(m), true) = (m, on) {
                w |= m;
            }
        };
        set(s.ready, u.alarm.is_none() && !busy);
        set(s.busy, busy);
        set(s.in_position, in_pos);
        set(Some(s.alarm), u.alarm.is_some());
        set(s.home_done, homed);
        w
    }

    fn write(&mut self, k: usize, address: u16, values: &[u16]) -> Result<(), Exception> {
        let p = self.profile.clone();
        let end = address as u32 + values.len() as u32;
        if end > 0x1_0000 {
            return Err(Exception::IllegalDataAddress);
        }
        // Every register touched must be writable and written whole.
        let writable = |r: &Register| {
            p.motion.position == *r
                || p.motion.trigger.reg == *r
                || p.motion.fixed.iter().any(|f| f.reg == *r)
                || [&p.motion.speed, &p.motion.accel, &p.motion.decel]
                    .into_iter()
                    .flatten()
                    .any(|s| s.reg == *r)
                || p.commands().iter().any(|c| c.reg.address == r.address)
        };
        let mut touched: Vec<Register> = Vec::new();
        let mut a = address as u32;
        while a < end {
            let r = self
                .find(Table::Holding, a as u16)
                .ok_or(Exception::IllegalDataAddress)?
                .clone();
            if !writable(&r) || (r.address as u32) < address as u32 || r.last() as u32 >= end {
                return Err(Exception::IllegalDataAddress);
            }
            a = r.last() as u32 + 1;
            touched.push(r);
        }
        let new_value = |r: &Register| {
            let at = (r.address - address) as usize;
            r.decode(&values[at..at + r.words() as usize])
        };
        let u = &self.units[k];
        let old_value = |r: &Register| {
            let w: Vec<u16> = (0..r.words())
                .map(|i| u.memory.get(&(r.address + i)).copied().unwrap_or(0))
                .collect();
            r.decode(&w)
        };
        // Check values before anything is written (an exception means "not done").
        let mut start = false;
        let mut actions: Vec<Action> = Vec::new();
        for r in &touched {
            let v = new_value(r);
            if *r == p.motion.trigger.reg {
                if v == p.motion.trigger.value {
                    start = true;
                } else if v != 0 {
                    return Err(Exception::IllegalDataValue);
                }
            }
            let cmds: Vec<_> = p
                .commands()
                .into_iter()
                .filter(|c| c.reg.address == r.address)
                .collect();
            if cmds.is_empty() {
                continue;
            }
            let edge = cmds.iter().any(|c| c.release.is_some());
            let old = old_value(r);
            if !edge && v != 0 && !cmds.iter().any(|c| c.value == v) {
                return Err(Exception::IllegalDataValue);
            }
            for c in cmds {
                let acts = if edge {
                    (v & !old) & c.value == c.value
                } else {
                    v == c.value
                };
                if acts {
                    actions.push(if std::ptr::eq(c, &p.home) {
                        Action::Home
                    } else if std::ptr::eq(c, &p.stop) {
                        Action::Stop
                    } else {
                        Action::AlarmReset
                    });
                }
            }
        }
        if start {
            // The speed the move will use: from this write or from memory.
            if let Some(s) = &p.motion.speed {
                let raw = if touched.contains(&s.reg) {
                    new_value(&s.reg)
                } else {
                    old_value(&s.reg)
                };
                if raw <= 0 {
                    return Err(Exception::IllegalDataValue);
                }
            }
        }
        let u = &mut self.units[k];
        for (i, v) in values.iter().enumerate() {
            u.memory.insert(address + i as u16, *v);
        }
        for a in actions {
            match a {
                Action::Home => self.home(k),
                Action::Stop => self.stop(k),
                Action::AlarmReset => {
                    self.units[k].alarm = None;
                    self.stats.alarm_resets += 1;
                }
            }
        }
        if start {
            self.start_move(k);
        }
        Ok(())
    }

    /// Home this unit's axis alone; the drive is busy for as long as the run back to
    /// the switch takes. Units on other axes are not touched.
    fn home(&mut self, k: usize) {
        let axis = self.units[k].axis;
        let took = lock(&self.rig).machine_mut().home_axis(axis.index());
        for u in self.units.iter_mut().filter(|u| u.axis == axis) {
            u.active = false;
            u.target = None;
        }
        self.units[k].homing_left_s = took.max(1e-6);
        self.stats.homings += 1;
    }

    /// Stop this unit's axis where it is; the other axis's move carries on.
    fn stop(&mut self, k: usize) {
        let axis = self.units[k].axis;
        lock(&self.rig).machine_mut().stop_axis(axis.index());
        for u in self.units.iter_mut().filter(|u| u.axis == axis) {
            u.active = false;
        }
        self.stats.stops += 1;
    }

    fn start_move(&mut self, k: usize) {
        let p = self.profile.clone();
        let u = &self.units[k];
        *self.stats.triggers.entry(u.id).or_insert(0) += 1;
        if u.alarm.is_some() {
            // A drive in alarm does not start.
            return;
        }
        let word = |r: &Register| -> i64 {
            let w: Vec<u16> = (0..r.words())
                .map(|i| u.memory.get(&(r.address + i)).copied().unwrap_or(0))
                .collect();
            r.decode(&w)
        };
        let target = word(&p.motion.position);
        let speed_mm_s = match &p.motion.speed {
            Some(s) => p.mechanics.from_register(s.unit, word(&s.reg) as f64),
            None => p.max_speed_mm_min / 60.0,
        };
        // The drive's own ramp (the gentler of acceleration and deceleration, as the
        // machine's axis profile is symmetric), the profile's where the block has none.
        let ramp = |r: &Option<protocol::modbus::profile::Scaled>, default: f64| {
            r.as_ref()
                .map(|s| p.mechanics.from_register(s.unit, word(&s.reg) as f64))
                .filter(|a| a.is_finite() && *a > 0.0)
                .unwrap_or(default)
        };
        let accel = ramp(&p.motion.accel, p.accel_mm_s2).min(ramp(&p.motion.decel, p.decel_mm_s2));
        let axis = u.axis;
        // This axis alone, on its own profile: the other axis carries on.
        let result = lock(&self.rig).machine_mut().start_axis_move_accel(
            axis.index(),
            p.mm(target),
            speed_mm_s * 60.0,
            accel,
        );
        for o in self.units.iter_mut().filter(|o| o.axis == axis) {
            o.active = false;
        }
        let u = &mut self.units[k];
        u.target = Some(target);
        match result {
            Ok(_) => u.active = true,
            Err(MachineRefusal::NotHomed) => u.alarm = Some(p.not_homed_code),
            Err(MachineRefusal::OutOfTravel { .. }) => u.alarm = Some(p.overtravel_code),
            Err(MachineRefusal::BadFeed(_) | MachineRefusal::BadAccel(_)) => {
                u.alarm = Some(p.overtravel_code)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::modbus::frame::Request as Req;
    use protocol::Board;
    use std::path::Path;
    use world::camera::CameraModel;
    use world::machine::MachineConfig;

    fn drives() -> DriveSet {
        let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
        let m = MachineConfig::load(&d.join("machines/c5-stage.toml")).unwrap();
        let c = CameraModel::load(&d.join("cameras/mono-1.3mp.toml")).unwrap();
        let b = Board::load(&d.join("boards/dot-grid-0.5mm.toml")).unwrap();
        let rig = world::shared_rig(m, b, c);
        let p = Arc::new(DriveProfile::load(&d.join("drives/generic.toml")).unwrap());
        DriveSet::new(
            rig,
            p,
            &[(1, MachineAxis::X), (2, MachineAxis::Y)],
            Clock::Unconstrained,
        )
    }

    #[test]
    fn exceptions_for_functions_addresses_and_values() {
        let mut d = drives();
        assert_eq!(
            d.handle(1, &[0x01, 0, 0, 0, 1], 0.0),
            Some(vec![0x81, 0x01]),
            "read coils"
        );
        let unmapped = Req::ReadHolding {
            address: 0x0500,
            count: 1,
        }
        .encode();
        assert_eq!(d.handle(1, &unmapped, 0.0), Some(vec![0x83, 0x02]));
        // Input registers are not holding registers.
        let wrong_table = Req::ReadHolding {
            address: 0x0020,
            count: 1,
        }
        .encode();
        assert_eq!(d.handle(1, &wrong_table, 0.0), Some(vec![0x83, 0x02]));
        // Half of the 32-bit target.
        let split = Req::WriteSingle {
            address: 0x0001,
            value: 5,
        }
        .encode();
        assert_eq!(d.handle(1, &split, 0.0), Some(vec![0x86, 0x02]));
        let bad_trigger = Req::WriteSingle {
            address: 0x0008,
            value: 9,
        }
        .encode();
        assert_eq!(d.handle(1, &bad_trigger, 0.0), Some(vec![0x86, 0x03]));
        // A move with speed 0 is an illegal value, and nothing is written.
        let zero_speed = Req::WriteMultiple {
            address: 0,
            values: vec![0, 100, 0, 0, 0, 1, 0, 1, 1],
        }
        .encode();
        assert_eq!(d.handle(1, &zero_speed, 0.0), Some(vec![0x90, 0x03]));
        assert_eq!(d.stats().triggers_of(1), 0);
        assert_eq!(d.stats().exceptions, 6);
        assert_eq!(
            d.handle(9, &unmapped, 0.0),
            None,
            "a unit not on the line stays silent"
        );
    }

    #[test]
    fn edge_commands_act_once_per_rising_edge_and_broadcasts_are_not_answered() {
        let mut d = drives();
        let home = Req::WriteSingle {
            address: 0x0010,
            value: 0x0001,
        }
        .encode();
        let release = Req::WriteSingle {
            address: 0x0010,
            value: 0,
        }
        .encode();
        assert_eq!(d.handle(1, &home, 0.0), Some(home.clone()), "echo");
        d.handle(1, &home, 0.0);
        assert_eq!(d.stats().homings, 1, "the bit stayed set: no second edge");
        d.handle(1, &release, 0.0);
        assert_eq!(d.handle(0, &home, 0.0), None, "broadcast");
        assert_eq!(d.stats().homings, 3, "the broadcast homed both units");
        // Status: busy (homing) on the first read, then done and homed.
        let status = Req::ReadInput {
            address: 0x0020,
            count: 1,
        }
        .encode();
        assert_eq!(
            d.handle(1, &status, 0.0),
            Some(vec![4, 2, 0, 0x12]),
            "busy + home done"
        );
        assert_eq!(
            d.handle(1, &status, 0.0),
            Some(vec![4, 2, 0, 0x15]),
            "ready + in position + home done"
        );
    }

    fn drives_on(clock: Clock) -> DriveSet {
        let mut d = drives();
        d.clock = clock;
        d
    }

    fn command(d: &mut DriveSet, unit: u8, bit: u16, now: f64) {
        for value in [bit, 0] {
            let w = Req::WriteSingle {
                address: 0x0010,
                value,
            }
            .encode();
            assert_eq!(d.handle(unit, &w, now), Some(w.clone()));
        }
    }

    /// The move block (target counts, speed counts/s, accel = decel counts/s²) and the
    /// trigger in one write.
    fn move_to(d: &mut DriveSet, unit: u8, counts: i32, speed: u32, now: f64) {
        let hi_lo = |v: u32| [(v >> 16) as u16, v as u16];
        let mut values = Vec::new();
        values.extend(hi_lo(counts as u32));
        values.extend(hi_lo(speed));
        values.extend(hi_lo(1_600_000));
        values.extend(hi_lo(1_600_000));
        values.push(1);
        let w = Req::WriteMultiple { address: 0, values }.encode();
        assert_eq!(d.handle(unit, &w, now).unwrap()[0], 0x10, "move of {unit}");
    }

    /// Status word, position (counts) and alarm code of a unit.
    fn status(d: &mut DriveSet, unit: u8, now: f64) -> (u16, i32, u16) {
        let r = Req::ReadInput {
            address: 0x0020,
            count: 4,
        }
        .encode();
        let b = d.handle(unit, &r, now).unwrap();
        assert_eq!(&b[..2], &[4, 8]);
        let w = |i: usize| u16::from_be_bytes([b[2 + 2 * i], b[3 + 2 * i]]);
        (
            w(0),
            ((u32::from(w(1)) << 16) | u32::from(w(2))) as i32,
            w(3),
        )
    }

    const HOME: u16 = 0x0001;
    const STOP: u16 = 0x0002;
    const ALARM_RESET: u16 = 0x0004;
    const HOME_DONE: u16 = 0x0010;
    const BUSY: u16 = 0x0002;
    const ALARM: u16 = 0x0008;

    #[test]
    fn homing_one_unit_leaves_the_other_not_homed() {
        let mut d = drives();
        command(&mut d, 1, HOME, 0.0);
        assert_ne!(status(&mut d, 1, 0.0).0 & HOME_DONE, 0);
        assert_ne!(status(&mut d, 1, 0.0).0 & HOME_DONE, 0);
        assert_eq!(
            status(&mut d, 2, 0.0).0 & HOME_DONE,
            0,
            "unit 2 never homed"
        );
        // Its move is refused as a drive that is not homed refuses it.
        move_to(&mut d, 2, 10_000, 20_000, 0.0);
        let (sw, pos, code) = status(&mut d, 2, 0.0);
        assert_ne!(sw & ALARM, 0);
        assert_eq!((pos, code), (0, 0x0102));
        command(&mut d, 2, HOME, 0.0);
        assert_ne!(status(&mut d, 2, 0.0).0 & HOME_DONE, 0);
    }

    #[test]
    fn a_stop_to_one_unit_leaves_the_others_move_running_to_its_target() {
        let mut d = drives_on(Clock::Scaled(1.0));
        command(&mut d, 1, HOME, 0.0);
        command(&mut d, 2, HOME, 0.0);
        let t = 10.0; // both homings over
        move_to(&mut d, 1, 200_000, 20_000, t);
        move_to(&mut d, 2, 200_000, 20_000, t);
        command(&mut d, 1, STOP, t + 2.0);
        let (sw1, x, _) = status(&mut d, 1, t + 2.0);
        assert_eq!(sw1 & BUSY, 0, "unit 1 stopped");
        assert!(x > 20_000 && x < 200_000, "{x}");
        let (sw2, y, _) = status(&mut d, 2, t + 2.0);
        assert_ne!(sw2 & BUSY, 0, "unit 2 still moving: {sw2:#06x} at {y}");
        let (sw2, y, _) = status(&mut d, 2, t + 30.0);
        assert_eq!((sw2 & BUSY, y), (0, 200_000), "unit 2 arrived");
        assert_eq!(status(&mut d, 1, t + 30.0).1, x, "unit 1 stayed");
    }

    #[test]
    fn each_unit_moves_at_its_own_speed() {
        let mut d = drives_on(Clock::Scaled(1.0));
        command(&mut d, 1, HOME, 0.0);
        command(&mut d, 2, HOME, 0.0);
        let t = 10.0;
        // Unit 2 at 10 mm/s, then unit 1 at 1 mm/s: unit 2 keeps its own speed.
        move_to(&mut d, 2, 200_000, 20_000, t);
        move_to(&mut d, 1, 200_000, 2_000, t);
        let (_, y, _) = status(&mut d, 2, t + 2.0);
        let (_, x, _) = status(&mut d, 1, t + 2.0);
        assert!((39_000..=40_000).contains(&y), "unit 2 at 10 mm/s: {y}");
        assert!((3_900..=4_000).contains(&x), "unit 1 at 1 mm/s: {x}");
    }

    #[test]
    fn an_alarm_on_one_unit_leaves_the_other_moving() {
        let mut d = drives_on(Clock::Scaled(1.0));
        command(&mut d, 2, HOME, 0.0);
        let t = 10.0;
        move_to(&mut d, 2, 100_000, 20_000, t);
        // Unit 1 was never homed: its move puts it in alarm.
        move_to(&mut d, 1, 10_000, 20_000, t + 1.0);
        let (sw1, _, code) = status(&mut d, 1, t + 1.0);
        assert_ne!(sw1 & ALARM, 0);
        assert_eq!(code, 0x0102);
        // A move beyond the travel: overtravel, and still unit 2 goes on.
        command(&mut d, 1, ALARM_RESET, t + 1.0);
        command(&mut d, 1, HOME, t + 1.0);
        move_to(&mut d, 1, 500_000, 20_000, t + 2.5);
        assert_eq!(status(&mut d, 1, t + 2.5).2, 0x0101);
        assert_ne!(
            status(&mut d, 2, t + 2.5).0 & BUSY,
            0,
            "unit 2 still moving"
        );
        let (sw2, y, _) = status(&mut d, 2, t + 20.0);
        assert_eq!((sw2 & (BUSY | ALARM), y), (0, 100_000));
    }
}
