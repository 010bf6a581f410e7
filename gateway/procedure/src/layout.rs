//! A cutting layout partitioned (source C): read, grouped per tool and window, shifted,
//! overlaps resolved, the shifted layout and its picture as artifacts.

use crate::command_line::{self, FileArg, Plan};
use crate::request::{LayoutFormat, LayoutRequest, PictureFormat};
use crate::{Artifact, Outcome, Sink};
use layout::{MaterialFit, Params, Partition, Resolution};
use layout_io::{Layout, ReadOptions};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// A layout file's text for a [`LayoutRequest`], through the bounded reader
/// ([`protocol::config::DataKind::Layout`]); the error names the file.
pub fn read_layout_file(path: &std::path::Path) -> Result<String, crate::Error> {
    Ok(protocol::config::read_kind(
        path,
        protocol::config::DataKind::Layout,
    )?)
}

/// A layout file's format from its extension.
fn format_of(path: &std::path::Path) -> Result<LayoutFormat, crate::Error> {
    let format = layout_io::Format::from_path(&path.to_string_lossy()).ok_or_else(|| {
        crate::Error::Input(format!(
            "{}: the extension must be .dxf, .svg or .json",
            path.display()
        ))
    })?;
    Ok(LayoutFormat::of(format))
}

/// The layout file read into the request at `at` (`""` or `partition/`), its format
/// from its extension; a file that is not a layout is refused naming it.
pub fn layout_file(path: &std::path::Path, at: &str, plan: &mut Plan) -> Result<(), crate::Error> {
    let format = format_of(path)?;
    let text = read_layout_file(path)?;
    Layout::read(text.as_bytes(), format.format(), &ReadOptions::default())
        .map_err(|e| crate::Error::input(format!("layout {}", path.display()), e))?;
    plan.set(&format!("{at}format"), format);
    plan.set(&format!("{at}layout"), text);
    plan.inputs.push(path.to_path_buf());
    Ok(())
}

/// A partitioned layout: what the report and the cut are made from.
pub struct Partitioned {
    pub doc: Layout,
    pub partition: Partition,
    pub resolution: Resolution,
    /// The material's width and the partitioned layout's.
    pub material: MaterialFit,
    /// The partition's time, ms.
    pub elapsed_ms: f64,
}

/// Reads and partitions the request's layout, overlaps resolved (shared by the
/// partition and the cut).
pub fn partitioned(request: &LayoutRequest) -> Result<Partitioned, crate::Error> {
    let forced = request
        .assignments()
        .map_err(|e| crate::Error::Input(e.to_string()))?;
    let options = ReadOptions {
        chord_tolerance_mm: request.chord_tolerance_mm,
        ..ReadOptions::default()
    };
    let doc = Layout::read(request.layout.as_bytes(), request.format.format(), &options)
        .map_err(|e| crate::Error::input("layout", e))?;
    let params = Params {
        tools: request.tools as usize,
        window_mm: request.window_mm,
        gap_mm: request.gap_mm,
        width_mm: request.width_mm.or(doc.width_mm),
        clearance_mm: request.clearance_mm,
    };
    let t0 = Instant::now();
    let outcome = (|| {
        let mut partition = layout::partition(&doc.parts, &params)?;
        let pinned = layout::assign(&doc.parts, &mut partition, &forced)?;
        let resolution = if request.widen {
            layout::resolve_widening(&doc.parts, &mut partition, &pinned)?
        } else {
            layout::resolve(&doc.parts, &mut partition, &pinned)?
        };
        let material = layout::fit_material(&doc.parts, &partition, request.material_width_mm)?;
        Ok::<_, layout::PartitionError>((partition, resolution, material))
    })();
    // What cannot be partitioned as asked (an overlap left, parts wider than the
    // material) is refused before anything is written or cut.
    let (partition, resolution, material) =
        outcome.map_err(|e| crate::Error::Refused(e.to_string()))?;
    Ok(Partitioned {
        doc,
        partition,
        resolution,
        material,
        elapsed_ms: t0.elapsed().as_secs_f64() * 1e3,
    })
}

/// `layout partition`'s result: the layout crate's report ([`layout::Report`]: parts,
/// groups, moves, overlaps, widenings, figures) and the partition's time and widths.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LayoutResult {
    /// The partition's report, its fields at the top level.
    #[serde(flatten)]
    #[schema(value_type = Object)]
    pub report: layout::Report,
    /// The partition's (wall) time.
    pub partition_ms: f64,
    /// The material's width.
    pub material_width_mm: f64,
    /// The partitioned layout's width (the parts after the shifts).
    pub partitioned_width_mm: f64,
}

/// The report of a partition: the layout crate's report and the partition's time.
pub fn report(p: &Partitioned) -> LayoutResult {
    LayoutResult {
        report: layout::report(&p.doc.parts, &p.partition, &p.resolution),
        partition_ms: p.elapsed_ms,
        material_width_mm: p.material.material_width_mm,
        partitioned_width_mm: p.material.partitioned_width_mm,
    }
}

/// Partitions the layout; the shifted layout (`layout.<ext>`, in `out_format` or the
/// input's) and the picture (`picture.svg`/`.png`) go to the sink as artifacts. Nothing
/// is produced when an overlap cannot be resolved.
pub fn partition(request: &LayoutRequest, sink: &mut dyn Sink) -> Outcome<LayoutResult> {
    let p = match partitioned(request) {
        Ok(p) => p,
        Err(e) => return Outcome::failed(e),
    };
    let out_format = request.out_format.unwrap_or(request.format);
    let shifted = match p.doc.translated(&p.partition.offsets()).and_then(|mut l| {
        // The written width is the partitioned layout's, from Y 0 (the JSON's frame).
        if p.partition.y0_mm >= 0.0 {
            l.width_mm = Some(p.partition.y0_mm + p.material.partitioned_width_mm);
        }
        l.write(out_format.format())
    }) {
        Ok(bytes) => bytes,
        Err(e) => return Outcome::failed(format!("writing the shifted layout: {e}")),
    };
    let (ext, media_type) = match out_format {
        LayoutFormat::Json => ("json", "application/json"),
        LayoutFormat::Dxf => ("dxf", "image/vnd.dxf"),
        LayoutFormat::Svg => ("svg", "image/svg+xml"),
    };
    if let Err(e) = sink.artifact(Artifact {
        name: format!("layout.{ext}"),
        title: None,
        media_type,
        bytes: shifted,
    }) {
        return Outcome::failed(e);
    }
    if let Some(kind) = request.picture {
        let pic = layout::Picture {
            parts: &p.doc.parts,
            partition: &p.partition,
            moves: &p.resolution.moves,
        };
        let (w, h) = pic.size(1600);
        let drawn = match kind {
            PictureFormat::Svg => plot::render_svg(&pic, w, h)
                .map(String::into_bytes)
                .map(|b| (b, "svg", "image/svg+xml")),
            PictureFormat::Png => plot::render_png(&pic, w, h).map(|b| (b, "png", "image/png")),
        };
        let (bytes, ext, media_type) = match drawn {
            Ok(d) => d,
            Err(e) => return Outcome::failed(format!("the picture: {e}")),
        };
        if let Err(e) = sink.artifact(Artifact {
            name: format!("picture.{ext}"),
            title: Some("The partition, coloured by group".into()),
            media_type,
            bytes,
        }) {
            return Outcome::failed(e);
        }
    }
    let result = report(&p);
    let (r, partitioned) = (&result.report, &result.report.figures.partitioned);
    let metrics = [
        ("parts", r.parts.into()),
        ("overlaps_resolved", r.overlaps_resolved.into()),
        ("groups", p.partition.groups.len().into()),
        ("moves", p.resolution.moves.len().into()),
        ("length_mm", partitioned.length_mm.into()),
        ("utilisation", partitioned.utilisation.into()),
    ];
    let metrics = metrics
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
    Outcome::succeeded(result, metrics)
}

/// The partition of a cutting layout as a registered procedure.
pub struct LayoutPartition;

impl crate::registry::Procedure for LayoutPartition {
    const KIND: &'static str = "layout";
    const TITLE: &'static str =
        "Partition a cutting layout into tool and window groups for a multi-tool cutter";
    const COMMAND: &'static str = "layout partition";
    const LABEL: &'static str = "Layout partition";
    const HELP: &'static str = "Splits a cutting layout into groups per tool and cutting window and shifts parts apart. The machine does not move.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("layout", "The layout file: JSON, DXF or SVG."),
        (
            "format",
            "Set from the file's name; change it only if the name is wrong.",
        ),
        (
            "tools",
            "Number of cutting tools (equal lanes across the material).",
        ),
        ("window_mm", "Length of the cutting window along the feed."),
        ("gap_mm", "Space between groups."),
        (
            "width_mm",
            "Material width. Empty: the file's, else the layout's width.",
        ),
        (
            "material_width_mm",
            "Width of the material the result is cut from. Empty: the material width.",
        ),
        (
            "clearance_mm",
            "Parts of different groups closer than this overlap. Empty: the gap.",
        ),
        (
            "assign",
            "Put a part in a group: one per line, PART=GROUP (e.g. a=2).",
        ),
        (
            "widen",
            "When shifted parts still overlap, widen the gaps instead of stopping.",
        ),
        (
            "chord_tolerance_mm",
            "How closely straight pieces follow arcs and curves.",
        ),
        (
            "out_format",
            "Format of the shifted layout. Empty: the same as the file's.",
        ),
        ("picture", "Also draw the groups as a picture."),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = LayoutRequest;
    type Result = LayoutResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional("layout", "The layout (.dxf, .svg or .json).", |path, plan| {
            layout_file(path, "", plan)
        }),
        FileArg::required(
            "out",
            "Where to write the shifted layout (its format from the extension: .dxf, .svg or .json).",
            |path, plan| {
                plan.set("out_format", format_of(path)?);
                let name = format!("layout.{}", command_line::extension(path));
                plan.artifacts.push((name, path.to_path_buf()));
                Ok(())
            },
        ),
        FileArg::flag(
            "picture",
            "Also draw the result (.svg or .png), coloured by group.",
            |path, plan| {
                let ext = command_line::extension(path);
                if ext != "svg" && ext != "png" {
                    return Err(crate::Error::Input(format!(
                        "--picture {}: the extension must be .svg or .png",
                        path.display()
                    )));
                }
                plan.set("picture", ext.clone());
                plan.artifacts.push((format!("picture.{ext}"), path.to_path_buf()));
                Ok(())
            },
        ),
    ];

    async fn run(request: LayoutRequest, cx: &mut dyn crate::Context) -> Outcome<LayoutResult> {
        partition(&request, cx.sink())
    }

    fn summary(result: &LayoutResult) -> String {
        summary(result)
    }

    /// The uploaded layout read as the job will read it (its format, its chord
    /// tolerance): a file the job would refuse is refused when queued, on its field.
    fn admit(
        request: &LayoutRequest,
        _facts: &crate::registry::Facts,
    ) -> Result<(), crate::RequestError> {
        let options = ReadOptions {
            chord_tolerance_mm: request.chord_tolerance_mm,
            ..ReadOptions::default()
        };
        let format = match request.format {
            LayoutFormat::Json => "JSON",
            LayoutFormat::Dxf => "DXF",
            LayoutFormat::Svg => "SVG",
        };
        layout_io::Layout::read(request.layout.as_bytes(), request.format.format(), &options)
            .map(|_| ())
            .map_err(|e| {
                crate::RequestError::new(
                    "layout",
                    format!("the file is not a layout the job can read as {format}: {e}"),
                )
            })
    }
}

/// The report as text, one line per figure (the CLI's output without `--json`).
pub fn summary(result: &LayoutResult) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let r = &result.report;
    let _ = writeln!(
        t,
        "{} parts, {} tools, window {:?} mm, gap {:?} mm, width {:?} mm: {:.3} ms",
        r.parts, r.tools, r.window_mm, r.gap_mm, r.width_mm, result.partition_ms
    );
    let _ = writeln!(t, "group  tool  window  dx_mm  dy_mm  parts");
    for g in &r.groups {
        let _ = writeln!(
            t,
            "{:>5}  {:>4}  {:>6}  {:>5}  {:>5}  {}",
            g.id.to_string(),
            g.tool.to_string(),
            g.window.to_string(),
            format!("{:?}", g.dx_mm),
            format!("{:?}", g.dy_mm),
            g.parts.len()
        );
    }
    let _ = writeln!(
        t,
        "overlaps between groups after S8: {}",
        r.overlaps_found.len()
    );
    for m in &r.moves {
        let _ = writeln!(
            t,
            "  moved `{}` from group {} to group {} (too close to `{}`: {:.3} mm; its overlaps {} -> {})",
            m.part,
            m.from_group,
            m.to_group,
            m.because_of.as_deref().unwrap_or("-"),
            m.distance_mm,
            m.overlaps_before,
            m.overlaps_after
        );
    }
    for w in &r.widenings {
        let _ = writeln!(
            t,
            "  widened: every {} from {} on moved {:.3} mm further",
            w.between, w.from, w.extra_mm
        );
    }
    let f = &r.figures;
    let row = |t: &mut String, name: &str, m: &layout::Material| {
        let _ = writeln!(t,
            "{name:<18} length {:>10.3} mm  width {:>9.3} mm  area {:>12.1} mm2  utilisation {:>6.2} %",
            m.length_mm, m.width_mm, m.area_mm2, m.utilisation * 100.0
        );
    };
    row(&mut t, "no gap", &f.no_gap);
    row(&mut t, "partitioned", &f.partitioned);
    row(&mut t, "gap every part", &f.gap_every_part);
    let _ = writeln!(
        t,
        "material {:.3} mm wide; the partition adds {:.3} mm across (width {:.3} mm)",
        result.material_width_mm, f.added_width_partitioned_mm, result.partitioned_width_mm
    );
    let _ = match f.added_length_fraction {
        Some(frac) => writeln!(
            t,
            "length added: {:.3} mm by the groups, {:.3} mm with a gap around every part ({:.1} %)",
            f.added_length_partitioned_mm,
            f.added_length_every_part_mm,
            frac * 100.0
        ),
        None => writeln!(
            t,
            "length added: {:.3} mm by the groups",
            f.added_length_partitioned_mm
        ),
    };
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Collect, End};
    use serde_json::{json, Value};

    /// Two lanes of 50 mm on 100 mm material, a part of lane 1 touching the top edge:
    /// S8 moves lane 1 up by the gap.
    fn request(material: Option<f64>) -> LayoutRequest {
        let layout = json!({"units": "mm", "width_mm": 100.0, "parts": [
            {"id": "a", "contours": [[[0, 0], [40, 0], [40, 40], [0, 40]]]},
            {"id": "b", "contours": [[[10, 60], [50, 60], [50, 100], [10, 100]]]},
        ]});
        LayoutRequest {
            layout: layout.to_string(),
            format: LayoutFormat::Json,
            tools: 2,
            window_mm: 100.0,
            gap_mm: 5.0,
            width_mm: None,
            material_width_mm: material,
            clearance_mm: None,
            assign: vec![],
            widen: false,
            chord_tolerance_mm: 0.01,
            out_format: None,
            picture: None,
        }
    }

    #[test]
    fn a_part_pushed_off_the_material_is_refused_by_name() {
        let out = partition(&request(None), &mut Collect::default());
        let End::Failed { error } = out.end else {
            panic!("{:?}", out.end)
        };
        assert!(
            error.contains("1 part(s) do not fit the 100.000 mm material")
                && error.contains("`b` (group 2, DY 5.000) at Y 65.000..105.000")
                && error.contains("needs 105.000 mm"),
            "{error}"
        );
    }

    #[test]
    fn the_written_width_is_the_partitioned_width_and_the_report_says_what_was_added() {
        let mut sink = Collect::default();
        let out = partition(&request(Some(110.0)), &mut sink);
        assert!(matches!(out.end, End::Succeeded), "{:?}", out.end);
        let r = out.result.unwrap();
        assert_eq!(r.material_width_mm, 110.0);
        assert_eq!(r.partitioned_width_mm, 105.0);
        assert_eq!(r.report.figures.added_width_partitioned_mm, 5.0);
        let written: Value = serde_json::from_slice(&sink.0[0].bytes).unwrap();
        assert_eq!(written["width_mm"], json!(105.0));
        assert!(summary(&r).contains("adds 5.000 mm across (width 105.000 mm)"));
        // The report's fields at the top level, read back as the store keeps them.
        let stored = serde_json::to_value(&r).unwrap();
        assert_eq!(stored["figures"]["added_width_partitioned_mm"], json!(5.0));
        assert_eq!(stored["parts"], 2);
        let back: LayoutResult = serde_json::from_value(stored).unwrap();
        assert_eq!(back, r);
        let e = request(Some(0.0)).check().unwrap_err();
        assert_eq!(e.field, "material_width_mm");
    }
}
