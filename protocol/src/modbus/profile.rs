//! Drive profiles: which registers of a Modbus positioning drive mean what, as data
//! (`config/drives/*.toml`), so a new vendor is a new file rather than new code.
//!
//! A profile names the registers for the target position, speed, acceleration,
//! deceleration and start trigger (all written in ONE write-multiple request, the
//! *move block*, so that a drive can never start on half-written data), the commands
//! for homing, stop and alarm reset, the status bits (ready, busy or in-position,
//! alarm, home done), the actual position and the alarm code, with their data types,
//! the word order of 32-bit values and the mechanics that turn counts into mm.
//!
//! Validation rejects, naming the file, line and key: a missing required register, an
//! unknown word order or data type, registers that overlap, a move block with unnamed
//! registers in it, values that do not fit their registers, units used for the wrong
//! quantity.

use super::value::{self, DataType, Mechanics, OutOfRange, Quantity, Unit, WordOrder};
use crate::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::fmt;
use std::path::Path;

/// The two register tables positioning drives use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Table {
    /// Read with function 3, written with 6 or 16.
    #[default]
    Holding,
    /// Read-only, read with function 4.
    Input,
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Table::Holding => "holding",
            Table::Input => "input",
        })
    }
}

// ------------------------------------------------------------------ raw file format

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProfile {
    drive: RawDrive,
    #[serde(rename = "move")]
    motion: RawMove,
    position: RawRegister,
    status: RawStatus,
    commands: RawCommands,
    readback: Option<RawReadback>,
    alarm: Option<RawAlarm>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDrive {
    name: String,
    #[serde(default)]
    word_order: WordOrder,
    counts_per_rev: f64,
    mm_per_rev: f64,
    max_speed_mm_min: f64,
    accel_mm_s2: f64,
    decel_mm_s2: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRegister {
    address: u16,
    #[serde(rename = "type")]
    ty: DataType,
    #[serde(default)]
    table: Table,
    word_order: Option<WordOrder>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScaled {
    address: u16,
    #[serde(rename = "type")]
    ty: DataType,
    unit: Unit,
    word_order: Option<WordOrder>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawValued {
    address: u16,
    #[serde(rename = "type", default = "u16_type")]
    ty: DataType,
    value: i64,
    word_order: Option<WordOrder>,
    /// What the value means (for messages), e.g. "operation type: absolute".
    #[serde(default)]
    name: String,
}

fn u16_type() -> DataType {
    DataType::U16
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMove {
    position: RawRegister,
    speed: Option<RawScaled>,
    accel: Option<RawScaled>,
    decel: Option<RawScaled>,
    trigger: RawValued,
    #[serde(default)]
    fixed: Vec<RawValued>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawReadback {
    target: RawRegister,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStatusRegister {
    address: u16,
    #[serde(rename = "type", default = "u16_type")]
    ty: DataType,
    #[serde(default)]
    table: Table,
    word_order: Option<WordOrder>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStatus {
    register: RawStatusRegister,
    ready: Option<u32>,
    busy: Option<u32>,
    in_position: Option<u32>,
    alarm: u32,
    home_done: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCommand {
    address: u16,
    #[serde(rename = "type", default = "u16_type")]
    ty: DataType,
    value: i64,
    release: Option<i64>,
    word_order: Option<WordOrder>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCommands {
    home: RawCommand,
    stop: RawCommand,
    alarm_reset: Option<RawCommand>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAlarm {
    code: Option<RawRegister>,
    #[serde(default)]
    text: Vec<RawAlarmText>,
    overtravel: Option<u32>,
    not_homed: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAlarmText {
    code: u32,
    message: String,
}

// ------------------------------------------------------------------ checked profile

/// One named register (or register pair) of a profile.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Register {
    /// Its key in the profile file (`move.position`), used in every message about it.
    pub key: String,
    pub table: Table,
    pub address: u16,
    pub ty: DataType,
    pub order: WordOrder,
}

impl Register {
    pub fn words(&self) -> u16 {
        self.ty.words()
    }

    /// Address of its last word.
    pub fn last(&self) -> u16 {
        self.address + (self.words() - 1)
    }

    pub fn contains(&self, table: Table, address: u16) -> bool {
        self.table == table && address >= self.address && address <= self.last()
    }

    fn overlaps(&self, o: &Register) -> bool {
        self.table == o.table && self.address <= o.last() && o.address <= self.last()
    }

    pub fn encode(&self, v: i64) -> Result<Vec<u16>, OutOfRange> {
        value::encode(v, self.ty, self.order)
    }

    /// Decode from exactly `self.words()` registers.
    pub fn decode(&self, words: &[u16]) -> i64 {
        value::decode(words, self.ty, self.order)
    }
}

impl fmt::Display for Register {
    /// `` `move.position` (holding 0x005C-0x005D, i32) ``: what error messages name.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.words() == 1 {
            write!(
                f,
                "`{}` ({} 0x{:04X}, {})",
                self.key, self.table, self.address, self.ty
            )
        } else {
            write!(
                f,
                "`{}` ({} 0x{:04X}-0x{:04X}, {})",
                self.key,
                self.table,
                self.address,
                self.last(),
                self.ty
            )
        }
    }
}

/// A register holding a physical quantity in a unit.
#[derive(Clone, Debug, PartialEq)]
pub struct Scaled {
    pub reg: Register,
    pub unit: Unit,
}

/// A register written with a constant value.
#[derive(Clone, Debug, PartialEq)]
pub struct Fixed {
    pub reg: Register,
    pub value: i64,
    pub name: String,
}

/// The registers written by one write-multiple request that sets up and starts a move.
#[derive(Clone, Debug, PartialEq)]
pub struct MoveBlock {
    /// First register of the block and number of registers.
    pub address: u16,
    pub len: u16,
    pub position: Register,
    pub speed: Option<Scaled>,
    pub accel: Option<Scaled>,
    pub decel: Option<Scaled>,
    pub trigger: Fixed,
    pub fixed: Vec<Fixed>,
}

/// A command: write `value` to `reg`; with `release`, write `release` right after (an
/// edge-triggered input bit, as Oriental Motor's remote inputs are). Without, every
/// write of `value` acts (a trigger register).
#[derive(Clone, Debug, PartialEq)]
pub struct Command {
    pub reg: Register,
    pub value: i64,
    pub release: Option<i64>,
}

/// Where the status bits are.
#[derive(Clone, Debug, PartialEq)]
pub struct StatusMap {
    pub reg: Register,
    pub ready: Option<u32>,
    pub busy: Option<u32>,
    pub in_position: Option<u32>,
    pub alarm: u32,
    pub home_done: Option<u32>,
}

/// A decoded status word.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriveStatus {
    pub raw: u32,
    pub ready: Option<bool>,
    /// Motion (or homing) in progress: the busy bit, or no in-position bit.
    pub busy: bool,
    pub in_position: Option<bool>,
    pub alarm: bool,
    pub home_done: Option<bool>,
}

/// A value that cannot be written: names the register.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{register}: {message}")]
pub struct ValueError {
    pub register: String,
    pub message: String,
}

/// A checked drive profile.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveProfile {
    pub name: String,
    /// The file it came from (for messages).
    pub file: String,
    pub mechanics: Mechanics,
    pub max_speed_mm_min: f64,
    pub accel_mm_s2: f64,
    pub decel_mm_s2: f64,
    pub motion: MoveBlock,
    /// The drive's latched target (the move block's position register unless the
    /// profile names another): read back to learn whether a move whose reply was lost
    /// was received.
    pub readback: Register,
    /// Actual (feedback) position.
    pub position: Register,
    pub status: StatusMap,
    pub alarm_code: Option<Register>,
    pub alarm_texts: Vec<(u32, String)>,
    pub home: Command,
    pub stop: Command,
    pub alarm_reset: Option<Command>,
    /// Alarm codes the emulator raises for a move beyond its travel and a move before
    /// homing (the drive's own codes where the profile knows them).
    pub overtravel_code: u32,
    pub not_homed_code: u32,
}

impl DriveProfile {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::from_doc(&ConfigDoc::read(path)?)
    }

    pub fn from_doc(doc: &ConfigDoc) -> Result<Self, ConfigError> {
        let raw: RawProfile = doc.parse()?;
        let d = &raw.drive;
        for (k, v) in [
            ("counts_per_rev", d.counts_per_rev),
            ("mm_per_rev", d.mm_per_rev),
            ("max_speed_mm_min", d.max_speed_mm_min),
            ("accel_mm_s2", d.accel_mm_s2),
            ("decel_mm_s2", d.decel_mm_s2.unwrap_or(d.accel_mm_s2)),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(doc.invalid(&format!("drive.{k}"), "must be a positive number"));
            }
        }
        let order = d.word_order;
        let reg = |key: &str, r: &RawRegister| Register {
            key: key.to_string(),
            table: r.table,
            address: r.address,
            ty: r.ty,
            order: r.word_order.unwrap_or(order),
        };
        let holding = |key: &str, address: u16, ty: DataType, wo: Option<WordOrder>| Register {
            key: key.to_string(),
            table: Table::Holding,
            address,
            ty,
            order: wo.unwrap_or(order),
        };
        let fits = |r: &Register, v: i64, what: &str| -> Result<(), ConfigError> {
            r.encode(v)
                .map(|_| ())
                .map_err(|e| doc.invalid(&r.key, format!("{what}: {e}")))
        };

        // Move block.
        let m = &raw.motion;
        if m.position.table != Table::Holding {
            return Err(doc.invalid(
                "move.position",
                "the move block is written: it must be holding registers",
            ));
        }
        let position = reg("move.position", &m.position);
        let scaled = |key: &str,
                      s: &Option<RawScaled>,
                      q: Quantity|
         -> Result<Option<Scaled>, ConfigError> {
            let Some(s) = s else { return Ok(None) };
            if s.unit.quantity() != q {
                let want = match q {
                    Quantity::Position => "counts",
                    Quantity::Speed => "counts/s or rpm",
                    Quantity::Acceleration => "counts/s2 or ms/1000rpm",
                };
                return Err(doc.invalid(
                    &format!("{key}.unit"),
                    format!(
                        "`{}` is not a unit of this quantity: use {want}",
                        s.unit.name()
                    ),
                ));
            }
            Ok(Some(Scaled {
                reg: holding(key, s.address, s.ty, s.word_order),
                unit: s.unit,
            }))
        };
        let speed = scaled("move.speed", &m.speed, Quantity::Speed)?;
        let accel = scaled("move.accel", &m.accel, Quantity::Acceleration)?;
        let decel = scaled("move.decel", &m.decel, Quantity::Acceleration)?;
        let valued = |key: &str, v: &RawValued| -> Result<Fixed, ConfigError> {
            let f = Fixed {
                reg: holding(key, v.address, v.ty, v.word_order),
                value: v.value,
                name: v.name.clone(),
            };
            fits(&f.reg, f.value, "value")?;
            Ok(f)
        };
        let trigger = valued("move.trigger", &m.trigger)?;
        if trigger.value == 0 {
            return Err(doc.invalid(
                "move.trigger.value",
                "a start trigger of 0 cannot be told from no trigger",
            ));
        }
        let fixed = m
            .fixed
            .iter()
            .enumerate()
            .map(|(i, v)| valued(&format!("move.fixed[{i}]"), v))
            .collect::<Result<Vec<_>, _>>()?;
        let mut block: Vec<&Register> = vec![&position, &trigger.reg];
        block.extend(
            [&speed, &accel, &decel]
                .into_iter()
                .flatten()
                .map(|s| &s.reg),
        );
        block.extend(fixed.iter().map(|f| &f.reg));

        let readback = match &raw.readback {
            Some(r) => reg("readback.target", &r.target),
            None => position.clone(),
        };
        let actual = reg("position", &raw.position);
        let s = &raw.status;
        let status_reg = Register {
            key: "status.register".into(),
            table: s.register.table,
            address: s.register.address,
            ty: s.register.ty,
            order: s.register.word_order.unwrap_or(order),
        };
        let alarm = raw.alarm.as_ref();
        let alarm_code = alarm
            .and_then(|a| a.code.as_ref())
            .map(|r| reg("alarm.code", r));

        // No two data registers may share an address.
        let mut data: Vec<&Register> = block.clone();
        if raw.readback.is_some() {
            data.push(&readback);
        }
        data.push(&actual);
        data.push(&status_reg);
        data.extend(alarm_code.as_ref());
        for r in &data {
            check_end(doc, r)?;
        }
        check_overlaps(doc, &data)?;

        // The block must be contiguous: every register in it named.
        let mut sorted = block.clone();
        sorted.sort_by_key(|r| r.address);
        let start = sorted[0].address;
        let mut next = start as u32;
        for r in &sorted {
            if r.address as u32 > next {
                return Err(doc.invalid(
                    "move",
                    format!(
                        "registers 0x{:04X}-0x{:04X} inside the move block are not named: the block is \
                         written in one request, so list them in `move.fixed` with their values",
                        next,
                        r.address - 1
                    ),
                ));
            }
            next = r.last() as u32 + 1;
        }
        let len = (next - start as u32) as u16;
        if len > super::frame::MAX_WRITE {
            return Err(doc.invalid(
                "move",
                format!("the move block spans {len} registers; one write carries at most 123"),
            ));
        }

        // Status bits.
        let bits_max = if status_reg.ty.words() == 1 {
            0xFFFF
        } else {
            u32::MAX
        };
        if matches!(status_reg.ty, DataType::I16 | DataType::I32) {
            return Err(doc.invalid("status.register.type", "a status word is u16 or u32"));
        }
        for (k, v) in [
            ("ready", s.ready),
            ("busy", s.busy),
            ("in_position", s.in_position),
            ("alarm", Some(s.alarm)),
            ("home_done", s.home_done),
        ] {
            if let Some(v) = v {
                if v == 0 || v > bits_max {
                    return Err(doc.invalid(
                        &format!("status.{k}"),
                        format!(
                            "a bit mask must be non-zero and fit the {} status register",
                            status_reg.ty
                        ),
                    ));
                }
            }
        }
        // Each condition has its own bits: with shared bits, one flag would read as
        // another (a drive "busy" whenever it is in position never ends a move).
        let masks: Vec<(&str, u32)> = [
            ("ready", s.ready),
            ("busy", s.busy),
            ("in_position", s.in_position),
            ("alarm", Some(s.alarm)),
            ("home_done", s.home_done),
        ]
        .into_iter()
        .filter_map(|(k, v)| Some((k, v?)))
        .collect();
        for (i, (k, v)) in masks.iter().enumerate() {
            if let Some((ok, ov)) = masks[..i].iter().find(|(_, ov)| ov & v != 0) {
                return Err(doc.invalid(
                    &format!("status.{k}"),
                    format!(
                        "bit mask 0x{v:04X} shares bits 0x{:04X} with `status.{ok}` (0x{ov:04X}): \
                         each status condition needs its own bits",
                        v & ov
                    ),
                ));
            }
        }
        if s.busy.is_none() && s.in_position.is_none() {
            return Err(doc.invalid(
                "status",
                "needs `busy` or `in_position` to know when motion ends",
            ));
        }

        // Commands: may share a command register among themselves, never a data one.
        let command = |key: &str, c: &RawCommand| -> Result<Command, ConfigError> {
            let reg = holding(key, c.address, c.ty, c.word_order);
            check_end(doc, &reg)?;
            fits(&reg, c.value, "value")?;
            if let Some(r) = c.release {
                fits(&reg, r, "release")?;
                if r == c.value {
                    return Err(doc.invalid(
                        &format!("{key}.release"),
                        "must differ from `value` (it ends the pulse)",
                    ));
                }
            }
            Ok(Command {
                reg,
                value: c.value,
                release: c.release,
            })
        };
        let home = command("commands.home", &raw.commands.home)?;
        let stop = command("commands.stop", &raw.commands.stop)?;
        let alarm_reset = raw
            .commands
            .alarm_reset
            .as_ref()
            .map(|c| command("commands.alarm_reset", c))
            .transpose()?;
        let commands: Vec<&Command> = [Some(&home), Some(&stop), alarm_reset.as_ref()]
            .into_iter()
            .flatten()
            .collect();
        for (i, c) in commands.iter().enumerate() {
            if let Some(d) = data.iter().find(|d| d.overlaps(&c.reg)) {
                return Err(doc.invalid(&c.reg.key, format!("{} overlaps {d}", c.reg)));
            }
            for o in &commands[..i] {
                if o.reg.overlaps(&c.reg)
                    && (o.reg.address != c.reg.address
                        || o.reg.ty != c.reg.ty
                        || o.release.is_some() != c.release.is_some())
                {
                    return Err(doc.invalid(
                        &c.reg.key,
                        format!(
                            "{} shares registers with {}: commands may share a command register only \
                             with the same address, type and release style",
                            c.reg, o.reg
                        ),
                    ));
                }
                if o.reg.address == c.reg.address && o.value == c.value {
                    return Err(doc.invalid(
                        &c.reg.key,
                        format!("same register and value as `{}`", o.reg.key),
                    ));
                }
            }
        }

        Ok(DriveProfile {
            name: d.name.clone(),
            file: doc.name.clone(),
            mechanics: Mechanics {
                counts_per_rev: d.counts_per_rev,
                mm_per_rev: d.mm_per_rev,
            },
            max_speed_mm_min: d.max_speed_mm_min,
            accel_mm_s2: d.accel_mm_s2,
            decel_mm_s2: d.decel_mm_s2.unwrap_or(d.accel_mm_s2),
            motion: MoveBlock {
                address: start,
                len,
                position,
                speed,
                accel,
                decel,
                trigger,
                fixed,
            },
            readback,
            position: actual,
            status: StatusMap {
                reg: status_reg,
                ready: s.ready,
                busy: s.busy,
                in_position: s.in_position,
                alarm: s.alarm,
                home_done: s.home_done,
            },
            alarm_code,
            alarm_texts: alarm
                .map(|a| a.text.iter().map(|t| (t.code, t.message.clone())).collect())
                .unwrap_or_default(),
            home,
            stop,
            alarm_reset,
            overtravel_code: alarm.and_then(|a| a.overtravel).unwrap_or(0xFFF1),
            not_homed_code: alarm.and_then(|a| a.not_homed).unwrap_or(0xFFF2),
        })
    }

    /// Counts per mm of position registers.
    pub fn counts_per_mm(&self) -> f64 {
        self.mechanics.counts_per_mm()
    }

    /// A position in mm as the drive's counts (rounded to the nearest count).
    pub fn counts(&self, mm: f64) -> i64 {
        (mm * self.counts_per_mm()).round() as i64
    }

    pub fn mm(&self, counts: i64) -> f64 {
        counts as f64 / self.counts_per_mm()
    }

    /// The registers of the move block (from `motion.address`) for an absolute move.
    pub fn move_words(&self, position_mm: f64, speed_mm_s: f64) -> Result<Vec<u16>, ValueError> {
        let m = &self.motion;
        let mut words = vec![0u16; m.len as usize];
        let mut put = |r: &Register, v: i64| -> Result<(), ValueError> {
            let w = r.encode(v).map_err(|e| ValueError {
                register: r.to_string(),
                message: e.to_string(),
            })?;
            let at = (r.address - m.address) as usize;
            words[at..at + w.len()].copy_from_slice(&w);
            Ok(())
        };
        if !position_mm.is_finite() {
            return Err(ValueError {
                register: m.position.to_string(),
                message: format!("position {position_mm} mm"),
            });
        }
        put(&m.position, self.counts(position_mm))?;
        let physical = |s: &Scaled, v: f64| -> Result<i64, ValueError> {
            let raw = self.mechanics.to_register(s.unit, v).round();
            if !(raw.is_finite()) || raw < 1.0 {
                return Err(ValueError {
                    register: s.reg.to_string(),
                    message: format!("{v} gives {raw} {}: must be at least 1", s.unit.name()),
                });
            }
            Ok(raw as i64)
        };
        if let Some(s) = &m.speed {
            put(&s.reg, physical(s, speed_mm_s)?)?;
        }
        if let Some(s) = &m.accel {
            put(&s.reg, physical(s, self.accel_mm_s2)?)?;
        }
        if let Some(s) = &m.decel {
            put(&s.reg, physical(s, self.decel_mm_s2)?)?;
        }
        for f in &m.fixed {
            put(&f.reg, f.value)?;
        }
        put(&m.trigger.reg, m.trigger.value)?;
        Ok(words)
    }

    pub fn decode_status(&self, raw: u32) -> DriveStatus {
        let s = &self.status;
        let bit = |m: Option<u32>| m.map(|m| raw & m != 0);
        let in_position = bit(s.in_position);
        let busy = match (bit(s.busy), in_position) {
            (Some(b), _) => b,
            (None, Some(ip)) => !ip,
            (None, None) => false,
        };
        DriveStatus {
            raw,
            ready: bit(s.ready),
            busy,
            in_position,
            alarm: raw & s.alarm != 0,
            home_done: bit(s.home_done),
        }
    }

    /// The profile's words for an alarm code, if it has them.
    pub fn alarm_text(&self, code: u32) -> Option<&str> {
        self.alarm_texts
            .iter()
            .find(|(c, _)| *c == code)
            .map(|(_, t)| t.as_str())
    }

    /// When status, actual position and alarm code are adjacent registers of one
    /// table, the span that reads them all in one request: (table, first, count).
    pub fn poll_span(&self) -> Option<(Table, u16, u16)> {
        let mut regs: Vec<&Register> = vec![&self.status.reg, &self.position];
        regs.extend(self.alarm_code.as_ref());
        if regs.iter().any(|r| r.table != regs[0].table) {
            return None;
        }
        regs.sort_by_key(|r| r.address);
        for w in regs.windows(2) {
            if w[0].last() as u32 + 1 != w[1].address as u32 {
                return None;
            }
        }
        let first = regs[0].address;
        Some((
            regs[0].table,
            first,
            regs[regs.len() - 1].last() - first + 1,
        ))
    }

    /// Every register of the profile a drive would answer a read of (data and command
    /// registers), for the emulator's address checks.
    pub fn registers(&self) -> Vec<&Register> {
        let m = &self.motion;
        let mut v: Vec<&Register> = vec![&m.position, &m.trigger.reg];
        v.extend(
            [&m.speed, &m.accel, &m.decel]
                .into_iter()
                .flatten()
                .map(|s| &s.reg),
        );
        v.extend(m.fixed.iter().map(|f| &f.reg));
        if self.readback != m.position {
            v.push(&self.readback);
        }
        v.push(&self.position);
        v.push(&self.status.reg);
        v.extend(self.alarm_code.as_ref());
        for c in self.commands() {
            if !v
                .iter()
                .any(|r| r.table == c.reg.table && r.address == c.reg.address)
            {
                v.push(&c.reg);
            }
        }
        v
    }

    pub fn commands(&self) -> Vec<&Command> {
        [
            Some(&self.home),
            Some(&self.stop),
            self.alarm_reset.as_ref(),
        ]
        .into_iter()
        .flatten()
        .collect()
    }
}

/// A register's words must all have addresses: a 32-bit register at 0xFFFF would need
/// 0x10000.
fn check_end(doc: &ConfigDoc, r: &Register) -> Result<(), ConfigError> {
    let last = r.address as u32 + r.words() as u32 - 1;
    if last > 0xFFFF {
        return Err(doc.invalid(
            &r.key,
            format!(
                "a {} register at 0x{:04X} needs addresses up to 0x{last:04X}, past the last \
                 Modbus address 0xFFFF",
                r.ty, r.address
            ),
        ));
    }
    Ok(())
}

fn check_overlaps(doc: &ConfigDoc, regs: &[&Register]) -> Result<(), ConfigError> {
    for (i, r) in regs.iter().enumerate() {
        if let Some(o) = regs[..i].iter().find(|o| o.overlaps(r)) {
            return Err(doc.invalid(&r.key, format!("{r} overlaps {o}")));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(text: &str) -> ConfigDoc {
        ConfigDoc::from_text("drive.toml", text, Path::new("."))
    }

    const GENERIC: &str = include_str!("../../../config/drives/generic.toml");
    const AZ: &str = include_str!("../../../config/drives/oriental-az.toml");
    const PR0: &str = include_str!("../../../config/drives/leadshine-pr0.toml");

    #[test]
    fn shipped_profiles_load() {
        for (name, text) in [("generic", GENERIC), ("az", AZ), ("pr0", PR0)] {
            let p = DriveProfile::from_doc(&doc(text)).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(p.motion.len >= 5, "{name}");
        }
    }

    #[test]
    fn leadshine_move_block_is_the_manual_example() {
        let p = DriveProfile::from_doc(&doc(PR0)).unwrap();
        // 100000 pulses at 10000 pulses/rev on 5 mm/rev = 50 mm; 500 rpm = 41.667 mm/s.
        let w = p.move_words(50.0, 500.0 * 5.0 / 60.0).unwrap();
        assert_eq!(p.motion.address, 0x6200);
        assert_eq!(
            w,
            vec![0x0001, 0x0001, 0x86A0, 0x01F4, 0x0064, 0x0064, 0x0000, 0x0010]
        );
    }

    #[test]
    fn oriental_block_is_sixteen_registers_upper_word_first() {
        let p = DriveProfile::from_doc(&doc(AZ)).unwrap();
        assert_eq!((p.motion.address, p.motion.len), (0x0058, 16));
        let w = p.move_words(-1.0 / p.counts_per_mm(), 10.0).unwrap();
        assert_eq!(&w[4..6], &[0xFFFF, 0xFFFF], "position -1 step at 0x005C");
        assert_eq!(&w[2..4], &[0, 1], "operation type 1 = absolute at 0x005A");
        assert_eq!(&w[14..16], &[0, 1], "trigger 1 at 0x0066");
    }

    #[test]
    fn generic_status_position_and_alarm_are_read_in_one_request() {
        let p = DriveProfile::from_doc(&doc(GENERIC)).unwrap();
        let (t, first, n) = p.poll_span().unwrap();
        assert_eq!((t, first, n), (Table::Input, p.status.reg.address, 4));
        let st = p.decode_status(p.status.busy.unwrap() | p.status.home_done.unwrap());
        assert!(st.busy && !st.alarm && st.home_done == Some(true));
    }

    fn err(text: &str) -> String {
        DriveProfile::from_doc(&doc(text)).unwrap_err().to_string()
    }

    #[test]
    fn overlapping_registers_are_rejected_with_file_line_and_key() {
        let bad = GENERIC.replace(
            "[position]\naddress = 0x0021",
            "[position]\naddress = 0x0020",
        );
        assert_ne!(bad, GENERIC);
        let e = err(&bad);
        assert!(
            e.starts_with("drive.toml:")
                && e.contains("key `status.register`")
                && e.contains("overlaps"),
            "{e}"
        );
    }

    #[test]
    fn bad_word_order_is_rejected_with_its_key() {
        let bad = GENERIC.replace(
            "word_order = \"high-first\"",
            "word_order = \"middle-endian\"",
        );
        assert_ne!(bad, GENERIC);
        let e = err(&bad);
        assert!(
            e.contains("key `drive.word_order`") && e.contains("high-first"),
            "{e}"
        );
    }

    #[test]
    fn missing_required_register_is_rejected() {
        let start = GENERIC.find("[position]").unwrap();
        let end = GENERIC[start..].find("\n\n").unwrap() + start;
        let bad = format!("{}{}", &GENERIC[..start], &GENERIC[end..]);
        let e = err(&bad);
        assert!(e.contains("missing field `position`"), "{e}");
    }

    #[test]
    fn a_gap_in_the_move_block_is_rejected() {
        let p = DriveProfile::from_doc(&doc(GENERIC)).unwrap();
        let at = format!("address = 0x{:04X}", p.motion.trigger.reg.address);
        let bad = GENERIC.replace(&at, "address = 0x000C");
        let e = err(&bad);
        assert!(e.contains("key `move`") && e.contains("not named"), "{e}");
    }

    #[test]
    fn values_that_do_not_fit_and_wrong_units_are_rejected() {
        let e = err(&GENERIC.replace("unit = \"counts/s\"", "unit = \"counts/s2\""));
        assert!(e.contains("key `move.speed.unit`"), "{e}");
        let p = DriveProfile::from_doc(&doc(PR0)).unwrap();
        // 10 m/s is 120000 rpm: too much for a u16 register.
        let e = p.move_words(1.0, 10_000.0).unwrap_err();
        assert!(
            e.to_string().contains("`move.speed` (holding 0x6203, u16)"),
            "{e}"
        );
    }
    #[test]
    fn overlapping_status_masks_are_rejected() {
        let bad = GENERIC.replace("busy = 0x0002", "busy = 0x0006");
        assert_ne!(bad, GENERIC);
        let e = err(&bad);
        assert!(
            e.starts_with("drive.toml:")
                && e.contains("key `status.in_position`")
                && e.contains("0x0004")
                && e.contains("`status.busy`"),
            "{e}"
        );
        let bad = GENERIC.replace("home_done = 0x0010", "home_done = 0x0001");
        let e = err(&bad);
        assert!(
            e.contains("key `status.home_done`") && e.contains("`status.ready`"),
            "{e}"
        );
    }

    #[test]
    fn registers_running_past_the_last_address_are_rejected() {
        let bad = GENERIC.replace(
            "[position]\naddress = 0x0021",
            "[position]\naddress = 0xFFFF",
        );
        assert_ne!(bad, GENERIC);
        let e = err(&bad);
        assert!(
            e.starts_with("drive.toml:") && e.contains("key `position`") && e.contains("0xFFFF"),
            "{e}"
        );
        // A 16-bit register at 0xFFFF is fine.
        let ok = GENERIC.replace(
            "code = { address = 0x0023, type = \"u16\", table = \"input\" }",
            "code = { address = 0xFFFF, type = \"u16\", table = \"input\" }",
        );
        assert_ne!(ok, GENERIC);
        DriveProfile::from_doc(&doc(&ok)).unwrap();
        // Commands too.
        let bad = GENERIC.replace(
            "stop = { address = 0x0010, value = 0x0002, release = 0 }",
            "stop = { address = 0xFFFF, type = \"u32\", value = 0x0002, release = 0 }",
        );
        assert_ne!(bad, GENERIC);
        let e = err(&bad);
        assert!(e.contains("key `commands.stop`"), "{e}");
    }
}
