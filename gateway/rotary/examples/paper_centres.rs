//! Writes the ball centres the paper's table (default constants, the paper's eight
//! errors) would give a perfect measurement, as a centres file on stdout: a sample input
//! for `gateway rotary identify`.
//!
//!     cargo run -p rotary --example paper_centres > centres.csv

use rotary::{
    centres_of, write_centres, Artifact, LocationErrors, MachineConstants, RotaryMachine,
};

fn main() {
    let machine = RotaryMachine::with_errors(MachineConstants::default(), LocationErrors::paper());
    print!(
        "{}",
        write_centres(&centres_of(&machine, &Artifact::default()))
    );
}
