//! CANopen over SLCAN on a real pseudo-terminal: SDO round trips per second, the
//! move-command latency (set-point to acknowledge, through the CiA 402 handshake), and
//! the frame rate the gateway's bus path sustains, compared with the frame capacity of
//! a 1 Mbit/s CAN bus. The drive emulator's motion clock is unconstrained, so the
//! figures measure the protocol path: driver, bus task, SLCAN codec, pty, emulator.
//!
//! Run: `cargo bench -p drivers --bench canopen`

use drivers::can::slcan::SlcanBus;
use drivers::canopen::{open_stage, AxisConfig, CanopenOptions};
use drivers::{Axis, AxisValues, Stage};
use emulators::canopen::{DriveSet, DriveSetConfig, SlcanPty};
use protocol::can::{bus_capacity_frames_per_s, CanFrame};
use protocol::canopen::NodeId;
use protocol::Board;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use world::camera::CameraModel;
use world::machine::MachineConfig;
use world::Clock;

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

fn main() {
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
    let m = MachineConfig::load(&cfg.join("machines/c5-stage.toml")).unwrap();
    let c = CameraModel::load(&cfg.join("cameras/mono-1.3mp.toml")).unwrap();
    let b = Board::load(&cfg.join("boards/dot-grid-0.5mm.toml")).unwrap();
    let rig = world::shared_rig(m, b, c);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let set = DriveSet::new(rig, &DriveSetConfig::xy(1, 2, Clock::Unconstrained), 0.0).unwrap();
        let emu = SlcanPty::spawn(Arc::new(Mutex::new(set)), None).unwrap();
        let axis = |axis, node, travel| AxisConfig {
            axis,
            node,
            counts_per_mm: 2000.0,
            min_mm: 0.0,
            max_mm: travel,
            max_feed_mm_min: 6000.0,
            accel_mm_s2: 800.0,
            homing_method: 17,
        };
        let bus = SlcanBus::open(emu.path(), 1_000_000).await.unwrap();
        let t_up = Instant::now();
        let axes = vec![axis(Axis::X, 1, 200.0), axis(Axis::Y, 2, 150.0)];
        let (mut stage, net) = open_stage(Box::new(bus), axes, CanopenOptions::default()).await.unwrap();
        let bring_up = t_up.elapsed().as_secs_f64();
        stage.home().await.unwrap();
        let node = NodeId::new(1).unwrap();

        // SDO: expedited uploads of the statusword, one after another.
        let n = 3000;
        let t = Instant::now();
        for _ in 0..n {
            net.sdo_read(node, 0x6041, 0).await.unwrap();
        }
        let sdo_s = t.elapsed().as_secs_f64();
        let sdo_rate = n as f64 / sdo_s;
        // Segmented upload (22-byte string: 4 request/response pairs).
        let t = Instant::now();
        for _ in 0..500 {
            net.sdo_read(node, 0x1008, 0).await.unwrap();
        }
        let seg_rate = 500.0 / t.elapsed().as_secs_f64();

        // Move-command latency: move_to (both axes: position from the process image,
        // then per axis RPDO velocity + set-point with bit 4, wait for bit 12, drop
        // bit 4) and wait_idle (TPDO2 with target reached).
        let mut cmd = Vec::new();
        let mut total = Vec::new();
        for i in 0..400 {
            let x = 20.0 + (i % 40) as f64 * 2.5;
            let y = 20.0 + (i / 40) as f64 * 5.0;
            let t = Instant::now();
            stage.move_to(AxisValues::xy(x, y), 3000.0).await.unwrap();
            cmd.push(t.elapsed().as_secs_f64() * 1e3);
            stage.wait_idle().await.unwrap();
            total.push(t.elapsed().as_secs_f64() * 1e3);
        }
        cmd.sort_by(f64::total_cmp);
        total.sort_by(f64::total_cmp);

        // Sustained one-way frame rate: RPDO2 (profile velocity, 4 bytes) to node 2 as
        // fast as the bus task takes them; counted as the emulator receives them.
        let before = emu.adapter_stats().frames_from_host;
        let frames = 40_000u64;
        let f = CanFrame::std(NodeId::new(2).unwrap().rpdo(2), &100_000u32.to_le_bytes());
        let t = Instant::now();
        for _ in 0..frames {
            net.send(f).await.unwrap();
        }
        let deadline = Instant::now() + Duration::from_secs(30);
        while emu.adapter_stats().frames_from_host < before + frames && Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        let blast_s = t.elapsed().as_secs_f64();
        let got = emu.adapter_stats().frames_from_host - before;
        let blast_rate = got as f64 / blast_s;

        let eight = CanFrame::std(0x181, &[0; 8]);
        let best = bus_capacity_frames_per_s(1_000_000, &eight, false);
        let worst = bus_capacity_frames_per_s(1_000_000, &eight, true);
        let sdo_frames = 2.0 * sdo_rate;
        println!("CANopen over SLCAN on a pseudo-terminal (emulated CiA 402 drives, unconstrained motion clock)");
        println!("  bring-up of 2 nodes (NMT, SDO checks, PDO mapping, enable): {:.1} ms", bring_up * 1e3);
        println!("  SDO expedited upload round trips: {sdo_rate:.0} /s ({:.1} us each, {n} in {sdo_s:.2} s)", 1e6 / sdo_rate);
        println!("  SDO segmented upload of 22 bytes (4 round trips): {seg_rate:.0} /s");
        println!(
            "  move command (2 axes, set-point to acknowledge): p50 {:.2} ms, p99 {:.2} ms; to target reached: p50 {:.2} ms, p99 {:.2} ms",
            percentile(&cmd, 0.5),
            percentile(&cmd, 0.99),
            percentile(&total, 0.5),
            percentile(&total, 0.99)
        );
        println!("  one-way frame rate sustained (RPDO, 4 data bytes): {blast_rate:.0} frames/s ({got} frames)");
        println!("  SDO traffic: {sdo_frames:.0} frames/s (request + response)");
        println!(
            "  1 Mbit/s bus capacity for 8-byte standard frames: {worst:.0}..{best:.0} frames/s (111 bits per frame + 0..24 stuff bits)"
        );
        println!(
            "  ratio sustained / bus capacity (worst-case stuffing): one-way {:.1}x, SDO {:.2}x",
            blast_rate / worst,
            sdo_frames / worst
        );
        let st = net.stats();
        println!("  bus stats: {:?}", st.bus);
    });
}
