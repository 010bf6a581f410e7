//! A G-code sender on the pass-through's port, as the operator's sender would be: the
//! tests of the `proxy` kind (both front ends, the page) run one session through it.

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialPortBuilderExt;

/// One session: the alarm of a fresh start unlocked (`$X`), then two lines, each batch
/// sent once the one before is answered; every answer `ok`. The sender then leaves (a
/// pass-through with `once` ends).
pub async fn unlock_and_move(port: &str) {
    let mut port = tokio_serial::new(port, 115_200)
        .open_native_async()
        .unwrap_or_else(|e| panic!("the sender's port {port:?}: {e}"));
    let mut got = String::new();
    for (lines, answers) in [("$X\n", 1), ("G21 G90\nG1 X20 Y20 F3000\n", 3)] {
        port.write_all(lines.as_bytes()).await.unwrap();
        let mut buf = [0u8; 256];
        while got.lines().filter(|l| l.trim() == "ok").count() < answers {
            let k = port.read(&mut buf).await.expect("read the sender's port");
            assert!(k > 0, "the pass-through closed the port: {got}");
            got.push_str(&String::from_utf8_lossy(&buf[..k]));
            assert!(!got.contains("error:"), "{got}");
        }
    }
}
