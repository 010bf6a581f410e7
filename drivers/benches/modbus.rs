//! Modbus transactions per second and latency percentiles through the Modbus driver's
//! bus (tokio-modbus with deadlines) against the drive emulator: TCP on the loopback
//! interface with one and with several connections, RTU on a real pseudo-terminal
//! (with the serial line's 1.75 ms silent interval, and without); then pymodbus doing
//! the same work against the same emulator, for the ratio.
//!
//! The work: read the generic profile's status, position and alarm code (function 4,
//! 4 registers at 0x0020) of unit 1, one request after the other per connection.
//!
//! Run: `cargo bench -p drivers --bench modbus` (pymodbus figures need python3 with
//! pymodbus; skipped with a note otherwise).

use drivers::modbus::{Endpoint, ModbusBus, ModbusOptions, Op, Parity};
use emulators::modbus::{DriveSet, MachineAxis, ModbusDevice, ModbusRtu, ModbusTcp};
use protocol::modbus::DriveProfile;
use protocol::Board;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};
use world::camera::CameraModel;
use world::machine::MachineConfig;
use world::Clock;

const N: usize = 4000;
const CONNECTIONS: usize = 4;

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() as f64 - 1.0) * p).round() as usize]
}

struct Figures {
    tx_per_s: f64,
    p50_us: f64,
    p90_us: f64,
    p99_us: f64,
}

fn figures(mut lat_us: Vec<f64>, wall: Duration) -> Figures {
    lat_us.sort_by(f64::total_cmp);
    Figures {
        tx_per_s: lat_us.len() as f64 / wall.as_secs_f64(),
        p50_us: percentile(&lat_us, 0.5),
        p90_us: percentile(&lat_us, 0.9),
        p99_us: percentile(&lat_us, 0.99),
    }
}

fn print(name: &str, f: &Figures) {
    println!(
        "{name:<34} {:>9.0} tx/s   p50 {:>7.1} us   p90 {:>7.1} us   p99 {:>7.1} us",
        f.tx_per_s, f.p50_us, f.p90_us, f.p99_us
    );
}

async fn run(endpoint: Endpoint, opts: ModbusOptions, n: usize) -> Vec<f64> {
    let mut bus = ModbusBus::new(endpoint, opts);
    let op = Op::ReadInput(0x0020, 4);
    let mut lat = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        let v = bus.call(1, &op, "bench", "read status").await.unwrap();
        lat.push(t.elapsed().as_secs_f64() * 1e6);
        assert_eq!(v.len(), 4);
    }
    assert_eq!(bus.stats().retries, 0);
    lat
}

fn pymodbus(args: &[&str]) -> Option<serde_like::Figures> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/modbus_pymodbus.py");
    let out = Command::new("python3")
        .arg(script)
        .args(args)
        .output()
        .ok()?;
    if !out.status.success() {
        eprintln!(
            "pymodbus run failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        return None;
    }
    serde_like::parse(&String::from_utf8_lossy(&out.stdout))
}

/// The Python script prints `tx_per_s p50_us p90_us p99_us` (no JSON crate needed).
mod serde_like {
    pub struct Figures(pub super::Figures);
    pub fn parse(s: &str) -> Option<Figures> {
        let v: Vec<f64> = s
            .split_whitespace()
            .filter_map(|t| t.parse().ok())
            .collect();
        (v.len() == 4).then(|| {
            Figures(super::Figures {
                tx_per_s: v[0],
                p50_us: v[1],
                p90_us: v[2],
                p99_us: v[3],
            })
        })
    }
}

fn main() {
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
    let m = MachineConfig::load(&cfg.join("machines/c5-stage.toml")).unwrap();
    let c = CameraModel::load(&cfg.join("cameras/mono-1.3mp.toml")).unwrap();
    let b = Board::load(&cfg.join("boards/dot-grid-0.5mm.toml")).unwrap();
    let rig = world::shared_rig(m, b, c);
    let profile = Arc::new(DriveProfile::load(&cfg.join("drives/generic.toml")).unwrap());
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let set = DriveSet::new(rig, profile, &[(1, MachineAxis::X), (2, MachineAxis::Y)], Clock::Unconstrained);
        let dev = ModbusDevice::new(set);
        let tcp = ModbusTcp::bind(dev.clone(), "127.0.0.1:0".parse().unwrap()).await.unwrap();
        let rtu = ModbusRtu::spawn(dev.clone(), None).unwrap();
        let opts = ModbusOptions { timeout: Duration::from_secs(2), ..Default::default() };
        let addr = tcp.local_addr();
        println!("Modbus read of 4 input registers (unit 1), {N} transactions per connection; 2-core machine");

        // Warm-up.
        run(Endpoint::Tcp(addr), opts.clone(), 200).await;

        let t = Instant::now();
        let tcp1 = figures(run(Endpoint::Tcp(addr), opts.clone(), N).await, t.elapsed());
        print("ours, TCP, 1 connection", &tcp1);

        let t = Instant::now();
        let tasks: Vec<_> =
            (0..CONNECTIONS).map(|_| tokio::spawn(run(Endpoint::Tcp(addr), opts.clone(), N))).collect();
        let mut all = Vec::new();
        for h in tasks {
            all.extend(h.await.unwrap());
        }
        let tcpn = figures(all, t.elapsed());
        print(&format!("ours, TCP, {CONNECTIONS} connections"), &tcpn);

        let rtu_ep = Endpoint::Rtu { path: rtu.path().to_string(), baud: 115_200, parity: Parity::None };
        let n_rtu = N / 2;
        let t = Instant::now();
        let rtu_std = figures(run(rtu_ep.clone(), opts.clone(), n_rtu).await, t.elapsed());
        print("ours, RTU pty, 1.75 ms gap", &rtu_std);
        let no_gap = ModbusOptions { rtu_gap: Some(Duration::ZERO), ..opts.clone() };
        let t = Instant::now();
        let rtu_fast = figures(run(rtu_ep.clone(), no_gap, n_rtu).await, t.elapsed());
        print("ours, RTU pty, no gap", &rtu_fast);

        // pymodbus, same work, same emulator (run while this runtime serves it).
        let addr_s = addr.to_string();
        let path = rtu.path().to_string();
        let py = tokio::task::spawn_blocking(move || {
            let n = N.to_string();
            let nr = (N / 2).to_string();
            let c = CONNECTIONS.to_string();
            (
                pymodbus(&["--tcp", &addr_s, "-n", &n, "--connections", "1"]),
                pymodbus(&["--tcp", &addr_s, "-n", &n, "--connections", &c]),
                pymodbus(&["--rtu", &path, "-n", &nr]),
            )
        })
        .await
        .unwrap();
        match py {
            (Some(a), Some(b), Some(r)) => {
                print("pymodbus, TCP, 1 connection", &a.0);
                print(&format!("pymodbus, TCP, {CONNECTIONS} connections"), &b.0);
                print("pymodbus, RTU pty (no gap)", &r.0);
                println!(
                    "ratio ours/pymodbus (tx/s): TCP 1 connection {:.1}x, TCP {CONNECTIONS} connections {:.1}x, RTU pty {:.1}x (ours without gap)",
                    tcp1.tx_per_s / a.0.tx_per_s,
                    tcpn.tx_per_s / b.0.tx_per_s,
                    rtu_fast.tx_per_s / r.0.tx_per_s
                );
            }
            _ => println!("pymodbus figures skipped: python3 with pymodbus is needed (python3 -m pip install pymodbus pyserial)"),
        }
        println!("emulator: {:?}", dev.stats().requests);
    });
}
