//! Peak memory of `board make`'s writers on the largest board whose certificate can be
//! read back (700 x 700 dots, 0.5 mm pitch): the four files streamed into files beside
//! their names (`protocol::config::write_output_with`), as the command line does.
//!
//! `cargo run -p board-art --example board_make_memory [--release] [COLS ROWS] [--in-memory]`
//! prints the bytes written, the time and the process's peak resident memory (VmHWM);
//! `--in-memory` builds each file whole first, for comparison.

use protocol::{Board, Polarity};

fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

fn main() -> std::io::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let in_memory = args.iter().any(|a| a == "--in-memory");
    let n: Vec<u32> = args.iter().filter_map(|a| a.parse().ok()).collect();
    let (cols, rows) = (*n.first().unwrap_or(&700), *n.get(1).unwrap_or(&700));
    let board = Board::nominal(
        "bench",
        0.5,
        0.25,
        Polarity::DarkOnLight,
        cols,
        rows,
        [0.0; 2],
    );
    let sizes = board_art::check(&board).map_err(std::io::Error::other)?;
    let dir = std::env::temp_dir().join(format!("board-make-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let before = peak_rss_mib();
    let t0 = std::time::Instant::now();
    let mut bytes = 0;
    for (ext, _, write) in board_art::FILES {
        let path = dir.join(format!("bench.{ext}"));
        if in_memory {
            let mut whole = Vec::new();
            write(&board, &mut whole)?;
            protocol::config::write_output(&path, &whole, &[])?;
        } else {
            protocol::config::write_output_with(&path, &[], |out| write(&board, out))?;
        }
        bytes += std::fs::metadata(&path)?.len();
    }
    println!(
        "{cols} x {rows} dots ({}): {:.1} MB written (estimated at most {:.1} MB) in {:.1} s; peak RSS {:.1} MiB ({:.1} MiB before writing)",
        if in_memory { "each file whole in memory" } else { "streamed" },
        bytes as f64 / 1e6,
        sizes.total() as f64 / 1e6,
        t0.elapsed().as_secs_f64(),
        peak_rss_mib(),
        before,
    );
    std::fs::remove_dir_all(&dir)
}
