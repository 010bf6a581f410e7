//! The 5-axis rotary machine behind the GRBL emulator on a real pseudo-terminal, driven
//! by the GRBL driver: six axes found from `$$` and the status reports, rotary
//! capabilities, probing moves onto the simulated balls through the link.

mod grbl_common;

use drivers::{Axis, AxisValues, DriverError, ProbeMode, Stage};
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use grbl_common::{connect, runtime};
use world::axes::AxesMachine;
use world::rotary::{RotaryMachineSim, RotaryWorkpiece, TouchProbe};

fn noiseless() -> RotaryMachineSim {
    let mut s = RotaryMachineSim::paper(3);
    s.probe = TouchProbe {
        noise_mm: 0.0,
        ..TouchProbe::default()
    };
    s
}

fn five_axis_emulator() -> GrblPty {
    let m = AxesMachine::new(Box::new(RotaryWorkpiece { sim: noiseless() })).shared();
    GrblPty::spawn(GrblDevice::with_axes(m, GrblConfig::default()), None).expect("pty")
}

const TOWARD: ProbeMode = ProbeMode {
    toward: true,
    must_trigger: true,
};

#[test]
fn the_driver_finds_six_axes_and_probes_a_ball_through_the_pty() {
    runtime().block_on(async {
        let pty = five_axis_emulator();
        let mut stage = connect(pty.path()).await;
        let axes: Vec<Axis> = stage.info().axes.iter().map(|a| a.axis).collect();
        assert_eq!(axes, Axis::ALL.to_vec());
        assert_eq!(
            stage.capabilities().rotary_axes,
            vec![Axis::A, Axis::B, Axis::C]
        );
        assert!(stage.capabilities().probing);

        // Above the 26 mm ball at A 15, C 30, then straight down onto its top.
        let truth = noiseless();
        let (a, c) = (15.0, 30.0);
        let centre = truth.ball_centre(0, a, c);
        let l = truth.geometry.tool_length_mm;
        let above = AxisValues::default()
            .with(Axis::X, centre.x)
            .with(Axis::Y, centre.y)
            .with(Axis::Z, centre.z + l + 25.0)
            .with(Axis::A, a)
            .with(Axis::C, c);
        stage.move_to(above, 2000.0).await.unwrap();
        stage.wait_idle().await.unwrap();
        let p = stage.position().await.unwrap();
        assert_eq!((p.get(Axis::A), p.get(Axis::C)), (Some(15.0), Some(30.0)));
        let down = AxisValues::default().with(Axis::Z, centre.z + l);
        let hit = stage.probe(down, 100.0, TOWARD).await.unwrap();
        assert!(hit.touched);
        // The stylus (radius 1.5) meets the ball (radius 13) on top of the centre; the
        // trigger comes 0.8 um later; the report has 1 um steps.
        let z = hit.position.get(Axis::Z).unwrap();
        let expected = centre.z + 13.0 + 1.5 + l - 0.0008;
        assert!((z - expected).abs() <= 0.0006, "{z} vs {expected}");
        assert_eq!(hit.position.get(Axis::C), Some(30.0));

        // Beside the ball nothing is touched: G38.2 ends in ALARM:5, an error.
        stage
            .move_to(
                AxisValues::default().with(Axis::Z, centre.z + l + 25.0),
                2000.0,
            )
            .await
            .unwrap();
        stage
            .move_to(AxisValues::default().with(Axis::X, centre.x + 40.0), 2000.0)
            .await
            .unwrap();
        stage.wait_idle().await.unwrap();
        let miss = stage.probe(down, 100.0, TOWARD).await;
        assert!(
            matches!(miss, Err(DriverError::Alarm { ref code, .. }) if *code == 5),
            "{miss:?}"
        );
    });
}
