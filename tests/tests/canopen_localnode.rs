//! The gateway's CANopen master against an independent slave: a python `canopen`
//! LocalNode (built from the same EDS) on python-can's `slcan` interface, both plugged
//! into an emulated bus with two SLCAN adapters on pseudo-terminals. Expedited and
//! segmented SDO, abort codes from another implementation, heartbeat supervision (and
//! its loss), EMCY. Fails, naming the missing peer and the install step
//! (`tests/install-peers.sh`), when python3 or the packages are missing.

use crate::canopen_common;

use canopen_common::runtime;
use drivers::can::slcan::SlcanBus;
use drivers::canopen::Network;
use drivers::DriverError;
use emulators::canopen::SlcanHub;
use protocol::canopen::NodeId;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;
use system_tests::{python_missing, Kill};

#[test]
fn our_master_talks_to_a_python_canopen_local_node() {
    if let Some(why) = python_missing("canopen, can, serial", "canopen python-can pyserial") {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
    let ws = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    runtime().block_on(async {
        let hub = SlcanHub::spawn(2).unwrap();
        let child = Command::new("python3")
            .arg(ws.join("tests/interop/canopen_localnode.py"))
            .arg(&hub.paths()[1])
            .arg(ws.join("config/canopen/drive.eds"))
            .arg("5")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start the python node");
        let mut child = Kill(child);
        let stdout = child.0.stdout.take().unwrap();
        // The python side prints `ready` once it serves (bounded by its own start-up).
        let ready = tokio::task::spawn_blocking(move || {
            let mut line = String::new();
            BufReader::new(stdout).read_line(&mut line).map(|_| line)
        });
        let line = tokio::time::timeout(Duration::from_secs(20), ready)
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        assert_eq!(line.trim(), "ready");

        let bus = SlcanBus::open(&hub.paths()[0], 1_000_000).await.unwrap();
        let net = Network::start(Box::new(bus), Duration::from_millis(1000));
        let node = NodeId::new(5).unwrap();
        // Expedited and segmented uploads from another SDO server.
        let dt = net.sdo_read(node, 0x1000, 0).await.unwrap();
        assert_eq!(dt, 0x0002_0192u32.to_le_bytes());
        let name = net.sdo_read(node, 0x1008, 0).await.unwrap();
        assert_eq!(name, b"CiA 402 drive emulator");
        net.sdo_write(node, 0x607A, 0, &(-1234i32).to_le_bytes())
            .await
            .unwrap();
        assert_eq!(
            net.sdo_read(node, 0x607A, 0).await.unwrap(),
            (-1234i32).to_le_bytes()
        );
        // Its abort codes arrive as typed refusals.
        let e = net.sdo_read(node, 0x2000, 0).await.unwrap_err();
        assert!(
            matches!(
                e,
                DriverError::Refused {
                    code: 0x0602_0000,
                    ..
                }
            ),
            "{e}"
        );
        let e = net
            .sdo_write(node, 0x1000, 0, &[0, 0, 0, 0])
            .await
            .unwrap_err();
        assert!(
            matches!(
                e,
                DriverError::Refused {
                    code: 0x0601_0002,
                    ..
                }
            ),
            "{e}"
        );
        // Heartbeat: started by writing 0x1017, supervised, then stopped: a loss.
        net.sdo_write(node, 0x1017, 0, &50u16.to_le_bytes())
            .await
            .unwrap();
        net.watch_heartbeat(node, Duration::from_millis(400))
            .unwrap();
        let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
        let heard = net.wait_for(node, deadline, |v| v.nmt).await.unwrap();
        assert!(heard.is_some(), "no heartbeat from the python node");
        // EMCY from its producer.
        net.sdo_write(node, 0x6040, 0, &0xEEEEu16.to_le_bytes())
            .await
            .unwrap();
        let emcy = net
            .wait_for(node, deadline, |v| v.emcy.back().copied())
            .await
            .unwrap()
            .expect("an EMCY");
        assert_eq!((emcy.code, emcy.register), (0x8611, 0x21));
        assert!(net.lost_nodes().is_empty());
        net.sdo_write(node, 0x1017, 0, &0u16.to_le_bytes())
            .await
            .unwrap();
        let none = net
            .wait_for_or_loss(node, deadline, |_| None::<()>)
            .await
            .unwrap();
        assert!(none.is_none());
        let lost = net.lost_nodes();
        assert_eq!(lost.len(), 1, "the silent node is reported");
        assert_eq!(lost[0].0, 5);
        drop(child.0.stdin.take());
    });
}
