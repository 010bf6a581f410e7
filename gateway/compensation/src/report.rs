//! The job report: per-target results and summary statistics, as text or JSON.
//!
//! Errors are magnitudes of the 2-D error vector, in micrometres. "Truth" figures exist
//! only when the machine is simulated (the simulator knows where the camera really was);
//! "estimate" figures are the gateway's own measurements, available on any machine.

use crate::session::{OrientationResult, TargetOutcome};
use serde::Serialize;
use vision::localize::Method;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Stats {
    pub max: f64,
    pub rms: f64,
    pub mean: f64,
}

impl Stats {
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let v: Vec<f64> = values.into_iter().collect();
        if v.is_empty() {
            return None;
        }
        let n = v.len() as f64;
        Some(Stats {
            max: v.iter().copied().fold(0.0, f64::max),
            rms: (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
            mean: v.iter().sum::<f64>() / n,
        })
    }
}

fn norm(v: [f64; 2]) -> f64 {
    v[0].hypot(v[1])
}

/// Truth errors (um) at a target's first and last measurement, when known.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct TruthAt {
    pub before_um: [f64; 2],
    pub after_um: [f64; 2],
}

#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct TargetRow {
    pub index: usize,
    pub target_mm: [f64; 2],
    pub final_command_mm: [f64; 2],
    pub corrections: usize,
    pub converged: bool,
    /// The job stopped while working on this target: its measurements so far, not a
    /// finished result (left out of the statistics).
    pub stopped: bool,
    /// The gateway's measured deviation D before and after, um.
    pub estimate_before_um: [f64; 2],
    pub estimate_after_um: [f64; 2],
    pub points: usize,
    pub residual_rms_um: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<TruthAt>,
}

#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct Iterations {
    pub mean: f64,
    pub max: usize,
}

#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct Report {
    pub job: String,
    pub stage: String,
    pub camera: String,
    pub method: Method,
    /// What the orientation check at the start measured (when it ran).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub orientation: Option<OrientationResult>,
    /// Targets finished (converged or out of iterations).
    pub targets: usize,
    pub targets_planned: usize,
    pub converged: usize,
    /// Error against the truth (simulated machines only), um.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub before_um: Option<Stats>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub after_um: Option<Stats>,
    /// The gateway's own measured |D|, um.
    pub estimate_before_um: Option<Stats>,
    pub estimate_after_um: Option<Stats>,
    pub iterations: Iterations,
    pub wall_time_s: f64,
    /// Set when the job stopped early; the rows above are what was done before.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    pub per_target: Vec<TargetRow>,
    /// Lost references found on a coded board (lost steps, no homing), in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rereferences: Vec<crate::session::Rereference>,
}

impl Report {
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        job: &str,
        stage: &str,
        camera: &str,
        method: Method,
        targets_planned: usize,
        outcomes: &[TargetOutcome],
        truth: &[Option<TruthAt>],
        wall_time_s: f64,
        error: Option<String>,
    ) -> Self {
        let rows: Vec<TargetRow> = outcomes
            .iter()
            .enumerate()
            .map(|(k, o)| TargetRow {
                index: o.index,
                target_mm: o.target_mm,
                final_command_mm: o.last().command_mm,
                corrections: o.corrections(),
                converged: o.converged,
                stopped: o.stopped,
                estimate_before_um: o.first().deviation.um(),
                estimate_after_um: o.last().deviation.um(),
                points: o.last().observation.points,
                residual_rms_um: o.last().observation.residual_rms_um,
                truth: truth.get(k).copied().flatten(),
            })
            .collect();
        let finished: Vec<&TargetRow> = rows.iter().filter(|r| !r.stopped).collect();
        let all_truth = !finished.is_empty() && finished.iter().all(|r| r.truth.is_some());
        let truth_stats = |f: fn(&TruthAt) -> [f64; 2]| {
            all_truth
                .then(|| Stats::of(finished.iter().map(|r| norm(f(r.truth.as_ref().unwrap())))))
                .flatten()
        };
        Report {
            job: job.to_string(),
            stage: stage.to_string(),
            camera: camera.to_string(),
            method,
            orientation: None,
            targets: finished.len(),
            targets_planned,
            converged: finished.iter().filter(|r| r.converged).count(),
            before_um: truth_stats(|t| t.before_um),
            after_um: truth_stats(|t| t.after_um),
            estimate_before_um: Stats::of(finished.iter().map(|r| norm(r.estimate_before_um))),
            estimate_after_um: Stats::of(finished.iter().map(|r| norm(r.estimate_after_um))),
            iterations: Iterations {
                mean: if finished.is_empty() {
                    0.0
                } else {
                    finished.iter().map(|r| r.corrections as f64).sum::<f64>()
                        / finished.len() as f64
                },
                max: finished.iter().map(|r| r.corrections).max().unwrap_or(0),
            },
            wall_time_s,
            error,
            per_target: rows,
            rereferences: Vec::new(),
        }
    }

    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let f = |st: &Option<Stats>| match st {
            Some(v) => format!("max {:7.3} um   rms {:7.3} um", v.max, v.rms),
            None => "n/a".to_string(),
        };
        s.push_str(&format!(
            "job:     {}\nstage:   {}\ncamera:  {}\nmethod:  {:?}\n\n",
            self.job, self.stage, self.camera, self.method
        ));
        let has_truth = self.per_target.iter().any(|r| r.truth.is_some());
        s.push_str(
            "  #   target X    target Y   corr  gateway D before (um)  gateway D after (um)",
        );
        if has_truth {
            s.push_str("   true err before   true err after");
        }
        s.push('\n');
        for r in &self.per_target {
            s.push_str(&format!(
                "{:3}  {:9.3}  {:9.3}   {:3}{}  {:9.3} {:9.3}    {:8.3} {:8.3}",
                r.index,
                r.target_mm[0],
                r.target_mm[1],
                r.corrections,
                if r.stopped {
                    "x"
                } else if r.converged {
                    " "
                } else {
                    "!"
                },
                r.estimate_before_um[0],
                r.estimate_before_um[1],
                r.estimate_after_um[0],
                r.estimate_after_um[1],
            ));
            if let Some(t) = &r.truth {
                s.push_str(&format!(
                    "    {:9.3} um    {:9.3} um",
                    norm(t.before_um),
                    norm(t.after_um)
                ));
            }
            s.push('\n');
        }
        s.push_str(&format!(
            "\ntargets: {} of {} ({} within tolerance)\n",
            self.targets, self.targets_planned, self.converged
        ));
        for r in &self.rereferences {
            s.push_str(&format!(
                "re-referenced at target #{}: the tool was found ({:+.4}, {:+.4}) mm from the target (deviation, seen minus target: lost steps or no homing, read from the coded board); commands offset by ({:+.4}, {:+.4}) mm from then on\n",
                r.target_index,
                r.deviation_mm[0],
                r.deviation_mm[1],
                r.offset_mm[0],
                r.offset_mm[1]
            ));
        }
        if self.per_target.iter().any(|r| r.stopped) {
            s.push_str("(x: the job stopped on this target; its measurements so far are shown and left out of the figures below)\n");
        }
        if let Some(o) = &self.orientation {
            s.push_str(&format!("orientation check: {o}\n"));
        }
        if has_truth {
            s.push_str(&format!(
                "error vs truth, before compensation: {}\n",
                f(&self.before_um)
            ));
            s.push_str(&format!(
                "error vs truth, after compensation:  {}\n",
                f(&self.after_um)
            ));
        }
        s.push_str(&format!(
            "gateway's own estimate, before:      {}\n",
            f(&self.estimate_before_um)
        ));
        s.push_str(&format!(
            "gateway's own estimate, after:       {}\n",
            f(&self.estimate_after_um)
        ));
        s.push_str(&format!(
            "corrective moves per target: mean {:.2}, max {}\nwall time: {:.2} s\n",
            self.iterations.mean, self.iterations.max, self.wall_time_s
        ));
        if let Some(e) = &self.error {
            s.push_str(&format!("\nSTOPPED: {e}\n"));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_are_max_rms_mean() {
        let s = Stats::of([3.0, 4.0]).unwrap();
        assert_eq!(s.max, 4.0);
        assert!((s.rms - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(s.mean, 3.5);
        assert!(Stats::of([]).is_none());
    }

    /// Issue 38: the text said "the machine was -3.2011 mm, 1.6922 mm off" for a
    /// `deviation_mm` of (3.2011, -1.6922): the text now shows the JSON's numbers.
    #[test]
    fn a_rereference_reads_with_the_sign_of_its_deviation() {
        let mut r = Report::build("j", "s", "c", Method::default(), 0, &[], &[], 0.0, None);
        r.rereferences.push(crate::session::Rereference {
            target_index: 0,
            deviation_mm: [3.2011, -1.6922],
            offset_mm: [-3.2011, 1.6922],
        });
        let text = r.to_text();
        assert!(
            text.contains("found (+3.2011, -1.6922) mm from the target")
                && text.contains("offset by (-3.2011, +1.6922) mm"),
            "{text}"
        );
    }
}
