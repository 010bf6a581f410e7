//! The CANopen driver and the drive emulator on a Linux SocketCAN interface (vcan0, or
//! another name with CANOPEN_VCAN=name; `tests/install-peers.sh` brings vcan0 up where
//! the kernel can: `modprobe vcan; ip link add vcan0 type vcan; ip link set vcan0 up`).
//! Where the kernel has CAN support but the interface is not up, the test fails naming
//! the set-up step. Only a kernel without CAN support at all (no AF_CAN sockets: many
//! containers and CI kernels) cannot run the exchange: the test then checks that opening
//! the interface fails with the clear `NotAvailable` error naming the missing kernel
//! support, and says so, since no install step can help. Opening a missing
//! interface is checked everywhere: it is `NotAvailable` with the reason, never a panic
//! or a hang.

use crate::canopen_common;

use canopen_common::*;
use drivers::can::socketcan::{unavailable, SocketCanBus};
use drivers::can::{open_bus, BusSpec};
use drivers::canopen::open_stage;
use drivers::{AxisValues, DriverError, Stage};
use emulators::canopen::socketcan::SocketCanPort;
use emulators::canopen::{DriveSet, DriveSetConfig};
use std::sync::{Arc, Mutex};
use world::Clock;

fn interface() -> String {
    std::env::var("CANOPEN_VCAN").unwrap_or_else(|_| "vcan0".into())
}

#[test]
fn a_missing_interface_is_not_available_with_the_reason() {
    let e = runtime()
        .block_on(open_bus(&BusSpec::SocketCan {
            interface: "nocan9".into(),
        }))
        .err()
        .expect("no interface nocan9");
    match &e {
        DriverError::NotAvailable { backend, reason } => {
            assert_eq!(backend, "socketcan nocan9");
            assert!(
                reason.contains("the kernel has no CAN support")
                    || reason.contains("no CAN interface `nocan9`"),
                "{reason}"
            );
        }
        other => panic!("{other}"),
    }
}

#[test]
fn driver_and_emulated_drives_on_a_vcan_interface() {
    let iface = interface();
    if let Some(why) = unavailable(&iface) {
        if why.starts_with("the kernel has no CAN support") {
            // Nothing to install: this kernel cannot have a CAN interface. What runs here
            // is the backend's answer on such a kernel: a clear error, not a hang.
            let e = runtime()
                .block_on(open_bus(&BusSpec::SocketCan {
                    interface: iface.clone(),
                }))
                .err()
                .expect("a kernel without CAN cannot open a SocketCAN bus");
            assert!(
                matches!(&e, DriverError::NotAvailable { reason, .. }
                    if reason.contains("the kernel has no CAN support")),
                "{e}"
            );
            eprintln!(
                "this kernel has no CAN support, so the drive exchange over {iface} cannot run \
                 here (CAN runs over SLCAN on a pseudo-terminal: canopen_driver.rs); checked \
                 instead: opening {iface} fails with `{e}`"
            );
            return;
        }
        panic!(
            "SocketCAN interface {iface}: {why}; bring it up with tests/install-peers.sh as root \
             (modprobe vcan; ip link add {iface} type vcan; ip link set {iface} up), \
             or name another with CANOPEN_VCAN"
        );
    }
    let rig = rig();
    runtime().block_on(async {
        let set = DriveSet::new(
            rig.clone(),
            &DriveSetConfig::xy(X_NODE, Y_NODE, Clock::Unconstrained),
            0.0,
        )
        .unwrap();
        let _emu = SocketCanPort::spawn(Arc::new(Mutex::new(set)), &iface)
            .expect("emulator on the interface");
        let bus = SocketCanBus::open(&iface).unwrap();
        let (mut stage, net) = open_stage(Box::new(bus), axes(), options()).await.unwrap();
        assert!(
            stage.info().name.contains(&format!("socketcan {iface}")),
            "{}",
            stage.info().name
        );
        stage.home().await.unwrap();
        stage
            .move_to(AxisValues::xy(33.0, 44.5), 3000.0)
            .await
            .unwrap();
        stage.wait_idle().await.unwrap();
        assert_eq!(
            stage.position().await.unwrap().to_xy().unwrap(),
            [33.0, 44.5]
        );
        assert_eq!(rig.lock().unwrap().machine().counts(), [66_000, 89_000]);
        let e = net
            .sdo_read(protocol::canopen::NodeId::new(1).unwrap(), 0x2000, 0)
            .await
            .unwrap_err();
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
    });
}
