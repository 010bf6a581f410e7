//! Opening a conveyor cutter's controllers (source C): the conveyor's and one per knife
//! head, GRBL controllers on serial ports, or the emulated cutter on pseudo-terminals
//! (`emulators::cutter::CutterPty`, kept alive as long as the links). Every link is
//! opened through the drivers' factory; a head that cannot run streamed programs is
//! refused before anything moves.

use crate::error::OpenError;
use drivers::grbl::GrblOptions;
use drivers::{DriverError, Stage, StageLink};
use emulators::cutter::CutterPty;
use std::time::Duration;
use world::cutter::{CutLog, CutterGeometry};

/// A cutter's controllers, open.
pub struct Cutter {
    /// The conveyor's controller (its X axis feeds the material).
    pub conveyor: Box<dyn Stage>,
    /// One controller per head, head 0 first; each runs streamed programs.
    pub heads: Vec<Box<dyn Stage>>,
    /// The emulated cutter the links talk to (dropped after them).
    emulator: Option<CutterPty>,
}

impl Cutter {
    /// Everything the emulated cutter cut so far; None on real controllers.
    pub fn log(&self) -> Option<CutLog> {
        self.emulator.as_ref().map(CutterPty::log)
    }
}

/// Opens the conveyor's and every head's GRBL controller (`baud`, `options` for all).
/// Call from inside the tokio runtime that will run the cut.
pub async fn open_cutter(
    conveyor: &str,
    heads: &[String],
    baud: u32,
    options: &GrblOptions,
) -> Result<Cutter, OpenError> {
    let link = |port: &str| StageLink::Grbl {
        port: port.to_string(),
        baud,
        options: options.clone(),
    };
    let conveyor = drivers::open_stage(&link(conveyor)).await?;
    let mut opened = Vec::with_capacity(heads.len());
    for (k, port) in heads.iter().enumerate() {
        let head = drivers::open_stage(&link(port)).await?;
        if !head.capabilities().program_streaming {
            return Err(OpenError::Driver(DriverError::Unsupported {
                device: head.info().name.clone(),
                message: format!(
                    "head {k} does not run streamed programs (capability `program_streaming` \
                     is false); a head cuts its groups as programs"
                ),
            }));
        }
        opened.push(head);
    }
    Ok(Cutter {
        conveyor,
        heads: opened,
        emulator: None,
    })
}

/// Starts the emulated cutter of `geometry` on pseudo-terminals and opens its
/// controllers (status polled every 2 ms: the emulated motion ends as soon as it is
/// asked about). Call from inside the tokio runtime that will run the cut.
pub async fn open_emulated_cutter(geometry: &CutterGeometry) -> Result<Cutter, OpenError> {
    let emulator = CutterPty::spawn(geometry).map_err(|e| OpenError::Emulator {
        what: "emulated cutter",
        message: format!("cannot create its pseudo-terminals: {e}"),
    })?;
    let options = GrblOptions {
        poll_interval: Duration::from_millis(2),
        ..GrblOptions::default()
    };
    let cutter = open_cutter(
        emulator.conveyor.path(),
        &emulator.head_paths(),
        115_200,
        &options,
    )
    .await?;
    Ok(Cutter {
        emulator: Some(emulator),
        ..cutter
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use world::cutter::HeadGeometry;

    #[test]
    fn the_emulated_cutter_opens_a_conveyor_and_streaming_heads() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let geometry = CutterGeometry {
                window_mm: 500.0,
                heads: vec![
                    HeadGeometry {
                        origin_y_mm: 0.0,
                        reach_y_mm: 800.0,
                    },
                    HeadGeometry {
                        origin_y_mm: 800.0,
                        reach_y_mm: 800.0,
                    },
                ],
                conveyor_min_mm: 0.0,
                conveyor_max_mm: 1000.0,
            };
            let cutter = open_emulated_cutter(&geometry).await.unwrap();
            assert_eq!(cutter.heads.len(), 2);
            assert!(cutter
                .heads
                .iter()
                .all(|h| h.capabilities().program_streaming));
            assert!(cutter.conveyor.info().name.starts_with("GRBL"));
            assert_eq!(cutter.log().map(|l| l.strokes.len()), Some(0));
        });
    }

    #[test]
    fn a_missing_port_is_a_driver_error() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let e = rt
            .block_on(open_cutter(
                "/dev/does-not-exist-conveyor",
                &[],
                115_200,
                &GrblOptions::default(),
            ))
            .err()
            .expect("refused");
        assert!(
            e.to_string().contains("/dev/does-not-exist-conveyor"),
            "{e}"
        );
    }
}
