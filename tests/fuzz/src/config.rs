//! Every TOML file kind: job, board (with its certificate), machine, camera, Modbus
//! drive profile. Each input is a document in the repository's folder of its kind, so
//! relative references resolve to the repository's files, which are compiled in.
//! Files are never read from paths the input chose: an input with a string naming a
//! path that is not one of those files is skipped. (A name without a separator can only
//! point into `config/<kind>/` under the working folder, where at most the
//! repository's own files are; the loader refuses anything but regular files.)

use protocol::config::ConfigDoc;
use protocol::modbus::DriveProfile;
use protocol::Board;
use world::camera::{CameraModel, CameraPose};
use world::machine::{MachineConfig, SimMachine};

/// The repository's configuration files, by their path in the repository.
static REPO_FILES: &[(&str, &str)] = &[
    (
        "config/gateway/canopen-demo.toml",
        include_str!("../../../config/gateway/canopen-demo.toml"),
    ),
    (
        "config/gateway/demo.toml",
        include_str!("../../../config/gateway/demo.toml"),
    ),
    (
        "config/gateway/gige-demo.toml",
        include_str!("../../../config/gateway/gige-demo.toml"),
    ),
    (
        "config/gateway/grbl-demo.toml",
        include_str!("../../../config/gateway/grbl-demo.toml"),
    ),
    (
        "config/gateway/modbus-demo.toml",
        include_str!("../../../config/gateway/modbus-demo.toml"),
    ),
    (
        "config/machines/c5-stage.toml",
        include_str!("../../../config/machines/c5-stage.toml"),
    ),
    (
        "config/cameras/mono-1.3mp.toml",
        include_str!("../../../config/cameras/mono-1.3mp.toml"),
    ),
    (
        "config/cameras/mono-5mp.toml",
        include_str!("../../../config/cameras/mono-5mp.toml"),
    ),
    (
        "config/boards/dot-grid-0.5mm.certified.csv",
        include_str!("../../../config/boards/dot-grid-0.5mm.certified.csv"),
    ),
    (
        "config/boards/dot-grid-0.5mm.toml",
        include_str!("../../../config/boards/dot-grid-0.5mm.toml"),
    ),
    (
        "config/drives/generic.toml",
        include_str!("../../../config/drives/generic.toml"),
    ),
    (
        "config/drives/leadshine-pr0.toml",
        include_str!("../../../config/drives/leadshine-pr0.toml"),
    ),
    (
        "config/drives/oriental-az.toml",
        include_str!("../../../config/drives/oriental-az.toml"),
    ),
    (
        "config/canopen/drive.eds",
        include_str!("../../../config/canopen/drive.eds"),
    ),
];

/// [`REPO_FILES`] with the board certificate cut to its first lines: the whole one
/// (135 000 points) would make every job that loads the board take milliseconds.
fn files() -> &'static [(&'static str, &'static str)] {
    static FILES: std::sync::OnceLock<&'static [(&'static str, &'static str)]> =
        std::sync::OnceLock::new();
    FILES.get_or_init(|| {
        let cut: Vec<(&'static str, &'static str)> = REPO_FILES
            .iter()
            .map(|&(name, text)| {
                if name.ends_with(".csv") {
                    let end = text
                        .match_indices('\n')
                        .nth(40)
                        .map_or(text.len(), |(i, _)| i + 1);
                    (name, &text[..end])
                } else {
                    (name, text)
                }
            })
            .collect();
        Box::leak(cut.into_boxed_slice())
    })
}

/// `dir/rel` with `.` and `..` resolved, as the loader resolves it.
fn normalize(dir: &str, rel: &str) -> Option<String> {
    if rel.starts_with('/') || rel.starts_with('\\') {
        return None;
    }
    let mut parts: Vec<&str> = dir.split('/').collect();
    for p in rel.split(['/', '\\']) {
        match p {
            "" | "." => {}
            ".." => {
                parts.pop()?;
            }
            p => parts.push(p),
        }
    }
    Some(parts.join("/"))
}

/// Whether every string in the document that names a path names one of [`files`]
/// (a document that is not TOML cannot get to reading anything).
fn paths_are_known(text: &str, dir: &str) -> bool {
    fn walk(v: &toml::Value, dir: &str) -> bool {
        match v {
            toml::Value::String(s) if s.contains(['/', '\\']) => {
                normalize(dir, s).is_some_and(|p| files().iter().any(|(name, _)| *name == p))
            }
            toml::Value::Array(a) => a.iter().all(|v| walk(v, dir)),
            toml::Value::Table(t) => t.values().all(|v| walk(v, dir)),
            _ => true,
        }
    }
    match text.parse::<toml::Table>() {
        Ok(t) => t.values().all(|v| walk(v, dir)),
        Err(_) => true,
    }
}

/// The input as a document of folder `dir`, or `None` if it is not UTF-8 or names a
/// path outside the repository's files.
fn doc(data: &[u8], dir: &str) -> Option<ConfigDoc> {
    let text = std::str::from_utf8(data).ok()?;
    if !paths_are_known(text, dir) {
        return None;
    }
    let mut doc =
        ConfigDoc::from_text(&format!("{dir}/fuzz.toml"), text, std::path::Path::new(dir));
    doc.embedded = files();
    Some(doc)
}

/// A job file: loaded with everything it refers to; a job that loads answers its
/// questions (pairing, targets, commands).
pub fn job_toml(data: &[u8]) {
    let Some(doc) = doc(data, "config/gateway") else {
        return;
    };
    match job::Job::from_doc(&doc) {
        Ok(job) => {
            let _ = job.check_pairing();
            for t in job.targets.iter().take(100) {
                let c = job.command_for(*t);
                assert!(c.iter().all(|v| !v.is_nan()), "{t:?} -> {c:?}");
            }
            let _ = job.session_targets();
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// A board file (its certificate from the repository), and the input as a
/// certificate of a small board: a certificate that is read is written back (the
/// points off nominal), and what is written reads back to the same board.
pub fn board_toml(data: &[u8]) {
    if let Some(doc) = doc(data, "config/boards") {
        match Board::from_doc(&doc) {
            Ok(b) => {
                let (lo, hi) = b.extent();
                assert!(lo.iter().chain(&hi).all(|v| v.is_finite()));
            }
            Err(e) => {
                let _ = e.to_string();
            }
        }
    }
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let nominal = Board::nominal(
        "fuzz",
        0.5,
        0.25,
        protocol::Polarity::DarkOnLight,
        6,
        5,
        [0.0, 0.0],
    );
    let mut board = nominal.clone();
    if board.apply_certificate("fuzz.csv", text).is_ok() {
        let written = board.certificate_csv();
        if written.lines().count() < 2 {
            // Every point listed was nominal: the writer lists none, and a certificate
            // without points is refused (the board file leaves `certified` out).
            return;
        }
        let mut again = nominal.clone();
        again
            .apply_certificate("written.csv", &written)
            .unwrap_or_else(|e| panic!("{written:?}: {e}"));
        assert_eq!(again.certificate_csv(), written);
    }
}

/// A simulated machine file: a machine that loads homes and moves.
pub fn machine_toml(data: &[u8]) {
    let Some(doc) = doc(data, "config/machines") else {
        return;
    };
    match MachineConfig::from_doc(&doc) {
        Ok(cfg) => {
            let mut m = SimMachine::new(cfg);
            m.home();
            let travel = [m.config().axes.x.travel_mm, m.config().axes.y.travel_mm];
            let target = [travel[0] / 2.0, travel[1] / 3.0];
            if m.start_move(target, 1000.0).is_ok() {
                m.finish_motion();
            }
            let p = m.position_mm();
            assert!(p.iter().all(|v| v.is_finite()), "{p:?}");
            let e = m.static_error_um(target);
            assert!(e.iter().all(|v| v.is_finite()), "{e:?}");
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// A simulated camera file: a camera that loads maps its centre to the board and back.
pub fn camera_toml(data: &[u8]) {
    let Some(doc) = doc(data, "config/cameras") else {
        return;
    };
    match CameraModel::from_doc(&doc) {
        Ok(cam) => {
            let pose = CameraPose {
                centre_mm: [5.0, 5.0],
                rotation_rad: 0.0,
            };
            let px = cam.board_to_pixel(&pose, [5.1, 4.9]);
            let back = cam.pixel_to_board(&pose, px);
            assert!(
                px.iter().chain(&back).all(|v| v.is_finite()),
                "{px:?} {back:?}"
            );
            let fov = cam.field_of_view_mm();
            assert!(fov.iter().all(|v| v.is_finite() && *v > 0.0), "{fov:?}");
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// A Modbus drive profile: a profile that loads encodes a move, decodes any status
/// word and names its registers.
pub fn modbus_profile(data: &[u8]) {
    let Some(doc) = doc(data, "config/drives") else {
        return;
    };
    match DriveProfile::from_doc(&doc) {
        Ok(p) => {
            let _ = p.move_words(12.5, 10.0);
            let _ = p.move_words(-1e9, 1e-9);
            for raw in [0, 1, 0x8000_0000, u32::MAX] {
                let _ = p.decode_status(raw);
                let _ = p.alarm_text(raw);
            }
            let _ = p.poll_span();
            for r in p.registers() {
                let _ = r.to_string();
                let _ = r.decode(&[0xFFFF; 4][..usize::from(r.words()).min(4)]);
            }
            let _ = p.commands();
            let mm = p.mm(p.counts(3.25));
            assert!(mm.is_finite());
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}
