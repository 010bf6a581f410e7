//! GRBL 1.1 real-time status reports: `<State|MPos:x,y,z|Bf:b,r|Ln:n|FS:f,s|Pn:..|WCO:..|Ov:f,r,s|A:..>`.
//!
//! The state comes first and the position second; the other fields are optional and in
//! no fixed order, so the parser accepts them in any order and keeps unknown fields
//! (forks such as grblHAL add their own) instead of failing on them.

use std::fmt::Write as _;

/// The machine state named first in a status report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MachineState {
    Idle,
    Run,
    /// `Hold:0` hold complete, ready to resume; `Hold:1` decelerating.
    Hold(u8),
    Jog,
    Alarm,
    /// `Door:0..3`.
    Door(u8),
    Check,
    Home,
    Sleep,
}

impl MachineState {
    pub fn parse(s: &str) -> Option<MachineState> {
        let (name, sub) = match s.split_once(':') {
            Some((n, sub)) => (n, Some(sub.parse::<u8>().ok()?)),
            None => (s, None),
        };
        Some(match (name, sub) {
            ("Idle", None) => MachineState::Idle,
            ("Run", None) => MachineState::Run,
            ("Hold", sub) => MachineState::Hold(sub.unwrap_or(0)),
            ("Jog", None) => MachineState::Jog,
            ("Alarm", None) => MachineState::Alarm,
            ("Door", sub) => MachineState::Door(sub.unwrap_or(0)),
            ("Check", None) => MachineState::Check,
            ("Home", None) => MachineState::Home,
            ("Sleep", None) => MachineState::Sleep,
            _ => return None,
        })
    }

    pub fn name(&self) -> String {
        match self {
            MachineState::Idle => "Idle".into(),
            MachineState::Run => "Run".into(),
            MachineState::Hold(s) => format!("Hold:{s}"),
            MachineState::Jog => "Jog".into(),
            MachineState::Alarm => "Alarm".into(),
            MachineState::Door(s) => format!("Door:{s}"),
            MachineState::Check => "Check".into(),
            MachineState::Home => "Home".into(),
            MachineState::Sleep => "Sleep".into(),
        }
    }
}

/// Which coordinates a report's position is in (`$10` bit 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PositionKind {
    Machine,
    Work,
}

/// One parsed status report. Absent optional fields are `None`.
#[derive(Clone, Debug, PartialEq)]
pub struct StatusReport {
    pub state: MachineState,
    pub position_kind: PositionKind,
    /// MPos or WPos values, one per axis GRBL reports (3 for stock GRBL).
    pub position: Vec<f64>,
    /// `Bf:` free planner blocks and free RX bytes.
    pub buffer: Option<(u16, u16)>,
    /// `Ln:` line number of the block executing.
    pub line_number: Option<u32>,
    /// Live feed rate (`FS:` or `F:`).
    pub feed: Option<f64>,
    /// Live spindle speed (`FS:` only).
    pub spindle: Option<f64>,
    /// `Pn:` triggered input pins, as letters (X Y Z P D H R S).
    pub pins: Option<String>,
    /// `WCO:` work coordinate offset (MPos = WPos + WCO).
    pub wco: Option<Vec<f64>>,
    /// `Ov:` feed, rapid, spindle override percentages.
    pub overrides: Option<[u16; 3]>,
    /// `A:` accessory state letters (S C F M).
    pub accessories: Option<String>,
    /// Fields this parser does not know, kept verbatim.
    pub other: Vec<String>,
}

/// Why a status report was rejected.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("bad status report `{line}`: {reason}")]
pub struct StatusError {
    pub line: String,
    pub reason: String,
}

fn numbers(s: &str) -> Option<Vec<f64>> {
    s.split(',')
        .map(|v| v.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect()
}

impl StatusReport {
    /// A report with only state and machine position.
    pub fn new(state: MachineState, mpos: Vec<f64>) -> Self {
        Self {
            state,
            position_kind: PositionKind::Machine,
            position: mpos,
            buffer: None,
            line_number: None,
            feed: None,
            spindle: None,
            pins: None,
            wco: None,
            overrides: None,
            accessories: None,
            other: Vec::new(),
        }
    }

    /// Parse one line (with or without the line ending), e.g. `<Idle|MPos:1.000,2.000,0.000|FS:0,0>`.
    pub fn parse(line: &str) -> Result<StatusReport, StatusError> {
        let err = |reason: &str| StatusError {
            line: line.to_string(),
            reason: reason.to_string(),
        };
        let body = line
            .trim_end_matches(['\r', '\n'])
            .strip_prefix('<')
            .and_then(|s| s.strip_suffix('>'))
            .ok_or_else(|| err("not enclosed in < >"))?;
        let mut fields = body.split('|');
        let state_s = fields.next().unwrap_or("");
        let state = MachineState::parse(state_s)
            .ok_or_else(|| err(&format!("unknown state `{state_s}`")))?;
        let mut report = StatusReport::new(state, Vec::new());
        let mut have_pos = false;
        for f in fields {
            let (key, value) = f.split_once(':').unwrap_or((f, ""));
            match key {
                "MPos" | "WPos" => {
                    report.position =
                        numbers(value).ok_or_else(|| err(&format!("bad {key} `{value}`")))?;
                    report.position_kind = if key == "MPos" {
                        PositionKind::Machine
                    } else {
                        PositionKind::Work
                    };
                    have_pos = true;
                }
                "Bf" => {
                    let v: Vec<u16> = value.split(',').filter_map(|x| x.parse().ok()).collect();
                    if v.len() != 2 {
                        return Err(err(&format!("bad Bf `{value}`")));
                    }
                    report.buffer = Some((v[0], v[1]));
                }
                "Ln" => {
                    report.line_number = Some(
                        value
                            .parse()
                            .map_err(|_| err(&format!("bad Ln `{value}`")))?,
                    )
                }
                "FS" => {
                    let v = numbers(value)
                        .filter(|v| v.len() == 2)
                        .ok_or_else(|| err(&format!("bad FS `{value}`")))?;
                    report.feed = Some(v[0]);
                    report.spindle = Some(v[1]);
                }
                "F" => {
                    report.feed = Some(
                        value
                            .parse()
                            .map_err(|_| err(&format!("bad F `{value}`")))?,
                    )
                }
                "Pn" => report.pins = Some(value.to_string()),
                "WCO" => {
                    report.wco =
                        Some(numbers(value).ok_or_else(|| err(&format!("bad WCO `{value}`")))?)
                }
                "Ov" => {
                    let v: Vec<u16> = value.split(',').filter_map(|x| x.parse().ok()).collect();
                    if v.len() != 3 {
                        return Err(err(&format!("bad Ov `{value}`")));
                    }
                    report.overrides = Some([v[0], v[1], v[2]]);
                }
                "A" => report.accessories = Some(value.to_string()),
                _ => report.other.push(f.to_string()),
            }
        }
        if !have_pos {
            return Err(err("no MPos or WPos field"));
        }
        Ok(report)
    }

    /// Machine position, if it can be known from this report (MPos, or WPos + WCO).
    pub fn machine_position(&self, last_wco: Option<&[f64]>) -> Option<Vec<f64>> {
        match self.position_kind {
            PositionKind::Machine => Some(self.position.clone()),
            PositionKind::Work => {
                let wco = self.wco.as_deref().or(last_wco)?;
                Some(self.position.iter().zip(wco).map(|(p, o)| p + o).collect())
            }
        }
    }

    /// The report as GRBL prints it, positions with `decimals` digits (3 in mm, 4 in
    /// inches), rates without decimals. No line ending.
    pub fn to_line(&self, decimals: usize) -> String {
        let axes = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:.decimals$}"))
                .collect::<Vec<_>>()
                .join(",")
        };
        let mut s = format!("<{}", self.state.name());
        let key = match self.position_kind {
            PositionKind::Machine => "MPos",
            PositionKind::Work => "WPos",
        };
        let _ = write!(s, "|{key}:{}", axes(&self.position));
        if let Some((b, r)) = self.buffer {
            let _ = write!(s, "|Bf:{b},{r}");
        }
        if let Some(n) = self.line_number {
            let _ = write!(s, "|Ln:{n}");
        }
        match (self.feed, self.spindle) {
            (Some(f), Some(sp)) => {
                let _ = write!(s, "|FS:{f:.0},{sp:.0}");
            }
            (Some(f), None) => {
                let _ = write!(s, "|F:{f:.0}");
            }
            _ => {}
        }
        if let Some(p) = &self.pins {
            let _ = write!(s, "|Pn:{p}");
        }
        if let Some(w) = &self.wco {
            let _ = write!(s, "|WCO:{}", axes(w));
        }
        if let Some([f, r, sp]) = self.overrides {
            let _ = write!(s, "|Ov:{f},{r},{sp}");
            if let Some(a) = &self.accessories {
                let _ = write!(s, "|A:{a}");
            }
        }
        for o in &self.other {
            let _ = write!(s, "|{o}");
        }
        s.push('>');
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_field() {
        let r = StatusReport::parse("<Hold:1|WPos:-1.500,2.250,0.000|Bf:12,100|Ln:42|FS:1500,8000|Pn:XP|WCO:10.000,0.000,-2.000|Ov:110,50,100|A:SF>\r\n").unwrap();
        assert_eq!(r.state, MachineState::Hold(1));
        assert_eq!(r.position_kind, PositionKind::Work);
        assert_eq!(r.position, vec![-1.5, 2.25, 0.0]);
        assert_eq!(r.buffer, Some((12, 100)));
        assert_eq!(r.line_number, Some(42));
        assert_eq!((r.feed, r.spindle), (Some(1500.0), Some(8000.0)));
        assert_eq!(r.pins.as_deref(), Some("XP"));
        assert_eq!(r.wco, Some(vec![10.0, 0.0, -2.0]));
        assert_eq!(r.overrides, Some([110, 50, 100]));
        assert_eq!(r.accessories.as_deref(), Some("SF"));
        assert_eq!(r.machine_position(None), Some(vec![8.5, 2.25, -2.0]));
        assert_eq!(
            r.to_line(3),
            "<Hold:1|WPos:-1.500,2.250,0.000|Bf:12,100|Ln:42|FS:1500,8000|Pn:XP|WCO:10.000,0.000,-2.000|Ov:110,50,100|A:SF>"
        );
    }

    #[test]
    fn plain_feed_field_fields_in_any_order_and_unknown_fields_kept() {
        let r = StatusReport::parse("<Idle|F:0|MPos:0.000,0.000,0.000|Foo:1>").unwrap();
        assert_eq!(r.feed, Some(0.0));
        assert_eq!(r.spindle, None);
        assert_eq!(r.other, vec!["Foo:1".to_string()]);
        assert_eq!(r.machine_position(None), Some(vec![0.0; 3]));
        let w = StatusReport::parse("<Run|WPos:1.000,1.000,1.000>").unwrap();
        assert_eq!(w.machine_position(None), None);
        assert_eq!(
            w.machine_position(Some(&[1.0, 2.0, 3.0])),
            Some(vec![2.0, 3.0, 4.0])
        );
    }

    #[test]
    fn rejects_malformed_reports() {
        for bad in [
            "<Idle>",
            "<Idle|MPos:1,x,0>",
            "<Dancing|MPos:0,0,0>",
            "Idle|MPos:0,0,0",
            "<Idle|MPos:0,0,0|Bf:1>",
            "<Idle|MPos:0,0,0|Ov:1,2>",
            "<Hold:x|MPos:0,0,0>",
        ] {
            assert!(StatusReport::parse(bad).is_err(), "{bad} accepted");
        }
    }
}
