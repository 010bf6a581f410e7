//! Machine axes.

use serde::{Deserialize, Serialize};
use std::fmt;

/// Machine axes by their usual letters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Axis {
    X,
    Y,
    Z,
    A,
    B,
    C,
}

impl Axis {
    pub const ALL: [Axis; 6] = [Axis::X, Axis::Y, Axis::Z, Axis::A, Axis::B, Axis::C];

    pub fn index(self) -> usize {
        self as usize
    }

    /// A, B and C turn (degrees); X, Y and Z translate (mm).
    pub fn is_rotary(self) -> bool {
        matches!(self, Axis::A | Axis::B | Axis::C)
    }

    pub fn letter(self) -> char {
        ['X', 'Y', 'Z', 'A', 'B', 'C'][self.index()]
    }
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.letter())
    }
}
