//! The partitioned layouts we write, read by independent readers: every written DXF by
//! `ezdxf` (strict reading, its audit, and its own INSERT transforms), every SVG by
//! `svgelements` (its own path parser, transforms and viewBox), every JSON by Python's
//! `json`. Each part's contours as they read them must be the input's parts moved by the
//! partition's shifts; the DXF must open with no repeated handle and no audit error,
//! with its header's unit and version kept. Fails, naming the install step
//! (`tests/install-peers.sh`), when python3, ezdxf or svgelements is missing.

use procedure::request::{LayoutFormat, LayoutRequest};
use procedure::{Collect, End};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use system_tests::{python_missing, workspace};

/// Reads a layout file with the independent readers and prints what they found as JSON:
/// `parts` (id, rings of [x, y] in the file's units), `warnings` (ezdxf's log), DXF
/// `errors` (ezdxf's audit), `insunits`, `version`, `measurement`, `block_records`.
const READER: &str = r#"
import sys, json, logging
fmt, path = sys.argv[1], sys.argv[2]
out = {"parts": [], "warnings": [], "errors": []}
class Keep(logging.Handler):
    def emit(self, r):
        if r.levelno >= logging.WARNING:
            out["warnings"].append(r.getMessage())
log = logging.getLogger("ezdxf")
log.addHandler(Keep()); log.propagate = False
if fmt == "dxf":
    import ezdxf
    doc = ezdxf.readfile(path)
    out["errors"] = [str(e.message) for e in doc.audit().errors]
    out["insunits"] = doc.header.get("$INSUNITS")
    out["measurement"] = doc.header.get("$MEASUREMENT")
    out["version"] = doc.dxfversion
    out["block_records"] = [r.dxf.name for r in doc.block_records]
    seen = {}
    for e in doc.modelspace():
        if e.dxftype() == "INSERT":
            n = e.dxf.name
            seen[n] = seen.get(n, 0) + 1
            pid = n if seen[n] == 1 else "%s#%d" % (n, seen[n])
            rings = [[list(p) for p in v.get_points("xy")]
                     for v in e.virtual_entities() if v.dxftype() == "LWPOLYLINE" and v.closed]
        elif e.dxftype() == "LWPOLYLINE" and e.closed:
            pid, rings = e.dxf.handle, [[list(p) for p in e.get_points("xy")]]
        else:
            continue
        out["parts"].append({"id": pid, "rings": rings})
elif fmt == "svg":
    import svgelements as se
    svg = se.SVG.parse(path, ppi=25.4)
    for el in svg.elements():
        if isinstance(el, se.Path):
            rings = []
            for seg in el.segments():
                if isinstance(seg, se.Move):
                    rings.append([[seg.end.x, seg.end.y]])
                elif isinstance(seg, se.Line):
                    rings[-1].append([seg.end.x, seg.end.y])
            out["parts"].append({"id": el.id, "rings": rings})
else:
    doc = json.load(open(path))
    out["width_mm"] = doc.get("width_mm")
    out["parts"] = [{"id": p["id"], "rings": p["contours"]} for p in doc["parts"]]
print(json.dumps(out))
"#;

/// Writes an apparel-style DXF with ezdxf: each piece a block (its outline a closed
/// LWPOLYLINE, a grain line inside, the base point at the piece's lower left) inserted
/// there, a TEXT beside, in the unit given (`$INSUNITS` 4 mm or 5 cm), `$MEASUREMENT` 1.
const WRITER: &str = r#"
import sys, json, ezdxf
src, dst, insunits = sys.argv[1], sys.argv[2], int(sys.argv[3])
scale = {4: 1.0, 5: 0.1}[insunits]
doc = ezdxf.new("R2010")
doc.header["$INSUNITS"] = insunits
doc.header["$MEASUREMENT"] = 1
msp = doc.modelspace()
for p in json.load(open(src))["parts"]:
    outer = [(x * scale, y * scale) for x, y in p["contours"][0]]
    x0 = min(x for x, _ in outer); y0 = min(y for _, y in outer)
    name = p["id"]
    blk = doc.blocks.new(name=name, base_point=(x0, y0))
    blk.add_lwpolyline(outer, close=True)
    xs = [x for x, _ in outer]; ys = [y for _, y in outer]
    cx = (min(xs) + max(xs)) / 2
    blk.add_line((cx, min(ys) + 0.1 * (max(ys) - min(ys))), (cx, max(ys) - 0.1 * (max(ys) - min(ys))))
    msp.add_blockref(name, (x0, y0))
msp.add_text("marker", dxfattribs={"insert": (0, -10 * scale)})
doc.saveas(dst)
"#;

fn require_peers() {
    if let Some(why) = python_missing("ezdxf, svgelements", "ezdxf svgelements") {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("layout-interop-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn python(script: &str, args: &[&str]) -> String {
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "python3 {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn read_back(format: &str, path: &Path) -> Value {
    let text = python(READER, &[format, path.to_str().unwrap()]);
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}: {text}"))
}

fn request(
    layout: String,
    format: LayoutFormat,
    tools: u64,
    window: f64,
    gap: f64,
) -> LayoutRequest {
    LayoutRequest {
        layout,
        format,
        tools,
        window_mm: window,
        gap_mm: gap,
        width_mm: None,
        material_width_mm: Some(10_000.0),
        clearance_mm: None,
        assign: vec![],
        widen: true,
        chord_tolerance_mm: 0.01,
        out_format: None,
        picture: None,
    }
}

/// Each part's rings, points rounded to a micrometre and sorted (the readers may start
/// a ring elsewhere or turn it the other way).
fn canonical(rings: &[Vec<[f64; 2]>]) -> Vec<Vec<(i64, i64)>> {
    let mut out: Vec<Vec<(i64, i64)>> = rings
        .iter()
        .map(|r| {
            let mut r = r.clone();
            // A closing point repeated is the first one.
            if r.len() > 1 && r[0] == r[r.len() - 1] {
                r.pop();
            }
            let mut pts: Vec<(i64, i64)> = r
                .iter()
                .map(|p| ((p[0] * 1e3).round() as i64, (p[1] * 1e3).round() as i64))
                .collect();
            pts.sort_unstable();
            pts
        })
        .collect();
    out.sort();
    out
}

fn rings_of(v: &Value, scale: f64, origin: [f64; 2]) -> Vec<Vec<[f64; 2]>> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|p| {
                    [
                        p[0].as_f64().unwrap() * scale + origin[0],
                        p[1].as_f64().unwrap() * scale + origin[1],
                    ]
                })
                .collect()
        })
        .collect()
}

/// Asserts that the reader found exactly the expected parts (ids and contours, within a
/// micrometre after rounding), with `scale` from the file's units to mm and `origin`
/// added (an SVG viewBox puts the layout's corner at 0, 0).
fn assert_same_parts(
    what: &str,
    read: &Value,
    expected: &[layout_io::Part],
    scale: f64,
    origin: [f64; 2],
) {
    let parts = read["parts"].as_array().unwrap();
    assert_eq!(parts.len(), expected.len(), "{what}: part count");
    let by_id: std::collections::HashMap<&str, &Value> = parts
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), &p["rings"]))
        .collect();
    for e in expected {
        let rings = by_id
            .get(e.id.as_str())
            .unwrap_or_else(|| panic!("{what}: part `{}` not found", e.id));
        let got = canonical(&rings_of(rings, scale, origin));
        let want = canonical(
            &std::iter::once(e.outer.clone())
                .chain(e.holes.iter().cloned())
                .collect::<Vec<_>>(),
        );
        // Within one micrometre after rounding (the writers print enough digits).
        let close = got.len() == want.len()
            && got.iter().zip(&want).all(|(g, w)| {
                g.len() == w.len()
                    && g.iter()
                        .zip(w)
                        .all(|(a, b)| (a.0 - b.0).abs() <= 1 && (a.1 - b.1).abs() <= 1)
            });
        assert!(
            close,
            "{what}: part `{}` read as {got:?}, expected {want:?}",
            e.id
        );
    }
}

/// Partitions `req` and writes it in every format; checks each file with the readers.
fn check_every_format(name: &str, req: &LayoutRequest, dxf_scale: f64, insunits: i64) {
    let p = procedure::layout::partitioned(req).unwrap();
    let expected = p.doc.translated(&p.partition.offsets()).unwrap().parts;
    let corner = expected.iter().fold([f64::INFINITY; 2], |c, q| {
        let b = q.bounds();
        [c[0].min(b[0]), c[1].min(b[1])]
    });
    let d = dir(name);
    for (format, ext) in [
        (LayoutFormat::Json, "json"),
        (LayoutFormat::Dxf, "dxf"),
        (LayoutFormat::Svg, "svg"),
    ] {
        let mut req = req.clone();
        req.out_format = Some(format);
        let mut sink = Collect::default();
        let out = procedure::layout::partition(&req, &mut sink);
        assert!(
            matches!(out.end, End::Succeeded),
            "{name} {ext}: {:?}",
            out.end
        );
        let result = out.result.unwrap();
        let path = d.join(format!("out.{ext}"));
        std::fs::write(&path, &sink.0[0].bytes).unwrap();
        let read = read_back(ext, &path);
        let what = format!("{name} as {ext}");
        match ext {
            "dxf" => {
                assert_eq!(
                    read["warnings"],
                    Value::Array(vec![]),
                    "{what}: ezdxf warned"
                );
                assert_eq!(
                    read["errors"],
                    Value::Array(vec![]),
                    "{what}: ezdxf's audit"
                );
                assert_eq!(read["insunits"], insunits, "{what}: $INSUNITS");
                let records: Vec<String> = read["block_records"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_str().unwrap().to_ascii_uppercase())
                    .collect();
                let unique: std::collections::HashSet<&String> = records.iter().collect();
                assert_eq!(unique.len(), records.len(), "{what}: {records:?}");
                assert_same_parts(&what, &read, &expected, dxf_scale, [0.0, 0.0]);
            }
            "svg" => assert_same_parts(&what, &read, &expected, 1.0, corner),
            _ => {
                assert_same_parts(&what, &read, &expected, 1.0, [0.0, 0.0]);
                // The written width is the partitioned width (from Y 0).
                let w = read["width_mm"].as_f64().unwrap();
                assert!(
                    (w - (result.report.y0_mm + result.partitioned_width_mm)).abs() < 1e-9,
                    "{what}: width {w}"
                );
                let top = expected
                    .iter()
                    .map(|q| q.bounds()[3])
                    .fold(f64::NEG_INFINITY, f64::max);
                assert!(top <= w + 1e-9, "{what}: parts reach {top}, width {w}");
            }
        }
    }
}

/// The ESICUP trousers (64 parts, JSON in), two tools, L' = 0.8 W, G = W / 80, widened:
/// written as JSON, DXF (one block per part) and SVG, each read back independently.
#[test]
fn trousers_written_in_every_format_read_back_by_independent_readers() {
    require_peers();
    let path = workspace().join("gateway/layout/data/esicup/trousers.json");
    let text = std::fs::read_to_string(path).unwrap();
    let w = 79.0;
    let req = request(text, LayoutFormat::Json, 2, 0.8 * w, w / 80.0);
    check_every_format("trousers", &req, 1.0, 4);
}

/// An apparel DXF made by ezdxf (R2010, pieces as blocks inserted at their corners, grain
/// lines, a TEXT; in mm and in cm): partitioned and written back as a DXF that ezdxf
/// opens with no warning or audit error, one block record each, its unit and version
/// kept, every piece where the shifts put it; and as JSON and SVG.
#[test]
fn an_ezdxf_drawing_partitioned_and_written_back_opens_in_ezdxf() {
    require_peers();
    let src = workspace().join("gateway/layout/data/esicup/shirts.json");
    for (insunits, scale) in [(4i64, 1.0), (5, 10.0)] {
        let d = dir(&format!("ezdxf-{insunits}"));
        let dxf = d.join("in.dxf");
        python(
            WRITER,
            &[
                src.to_str().unwrap(),
                dxf.to_str().unwrap(),
                &insunits.to_string(),
            ],
        );
        let text = std::fs::read_to_string(&dxf).unwrap();
        let w = 40.0;
        let req = request(text, LayoutFormat::Dxf, 2, 0.8 * w, w / 80.0);
        check_every_format(&format!("shirts-dxf-{insunits}"), &req, scale, insunits);
        // The version the drawing was made in stays.
        let mut out_req = req.clone();
        out_req.out_format = Some(LayoutFormat::Dxf);
        let mut sink = Collect::default();
        procedure::layout::partition(&out_req, &mut sink);
        let back = d.join("back.dxf");
        std::fs::write(&back, &sink.0[0].bytes).unwrap();
        let read = read_back("dxf", &back);
        assert_eq!(read["version"], "AC1024", "{read:?}");
        assert_eq!(read["measurement"], 1);
    }
}
