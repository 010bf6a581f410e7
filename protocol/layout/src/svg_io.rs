//! SVG layouts: one part per `<path>`, `<polygon>`, `<rect>` or `<circle>` element.
//!
//! Coordinates: the element's points through every `transform` of it and its ancestors,
//! in user units of the root. One user unit is 1 mm, unless the root element has a
//! `viewBox` and a `width` in a physical unit (`mm`, `cm`, `in`, `pt`, `pc`): then one
//! user unit is `width / viewBox width` (e.g. `width="500mm" viewBox="0 0 1000 400"`:
//! 0.5 mm). SVG's Y axis points down; the layout's Y is SVG's y as it is, so the
//! numbers match the file (a CAD view with Y up shows the layout mirrored).
//!
//! A path's subpaths are its contours: each must be closed (`Z`, or ending on its start
//! within the join tolerance); the one of largest area is the outer contour, the others
//! holes. Curves are flattened within the chord tolerance (elliptical arcs are first
//! turned into cubic Béziers by `svgtypes`, within about 1e-4 of their radius). Elements
//! inside `<defs>`, `<clipPath>`, `<mask>`, `<symbol>`, `<marker>` or `<pattern>` are not
//! parts; `<line>` and `<polyline>` are refused (open), `<ellipse>` and `<use>` too (not
//! read, rather than left out unseen). The part's id is the element's
//! `id` (else `path3` for the 4th element read), its layer the `class`, and its other
//! attributes are kept and written back.

use std::collections::BTreeMap;
use std::str::FromStr;

use svgtypes::{SimplePathSegment, SimplifyingPathParser, Transform};

use crate::model::{LayoutError, Part, Point, ReadOptions};

const SKIPPED_CONTAINERS: [&str; 6] = ["defs", "clipPath", "mask", "symbol", "marker", "pattern"];
/// Attributes that carry geometry: not kept, the writer writes the geometry itself.
const GEOMETRY_ATTRIBUTES: [&str; 13] = [
    "id",
    "class",
    "d",
    "points",
    "transform",
    "x",
    "y",
    "width",
    "height",
    "cx",
    "cy",
    "r",
    "rx",
];

fn mul(p: &Transform, q: &Transform) -> Transform {
    // p applied after q.
    Transform::new(
        p.a * q.a + p.c * q.b,
        p.b * q.a + p.d * q.b,
        p.a * q.c + p.c * q.d,
        p.b * q.c + p.d * q.d,
        p.a * q.e + p.c * q.f + p.e,
        p.b * q.e + p.d * q.f + p.f,
    )
}

fn apply(t: &Transform, x: f64, y: f64) -> Point {
    [t.a * x + t.c * y + t.e, t.b * x + t.d * y + t.f]
}

fn syntax(node: &roxmltree::Node, doc: &roxmltree::Document, message: String) -> LayoutError {
    let pos = doc.text_pos_at(node.range().start);
    let name = node.tag_name().name();
    let id = node
        .attribute("id")
        .map(|i| format!(" id=\"{i}\""))
        .unwrap_or_default();
    LayoutError::Entity {
        place: format!("SVG line {}, column {}: <{name}{id}>", pos.row, pos.col),
        message,
    }
}

/// Points of a cubic Bézier after `p0`, halving it until its control points lie within
/// `tol` of its chord (the curve lies in their hull, so it is within `tol` too).
fn cubic(p: [Point; 4], tol: f64, depth: u32, out: &mut Vec<Point>) {
    let dev = |q: Point| {
        let (dx, dy) = (p[3][0] - p[0][0], p[3][1] - p[0][1]);
        let len = (dx * dx + dy * dy).sqrt();
        if len == 0.0 {
            ((q[0] - p[0][0]).powi(2) + (q[1] - p[0][1]).powi(2)).sqrt()
        } else {
            ((q[0] - p[0][0]) * dy - (q[1] - p[0][1]) * dx).abs() / len
        }
    };
    if depth >= 16 || (dev(p[1]) <= tol && dev(p[2]) <= tol) {
        out.push(p[3]);
        return;
    }
    let m = |a: Point, b: Point| [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
    let (p01, p12, p23) = (m(p[0], p[1]), m(p[1], p[2]), m(p[2], p[3]));
    let (p012, p123) = (m(p01, p12), m(p12, p23));
    let mid = m(p012, p123);
    cubic([p[0], p01, p012, mid], tol, depth + 1, out);
    cubic([mid, p123, p23, p[3]], tol, depth + 1, out);
}

fn ring_area(r: &[Point]) -> f64 {
    let n = r.len();
    (0..n)
        .map(|i| r[i][0] * r[(i + 1) % n][1] - r[(i + 1) % n][0] * r[i][1])
        .sum::<f64>()
        / 2.0
}

/// The largest coordinate or arc radius read in path data, in user units: far above
/// any part a layout may hold (`MAX_COORDINATE_MM` in model.rs, whatever the
/// viewBox's scale), low enough that an arc stays a few hundred cubics.
const MAX_PATH_NUMBER: f64 = 1e9;

/// Closed rings of a path's `d` in the element's own coordinates.
fn path_rings(d: &str, tol: f64, join: f64) -> Result<Vec<Vec<Point>>, String> {
    let mut rings = Vec::new();
    let mut current: Vec<Point> = Vec::new();
    let mut closed = false;
    let finish = |ring: &mut Vec<Point>,
                  closed: bool,
                  rings: &mut Vec<Vec<Point>>|
     -> Result<(), String> {
        if ring.len() <= 1 {
            ring.clear();
            return Ok(());
        }
        let (a, b) = (ring[0], ring[ring.len() - 1]);
        let gap = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        // A `Z` closes the subpath itself: its last point is a vertex of its own unless
        // it repeats the start (up to rounding of relative moves). Without `Z`, an end
        // within the join tolerance of the start closes it.
        let repeats_start = gap <= 1e-9 * (1.0 + a[0].abs().max(a[1].abs()));
        if repeats_start || (!closed && gap <= join) {
            ring.pop();
        } else if !closed {
            return Err(format!(
                "subpath {} is open: it ends at ({:.3}, {:.3}), {gap:.3} from its start ({:.3}, {:.3})",
                rings.len() + 1,
                b[0],
                b[1],
                a[0],
                a[1]
            ));
        }
        rings.push(std::mem::take(ring));
        Ok(())
    };
    // svgtypes turns an arc into cubics within 0.1 user units (kurbo), so their count
    // grows with the radius, which is at least half the chord: a radius or an end point
    // of 1e50 in a file would ask for ~1e8 of them. Numbers past any cutting table are
    // refused before that conversion.
    for seg in svgtypes::PathParser::from(d) {
        use svgtypes::PathSegment as S;
        let numbers: &[f64] = match &seg {
            Ok(S::MoveTo { x, y, .. }) | Ok(S::LineTo { x, y, .. }) => &[*x, *y],
            Ok(S::HorizontalLineTo { x, .. }) => &[*x],
            Ok(S::VerticalLineTo { y, .. }) => &[*y],
            Ok(S::CurveTo {
                x1,
                y1,
                x2,
                y2,
                x,
                y,
                ..
            }) => &[*x1, *y1, *x2, *y2, *x, *y],
            Ok(S::SmoothCurveTo { x2, y2, x, y, .. }) => &[*x2, *y2, *x, *y],
            Ok(S::Quadratic { x1, y1, x, y, .. }) => &[*x1, *y1, *x, *y],
            Ok(S::SmoothQuadratic { x, y, .. }) => &[*x, *y],
            Ok(S::EllipticalArc { rx, ry, x, y, .. }) => &[*rx, *ry, *x, *y],
            Ok(S::ClosePath { .. }) | Err(_) => &[],
        };
        if let Some(v) = numbers.iter().find(|v| !(v.abs() <= MAX_PATH_NUMBER)) {
            return Err(format!(
                "path data: the number {v:e} is beyond {MAX_PATH_NUMBER:e} user units"
            ));
        }
    }
    for seg in SimplifyingPathParser::from(d) {
        let seg = seg.map_err(|e| format!("path data: {e}"))?;
        match seg {
            SimplePathSegment::MoveTo { x, y } => {
                finish(&mut current, closed, &mut rings)?;
                closed = false;
                current.push([x, y]);
            }
            SimplePathSegment::LineTo { x, y } => current.push([x, y]),
            SimplePathSegment::CurveTo {
                x1,
                y1,
                x2,
                y2,
                x,
                y,
            } => {
                let p0 = *current.last().ok_or("curve before any point")?;
                cubic([p0, [x1, y1], [x2, y2], [x, y]], tol, 0, &mut current);
            }
            SimplePathSegment::Quadratic { x1, y1, x, y } => {
                let p0 = *current.last().ok_or("curve before any point")?;
                // The same curve as a cubic (degree elevation).
                let c1 = [
                    p0[0] + 2.0 / 3.0 * (x1 - p0[0]),
                    p0[1] + 2.0 / 3.0 * (y1 - p0[1]),
                ];
                let c2 = [x + 2.0 / 3.0 * (x1 - x), y + 2.0 / 3.0 * (y1 - y)];
                cubic([p0, c1, c2, [x, y]], tol, 0, &mut current);
            }
            SimplePathSegment::ClosePath => {
                // The point after a Z starts where the subpath started.
                let start = current.first().copied();
                finish(&mut current, true, &mut rings)?;
                closed = false;
                if let Some(s) = start {
                    current.push(s);
                }
            }
        }
    }
    finish(&mut current, closed, &mut rings)?;
    Ok(rings)
}

fn number(node: &roxmltree::Node, name: &str) -> Result<f64, String> {
    let text = node.attribute(name).unwrap_or("0");
    let len = svgtypes::Length::from_str(text)
        .map_err(|e| format!("attribute {name}=\"{text}\": {e}"))?;
    if len.unit != svgtypes::LengthUnit::None && len.unit != svgtypes::LengthUnit::Px {
        return Err(format!(
            "attribute {name}=\"{text}\": give the value in user units"
        ));
    }
    Ok(len.number)
}

/// The user unit in mm (see the module's documentation). A `width` or `viewBox` that
/// is there but not readable is refused: guessing 1 mm a unit would cut the parts at
/// another scale.
fn user_unit(root: &roxmltree::Node, doc: &roxmltree::Document) -> Result<f64, LayoutError> {
    let width = match root.attribute("width") {
        Some(w) => Some(
            svgtypes::Length::from_str(w)
                .ok()
                .filter(|l| l.number.is_finite() && l.number > 0.0)
                .ok_or_else(|| {
                    syntax(root, doc, format!("width `{w}` is not a positive length"))
                })?,
        ),
        None => None,
    };
    let view_box = match root.attribute("viewBox") {
        Some(v) => Some(
            svgtypes::ViewBox::from_str(v)
                .ok()
                .filter(|b| {
                    [b.x, b.y, b.w, b.h].iter().all(|n| n.is_finite()) && b.w > 0.0 && b.h > 0.0
                })
                .ok_or_else(|| {
                    syntax(
                        root,
                        doc,
                        format!(
                            "viewBox `{v}` is not four numbers with a positive width and height"
                        ),
                    )
                })?,
        ),
        None => None,
    };
    let (Some(w), Some(vb)) = (width, view_box) else {
        return Ok(1.0);
    };
    use svgtypes::LengthUnit as U;
    let mm = match w.unit {
        U::Mm => 1.0,
        U::Cm => 10.0,
        U::In => 25.4,
        U::Pt => 25.4 / 72.0,
        U::Pc => 25.4 / 6.0,
        _ => return Ok(1.0),
    };
    Ok(w.number * mm / vb.w)
}

/// The most attributes one element may have. The XML parser's duplicate check is
/// quadratic in them (an element of 200 000 attributes took minutes); drawings have a
/// few dozen.
pub const MAX_ATTRIBUTES: usize = 1000;

/// Refuses, before parsing, a start tag with more than [`MAX_ATTRIBUTES`] attributes,
/// naming its line and column: one pass over the text, counting `=` outside quotes
/// between `<name` and `>` (comments, CDATA, declarations and processing instructions
/// skipped).
fn check_attribute_counts(text: &str) -> Result<(), LayoutError> {
    let b = text.as_bytes();
    let mut i = 0;
    while let Some(k) = b[i..].iter().position(|&c| c == b'<') {
        let start = i + k;
        let rest = &b[start..];
        let skip_to = |end: &[u8]| {
            rest.windows(end.len())
                .position(|w| w == end)
                .map(|p| start + p + end.len())
                .unwrap_or(b.len())
        };
        if rest.starts_with(b"<!--") {
            i = skip_to(b"-->");
            continue;
        }
        if rest.starts_with(b"<![CDATA[") {
            i = skip_to(b"]]>");
            continue;
        }
        if !rest
            .get(1)
            .is_some_and(|c| c.is_ascii_alphabetic() || *c == b'_' || *c == b':')
        {
            i = start + 1;
            continue;
        }
        let mut quote = None;
        let mut attributes = 0usize;
        let mut j = start + 1;
        while j < b.len() {
            let c = b[j];
            match quote {
                Some(q) if c == q => quote = None,
                Some(_) => {}
                None if c == b'"' || c == b'\'' => quote = Some(c),
                None if c == b'=' => attributes += 1,
                None if c == b'>' || c == b'<' => break,
                None => {}
            }
            j += 1;
        }
        if attributes > MAX_ATTRIBUTES {
            let line = b[..start].iter().filter(|&&c| c == b'\n').count() + 1;
            let column = start
                - b[..start]
                    .iter()
                    .rposition(|&c| c == b'\n')
                    .map_or(0, |p| p + 1)
                + 1;
            let name: String = text[start + 1..]
                .chars()
                .take_while(|c| !c.is_whitespace() && *c != '>' && *c != '/')
                .take(40)
                .collect();
            return Err(LayoutError::Syntax {
                format: "SVG",
                message: format!(
                    "line {line}, column {column}: element <{name}> has {attributes} attributes, more than the {MAX_ATTRIBUTES} a drawing's element may have"
                ),
            });
        }
        i = j.max(start + 1);
    }
    Ok(())
}

pub(crate) fn read(bytes: &[u8], options: &ReadOptions) -> Result<Vec<Part>, LayoutError> {
    let text = std::str::from_utf8(bytes).map_err(|e| LayoutError::Syntax {
        format: "SVG",
        message: format!("not UTF-8: {e}"),
    })?;
    check_attribute_counts(text)?;
    let doc = roxmltree::Document::parse(text).map_err(|e| LayoutError::Syntax {
        format: "SVG",
        message: e.to_string(),
    })?;
    let root = doc.root_element();
    if root.tag_name().name() != "svg" {
        return Err(LayoutError::Syntax {
            format: "SVG",
            message: "the root element is not <svg>".into(),
        });
    }
    let unit = user_unit(&root, &doc)?;
    let root_ctm = Transform::new(unit, 0.0, 0.0, unit, 0.0, 0.0);
    let mut parts = Vec::new();
    let mut count = 0usize;
    for node in root.descendants().filter(|n| n.is_element()) {
        let name = node.tag_name().name();
        if !matches!(
            name,
            "path" | "polygon" | "rect" | "circle" | "line" | "polyline" | "ellipse" | "use"
        ) {
            continue;
        }
        if node
            .ancestors()
            .any(|a| SKIPPED_CONTAINERS.contains(&a.tag_name().name()))
        {
            continue;
        }
        count += 1;
        let err = |m: String| syntax(&node, &doc, m);
        // The transforms from the root down to the element.
        let mut ctm = root_ctm;
        let chain: Vec<_> = node.ancestors().collect();
        for n in chain.iter().rev() {
            if let Some(t) = n.attribute("transform") {
                let t =
                    Transform::from_str(t).map_err(|e| err(format!("transform \"{t}\": {e}")))?;
                ctm = mul(&ctm, &t);
            }
        }
        let scale = (ctm.a * ctm.d - ctm.b * ctm.c).abs().sqrt();
        if !(scale > 0.0) || !scale.is_finite() {
            return Err(err("the element's transforms collapse it".into()));
        }
        // Tolerances in the element's own units.
        let tol = options.chord_tolerance_mm / scale;
        let join = options.join_tolerance_mm / scale;
        let rings: Vec<Vec<Point>> = match name {
            "path" => path_rings(node.attribute("d").unwrap_or(""), tol, join).map_err(err)?,
            "polygon" => {
                let pts: Vec<Point> =
                    svgtypes::PointsParser::from(node.attribute("points").unwrap_or(""))
                        .map(|(x, y)| [x, y])
                        .collect();
                vec![pts]
            }
            "rect" => {
                let (x, y, w, h) = (
                    number(&node, "x"),
                    number(&node, "y"),
                    number(&node, "width"),
                    number(&node, "height"),
                );
                let (x, y, w, h) = (
                    x.map_err(err)?,
                    y.map_err(err)?,
                    w.map_err(err)?,
                    h.map_err(err)?,
                );
                if node.attribute("rx").is_some() || node.attribute("ry").is_some() {
                    return Err(err(
                        "rounded rectangles are not read: draw them as a path".into()
                    ));
                }
                vec![vec![[x, y], [x + w, y], [x + w, y + h], [x, y + h]]]
            }
            "circle" => {
                let (cx, cy, r) = (
                    number(&node, "cx").map_err(err)?,
                    number(&node, "cy").map_err(err)?,
                    number(&node, "r").map_err(err)?,
                );
                let mut pts =
                    crate::flatten::arc_points([cx, cy], r, 0.0, std::f64::consts::TAU, tol)
                        .map_err(err)?;
                pts.pop();
                vec![pts]
            }
            "ellipse" => return Err(err("ellipses are not read: draw them as a path".into())),
            "use" => {
                return Err(err(
                    "a <use> reference is not read: expand it into its shape".into(),
                ))
            }
            _ => return Err(err("an open line cannot be a part's contour".into())),
        };
        let mut rings: Vec<Vec<Point>> = rings
            .into_iter()
            .map(|r| r.into_iter().map(|p| apply(&ctm, p[0], p[1])).collect())
            .collect();
        if rings.is_empty() {
            return Err(err("the element draws no contour".into()));
        }
        let outer_index = (0..rings.len())
            .max_by(|&a, &b| {
                ring_area(&rings[a])
                    .abs()
                    .total_cmp(&ring_area(&rings[b]).abs())
            })
            .unwrap_or(0);
        let outer = rings.swap_remove(outer_index);
        let attributes: BTreeMap<String, String> = node
            .attributes()
            .filter(|a| {
                a.namespace().is_none()
                    && !GEOMETRY_ATTRIBUTES.contains(&a.name())
                    && a.name() != "ry"
                    && a.name() != "r"
            })
            .map(|a| (a.name().to_string(), a.value().to_string()))
            .collect();
        parts.push(Part {
            id: node
                .attribute("id")
                .map(str::to_string)
                .unwrap_or_else(|| format!("{name}{}", count - 1)),
            outer,
            holes: rings,
            layer: node.attribute("class").unwrap_or("").to_string(),
            attributes,
        });
    }
    Ok(parts)
}

fn xml_name(k: &str) -> bool {
    let mut chars = k.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
        && !GEOMETRY_ATTRIBUTES.contains(&k)
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The layout as SVG: one `<path>` per part (user unit 1 mm, `fill-rule="evenodd"` so
/// holes show), keeping id, class and attributes.
pub(crate) fn write(parts: &[Part]) -> String {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in parts {
        let pb = p.bounds();
        b = [
            b[0].min(pb[0]),
            b[1].min(pb[1]),
            b[2].max(pb[2]),
            b[3].max(pb[3]),
        ];
    }
    if !b[0].is_finite() {
        b = [0.0, 0.0, 1.0, 1.0];
    }
    let (w, h) = ((b[2] - b[0]).max(1e-9), (b[3] - b[1]).max(1e-9));
    let mut s = format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}mm\" height=\"{h}mm\" viewBox=\"{} {} {w} {h}\">\n",
        b[0], b[1]
    );
    for p in parts {
        let mut d = String::new();
        for ring in std::iter::once(&p.outer).chain(&p.holes) {
            for (i, q) in ring.iter().enumerate() {
                d.push_str(if i == 0 { "M" } else { " L" });
                d.push_str(&format!("{} {}", q[0], q[1]));
            }
            d.push_str(" Z ");
        }
        s.push_str(&format!("  <path id=\"{}\"", escape(&p.id)));
        if !p.layer.is_empty() {
            s.push_str(&format!(" class=\"{}\"", escape(&p.layer)));
        }
        let mut attributes = p.attributes.clone();
        attributes
            .entry("fill-rule".into())
            .or_insert_with(|| "evenodd".into());
        // Only keys that are XML names can be attributes (JSON attributes may be anything).
        for (k, v) in attributes.iter().filter(|(k, _)| xml_name(k)) {
            s.push_str(&format!(" {}=\"{}\"", k, escape(v)));
        }
        s.push_str(&format!(" d=\"{}\"/>\n", d.trim_end()));
    }
    s.push_str("</svg>\n");
    s
}
