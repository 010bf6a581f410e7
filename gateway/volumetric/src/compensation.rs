//! The volumetric model as a compensation for the program rewriter: X, Y and Z commands
//! from the inverse model (no backlash in this model: the approach side is ignored).

use crate::Model;
use rewrite::{Approach, Compensation, Pose, N_AXIS};

impl Compensation for Model {
    fn describe(&self) -> String {
        format!("volumetric model ({}, 21 errors)", self.file.structure)
    }

    fn axes(&self) -> &[usize] {
        &[0, 1, 2]
    }

    /// The closest row spacing of the three tables.
    fn feature_length_mm(&self) -> f64 {
        self.file
            .tables
            .iter()
            .flat_map(|t| t.positions_mm.windows(2).map(|w| w[1] - w[0]))
            .fold(f64::INFINITY, f64::min)
    }

    fn command_for(&self, nominal: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Model::command_for(self, *nominal).map_err(|e| e.to_string())
    }

    fn command_near(
        &self,
        nominal: &Pose,
        _: &[Approach; N_AXIS],
        guess: &Pose,
    ) -> Result<Pose, String> {
        self.command_from(*nominal, *guess)
            .map_err(|e| e.to_string())
    }

    fn tool_for(&self, command: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        let e = self.error_exact(*command).map_err(|e| e.to_string())?;
        Ok(std::array::from_fn(|k| command[k] + e[k]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::realistic;
    use protocol::volumetric::Structure;

    #[test]
    fn rewriter_view_inverts_and_refuses() {
        let m = realistic(Structure::Xyfz);
        let c: &dyn Compensation = &m;
        let dir = [Approach::Forward; N_AXIS];
        let target = [100.0, 200.0, 300.0];
        let cmd = c.command_for(&target, &dir).unwrap();
        let tool = c.tool_for(&cmd, &dir).unwrap();
        for k in 0..3 {
            assert!((tool[k] - target[k]).abs() < 1e-9);
        }
        assert!((c.feature_length_mm() - 10.0).abs() < 1e-9);
        let e = c.command_for(&[600.0, 0.0, 0.0], &dir).unwrap_err();
        assert!(e.contains("outside the measured travel"), "{e}");
    }
}
