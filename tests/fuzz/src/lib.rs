//! One fuzz target per parser of outside input: each `pub fn <target>(data: &[u8])`
//! feeds the bytes to the parser(s) and checks what must hold whatever the bytes are:
//! no panic, bounded output, and where the format has a writer, parse -> write -> parse
//! gives the same value.
//!
//! The functions build on stable with no fuzzing dependency. The libFuzzer binaries in
//! `fuzz_targets/` (nightly, `--features libfuzzer`) call them, and
//! `tests/corpus_and_regressions.rs` replays every file of `corpus/<target>/` and
//! `regressions/<target>/` through them in `cargo test`. [`TARGETS`] lists them all.

#![forbid(unsafe_code)]

use std::path::Path;

mod canopen;
mod config;
mod errormap;
mod fanuc;
mod gige;
mod grbl;
mod iso230;
mod layout;
mod linuxcnc;
mod media;
mod modbus;
mod nc;
mod ngc;
mod outside;
mod rewrite;
mod rotary;
mod service;
mod slcan;
mod sparkplug;
mod volumetric;

pub use canopen::{canopen_eds, sdo_client, sdo_server};
pub use config::{board_toml, camera_toml, job_toml, machine_toml, modbus_profile};
pub use errormap::{error_map_json, scan_journal};
pub use fanuc::{fanuc_rewrite, fanuc_tape};
pub use gige::{genicam_xml, gige_url, gige_zip, gvcp, gvsp};
pub use grbl::{grbl_gcode, grbl_response};
pub use iso230::iso230_csv;
pub use layout::{layout_cut, layout_dxf, layout_json, layout_svg};
pub use linuxcnc::linuxcnc_reply;
pub use media::{localize, png_load};
pub use modbus::modbus_frame;
pub use nc::nc_program;
pub use ngc::ngc_rewrite;
pub use outside::{
    dollar_hash, gcode_dialect, program_lines, reference_record, rotary_errors, volumetric_campaign,
};
pub use rewrite::{nc_rewrite, proxy_stream};
pub use rotary::{grbl_probe, rotary_centres, rotary_json, rotary_rewrite};
pub use service::{api_job_body, box_toml};
pub use slcan::slcan;
pub use sparkplug::sparkplug_ncmd;
pub use volumetric::volumetric_model;

/// A fuzz target: any bytes in, a panic on a broken invariant.
pub type Target = fn(&[u8]);

/// Every target by name, as the corpus and regression folders and the libFuzzer
/// binaries are named.
pub const TARGETS: &[(&str, Target)] = &[
    ("grbl_response", grbl_response),
    ("grbl_gcode", grbl_gcode),
    ("nc_program", nc_program),
    ("slcan", slcan),
    ("sdo_client", sdo_client),
    ("sdo_server", sdo_server),
    ("canopen_eds", canopen_eds),
    ("modbus_frame", modbus_frame),
    ("modbus_profile", modbus_profile),
    ("gvcp", gvcp),
    ("gvsp", gvsp),
    ("genicam_xml", genicam_xml),
    ("gige_zip", gige_zip),
    ("gige_url", gige_url),
    ("png_load", png_load),
    ("localize", localize),
    ("job_toml", job_toml),
    ("box_toml", box_toml),
    ("sparkplug_ncmd", sparkplug_ncmd),
    ("api_job_body", api_job_body),
    ("board_toml", board_toml),
    ("machine_toml", machine_toml),
    ("camera_toml", camera_toml),
    ("error_map_json", error_map_json),
    ("scan_journal", scan_journal),
    ("layout_dxf", layout_dxf),
    ("layout_svg", layout_svg),
    ("layout_json", layout_json),
    ("layout_cut", layout_cut),
    ("nc_rewrite", nc_rewrite),
    ("proxy_stream", proxy_stream),
    ("rotary_centres", rotary_centres),
    ("rotary_json", rotary_json),
    ("grbl_probe", grbl_probe),
    ("rotary_rewrite", rotary_rewrite),
    ("iso230_csv", iso230_csv),
    ("volumetric_model", volumetric_model),
    ("dollar_hash", dollar_hash),
    ("volumetric_campaign", volumetric_campaign),
    ("rotary_errors", rotary_errors),
    ("program_lines", program_lines),
    ("gcode_dialect", gcode_dialect),
    ("reference_record", reference_record),
    ("linuxcnc_reply", linuxcnc_reply),
    ("fanuc_tape", fanuc_tape),
    ("fanuc_rewrite", fanuc_rewrite),
    ("ngc_rewrite", ngc_rewrite),
];

/// The fuzz crate's folder (corpora, regressions).
pub fn fuzz_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Records of an input: each is one length byte, then up to that many bytes (fewer at
/// the end). Lets one input carry a sequence of frames or datagrams.
pub(crate) fn records(mut data: &[u8]) -> impl Iterator<Item = &[u8]> {
    std::iter::from_fn(move || {
        let (&n, rest) = data.split_first()?;
        let n = (n as usize).min(rest.len());
        let (r, rest) = rest.split_at(n);
        data = rest;
        Some(r)
    })
}

/// Feeds `data` in pieces whose sizes come from `seed` (1..=8 bytes), the way a
/// byte link may chunk it.
pub(crate) fn chunked(data: &[u8], seed: u8, mut feed: impl FnMut(&[u8])) {
    let mut rest = data;
    let mut k = seed as usize;
    while !rest.is_empty() {
        let n = (k % 8 + 1).min(rest.len());
        k = k.wrapping_mul(5).wrapping_add(3);
        let (a, b) = rest.split_at(n);
        feed(a);
        rest = b;
    }
}
