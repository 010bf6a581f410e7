//! Line commands a host sends to GRBL (everything except the real-time bytes), encoded
//! exactly as they go on the wire: one line ending in `\n`.

use std::fmt;

/// A `$RST=` target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RestoreTarget {
    /// `$RST=$`: settings to defaults.
    Settings,
    /// `$RST=#`: clear G54-G59, G28, G30 offsets.
    Parameters,
    /// `$RST=*`: everything.
    All,
}

/// One line for GRBL.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// `$`: help.
    Help,
    /// `$$`: list settings.
    ViewSettings,
    /// `$n=value`: write a setting (send-response only: EEPROM write).
    WriteSetting(u16, f64),
    /// `$#`: coordinate offsets and probe result.
    ViewParameters,
    /// `$G`: parser modal state.
    ViewParserState,
    /// `$I`: build info (`[VER:]`, `[OPT:]`).
    BuildInfo,
    /// `$N`: startup lines.
    ViewStartupLines,
    /// `$Nn=line`: store a startup line.
    WriteStartupLine(u8, String),
    /// `$C`: toggle check mode.
    CheckMode,
    /// `$X`: kill alarm lock.
    Unlock,
    /// `$H`: run the homing cycle.
    Home,
    /// `$J=line`: jog (the G-code words after `=`).
    Jog(String),
    /// `$RST=...`.
    Restore(RestoreTarget),
    /// `$SLP`: sleep.
    Sleep,
    /// A G-code block.
    Gcode(String),
}

impl Command {
    /// The text of the line, without the line ending.
    pub fn text(&self) -> String {
        match self {
            Command::Help => "$".into(),
            Command::ViewSettings => "$$".into(),
            Command::WriteSetting(n, v) => format!("${n}={}", trim_float(*v, 4)),
            Command::ViewParameters => "$#".into(),
            Command::ViewParserState => "$G".into(),
            Command::BuildInfo => "$I".into(),
            Command::ViewStartupLines => "$N".into(),
            Command::WriteStartupLine(n, l) => format!("$N{n}={l}"),
            Command::CheckMode => "$C".into(),
            Command::Unlock => "$X".into(),
            Command::Home => "$H".into(),
            Command::Jog(words) => format!("$J={words}"),
            Command::Restore(RestoreTarget::Settings) => "$RST=$".into(),
            Command::Restore(RestoreTarget::Parameters) => "$RST=#".into(),
            Command::Restore(RestoreTarget::All) => "$RST=*".into(),
            Command::Sleep => "$SLP".into(),
            Command::Gcode(l) => l.clone(),
        }
    }

    /// The bytes on the wire, `\n`-terminated (GRBL also accepts `\r`, but `\r\n` would
    /// be two lines and two `ok`s).
    pub fn encode(&self) -> Vec<u8> {
        let mut v = self.text().into_bytes();
        v.push(b'\n');
        v
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text())
    }
}

/// A number with at most `decimals` decimals and no trailing zeros (`10`, `2.5`,
/// `-0.0005`), the shortest form GRBL parses exactly; saves RX buffer bytes.
pub fn trim_float(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodings() {
        assert_eq!(Command::ViewSettings.encode(), b"$$\n");
        assert_eq!(Command::WriteSetting(110, 6000.0).encode(), b"$110=6000\n");
        assert_eq!(Command::Jog("G91X1F100".into()).encode(), b"$J=G91X1F100\n");
        assert_eq!(Command::Restore(RestoreTarget::Parameters).text(), "$RST=#");
        assert_eq!(trim_float(12.34560, 4), "12.3456");
        assert_eq!(trim_float(-0.00001, 4), "0");
        assert_eq!(trim_float(100.0, 4), "100");
    }
}
