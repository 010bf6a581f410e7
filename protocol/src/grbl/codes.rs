//! GRBL 1.1 error and alarm codes with their meanings (from GRBL's own code tables), so
//! every refusal reaching a user says what the number means.

/// Short name and explanation of an `error:N` code.
pub fn error_text(code: u8) -> &'static str {
    match code {
        1 => "expected command letter: a G-code word has no letter",
        2 => "bad number format: a word value is missing or not a number",
        3 => "invalid statement: '$' command not recognised or not supported",
        4 => "value < 0: negative value for a positive setting",
        5 => "setting disabled: homing is not enabled ($22)",
        6 => "value < 3 usec: step pulse must be at least 3 us",
        7 => "EEPROM read fail: using defaults",
        8 => "not idle: '$' command needs the Idle state",
        9 => "G-code lock: G-code is locked out in Alarm or Jog state",
        10 => "soft limits need homing enabled ($22)",
        11 => "line overflow: more than 80 characters in the line",
        12 => "step rate > 30 kHz",
        13 => "check door: safety door is open",
        14 => "line length exceeded: build info or startup line too long",
        15 => "travel exceeded: jog target beyond machine travel",
        16 => "invalid jog command",
        17 => "setting disabled: laser mode needs PWM output",
        20 => "unsupported command: G or M command not supported",
        21 => "modal group violation: two commands of one modal group in the block",
        22 => "undefined feed rate: no F word for a feed motion",
        23 => "G-code command in block requires an integer value",
        24 => "two G-code commands in the block both require axis words",
        25 => "a G-code word was repeated in the block",
        26 => "a command requires axis words but none were found",
        27 => "N line number outside 1..9999999",
        28 => "a command is missing a required P or L value word",
        29 => "G59.x work coordinate systems are not supported",
        30 => "G53 needs G0 or G1 motion mode",
        31 => "axis words found in a block with no command or modal motion to use them",
        32 => "G2/G3 arc has no axis words in the selected plane",
        33 => "motion command target is invalid",
        34 => "arc radius definition: impossible arc geometry",
        35 => "G2/G3 arc (offset form) has no offset word in the selected plane",
        36 => "unused value words left in the block",
        37 => "G43.1 tool length offset is not on the tool length axis",
        38 => "tool number greater than the maximum",
        _ => "unknown error code",
    }
}

/// Explanation of an `ALARM:N` code.
pub fn alarm_text(code: u8) -> &'static str {
    match code {
        1 => "hard limit triggered: machine position likely lost, re-home",
        2 => "soft limit: motion target exceeds machine travel (position retained)",
        3 => "reset while in motion: position may be lost, re-home",
        4 => "probe fail: probe not in the expected initial state",
        5 => "probe fail: probe did not contact within the programmed travel",
        6 => "homing fail: reset during the homing cycle",
        7 => "homing fail: safety door opened during homing",
        8 => "homing fail: pull-off did not clear the limit switch",
        9 => "homing fail: limit switch not found within the search distance",
        10 => "homing fail: second switch of a dual axis not found",
        _ => "unknown alarm code",
    }
}

/// GRBL's status codes as constants, for the parser and the emulator.
pub mod status {
    pub const EXPECTED_COMMAND_LETTER: u8 = 1;
    pub const BAD_NUMBER_FORMAT: u8 = 2;
    pub const INVALID_STATEMENT: u8 = 3;
    pub const NEGATIVE_VALUE: u8 = 4;
    pub const SETTING_DISABLED: u8 = 5;
    pub const SETTING_STEP_PULSE_MIN: u8 = 6;
    pub const IDLE_ERROR: u8 = 8;
    pub const SYSTEM_GC_LOCK: u8 = 9;
    pub const SOFT_LIMIT_ERROR: u8 = 10;
    pub const OVERFLOW: u8 = 11;
    pub const LINE_LENGTH_EXCEEDED: u8 = 14;
    pub const TRAVEL_EXCEEDED: u8 = 15;
    pub const INVALID_JOG_COMMAND: u8 = 16;
    pub const UNSUPPORTED_COMMAND: u8 = 20;
    pub const MODAL_GROUP_VIOLATION: u8 = 21;
    pub const UNDEFINED_FEED_RATE: u8 = 22;
    pub const COMMAND_VALUE_NOT_INTEGER: u8 = 23;
    pub const AXIS_COMMAND_CONFLICT: u8 = 24;
    pub const WORD_REPEATED: u8 = 25;
    pub const NO_AXIS_WORDS: u8 = 26;
    pub const INVALID_LINE_NUMBER: u8 = 27;
    pub const VALUE_WORD_MISSING: u8 = 28;
    pub const UNSUPPORTED_COORD_SYS: u8 = 29;
    pub const G53_INVALID_MOTION_MODE: u8 = 30;
    pub const AXIS_WORDS_EXIST: u8 = 31;
    pub const NO_AXIS_WORDS_IN_PLANE: u8 = 32;
    pub const INVALID_TARGET: u8 = 33;
    pub const ARC_RADIUS_ERROR: u8 = 34;
    pub const NO_OFFSETS_IN_PLANE: u8 = 35;
    pub const UNUSED_WORDS: u8 = 36;
    pub const G43_DYNAMIC_AXIS_ERROR: u8 = 37;
    pub const MAX_VALUE_EXCEEDED: u8 = 38;
}

/// GRBL's alarm codes as constants.
pub mod alarm {
    pub const HARD_LIMIT: u8 = 1;
    pub const SOFT_LIMIT: u8 = 2;
    pub const ABORT_CYCLE: u8 = 3;
    pub const PROBE_FAIL_INITIAL: u8 = 4;
    pub const PROBE_FAIL_CONTACT: u8 = 5;
    pub const HOMING_FAIL_RESET: u8 = 6;
}
