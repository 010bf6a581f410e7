//! The map as a compensation for the program rewriter: X and Y commands from the
//! inverse model, Z passed through (the map is planar).

use crate::{Direction, MapModel};
use rewrite::{Approach, Compensation, Pose, N_AXIS};

impl Compensation for MapModel {
    fn describe(&self) -> String {
        let m = self.map();
        format!(
            "error map v{} of {} ({}), scanned {}",
            m.version, m.identity.machine, m.identity.controller, m.created
        )
    }

    fn axes(&self) -> &[usize] {
        &[0, 1]
    }

    /// The closest node spacing of the grid and the dense lines.
    fn feature_length_mm(&self) -> f64 {
        let m = self.map();
        let spacing = |xs: &[f64]| {
            xs.windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::INFINITY, f64::min)
        };
        let mut f = spacing(&m.grid.xs).min(spacing(&m.grid.ys));
        for line in m.x_lines.iter().chain(&m.y_lines) {
            f = f.min(spacing(&line.positions));
        }
        f
    }

    fn command_for(&self, nominal: &Pose, approach: &[Approach; N_AXIS]) -> Result<Pose, String> {
        self.command_near(nominal, approach, nominal)
    }

    fn command_near(
        &self,
        nominal: &Pose,
        approach: &[Approach; N_AXIS],
        guess: &Pose,
    ) -> Result<Pose, String> {
        let dir = Direction {
            x: approach[0],
            y: approach[1],
        };
        let c = self
            .command_from([nominal[0], nominal[1]], dir, [guess[0], guess[1]])
            .map_err(|e| e.to_string())?;
        let mut out = *nominal;
        out[0] = c[0];
        out[1] = c[1];
        Ok(out)
    }

    fn tool_for(&self, command: &Pose, approach: &[Approach; N_AXIS]) -> Result<Pose, String> {
        let dir = Direction {
            x: approach[0],
            y: approach[1],
        };
        let e = self
            .tool_error_um([command[0], command[1]], dir)
            .map_err(|e| e.to_string())?;
        let mut out = *command;
        out[0] += e[0] / 1000.0;
        out[1] += e[1] / 1000.0;
        Ok(out)
    }
}
