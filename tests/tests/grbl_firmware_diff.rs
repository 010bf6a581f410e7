//! Differential tests: the same bytes through real GRBL 1.1h (grbl-sim, built from
//! `../shared/peers` by `tests/firmware/build.sh`) and through our GRBL emulator.

use std::time::Duration;
use system_tests::firmware::Firmware;

const LIMIT: Duration = Duration::from_secs(20);

#[test]
fn real_grbl_first_power_up_prints_error_7_the_settings_and_the_banner() {
    let fw = Firmware::Grbl11h.start().unwrap_or_else(|e| panic!("{e}"));
    let mut c = fw.open().unwrap_or_else(|e| panic!("{e}"));
    let boot = c
        .read_through_line(LIMIT, |l| l.starts_with("Grbl 1.1h"))
        .unwrap();
    assert!(boot.starts_with("error:7\r\n$0=10\r\n"), "{boot}");
    c.send(b"$I\n");
    let i = c.read_through_line(LIMIT, |l| l == "ok").unwrap();
    assert_eq!(i, "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n");
}
