//! Probing results: the `[PRB:...]` report and the probe alarms.
//!
//! GRBL 1.1 answers every probing cycle (G38.2 to G38.5) that ends, touched or not, with
//! `[PRB:x,y,z:s]`: the machine position (MPos, mm or inches as `$13` says) where the
//! probe triggered, or where the move ended without a trigger, and `s` = 1 for a touch,
//! 0 for none. grblHAL prints one value per configured axis (`[PRB:x,y,z,a,c:1]` on a
//! machine with A and C); the same line is the last-probe entry of the `$#` reply.
//! A probe move that finds nothing where contact was required (G38.2, G38.4) ends in
//! `ALARM:5`; a probe already in the state the move is to look for ends in `ALARM:4`.
//! G38.3 and G38.5 report `s` = 0 and raise no alarm.
//!
//! Example: `[PRB:10.000,-2.500,-31.204:1]` is a touch at X 10, Y -2.5, Z -31.204.

use super::response::Response;

/// The axis letters in the order GRBL and grblHAL print them, up to six axes.
pub const AXIS_ORDER: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// A parsed `[PRB:...]` report.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeReport {
    /// Machine position, one value per axis the controller reports (3 to 6).
    pub position: Vec<f64>,
    /// The probe triggered (`:1`).
    pub touched: bool,
}

/// Why a `[PRB:...]` report was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ProbeReportError {
    #[error("not a [PRB:...] report")]
    NotProbe,
    #[error("PRB report `{0}`: expected 3 to 6 comma-separated numbers, `:`, then 0 or 1")]
    Malformed(String),
}

impl ProbeReport {
    /// Parses a whole line (`[PRB:1.000,2.000,3.000:1]`).
    pub fn parse_line(line: &str) -> Result<Self, ProbeReportError> {
        match Response::parse(line.trim()) {
            Response::Parameter { name, value } if name == "PRB" => Self::parse_value(&value),
            _ => Err(ProbeReportError::NotProbe),
        }
    }

    /// Parses the part after `PRB:` (`1.000,2.000,3.000:1`).
    pub fn parse_value(value: &str) -> Result<Self, ProbeReportError> {
        let bad = || ProbeReportError::Malformed(crate::text::escape_bytes(value.as_bytes()));
        let (coords, flag) = value.rsplit_once(':').ok_or_else(bad)?;
        let touched = match flag.trim() {
            "1" => true,
            "0" => false,
            _ => return Err(bad()),
        };
        let position: Vec<f64> = coords
            .split(',')
            .map(|v| v.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(bad)?;
        if !(3..=AXIS_ORDER.len()).contains(&position.len()) {
            return Err(bad());
        }
        Ok(Self { position, touched })
    }

    /// The report as GRBL prints it (3 decimals, mm).
    pub fn to_line(&self) -> String {
        let coords: Vec<String> = self.position.iter().map(|v| format!("{v:.3}")).collect();
        format!("[PRB:{}:{}]", coords.join(","), u8::from(self.touched))
    }
}

/// The probe alarms of GRBL 1.1 (`ALARM:4`, `ALARM:5`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProbeAlarm {
    /// `ALARM:4`: the probe was not in the expected state when the cycle started
    /// (already triggered for G38.2/G38.3, not triggered for G38.4/G38.5).
    InitialState,
    /// `ALARM:5`: no contact within the programmed travel (G38.2, G38.4).
    NoContact,
}

impl ProbeAlarm {
    /// The probe alarm an `ALARM:N` code is, if it is one.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            4 => Some(Self::InitialState),
            5 => Some(Self::NoContact),
            _ => None,
        }
    }

    pub fn code(self) -> u8 {
        match self {
            Self::InitialState => 4,
            Self::NoContact => 5,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_and_five_axis_reports() {
        let r = ProbeReport::parse_line("[PRB:10.000,-2.500,-31.204:1]").unwrap();
        assert_eq!(r.position, vec![10.0, -2.5, -31.204]);
        assert!(r.touched);
        assert_eq!(r.to_line(), "[PRB:10.000,-2.500,-31.204:1]");
        let r = ProbeReport::parse_line("[PRB:1.000,2.000,3.000,45.000,-90.000:0]").unwrap();
        assert_eq!(r.position.len(), 5);
        assert!(!r.touched);
        assert_eq!(
            ProbeReport::parse_line(&r.to_line()).unwrap(),
            r,
            "written reports read back"
        );
    }

    #[test]
    fn malformed_reports_are_refused() {
        for bad in [
            "[PRB:1,2:1]",
            "[PRB:1,2,3,4,5,6,7:1]",
            "[PRB:1,2,3:2]",
            "[PRB:1,2,3]",
            "[PRB:1,x,3:1]",
            "[PRB:1,inf,3:1]",
        ] {
            assert!(
                matches!(
                    ProbeReport::parse_line(bad),
                    Err(ProbeReportError::Malformed(_))
                ),
                "{bad}"
            );
        }
        assert_eq!(
            ProbeReport::parse_line("[G54:0.000,0.000,0.000]"),
            Err(ProbeReportError::NotProbe)
        );
        assert_eq!(
            ProbeReport::parse_line("ok"),
            Err(ProbeReportError::NotProbe)
        );
    }

    #[test]
    fn probe_alarms_are_four_and_five() {
        assert_eq!(ProbeAlarm::from_code(4), Some(ProbeAlarm::InitialState));
        assert_eq!(ProbeAlarm::from_code(5), Some(ProbeAlarm::NoContact));
        assert_eq!(ProbeAlarm::from_code(2), None);
        assert_eq!(ProbeAlarm::NoContact.code(), 5);
    }
}
