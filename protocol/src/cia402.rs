//! CiA 402 (drives and motion control), sans-IO: controlword and statusword, the power
//! state machine (device side and the master's path to "Operation enabled"), the
//! profile-position set-point handshake, homing status, and position scaling.

/// Object indices of the drive profile used here.
pub mod obj {
    pub const ERROR_CODE: u16 = 0x603F;
    pub const CONTROLWORD: u16 = 0x6040;
    pub const STATUSWORD: u16 = 0x6041;
    pub const QUICK_STOP_OPTION: u16 = 0x605A;
    pub const MODES_OF_OPERATION: u16 = 0x6060;
    pub const MODES_DISPLAY: u16 = 0x6061;
    pub const POSITION_DEMAND: u16 = 0x6062;
    pub const POSITION_ACTUAL: u16 = 0x6064;
    pub const FOLLOWING_ERROR_WINDOW: u16 = 0x6065;
    pub const POSITION_WINDOW: u16 = 0x6067;
    pub const TARGET_POSITION: u16 = 0x607A;
    pub const HOME_OFFSET: u16 = 0x607C;
    pub const SOFTWARE_LIMITS: u16 = 0x607D;
    pub const MAX_PROFILE_VELOCITY: u16 = 0x607F;
    pub const PROFILE_VELOCITY: u16 = 0x6081;
    pub const PROFILE_ACCELERATION: u16 = 0x6083;
    pub const PROFILE_DECELERATION: u16 = 0x6084;
    pub const QUICK_STOP_DECELERATION: u16 = 0x6085;
    pub const FEED_CONSTANT: u16 = 0x6092;
    pub const HOMING_METHOD: u16 = 0x6098;
    pub const HOMING_SPEEDS: u16 = 0x6099;
    pub const HOMING_ACCELERATION: u16 = 0x609A;
    pub const FOLLOWING_ERROR_ACTUAL: u16 = 0x60F4;
    pub const SUPPORTED_MODES: u16 = 0x6502;
}

/// Controlword (0x6040) bits.
pub mod cw {
    pub const SWITCH_ON: u16 = 1 << 0;
    pub const ENABLE_VOLTAGE: u16 = 1 << 1;
    /// Quick stop is *active low*: 0 requests a quick stop.
    pub const QUICK_STOP: u16 = 1 << 2;
    pub const ENABLE_OPERATION: u16 = 1 << 3;
    /// PP: new set-point (rising edge); HM: homing operation start.
    pub const NEW_SET_POINT: u16 = 1 << 4;
    pub const HOMING_START: u16 = 1 << 4;
    /// PP: change set immediately.
    pub const CHANGE_IMMEDIATELY: u16 = 1 << 5;
    /// PP: target is relative.
    pub const RELATIVE: u16 = 1 << 6;
    /// Fault reset (rising edge).
    pub const FAULT_RESET: u16 = 1 << 7;
    pub const HALT: u16 = 1 << 8;

    pub const SHUTDOWN: u16 = 0x06;
    pub const SWITCH_ON_CMD: u16 = 0x07;
    pub const DISABLE_VOLTAGE: u16 = 0x00;
    pub const QUICK_STOP_CMD: u16 = 0x02;
    pub const DISABLE_OPERATION: u16 = 0x07;
    pub const ENABLE_OPERATION_CMD: u16 = 0x0F;
}

/// Statusword (0x6041) bits.
pub mod sw {
    pub const READY_TO_SWITCH_ON: u16 = 1 << 0;
    pub const SWITCHED_ON: u16 = 1 << 1;
    pub const OPERATION_ENABLED: u16 = 1 << 2;
    pub const FAULT: u16 = 1 << 3;
    pub const VOLTAGE_ENABLED: u16 = 1 << 4;
    /// Quick stop is *active low*: 0 = quick stop active.
    pub const QUICK_STOP: u16 = 1 << 5;
    pub const SWITCH_ON_DISABLED: u16 = 1 << 6;
    pub const WARNING: u16 = 1 << 7;
    pub const REMOTE: u16 = 1 << 9;
    pub const TARGET_REACHED: u16 = 1 << 10;
    pub const INTERNAL_LIMIT: u16 = 1 << 11;
    /// PP: set-point acknowledge; HM: homing attained.
    pub const SET_POINT_ACK: u16 = 1 << 12;
    pub const HOMING_ATTAINED: u16 = 1 << 12;
    /// PP: following error; HM: homing error.
    pub const FOLLOWING_ERROR: u16 = 1 << 13;
    pub const HOMING_ERROR: u16 = 1 << 13;
}

/// The power state machine's states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum State {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

impl State {
    /// Decode the state from a statusword (CiA 402 table of masks).
    pub fn from_statusword(s: u16) -> State {
        match (s & 0x4F, s & 0x6F) {
            (0x00, _) => State::NotReadyToSwitchOn,
            (0x40, _) => State::SwitchOnDisabled,
            (0x0F, _) => State::FaultReactionActive,
            (0x08, _) => State::Fault,
            (_, 0x21) => State::ReadyToSwitchOn,
            (_, 0x23) => State::SwitchedOn,
            (_, 0x27) => State::OperationEnabled,
            (_, 0x07) => State::QuickStopActive,
            // Not a defined combination; a fault bit wins, else treat as not ready.
            _ if s & sw::FAULT != 0 => State::Fault,
            _ => State::NotReadyToSwitchOn,
        }
    }

    /// The state's statusword bits (bits 0-3, 5, 6) plus "voltage enabled" where the
    /// power stage is supplied.
    pub fn statusword_bits(self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 0x0000,
            State::SwitchOnDisabled => 0x0040,
            State::ReadyToSwitchOn => 0x0021 | sw::VOLTAGE_ENABLED,
            State::SwitchedOn => 0x0023 | sw::VOLTAGE_ENABLED,
            State::OperationEnabled => 0x0027 | sw::VOLTAGE_ENABLED,
            State::QuickStopActive => 0x0007 | sw::VOLTAGE_ENABLED,
            State::FaultReactionActive => 0x000F | sw::VOLTAGE_ENABLED,
            State::Fault => 0x0008,
        }
    }

    /// The name python-canopen and most tools use (upper case, as in CiA 402).
    pub fn name(self) -> &'static str {
        match self {
            State::NotReadyToSwitchOn => "NOT READY TO SWITCH ON",
            State::SwitchOnDisabled => "SWITCH ON DISABLED",
            State::ReadyToSwitchOn => "READY TO SWITCH ON",
            State::SwitchedOn => "SWITCHED ON",
            State::OperationEnabled => "OPERATION ENABLED",
            State::QuickStopActive => "QUICK STOP ACTIVE",
            State::FaultReactionActive => "FAULT REACTION ACTIVE",
            State::Fault => "FAULT",
        }
    }

    /// Whether the drive holds the motor under control (motion commands are obeyed).
    pub fn is_enabled(self) -> bool {
        self == State::OperationEnabled
    }
}

/// What a drive does on a quick stop, by its quick stop option code (0x605A, CiA 402):
/// 0 disable the drive function (coast); 1 slow down on the slow-down ramp (profile
/// deceleration 0x6084), 2 on the quick stop ramp (0x6085), 3 at the current limit, 4 at
/// the voltage limit, each then going on to Switch on disabled; 5-8 the same four but
/// staying in Quick stop active (from where "enable operation" resumes, transition 16).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QuickStopOption(pub i16);

impl QuickStopOption {
    /// The deceleration object the drive slows down on; None: it coasts (option 0).
    /// The current and voltage limits (3, 4, 7, 8) stop as hard as the drive can:
    /// modelled here as the quick stop ramp.
    pub fn ramp(self) -> Option<u16> {
        match self.0 {
            0 => None,
            1 | 5 => Some(obj::PROFILE_DECELERATION),
            _ => Some(obj::QUICK_STOP_DECELERATION),
        }
    }

    /// Whether the drive stays in Quick stop active once stopped (5-8) rather than
    /// going on to Switch on disabled (0-4, transition 12).
    pub fn stays_active(self) -> bool {
        (5..=8).contains(&self.0)
    }
}

/// Device side: the state after the controlword changed from `prev` to `cw`
/// (transitions 2-12, 15, 16 of CiA 402; 1, 13 and 14 are the device's own). Leaving
/// Quick stop active by "enable operation" (16) is allowed only for quick stop option
/// codes 5-8; for 0-4 the drive goes on to Switch on disabled by itself once stopped
/// (12), which is the caller's to do (it knows when the axis has stopped).
pub fn device_transition(state: State, prev: u16, cw: u16, option: QuickStopOption) -> State {
    let fault_reset_edge = cw & cw::FAULT_RESET != 0 && prev & cw::FAULT_RESET == 0;
    if cw & cw::FAULT_RESET != 0 {
        // While bit 7 is high no other command is taken (its edge resets a fault).
        return if state == State::Fault && fault_reset_edge {
            State::SwitchOnDisabled
        } else {
            state
        };
    }
    let shutdown = cw & 0x87 == 0x06;
    let switch_on = cw & 0x8F == 0x07;
    let enable = cw & 0x8F == 0x0F;
    let disable_voltage = cw & 0x82 == 0x00;
    let quick_stop = cw & 0x86 == 0x02;
    use State::*;
    match state {
        SwitchOnDisabled if shutdown => ReadyToSwitchOn,
        ReadyToSwitchOn if switch_on => SwitchedOn,
        ReadyToSwitchOn if enable => OperationEnabled,
        ReadyToSwitchOn if disable_voltage || quick_stop => SwitchOnDisabled,
        SwitchedOn if enable => OperationEnabled,
        SwitchedOn if shutdown => ReadyToSwitchOn,
        SwitchedOn if disable_voltage || quick_stop => SwitchOnDisabled,
        OperationEnabled if switch_on => SwitchedOn,
        OperationEnabled if shutdown => ReadyToSwitchOn,
        OperationEnabled if disable_voltage => SwitchOnDisabled,
        OperationEnabled if quick_stop => QuickStopActive,
        QuickStopActive if enable && option.stays_active() => OperationEnabled,
        QuickStopActive if disable_voltage => SwitchOnDisabled,
        s => s,
    }
}

/// Master side: the controlword that moves a drive in `state` one step towards
/// "Operation enabled", or `None` when it is there or must be waited for. A fault
/// needs a rising edge of bit 7: send `0x00` first if the last controlword had it set.
pub fn next_controlword_to_enable(state: State) -> Option<u16> {
    match state {
        State::Fault => Some(cw::FAULT_RESET),
        State::SwitchOnDisabled => Some(cw::SHUTDOWN),
        State::ReadyToSwitchOn => Some(cw::SWITCH_ON_CMD),
        State::SwitchedOn => Some(cw::ENABLE_OPERATION_CMD),
        State::QuickStopActive => Some(cw::DISABLE_VOLTAGE),
        State::OperationEnabled | State::NotReadyToSwitchOn | State::FaultReactionActive => None,
    }
}

/// Modes of operation (0x6060 / 0x6061).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    ProfilePosition = 1,
    Velocity = 2,
    ProfileVelocity = 3,
    ProfileTorque = 4,
    Homing = 6,
    InterpolatedPosition = 7,
    CyclicSyncPosition = 8,
    CyclicSyncVelocity = 9,
    CyclicSyncTorque = 10,
}

impl Mode {
    pub fn from_i8(v: i8) -> Option<Self> {
        Some(match v {
            1 => Self::ProfilePosition,
            2 => Self::Velocity,
            3 => Self::ProfileVelocity,
            4 => Self::ProfileTorque,
            6 => Self::Homing,
            7 => Self::InterpolatedPosition,
            8 => Self::CyclicSyncPosition,
            9 => Self::CyclicSyncVelocity,
            10 => Self::CyclicSyncTorque,
            _ => return None,
        })
    }

    /// The mode's bit in "supported drive modes" (0x6502).
    pub fn supported_bit(self) -> u32 {
        match self {
            Self::ProfilePosition => 0x001,
            Self::Velocity => 0x002,
            Self::ProfileVelocity => 0x004,
            Self::ProfileTorque => 0x008,
            Self::Homing => 0x020,
            Self::InterpolatedPosition => 0x040,
            Self::CyclicSyncPosition => 0x080,
            Self::CyclicSyncVelocity => 0x100,
            Self::CyclicSyncTorque => 0x200,
        }
    }
}

/// Homing progress from the statusword (bits 13, 12, 10) in homing mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HomingStatus {
    InProgress,
    /// Interrupted or not started.
    Idle,
    AttainedNotReached,
    Completed,
    Error,
}

pub fn homing_status(s: u16) -> HomingStatus {
    match (
        s & sw::HOMING_ERROR != 0,
        s & sw::HOMING_ATTAINED != 0,
        s & sw::TARGET_REACHED != 0,
    ) {
        (true, _, _) => HomingStatus::Error,
        (false, false, false) => HomingStatus::InProgress,
        (false, false, true) => HomingStatus::Idle,
        (false, true, false) => HomingStatus::AttainedNotReached,
        (false, true, true) => HomingStatus::Completed,
    }
}

/// A set-point latched by the profile-position handshake.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SetPoint {
    pub target: i32,
    pub relative: bool,
    pub immediate: bool,
}

/// What the drive does with a controlword in profile-position mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PpAction {
    None,
    /// Start (or, if `immediate`, replace the current motion with) this set-point.
    Start(SetPoint),
    /// The set-point was buffered behind the motion in progress.
    Buffered,
}

/// Device side of the profile-position set-point handshake (single set-point with a
/// one-deep buffer, change-immediately, relative): the master raises bit 4 with a
/// target in 0x607A; the drive latches it and sets bit 12; the master drops bit 4; the
/// drive drops bit 12 once it can take another set-point.
#[derive(Clone, Debug, Default)]
pub struct PpHandshake {
    ack: bool,
    buffered: Option<SetPoint>,
    bit4: bool,
}

impl PpHandshake {
    /// The set-point-acknowledge bit (statusword bit 12).
    pub fn ack(&self) -> bool {
        self.ack
    }

    /// A controlword arrived (with 0x607A already written); `busy` if a motion runs.
    pub fn on_controlword(&mut self, cw: u16, target: i32, busy: bool) -> PpAction {
        let bit4 = cw & cw::NEW_SET_POINT != 0;
        let rising = bit4 && !self.bit4;
        self.bit4 = bit4;
        if !bit4 {
            if self.buffered.is_none() {
                self.ack = false;
            }
            return PpAction::None;
        }
        if !rising || self.ack {
            return PpAction::None;
        }
        let sp = SetPoint {
            target,
            relative: cw & cw::RELATIVE != 0,
            immediate: cw & cw::CHANGE_IMMEDIATELY != 0,
        };
        self.ack = true;
        if busy && !sp.immediate {
            self.buffered = Some(sp);
            return PpAction::Buffered;
        }
        PpAction::Start(sp)
    }

    /// The motion ended: the buffered set-point, if any, starts now.
    pub fn on_motion_done(&mut self) -> Option<SetPoint> {
        let sp = self.buffered.take()?;
        if !self.bit4 {
            self.ack = false;
        }
        Some(sp)
    }

    /// Forget everything (mode change, disable, fault).
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}

/// Position scaling between millimetres and drive position units (counts), e.g. from
/// the feed constant (0x6092: feed per shaft revolution) and the encoder resolution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scaling {
    pub counts_per_mm: f64,
}

/// A position that does not fit the drive's INTEGER32 position units.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{mm} mm is {counts:.0} counts: outside the drive's 32-bit position range")]
pub struct ScalingError {
    pub mm: f64,
    pub counts: f64,
}

impl Scaling {
    pub fn new(counts_per_mm: f64) -> Self {
        Self { counts_per_mm }
    }

    /// From the feed constant: `feed` units per `revolutions` shaft revolutions, with
    /// `counts_per_rev` encoder counts per revolution, where one feed unit is `mm_per_unit`.
    pub fn from_feed_constant(
        feed: u32,
        revolutions: u32,
        counts_per_rev: u32,
        mm_per_unit: f64,
    ) -> Self {
        let mm_per_rev = f64::from(feed) * mm_per_unit / f64::from(revolutions.max(1));
        Self {
            counts_per_mm: f64::from(counts_per_rev) / mm_per_rev,
        }
    }

    pub fn to_counts(&self, mm: f64) -> Result<i32, ScalingError> {
        let c = (mm * self.counts_per_mm).round();
        if c.is_finite() && c >= f64::from(i32::MIN) && c <= f64::from(i32::MAX) {
            Ok(c as i32)
        } else {
            Err(ScalingError { mm, counts: c })
        }
    }

    pub fn to_mm(&self, counts: i32) -> f64 {
        f64::from(counts) / self.counts_per_mm
    }

    /// mm/min as counts/s (velocity units), at least 1.
    pub fn speed_to_counts_s(&self, mm_min: f64) -> u32 {
        (mm_min / 60.0 * self.counts_per_mm)
            .round()
            .clamp(1.0, f64::from(u32::MAX)) as u32
    }

    /// mm/s^2 as counts/s^2, at least 1.
    pub fn accel_to_counts_s2(&self, mm_s2: f64) -> u32 {
        (mm_s2 * self.counts_per_mm)
            .round()
            .clamp(1.0, f64::from(u32::MAX)) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statusword_decodes_every_state_and_back() {
        use State::*;
        for s in [
            NotReadyToSwitchOn,
            SwitchOnDisabled,
            ReadyToSwitchOn,
            SwitchedOn,
            OperationEnabled,
            QuickStopActive,
            FaultReactionActive,
            Fault,
        ] {
            let w = s.statusword_bits() | sw::REMOTE | sw::TARGET_REACHED | sw::SET_POINT_ACK;
            assert_eq!(State::from_statusword(w), s, "{s:?} {w:#06x}");
        }
        assert_eq!(State::from_statusword(0x0237), OperationEnabled);
        assert_eq!(State::from_statusword(0x0250), SwitchOnDisabled);
        assert_eq!(State::from_statusword(0x0218), Fault);
    }

    #[test]
    fn the_enable_sequence_walks_the_state_machine() {
        let mut s = State::SwitchOnDisabled;
        let mut prev = 0;
        let mut words = Vec::new();
        while let Some(c) = next_controlword_to_enable(s) {
            words.push(c);
            s = device_transition(s, prev, c, QuickStopOption(6));
            prev = c;
            assert!(words.len() < 10);
        }
        assert_eq!(words, [0x06, 0x07, 0x0F]);
        assert_eq!(s, State::OperationEnabled);
        // Quick stop, then back.
        assert_eq!(
            device_transition(s, 0x0F, 0x0B, QuickStopOption(6)),
            State::QuickStopActive
        );
        assert_eq!(
            device_transition(State::QuickStopActive, 0x0B, 0x00, QuickStopOption(6)),
            State::SwitchOnDisabled
        );
        // A fault is reset only by a rising edge of bit 7.
        assert_eq!(
            device_transition(State::Fault, 0x80, 0x80, QuickStopOption(6)),
            State::Fault
        );
        assert_eq!(
            device_transition(State::Fault, 0x00, 0x80, QuickStopOption(6)),
            State::SwitchOnDisabled
        );
        assert_eq!(
            device_transition(State::Fault, 0x00, 0x0F, QuickStopOption(6)),
            State::Fault
        );
        // Shutdown straight from operation enabled; enable straight from ready.
        assert_eq!(
            device_transition(State::OperationEnabled, 0x0F, 0x06, QuickStopOption(6)),
            State::ReadyToSwitchOn
        );
        assert_eq!(
            device_transition(State::ReadyToSwitchOn, 0x06, 0x0F, QuickStopOption(6)),
            State::OperationEnabled
        );
    }

    #[test]
    fn enable_operation_leaves_quick_stop_only_for_option_codes_5_to_8() {
        for code in -1..=9 {
            let option = QuickStopOption(code);
            let s = device_transition(State::QuickStopActive, 0x0B, 0x0F, option);
            let expected = if (5..=8).contains(&code) {
                State::OperationEnabled
            } else {
                State::QuickStopActive
            };
            assert_eq!(s, expected, "option {code}");
            assert_eq!(option.stays_active(), (5..=8).contains(&code));
        }
        assert_eq!(QuickStopOption(0).ramp(), None);
        assert_eq!(QuickStopOption(1).ramp(), Some(obj::PROFILE_DECELERATION));
        assert_eq!(QuickStopOption(5).ramp(), Some(obj::PROFILE_DECELERATION));
        assert_eq!(
            QuickStopOption(2).ramp(),
            Some(obj::QUICK_STOP_DECELERATION)
        );
        assert_eq!(
            QuickStopOption(6).ramp(),
            Some(obj::QUICK_STOP_DECELERATION)
        );
    }

    #[test]
    fn set_point_handshake_with_buffer_and_change_immediately() {
        let mut h = PpHandshake::default();
        assert_eq!(h.on_controlword(0x0F, 100, false), PpAction::None);
        let a = h.on_controlword(0x1F, 100, false);
        assert_eq!(
            a,
            PpAction::Start(SetPoint {
                target: 100,
                relative: false,
                immediate: false
            })
        );
        assert!(h.ack());
        // Holding bit 4 high does not start again.
        assert_eq!(h.on_controlword(0x1F, 200, true), PpAction::None);
        assert_eq!(h.on_controlword(0x0F, 200, true), PpAction::None);
        assert!(!h.ack(), "ack drops with bit 4 when the buffer is free");
        // Busy: a second set-point is buffered; ack stays up while it waits.
        assert_eq!(h.on_controlword(0x5F, 10, true), PpAction::Buffered);
        assert_eq!(h.on_controlword(0x0F, 10, true), PpAction::None);
        assert!(h.ack());
        assert_eq!(
            h.on_motion_done(),
            Some(SetPoint {
                target: 10,
                relative: true,
                immediate: false
            })
        );
        assert!(!h.ack());
        // Change immediately replaces the motion in progress.
        let a = h.on_controlword(0x3F, 7, true);
        assert_eq!(
            a,
            PpAction::Start(SetPoint {
                target: 7,
                relative: false,
                immediate: true
            })
        );
    }

    #[test]
    fn homing_status_and_scaling() {
        assert_eq!(homing_status(0x0237), HomingStatus::InProgress);
        assert_eq!(homing_status(0x1637), HomingStatus::Completed);
        assert_eq!(homing_status(0x2637), HomingStatus::Error);
        assert_eq!(homing_status(0x0637), HomingStatus::Idle);
        let s = Scaling::from_feed_constant(5000, 1, 10_000, 0.001);
        assert_eq!(s.counts_per_mm, 2000.0);
        assert_eq!(s.to_counts(12.3456), Ok(24691));
        assert!((s.to_mm(24691) - 12.3455).abs() < 1e-9);
        assert!(s.to_counts(2.0e6).is_err());
        assert_eq!(s.speed_to_counts_s(3000.0), 100_000);
        assert_eq!(
            Mode::Homing.supported_bit() | Mode::ProfilePosition.supported_bit(),
            0x21
        );
    }
}
