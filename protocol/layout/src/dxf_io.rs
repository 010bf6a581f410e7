//! DXF layouts, read and written with the `dxf` crate.
//!
//! Units: `$INSUNITS` in the header says the drawing unit (1 in = 25.4 mm, 2 ft,
//! 4 mm, 5 cm, 6 m); a drawing without it (or unitless, 0) is refused, since a layout
//! read in the wrong unit would be cut at the wrong size. Only model space is read.
//!
//! Parts:
//! - An INSERT of a block is one part, as apparel CAD exports pieces (one block per
//!   piece). Its id is the block name (`name#2`, `name#3` for later inserts of the same
//!   block). The block's closed contours are the part: the largest is the outer contour,
//!   the others its holes; open pieces inside a block (grain lines, notches, drill marks)
//!   are marks, not contours, and are left out. Arrays (MINSERT) and nested INSERTs are
//!   refused.
//! - Elsewhere, every closed contour is one: closed LWPOLYLINE/POLYLINE (bulges flattened),
//!   CIRCLE, closed SPLINE, or a loop of LINE, ARC, open polyline and open SPLINE pieces
//!   whose ends meet within the join tolerance. A contour inside another is its hole; one
//!   inside a hole is a part again. The part's id is the handle of the outer contour's
//!   first entity (hex, as in the file), its layer that entity's layer. A piece that does
//!   not close is refused with the handles of its entities.
//! - Other entities (TEXT, POINT, HATCH, DIMENSION, ...) are not parts and stay where
//!   they are.
//!
//! Entities whose extrusion direction is (0, 0, -1) (mirrored object coordinates) are
//! read mirrored in X as DXF defines; any other non-Z extrusion is refused.
//!
//! Writing a DXF layout back moves each part's own entities (or its INSERT and the
//! INSERT's attributes) by the part's offset; nothing else in the drawing changes. A
//! layout from another format is written as one block per part (named by the part's id,
//! closed LWPOLYLINEs on the part's layer) inserted at the origin, with `$INSUNITS` = 4.

use std::collections::HashMap;

use dxf::entities::{Entity, EntityType, Insert, LwPolyline};
use dxf::enums::Units;
use dxf::{Block, Drawing, LwPolylineVertex};

use crate::flatten::{arc_points, bulge_points, nurbs_points};
use crate::model::{LayoutError, Part, Point, ReadOptions};

/// Which entities of the drawing make up each part (indices into the model-space
/// entity list), for moving them on writing.
#[derive(Debug, Clone)]
pub(crate) struct DxfSource {
    drawing: Drawing,
    unit_mm: f64,
    parts: Vec<Vec<usize>>,
    offsets: Vec<Point>,
    /// What the crate does not write back (see `dxf_tidy`).
    mlines: crate::dxf_tidy::MlineElements,
}

fn handle(e: &Entity) -> String {
    format!(
        "DXF entity {} (handle {})",
        type_name(&e.specific),
        e.common.handle.as_string()
    )
}

fn type_name(t: &EntityType) -> &'static str {
    match t {
        EntityType::LwPolyline(_) => "LWPOLYLINE",
        EntityType::Polyline(_) => "POLYLINE",
        EntityType::Line(_) => "LINE",
        EntityType::Arc(_) => "ARC",
        EntityType::Circle(_) => "CIRCLE",
        EntityType::Spline(_) => "SPLINE",
        EntityType::Insert(_) => "INSERT",
        _ => "entity",
    }
}

fn entity_error(e: &Entity, message: impl Into<String>) -> LayoutError {
    LayoutError::Entity {
        place: handle(e),
        message: message.into(),
    }
}

/// +1, or -1 when the entity's object coordinates are mirrored (extrusion (0,0,-1)).
fn ocs_sign(e: &Entity, z: (f64, f64, f64)) -> Result<f64, LayoutError> {
    let (x, y, zz) = z;
    if x.abs() > 1e-9 || y.abs() > 1e-9 || !(zz.abs() > 0.0) {
        return Err(entity_error(
            e,
            format!("extrusion direction ({x}, {y}, {zz}) is not along Z: not a flat contour"),
        ));
    }
    Ok(zz.signum())
}

/// A contour or an open piece of one, in drawing units.
struct Piece {
    points: Vec<Point>,
    closed: bool,
    entity: usize,
}

/// The pieces one entity draws, or none when it draws no contour (text, points, ...).
fn pieces_of(e: &Entity, index: usize, tol: f64) -> Result<Option<Piece>, LayoutError> {
    let err = |m: String| entity_error(e, m);
    let piece = |points: Vec<Point>, closed: bool| {
        if closed && points.len() < 3 {
            return Err(entity_error(
                e,
                format!("closed contour of {} point(s)", points.len()),
            ));
        }
        Ok(Some(Piece {
            points,
            closed,
            entity: index,
        }))
    };
    match &e.specific {
        EntityType::LwPolyline(p) => {
            let s = ocs_sign(
                e,
                (
                    p.extrusion_direction.x,
                    p.extrusion_direction.y,
                    p.extrusion_direction.z,
                ),
            )?;
            let v: Vec<(Point, f64)> = p
                .vertices
                .iter()
                .map(|v| ([s * v.x, v.y], s * v.bulge))
                .collect();
            piece(bulged(&v, p.is_closed(), tol).map_err(err)?, p.is_closed())
        }
        EntityType::Polyline(p) => {
            if p.is_3d_polygon_mesh() || p.is_polyface_mesh() {
                return Err(err("a mesh is not a contour".into()));
            }
            let s = if p.is_3d_polyline() {
                1.0
            } else {
                ocs_sign(e, (p.normal.x, p.normal.y, p.normal.z))?
            };
            let v: Vec<(Point, f64)> = p
                .vertices()
                .map(|v| ([s * v.location.x, v.location.y], s * v.bulge))
                .collect();
            piece(bulged(&v, p.is_closed(), tol).map_err(err)?, p.is_closed())
        }
        EntityType::Line(l) => piece(vec![[l.p1.x, l.p1.y], [l.p2.x, l.p2.y]], false),
        EntityType::Arc(a) => {
            let s = ocs_sign(e, (a.normal.x, a.normal.y, a.normal.z))?;
            let (start, mut end) = (a.start_angle.to_radians(), a.end_angle.to_radians());
            while end <= start {
                end += std::f64::consts::TAU;
            }
            let c = [a.center.x, a.center.y];
            let mut pts = vec![[c[0] + a.radius * start.cos(), c[1] + a.radius * start.sin()]];
            pts.extend(arc_points(c, a.radius, start, end - start, tol).map_err(err)?);
            piece(pts.into_iter().map(|p| [s * p[0], p[1]]).collect(), false)
        }
        EntityType::Circle(c) => {
            let s = ocs_sign(e, (c.normal.x, c.normal.y, c.normal.z))?;
            let mut pts = arc_points(
                [c.center.x, c.center.y],
                c.radius,
                0.0,
                std::f64::consts::TAU,
                tol,
            )
            .map_err(err)?;
            pts.pop();
            piece(pts.into_iter().map(|p| [s * p[0], p[1]]).collect(), true)
        }
        EntityType::Spline(sp) => {
            if sp.control_points.is_empty() {
                return Err(err(format!(
                    "a spline given only by {} fit points is not read: export it with control points",
                    sp.fit_points.len()
                )));
            }
            let degree = usize::try_from(sp.degree_of_curve)
                .map_err(|_| err("negative spline degree".into()))?;
            let ctrl: Vec<Point> = sp.control_points.iter().map(|p| [p.x, p.y]).collect();
            let mut pts = nurbs_points(degree, &sp.knot_values, &ctrl, &sp.weight_values, tol)
                .map_err(err)?;
            let closed = pts.len() > 2 && dist(pts[0], pts[pts.len() - 1]) <= tol;
            if closed {
                pts.pop();
            }
            piece(pts, closed)
        }
        _ => Ok(None),
    }
}

fn dist(a: Point, b: Point) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// A polyline's points with its bulged segments flattened.
fn bulged(v: &[(Point, f64)], closed: bool, tol: f64) -> Result<Vec<Point>, String> {
    let Some(first) = v.first() else {
        return Ok(vec![]);
    };
    let mut pts = vec![first.0];
    let segments = if closed { v.len() } else { v.len() - 1 };
    for i in 0..segments {
        let (p0, b) = v[i];
        let p1 = v[(i + 1) % v.len()].0;
        pts.extend(bulge_points(p0, p1, b, tol)?);
    }
    if closed {
        pts.pop();
    }
    Ok(pts)
}

/// Joins pieces end to end (either way round) into closed contours; returns the
/// contours (with the entities they came from) and the chains left open.
/// A chain of points with the entities (indices) it was drawn by.
type Chain = (Vec<Point>, Vec<usize>);
/// An outer contour, its entities, and its holes.
type Nested = (Vec<Point>, Vec<usize>, Vec<Vec<Point>>);

fn join(pieces: Vec<Piece>, tol: f64) -> (Vec<Chain>, Vec<Chain>) {
    let mut closed = Vec::new();
    let mut open_pieces = Vec::new();
    for p in pieces {
        if p.closed {
            closed.push((p.points, vec![p.entity]));
        } else if p.points.len() >= 2 {
            open_pieces.push(p);
        }
    }
    let mut used = vec![false; open_pieces.len()];
    let mut open = Vec::new();
    for i in 0..open_pieces.len() {
        if used[i] {
            continue;
        }
        used[i] = true;
        let mut chain = open_pieces[i].points.clone();
        let mut entities = vec![open_pieces[i].entity];
        loop {
            let end = chain[chain.len() - 1];
            if chain.len() > 2 && dist(end, chain[0]) <= tol {
                chain.pop();
                closed.push((std::mem::take(&mut chain), entities.clone()));
                break;
            }
            let next = (0..open_pieces.len()).find_map(|j| {
                if used[j] {
                    return None;
                }
                let pts = &open_pieces[j].points;
                if dist(pts[0], end) <= tol {
                    Some((j, false))
                } else if dist(pts[pts.len() - 1], end) <= tol {
                    Some((j, true))
                } else {
                    None
                }
            });
            let Some((j, reversed)) = next else {
                open.push((chain, entities));
                break;
            };
            used[j] = true;
            entities.push(open_pieces[j].entity);
            let mut pts = open_pieces[j].points.clone();
            if reversed {
                pts.reverse();
            }
            chain.extend(pts.into_iter().skip(1));
        }
    }
    (closed, open)
}

fn area(r: &[Point]) -> f64 {
    let n = r.len();
    (0..n)
        .map(|i| r[i][0] * r[(i + 1) % n][1] - r[(i + 1) % n][0] * r[i][1])
        .sum::<f64>()
        / 2.0
}

fn inside(p: Point, ring: &[Point]) -> bool {
    let mut c = false;
    let n = ring.len();
    for i in 0..n {
        let (a, b) = (ring[i], ring[(i + 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1])
            && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0]
        {
            c = !c;
        }
    }
    c
}

fn bbox(r: &[Point]) -> [f64; 4] {
    r.iter().fold(
        [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ],
        |b, p| {
            [
                b[0].min(p[0]),
                b[1].min(p[1]),
                b[2].max(p[0]),
                b[3].max(p[1]),
            ]
        },
    )
}

/// Groups rings into (outer, holes) by nesting: a ring's container is the smallest ring
/// holding it; rings at even depth are outer contours, at odd depth holes.
fn nest(rings: Vec<Chain>) -> Vec<Nested> {
    let mut order: Vec<usize> = (0..rings.len()).collect();
    let areas: Vec<f64> = rings.iter().map(|r| area(&r.0).abs()).collect();
    let boxes: Vec<[f64; 4]> = rings.iter().map(|r| bbox(&r.0)).collect();
    // Largest first, so a ring's containers are all before it.
    order.sort_by(|&a, &b| areas[b].total_cmp(&areas[a]));
    let mut depth = vec![0usize; rings.len()];
    let mut parent = vec![usize::MAX; rings.len()];
    for (k, &i) in order.iter().enumerate() {
        let p = rings[i].0[0];
        let b = boxes[i];
        // The smallest earlier (larger) ring that holds this one.
        for &j in order[..k].iter().rev() {
            let c = boxes[j];
            if b[0] >= c[0]
                && b[1] >= c[1]
                && b[2] <= c[2]
                && b[3] <= c[3]
                && areas[j] > areas[i]
                && inside(p, &rings[j].0)
            {
                depth[i] = depth[j] + 1;
                parent[i] = j;
                break;
            }
        }
    }
    let mut out: Vec<Nested> = Vec::new();
    let mut slot = HashMap::new();
    let mut rings: Vec<Option<Chain>> = rings.into_iter().map(Some).collect();
    let mut by_index: Vec<usize> = (0..rings.len()).collect();
    by_index.sort_by_key(|&i| rings[i].as_ref().map(|r| r.1[0]).unwrap_or(0));
    for &i in &by_index {
        if depth[i].is_multiple_of(2) {
            if let Some((pts, ents)) = rings[i].take() {
                slot.insert(i, out.len());
                out.push((pts, ents, vec![]));
            }
        }
    }
    for i in 0..rings.len() {
        if depth[i] % 2 == 1 {
            if let (Some((pts, ents)), Some(&s)) = (rings[i].take(), slot.get(&parent[i])) {
                out[s].1.extend(ents);
                out[s].2.push(pts);
            }
        }
    }
    out
}

fn unit_mm(drawing: &Drawing) -> Result<f64, LayoutError> {
    match drawing.header.default_drawing_units {
        Units::Unitless => Err(LayoutError::MissingUnits),
        Units::Inches => Ok(25.4),
        Units::Feet => Ok(304.8),
        Units::Millimeters => Ok(1.0),
        Units::Centimeters => Ok(10.0),
        Units::Meters => Ok(1000.0),
        other => Err(LayoutError::UnsupportedUnits(format!("{other:?}"))),
    }
}

/// The most vertices a DXF layout may expand to (its parts' contours, every INSERT's
/// copy of its block included): 64 MB of points, far beyond any cutting layout (a marker
/// of 500 pieces of 1 000 vertices is 500 000). A drawing of 20 000 INSERTs of one
/// large block grew to 2.5 GB before this bound.
pub const MAX_VERTICES: usize = 4_000_000;

/// A block's contours at one chord tolerance (in block units): the outer contour and
/// the holes, and their vertex count.
type BlockShape = (Vec<Point>, Vec<Vec<Point>>);

fn vertices_of(shape: &BlockShape) -> usize {
    shape.0.len() + shape.1.iter().map(Vec::len).sum::<usize>()
}

/// The tolerance key of an INSERT: its block and its scale (the chord tolerance in block
/// units depends on it).
type InsertKey = (String, u64, u64);

fn insert_key(ins: &Insert) -> InsertKey {
    (
        ins.name.clone(),
        ins.x_scale_factor.abs().to_bits(),
        ins.y_scale_factor.abs().to_bits(),
    )
}

/// Before any INSERT is placed: the vertices all of them expand to, estimated from each
/// distinct (block, scale) flattened once, times the INSERTs of it; refused naming the
/// estimate when beyond [`MAX_VERTICES`]. The flattening stops as soon as the estimate
/// passes the bound, so the work is bounded too. Returns the shapes to place and the
/// vertices they expand to.
fn insert_shapes(
    blocks: &HashMap<&str, &Block>,
    inserts: &[(&Entity, &Insert)],
    options: &ReadOptions,
    unit: f64,
) -> Result<(HashMap<InsertKey, BlockShape>, usize), LayoutError> {
    let mut uses: HashMap<InsertKey, (usize, &Entity, &Insert)> = HashMap::new();
    for (e, ins) in inserts {
        uses.entry(insert_key(ins)).or_insert((0, e, ins)).0 += 1;
    }
    // Most-used first: an explosion is found after flattening few blocks.
    let mut order: Vec<_> = uses.into_iter().collect();
    order.sort_by(|a, b| b.1 .0.cmp(&a.1 .0).then_with(|| a.0.cmp(&b.0)));
    let mut shapes = HashMap::new();
    let mut estimate = 0usize;
    for (key, (n, e, ins)) in order {
        let shape = block_shape(blocks, e, ins, options, unit)?;
        let each = vertices_of(&shape);
        estimate = estimate.saturating_add(each.saturating_mul(n));
        if estimate > MAX_VERTICES {
            return Err(entity_error(
                e,
                format!(
                    "the drawing's {} INSERTs expand to at least {estimate} vertices (block `{}` of {each} vertices placed {n} times), more than the {MAX_VERTICES} a layout may have",
                    inserts.len(),
                    ins.name
                ),
            ));
        }
        shapes.insert(key, shape);
    }
    Ok((shapes, estimate))
}

/// The part an INSERT places: its block's closed contours (flattened once per block and
/// scale, [`insert_shapes`]), placed by the INSERT.
fn place_insert(
    shape: &BlockShape,
    block: &Block,
    e: &Entity,
    ins: &Insert,
    unit: f64,
) -> Result<(Vec<Point>, Vec<Vec<Point>>), LayoutError> {
    let s = ocs_sign(
        e,
        (
            ins.extrusion_direction.x,
            ins.extrusion_direction.y,
            ins.extrusion_direction.z,
        ),
    )?;
    let (sx, sy) = (ins.x_scale_factor, ins.y_scale_factor);
    let (rot_sin, rot_cos) = ins.rotation.to_radians().sin_cos();
    let b = [block.base_point.x, block.base_point.y];
    let place = |p: &Point| {
        let (x, y) = ((p[0] - b[0]) * sx, (p[1] - b[1]) * sy);
        let (x, y) = (
            x * rot_cos - y * rot_sin + ins.location.x,
            x * rot_sin + y * rot_cos + ins.location.y,
        );
        [s * x * unit, y * unit]
    };
    Ok((
        shape.0.iter().map(place).collect(),
        shape
            .1
            .iter()
            .map(|h| h.iter().map(place).collect())
            .collect(),
    ))
}

/// An INSERT's block flattened at the INSERT's scale: its one outer contour and holes,
/// in block units.
fn block_shape(
    blocks: &HashMap<&str, &Block>,
    e: &Entity,
    ins: &Insert,
    options: &ReadOptions,
    unit: f64,
) -> Result<BlockShape, LayoutError> {
    let err = |m: String| entity_error(e, m);
    if ins.column_count > 1 || ins.row_count > 1 {
        return Err(err(format!(
            "an array insert ({} x {}) is not read",
            ins.column_count, ins.row_count
        )));
    }
    let block = blocks
        .get(ins.name.as_str())
        .ok_or_else(|| err(format!("block `{}` is not defined", ins.name)))?;
    ocs_sign(
        e,
        (
            ins.extrusion_direction.x,
            ins.extrusion_direction.y,
            ins.extrusion_direction.z,
        ),
    )?;
    let (sx, sy) = (ins.x_scale_factor, ins.y_scale_factor);
    if !(sx.abs() > 0.0) || !(sy.abs() > 0.0) || !sx.is_finite() || !sy.is_finite() {
        return Err(err(format!(
            "scale factors ({sx}, {sy}) must be finite and non-zero"
        )));
    }
    // Block units are scaled by the insert: tolerances in block units shrink accordingly.
    let scale = sx.abs().min(sy.abs());
    let tol = options.chord_tolerance_mm / unit / scale;
    let join_tol = options.join_tolerance_mm / unit / scale;
    let mut pieces = Vec::new();
    for (k, be) in block.entities.iter().enumerate() {
        if matches!(be.specific, EntityType::Insert(_)) {
            return Err(err(format!(
                "block `{}` holds another INSERT: nested blocks are not read",
                ins.name
            )));
        }
        if let Some(p) = pieces_of(be, k, tol)? {
            pieces.push(p);
        }
    }
    let (rings, _marks) = join(pieces, join_tol);
    let mut parts = nest(rings);
    if parts.is_empty() {
        return Err(err(format!("block `{}` has no closed contour", ins.name)));
    }
    if parts.len() > 1 {
        return Err(err(format!(
            "block `{}` has {} separate outer contours: one piece per block",
            ins.name,
            parts.len()
        )));
    }
    let (outer, _, holes) = parts.remove(0);
    Ok((outer, holes))
}

pub(crate) fn read(
    bytes: &[u8],
    options: &ReadOptions,
) -> Result<(Vec<Part>, DxfSource), LayoutError> {
    // The dxf crate panics (in chrono) on some out-of-range header dates, e.g. a
    // $TDCREATE of 2461368032384259161: such a file is refused like any unreadable one.
    let loaded = std::panic::catch_unwind(|| Drawing::load(&mut std::io::Cursor::new(bytes)));
    let drawing = match loaded {
        Ok(Ok(d)) => d,
        Ok(Err(e)) => {
            return Err(LayoutError::Syntax {
                format: "DXF",
                message: e.to_string(),
            })
        }
        Err(_) => {
            return Err(LayoutError::Syntax {
                format: "DXF",
                message: "the DXF reader failed on this file (a header value out of range?)".into(),
            })
        }
    };
    let unit = unit_mm(&drawing)?;
    let blocks: HashMap<&str, &Block> = drawing.blocks().map(|b| (b.name.as_str(), b)).collect();
    let entities: Vec<&Entity> = drawing.entities().collect();
    let tol = options.chord_tolerance_mm / unit;
    let mut parts = Vec::new();
    let mut sources = Vec::new();
    let mut inserts_seen: HashMap<String, usize> = HashMap::new();
    let mut pieces = Vec::new();
    let inserts: Vec<(&Entity, &Insert)> = entities
        .iter()
        .filter(|e| !e.common.is_in_paper_space)
        .filter_map(|e| match &e.specific {
            EntityType::Insert(ins) => Some((*e, ins)),
            _ => None,
        })
        .collect();
    let (shapes, mut vertices) = insert_shapes(&blocks, &inserts, options, unit)?;
    for (i, e) in entities.iter().enumerate() {
        if e.common.is_in_paper_space {
            continue;
        }
        if let EntityType::Insert(ins) = &e.specific {
            let shape = &shapes[&insert_key(ins)];
            let block = blocks[ins.name.as_str()];
            let (outer, holes) = place_insert(shape, block, e, ins, unit)?;
            let n = inserts_seen.entry(ins.name.clone()).or_insert(0);
            *n += 1;
            let id = if *n == 1 {
                ins.name.clone()
            } else {
                format!("{}#{}", ins.name, n)
            };
            parts.push(Part {
                id,
                outer,
                holes,
                layer: e.common.layer.clone(),
                attributes: Default::default(),
            });
            sources.push(vec![i]);
        } else if let Some(p) = pieces_of(e, i, tol)? {
            // Each piece is bounded (arcs and splines to 200 000 chords); their sum too.
            vertices = vertices.saturating_add(p.points.len());
            if vertices > MAX_VERTICES {
                return Err(entity_error(
                    e,
                    format!(
                        "the drawing's contours reach {vertices} vertices here, more than the {MAX_VERTICES} a layout may have"
                    ),
                ));
            }
            pieces.push(p);
        }
    }
    let (rings, open) = join(pieces, options.join_tolerance_mm / unit);
    if let Some((chain, ents)) = open.first() {
        let names: Vec<String> = ents.iter().map(|&k| handle(entities[k])).collect();
        let (a, b) = (chain[0], chain[chain.len() - 1]);
        return Err(LayoutError::Entity {
            place: names.join(", "),
            message: format!(
                "open contour: it runs from ({:.3}, {:.3}) to ({:.3}, {:.3}) mm and nothing closes it within {} mm",
                a[0] * unit,
                a[1] * unit,
                b[0] * unit,
                b[1] * unit,
                options.join_tolerance_mm
            ),
        });
    }
    let to_mm = |r: Vec<Point>| {
        r.into_iter()
            .map(|p| [p[0] * unit, p[1] * unit])
            .collect::<Vec<_>>()
    };
    for (outer, ents, holes) in nest(rings) {
        let first = entities[ents[0]];
        parts.push(Part {
            id: first.common.handle.as_string(),
            outer: to_mm(outer),
            holes: holes.into_iter().map(to_mm).collect(),
            layer: first.common.layer.clone(),
            attributes: Default::default(),
        });
        sources.push(ents);
    }
    let n = parts.len();
    Ok((
        parts,
        DxfSource {
            drawing,
            unit_mm: unit,
            parts: sources,
            offsets: vec![[0.0, 0.0]; n],
            mlines: crate::dxf_tidy::mline_elements(bytes),
        },
    ))
}

fn shift(p: &mut dxf::Point, s: f64, d: Point) {
    p.x += s * d[0];
    p.y += d[1];
}

/// Moves one entity by `d` (drawing units, world X/Y).
fn translate_entity(e: &mut Entity, d: Point) {
    // Object coordinates mirrored in X move the other way in x.
    let sign = |z: f64| if z < 0.0 { -1.0 } else { 1.0 };
    match &mut e.specific {
        EntityType::LwPolyline(p) => {
            let s = sign(p.extrusion_direction.z);
            for v in p.vertices.iter_mut() {
                v.x += s * d[0];
                v.y += d[1];
            }
        }
        EntityType::Polyline(p) => {
            let s = if p.is_3d_polyline() {
                1.0
            } else {
                sign(p.normal.z)
            };
            for v in p.vertices_mut() {
                shift(&mut v.location, s, d);
            }
        }
        EntityType::Line(l) => {
            shift(&mut l.p1, 1.0, d);
            shift(&mut l.p2, 1.0, d);
        }
        EntityType::Arc(a) => shift(&mut a.center, sign(a.normal.z), d),
        EntityType::Circle(c) => shift(&mut c.center, sign(c.normal.z), d),
        EntityType::Spline(sp) => {
            for p in sp.control_points.iter_mut().chain(sp.fit_points.iter_mut()) {
                shift(p, 1.0, d);
            }
        }
        EntityType::Insert(ins) => {
            let s = sign(ins.extrusion_direction.z);
            shift(&mut ins.location, s, d);
            for a in ins.attributes_mut() {
                shift(&mut a.location, 1.0, d);
                shift(&mut a.second_alignment_point, 1.0, d);
            }
        }
        _ => {}
    }
}

impl DxfSource {
    pub(crate) fn translate(&mut self, offsets: &[Point]) {
        for (o, d) in self.offsets.iter_mut().zip(offsets) {
            o[0] += d[0];
            o[1] += d[1];
        }
    }

    pub(crate) fn write(&self) -> Result<Vec<u8>, LayoutError> {
        let mut drawing = self.drawing.clone();
        let mut moves: HashMap<usize, Point> = HashMap::new();
        for (ents, o) in self.parts.iter().zip(&self.offsets) {
            for &k in ents {
                moves.insert(k, [o[0] / self.unit_mm, o[1] / self.unit_mm]);
            }
        }
        for (k, e) in drawing.entities_mut().enumerate() {
            if let Some(d) = moves.get(&k) {
                translate_entity(e, *d);
            }
        }
        save(&drawing, &self.mlines)
    }
}

fn save(
    drawing: &Drawing,
    mlines: &crate::dxf_tidy::MlineElements,
) -> Result<Vec<u8>, LayoutError> {
    let mut out = Vec::new();
    drawing.save(&mut out).map_err(|e| LayoutError::Write {
        format: "DXF",
        message: e.to_string(),
    })?;
    // Unique handles and one block record each (see `dxf_tidy`).
    Ok(crate::dxf_tidy::tidy(out, mlines))
}

/// A new drawing: one block per part, inserted at the origin (see the module's notes).
pub(crate) fn write_parts(parts: &[Part]) -> Result<Vec<u8>, LayoutError> {
    let mut drawing = Drawing::new();
    drawing.header.version = dxf::enums::AcadVersion::R2000;
    drawing.header.default_drawing_units = Units::Millimeters;
    for part in parts {
        let mut block = Block {
            name: part.id.clone(),
            layer: part.layer.clone(),
            ..Default::default()
        };
        if block.layer.is_empty() {
            block.layer = "0".into();
        }
        for ring in std::iter::once(&part.outer).chain(&part.holes) {
            let mut lw = LwPolyline::default();
            lw.set_is_closed(true);
            lw.vertices = ring
                .iter()
                .map(|p| LwPolylineVertex {
                    x: p[0],
                    y: p[1],
                    ..Default::default()
                })
                .collect();
            let mut e = Entity::new(EntityType::LwPolyline(lw));
            e.common.layer = block.layer.clone();
            block.entities.push(e);
        }
        drawing.add_block(block);
        let mut e = Entity::new(EntityType::Insert(Insert {
            name: part.id.clone(),
            ..Default::default()
        }));
        e.common.layer = if part.layer.is_empty() {
            "0".into()
        } else {
            part.layer.clone()
        };
        drawing.add_entity(e);
    }
    save(&drawing, &Default::default())
}
