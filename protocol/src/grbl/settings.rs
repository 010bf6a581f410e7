//! GRBL 1.1 `$n=value` settings: the table of numbers, their meaning and kind, GRBL's
//! own validation of a write, and typed access to the values a driver needs.

use super::codes::status;
use std::collections::BTreeMap;

/// How GRBL stores and prints a setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingKind {
    /// uint8, printed without decimals.
    Integer,
    /// Boolean flag (0/1).
    Flag,
    /// Bit mask.
    Mask,
    /// float, printed with this many decimals.
    Float(usize),
}

/// Number, kind and description of every GRBL 1.1 setting.
pub const TABLE: &[(u16, SettingKind, &str)] = &[
    (0, SettingKind::Integer, "step pulse time, us"),
    (1, SettingKind::Integer, "step idle delay, ms"),
    (2, SettingKind::Mask, "step pulse invert mask"),
    (3, SettingKind::Mask, "step direction invert mask"),
    (4, SettingKind::Flag, "invert step enable pin"),
    (5, SettingKind::Flag, "invert limit pins"),
    (6, SettingKind::Flag, "invert probe pin"),
    (
        10,
        SettingKind::Mask,
        "status report options (1 = MPos, 2 = buffer state)",
    ),
    (11, SettingKind::Float(3), "junction deviation, mm"),
    (12, SettingKind::Float(3), "arc tolerance, mm"),
    (13, SettingKind::Flag, "report in inches"),
    (20, SettingKind::Flag, "soft limits enable"),
    (21, SettingKind::Flag, "hard limits enable"),
    (22, SettingKind::Flag, "homing cycle enable"),
    (23, SettingKind::Mask, "homing direction invert mask"),
    (24, SettingKind::Float(3), "homing locate feed rate, mm/min"),
    (25, SettingKind::Float(3), "homing search seek rate, mm/min"),
    (26, SettingKind::Integer, "homing switch debounce delay, ms"),
    (
        27,
        SettingKind::Float(3),
        "homing switch pull-off distance, mm",
    ),
    (30, SettingKind::Float(0), "maximum spindle speed, rpm"),
    (31, SettingKind::Float(0), "minimum spindle speed, rpm"),
    (32, SettingKind::Flag, "laser mode enable"),
    (100, SettingKind::Float(3), "X steps/mm"),
    (101, SettingKind::Float(3), "Y steps/mm"),
    (102, SettingKind::Float(3), "Z steps/mm"),
    (110, SettingKind::Float(3), "X maximum rate, mm/min"),
    (111, SettingKind::Float(3), "Y maximum rate, mm/min"),
    (112, SettingKind::Float(3), "Z maximum rate, mm/min"),
    (120, SettingKind::Float(3), "X acceleration, mm/s^2"),
    (121, SettingKind::Float(3), "Y acceleration, mm/s^2"),
    (122, SettingKind::Float(3), "Z acceleration, mm/s^2"),
    (130, SettingKind::Float(3), "X maximum travel, mm"),
    (131, SettingKind::Float(3), "Y maximum travel, mm"),
    (132, SettingKind::Float(3), "Z maximum travel, mm"),
];

/// The per-axis settings of grblHAL's A, B and C axes ($103-$105, $113-$115,
/// $123-$125, $133-$135): the same four groups as X Y Z, in degrees for a rotary axis.
pub const ROTARY_TABLE: &[(u16, SettingKind, &str)] = &[
    (103, SettingKind::Float(3), "A steps/deg"),
    (104, SettingKind::Float(3), "B steps/deg"),
    (105, SettingKind::Float(3), "C steps/deg"),
    (113, SettingKind::Float(3), "A maximum rate, deg/min"),
    (114, SettingKind::Float(3), "B maximum rate, deg/min"),
    (115, SettingKind::Float(3), "C maximum rate, deg/min"),
    (123, SettingKind::Float(3), "A acceleration, deg/s^2"),
    (124, SettingKind::Float(3), "B acceleration, deg/s^2"),
    (125, SettingKind::Float(3), "C acceleration, deg/s^2"),
    (133, SettingKind::Float(3), "A maximum travel, deg"),
    (134, SettingKind::Float(3), "B maximum travel, deg"),
    (135, SettingKind::Float(3), "C maximum travel, deg"),
];

/// Kind and description of a setting number, if GRBL 1.1 (three axes) has it.
pub fn describe(number: u16) -> Option<(SettingKind, &'static str)> {
    describe_for_axes(number, 3)
}

/// Kind and description of a setting number on a controller with `axes` axes (3..=6,
/// X Y Z then A B C): $103 exists from four axes on, $105 only with six.
pub fn describe_for_axes(number: u16, axes: usize) -> Option<(SettingKind, &'static str)> {
    let rotary = ROTARY_TABLE
        .iter()
        .filter(|(n, _, _)| usize::from(n % 10) < axes.min(6));
    TABLE
        .iter()
        .chain(rotary)
        .find(|(n, _, _)| *n == number)
        .map(|(_, k, d)| (*k, *d))
}

/// GRBL's compiled-in defaults (defaults.h, generic machine).
pub const DEFAULTS: &[(u16, f64)] = &[
    (0, 10.0),
    (1, 25.0),
    (2, 0.0),
    (3, 0.0),
    (4, 0.0),
    (5, 0.0),
    (6, 0.0),
    (10, 1.0),
    (11, 0.010),
    (12, 0.002),
    (13, 0.0),
    (20, 0.0),
    (21, 0.0),
    (22, 0.0),
    (23, 0.0),
    (24, 25.0),
    (25, 500.0),
    (26, 250.0),
    (27, 1.0),
    (30, 1000.0),
    (31, 0.0),
    (32, 0.0),
    (100, 250.0),
    (101, 250.0),
    (102, 250.0),
    (110, 500.0),
    (111, 500.0),
    (112, 500.0),
    (120, 10.0),
    (121, 10.0),
    (122, 10.0),
    (130, 200.0),
    (131, 200.0),
    (132, 200.0),
];

/// A set of setting values (a device's, or what a driver read with `$$`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Settings {
    values: BTreeMap<u16, f64>,
    /// Axes of the controller beyond GRBL 1.1's three (0..=3: A, B, C).
    extra_axes: usize,
}

impl Settings {
    /// GRBL's defaults.
    pub fn defaults() -> Self {
        Self {
            values: DEFAULTS.iter().copied().collect(),
            extra_axes: 0,
        }
    }

    /// The defaults of a controller with `axes` axes (clamped to 3..=6): the A B C
    /// groups take grblHAL's generic defaults, the same numbers as X (250 steps/deg,
    /// 500 deg/min, 10 deg/s^2, 200 deg).
    pub fn defaults_for_axes(axes: usize) -> Self {
        let mut s = Self::defaults();
        s.extra_axes = axes.clamp(3, 6) - 3;
        for axis in 3..s.axes() {
            for base in [100, 110, 120, 130] {
                let x = s.get(base).unwrap_or(0.0);
                s.values.insert(base + axis as u16, x);
            }
        }
        s
    }

    /// How many axes these settings describe (3..=6).
    pub fn axes(&self) -> usize {
        3 + self.extra_axes
    }

    pub fn get(&self, n: u16) -> Option<f64> {
        self.values.get(&n).copied()
    }

    pub fn len(&self) -> usize {
        self.values.len()
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    pub fn iter(&self) -> impl Iterator<Item = (u16, f64)> + '_ {
        self.values.iter().map(|(k, v)| (*k, *v))
    }

    /// Record a value as read from a device (no validation: the device is the authority).
    pub fn insert(&mut self, n: u16, v: f64) {
        if let Some(axis) = axis_of_setting(n).filter(|&a| a >= 3) {
            self.extra_axes = self.extra_axes.max(axis - 2);
        }
        self.values.insert(n, v);
    }

    /// Apply a `$n=value` write with GRBL's validation (settings.c): unknown number ->
    /// error 3, negative -> 4, step pulse < 3 us -> 6, soft limits without homing -> 10.
    /// Disabling homing also disables soft limits, as GRBL does. Integer settings are
    /// truncated as GRBL's uint8 storage does.
    pub fn write(&mut self, n: u16, value: f64) -> Result<(), u8> {
        let (kind, _) = describe_for_axes(n, self.axes()).ok_or(status::INVALID_STATEMENT)?;
        if value < 0.0 {
            return Err(status::NEGATIVE_VALUE);
        }
        let v = match kind {
            SettingKind::Float(_) => value,
            SettingKind::Flag => {
                if value.trunc() != 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            SettingKind::Integer | SettingKind::Mask => (value.trunc() as u64 % 256) as f64,
        };
        match n {
            0 if v < 3.0 => return Err(status::SETTING_STEP_PULSE_MIN),
            20 if v != 0.0 && !self.flag(22) => return Err(status::SOFT_LIMIT_ERROR),
            22 if v == 0.0 => {
                self.values.insert(20, 0.0);
            }
            _ => {}
        }
        self.values.insert(n, v);
        Ok(())
    }

    /// The `$n=value` line as GRBL 1.1 prints it in `$$`.
    pub fn line(&self, n: u16) -> Option<String> {
        let v = self.get(n)?;
        Some(
            match describe_for_axes(n, self.axes())
                .map(|d| d.0)
                .unwrap_or(SettingKind::Float(3))
            {
                SettingKind::Float(d) => format!("${n}={v:.d$}"),
                _ => format!("${n}={}", v as u64),
            },
        )
    }

    fn flag(&self, n: u16) -> bool {
        self.get(n).is_some_and(|v| v != 0.0)
    }

    /// Axis index 0..6 (X, Y, Z, A, B, C) value of an axis setting group (100, 110, 120, 130).
    fn axis(&self, base: u16, axis: usize) -> Option<f64> {
        self.get(base + axis as u16)
    }

    pub fn steps_per_mm(&self, axis: usize) -> Option<f64> {
        self.axis(100, axis)
    }
    pub fn max_rate_mm_min(&self, axis: usize) -> Option<f64> {
        self.axis(110, axis)
    }
    pub fn accel_mm_s2(&self, axis: usize) -> Option<f64> {
        self.axis(120, axis)
    }
    pub fn max_travel_mm(&self, axis: usize) -> Option<f64> {
        self.axis(130, axis)
    }
    pub fn soft_limits(&self) -> bool {
        self.flag(20)
    }
    pub fn hard_limits(&self) -> bool {
        self.flag(21)
    }
    pub fn homing_enabled(&self) -> bool {
        self.flag(22)
    }
    pub fn homing_dir_mask(&self) -> u8 {
        self.get(23).unwrap_or(0.0) as u8
    }
    pub fn report_inches(&self) -> bool {
        self.flag(13)
    }
    /// `$10` bit 0: positions are reported as MPos (else WPos).
    pub fn reports_mpos(&self) -> bool {
        self.get(10).is_some_and(|v| (v as u8) & 1 != 0)
    }
    /// `$10` bit 1: status reports carry `Bf:`.
    pub fn reports_buffer(&self) -> bool {
        self.get(10).is_some_and(|v| (v as u8) & 2 != 0)
    }
    pub fn arc_tolerance_mm(&self) -> f64 {
        self.get(12).unwrap_or(0.002)
    }
    pub fn homing_pulloff_mm(&self) -> f64 {
        self.get(27).unwrap_or(1.0)
    }

    /// Machine travel of an axis in GRBL's machine coordinates, given homing direction
    /// and whether the build forces the origin at the home position (`[OPT:..Z..]`).
    /// Stock GRBL's machine space is negative (-travel..0); with the force-origin option
    /// an axis homing towards negative spans 0..travel.
    pub fn travel_range(&self, axis: usize, force_origin: bool) -> Option<(f64, f64)> {
        let t = self.max_travel_mm(axis)?;
        let negative_homing = self.homing_dir_mask() & (1 << axis) != 0;
        Some(if force_origin && negative_homing {
            (0.0, t)
        } else {
            (-t, 0.0)
        })
    }
}

/// The axis (0..6) a per-axis setting ($100-$135) belongs to.
fn axis_of_setting(n: u16) -> Option<usize> {
    ((100..=135).contains(&n) && n % 10 < 6).then_some(usize::from(n % 10))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_are_validated_as_grbl_does() {
        let mut s = Settings::defaults();
        assert_eq!(s.write(999, 1.0), Err(status::INVALID_STATEMENT));
        assert_eq!(s.write(110, -1.0), Err(status::NEGATIVE_VALUE));
        assert_eq!(s.write(0, 2.0), Err(status::SETTING_STEP_PULSE_MIN));
        assert_eq!(s.write(20, 1.0), Err(status::SOFT_LIMIT_ERROR));
        s.write(22, 1.0).unwrap();
        s.write(20, 1.0).unwrap();
        assert!(s.soft_limits());
        s.write(22, 0.0).unwrap();
        assert!(!s.soft_limits(), "disabling homing disables soft limits");
        s.write(10, 259.0).unwrap();
        assert_eq!(s.get(10), Some(3.0));
        assert_eq!(s.line(10).unwrap(), "$10=3");
        s.write(100, 2000.0).unwrap();
        assert_eq!(s.line(100).unwrap(), "$100=2000.000");
        assert_eq!(s.line(30).unwrap(), "$30=1000");
    }

    #[test]
    fn travel_range_follows_homing_direction() {
        let mut s = Settings::defaults();
        s.write(130, 200.0).unwrap();
        s.write(23, 1.0).unwrap();
        assert_eq!(s.travel_range(0, true), Some((0.0, 200.0)));
        assert_eq!(s.travel_range(0, false), Some((-200.0, 0.0)));
        assert_eq!(s.travel_range(1, true), Some((-200.0, 0.0)));
    }

    #[test]
    fn rotary_settings_exist_only_on_controllers_with_those_axes() {
        let mut three = Settings::defaults();
        assert_eq!(three.write(103, 100.0), Err(status::INVALID_STATEMENT));
        let mut five = Settings::defaults_for_axes(5);
        assert_eq!(five.axes(), 5);
        assert_eq!(five.get(104), Some(250.0));
        assert_eq!(five.get(105), None);
        five.write(133, 360.0).unwrap();
        assert_eq!(five.line(133).unwrap(), "$133=360.000");
        assert_eq!(five.write(135, 1.0), Err(status::INVALID_STATEMENT));
        assert_eq!(
            describe_for_axes(115, 6).unwrap().1,
            "C maximum rate, deg/min"
        );
        assert_eq!(describe_for_axes(115, 5), None);
        // What a driver reads with `$$` tells it the axes.
        let mut read = Settings::default();
        read.insert(100, 250.0);
        assert_eq!(read.axes(), 3);
        read.insert(135, 360.0);
        assert_eq!(read.axes(), 6);
        assert_eq!(read.max_travel_mm(5), Some(360.0));
    }
}
