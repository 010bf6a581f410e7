use dxf::entities::{Arc, Circle, Entity, EntityType, Insert, Line, LwPolyline, Spline};
use dxf::enums::Units;
use dxf::{Block, Drawing, LwPolylineVertex};
use geo::Area;

use super::*;

fn opts() -> ReadOptions {
    ReadOptions::default()
}

fn area(p: &Part) -> f64 {
    p.polygon().unsigned_area()
}

fn close(a: Point, b: Point, tol: f64) -> bool {
    (a[0] - b[0]).abs() <= tol && (a[1] - b[1]).abs() <= tol
}

#[test]
fn arc_chord_count_matches_the_worked_example() {
    let pts = arc_points([0.0, 0.0], 10.0, 0.0, std::f64::consts::FRAC_PI_2, 0.01).unwrap();
    assert_eq!(pts.len(), 18);
    assert!(close(pts[17], [0.0, 10.0], 1e-12));
    // Each chord's sagitta is within the tolerance.
    let theta = std::f64::consts::FRAC_PI_2 / 18.0;
    assert!(10.0 * (1.0 - (theta / 2.0).cos()) <= 0.01);
}

#[test]
fn bulge_one_is_a_half_circle_to_the_right() {
    let pts = bulge_points([0.0, 0.0], [2.0, 0.0], 1.0, 0.001).unwrap();
    assert!(close(*pts.last().unwrap(), [2.0, 0.0], 0.0));
    assert!(pts
        .iter()
        .all(|p| ((p[0] - 1.0).hypot(p[1]) - 1.0).abs() < 1e-9));
    assert!(pts.iter().any(|p| close(*p, [1.0, -1.0], 1e-3)));
    // Negative bulge: the other side.
    let pts = bulge_points([0.0, 0.0], [2.0, 0.0], -1.0, 0.001).unwrap();
    assert!(pts.iter().any(|p| close(*p, [1.0, 1.0], 1e-3)));
}

#[test]
fn rational_quadratic_spline_is_a_quarter_circle_within_tolerance() {
    let w = std::f64::consts::FRAC_1_SQRT_2;
    let pts = nurbs_points(
        2,
        &[0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
        &[[10.0, 0.0], [10.0, 10.0], [0.0, 10.0]],
        &[1.0, w, 1.0],
        0.01,
    )
    .unwrap();
    assert!(close(pts[0], [10.0, 0.0], 1e-12) && close(*pts.last().unwrap(), [0.0, 10.0], 1e-12));
    assert!(pts.iter().all(|p| (p[0].hypot(p[1]) - 10.0).abs() < 1e-9));
    // Chords within 0.01 mm: the sagitta of every chord.
    for c in pts.windows(2) {
        let half = ((c[1][0] - c[0][0]).hypot(c[1][1] - c[0][1])) / 2.0;
        assert!(10.0 - (100.0 - half * half).sqrt() <= 0.01 + 1e-12);
    }
    assert!(nurbs_points(
        2,
        &[0.0, 1.0],
        &[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]],
        &[],
        0.01
    )
    .is_err());
}

fn square(id: &str, x: f64, y: f64, s: f64) -> Part {
    Part {
        id: id.into(),
        outer: vec![[x, y], [x + s, y], [x + s, y + s], [x, y + s]],
        holes: vec![],
        layer: String::new(),
        attributes: Default::default(),
    }
}

#[test]
fn json_round_trip_keeps_holes_layers_and_attributes() {
    let text = br#"{"units":"mm","width_mm":1600,"parts":[
        {"id":"front","layer":"1","attributes":{"size":"M"},
         "contours":[[[0,0],[100,0],[100,50],[0,50]],[[10,10],[20,10],[20,20]]]},
        {"id":"back","contours":[[[200,0],[300,0],[300,50]]]}]}"#;
    let layout = Layout::read(text, Format::Json, &opts()).unwrap();
    assert_eq!(layout.parts.len(), 2);
    assert_eq!(layout.parts[0].holes.len(), 1);
    assert_eq!(layout.parts[0].attributes["size"], "M");
    assert_eq!(layout.width_mm, Some(1600.0));
    assert_eq!(area(&layout.parts[0]), 5000.0 - 50.0);
    let moved = layout.translated(&[[1.0, 2.0], [0.0, -3.0]]).unwrap();
    let back = Layout::read(&moved.write(Format::Json).unwrap(), Format::Json, &opts()).unwrap();
    assert_eq!(back.parts, moved.parts);
    assert_eq!(back.parts[0].outer[0], [1.0, 2.0]);
    assert_eq!(back.parts[1].outer[2], [300.0, 47.0]);
}

#[test]
fn a_contour_that_turns_back_on_itself_is_refused_wherever_it_lies() {
    // (1,0) -> (100,0) -> (50,0) runs back along the same line: a spike of no width. Rotated
    // by 5 degrees its points are collinear only to rounding, which decided before whether
    // the part was accepted (and the same part moved by 1 mm then refused).
    let (s, c) = 5f64.to_radians().sin_cos();
    let rot = |x: f64, y: f64| [x * c - y * s + 10.0, x * s + y * c];
    let pts = [
        rot(1.0, 0.0),
        rot(100.0, 0.0),
        rot(50.0, 0.0),
        rot(50.0, -50.0),
    ];
    for shift in [0.0, 1.0, 123.456] {
        let contour: Vec<String> = pts
            .iter()
            .map(|p| format!("[{},{}]", p[0] + shift, p[1] + shift))
            .collect();
        let doc = format!(
            r#"{{"parts":[{{"id":"spike","contours":[[{}]]}}]}}"#,
            contour.join(",")
        );
        let e = Layout::read(doc.as_bytes(), Format::Json, &opts())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("part `spike`") && e.contains("turns back"),
            "{e}"
        );
    }
}

#[test]
fn an_svg_arc_of_absurd_radius_is_refused_before_it_is_converted() {
    let svg = br#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm" viewBox="0 0 200 100">
  <path id="giant" d="M20 50 a 6e49 10 31 1 0 30 0 z"/>
</svg>"#;
    let e = Layout::read(svg, Format::Svg, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("giant") && e.contains("beyond"), "{e}");
    // A small radius with a far end point: SVG scales the radii up to reach it.
    let far = br#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm" viewBox="0 0 200 100">
  <path id="far" d="M20 50 a 20 10 30 1 0 8e75 0 z"/>
</svg>"#;
    let e = Layout::read(far, Format::Svg, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("far") && e.contains("beyond"), "{e}");
    // A large but sane radius still reads (a 10 m arc through two points).
    let ok = br#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm" viewBox="0 0 200 100">
  <path id="flat" d="M20 50 A 10000 10000 0 0 1 80 50 L 80 90 L 20 90 Z"/>
</svg>"#;
    Layout::read(ok, Format::Svg, &opts()).unwrap();
}

#[test]
fn a_part_beyond_a_kilometre_is_refused() {
    let far = br#"{"parts":[{"id":"far","contours":[[[0,0],[150,30],[1519030,0]]]}]}"#;
    let e = Layout::read(far, Format::Json, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("part `far`") && e.contains("1 km"), "{e}");
    let near = br#"{"parts":[{"id":"near","contours":[[[0,0],[150,30],[999000,0]]]}]}"#;
    Layout::read(near, Format::Json, &opts()).unwrap();
}

#[test]
fn a_part_under_a_micrometre_is_refused_and_a_closing_vertex_is_kept() {
    let speck = br#"{"parts":[{"id":"speck","contours":[[[0,0],[1e-11,0],[0,1e-11]]]}]}"#;
    let e = Layout::read(speck, Format::Json, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("part `speck`") && e.contains("across"), "{e}");
    // With `Z`, a last vertex near the start (closer than the join tolerance) is a vertex.
    let svg = br#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm" viewBox="0 0 200 100">
  <path id="t" d="M0 0 L10 0 L10 10 L0.004 0.004 Z"/>
</svg>"#;
    let l = Layout::read(svg, Format::Svg, &opts()).unwrap();
    assert_eq!(l.parts[0].outer.len(), 4);
    // A relative path back to its start, up to rounding, does not repeat the start.
    let svg = br#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm" viewBox="0 0 200 100">
  <path id="r" d="m0.1 0.2 l10.1 0 l0 10.2 l-10.1 -10.2 z"/>
</svg>"#;
    let l = Layout::read(svg, Format::Svg, &opts()).unwrap();
    assert_eq!(l.parts[0].outer.len(), 3);
}

#[test]
fn json_bad_parts_are_named() {
    let bow_tie = br#"{"parts":[{"id":"tie","contours":[[[0,0],[10,10],[10,0],[0,10]]]}]}"#;
    let e = Layout::read(bow_tie, Format::Json, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("part `tie`") && e.contains("self-intersection"),
        "{e}"
    );
    let two = br#"{"parts":[{"id":"p","contours":[[[0,0],[10,10]]]}]}"#;
    let e = Layout::read(two, Format::Json, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("part `p`") && e.contains("fewer than 3 points"),
        "{e}"
    );
    let hole_out = br#"{"parts":[{"id":"h","contours":[[[0,0],[10,0],[10,10],[0,10]],[[20,20],[30,20],[30,30]]]}]}"#;
    assert!(Layout::read(hole_out, Format::Json, &opts())
        .unwrap_err()
        .to_string()
        .contains("part `h`"));
    let dup = br#"{"parts":[{"id":"a","contours":[[[0,0],[1,0],[1,1]]]},{"id":"a","contours":[[[5,0],[6,0],[6,1]]]}]}"#;
    assert_eq!(
        Layout::read(dup, Format::Json, &opts()).unwrap_err(),
        LayoutError::DuplicateId("a".into())
    );
    let bad = br#"{"parts":[{"id":"a","contours":[[[0,0],[1,"x"],[1,1]]]}]}"#;
    let e = Layout::read(bad, Format::Json, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("parts[0].contours[0][1]"), "{e}");
    assert_eq!(
        Layout::read(br#"{"parts":[]}"#, Format::Json, &opts()).unwrap_err(),
        LayoutError::Empty
    );
}

#[test]
fn svg_reads_paths_with_transforms_curves_and_holes() {
    let svg = br#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm" viewBox="0 0 400 200">
      <defs><path id="ghost" d="M0 0 L1 0 L1 1 Z"/></defs>
      <g transform="translate(10 0)">
        <path id="ring" class="cut" data-size="M" d="M0 0 H100 V100 H0 Z M25 25 v50 h50 v-50 z"/>
      </g>
      <rect id="r" x="200" y="0" width="40" height="20"/>
      <circle id="c" cx="300" cy="100" r="20"/>
      <path id="lens" d="M300 0 Q 320 40 340 0 Z"/>
    </svg>"#;
    let layout = Layout::read(svg, Format::Svg, &opts()).unwrap();
    let ids: Vec<&str> = layout.parts.iter().map(|p| p.id.as_str()).collect();
    assert_eq!(ids, ["ring", "r", "c", "lens"]);
    let ring = &layout.parts[0];
    // User unit 0.5 mm; the group's translate moves it by 10 user units = 5 mm.
    assert_eq!(ring.bounds(), [5.0, 0.0, 55.0, 50.0]);
    assert_eq!(ring.holes.len(), 1);
    assert_eq!(area(ring), 2500.0 - 625.0);
    assert_eq!(ring.layer, "cut");
    assert_eq!(ring.attributes["data-size"], "M");
    let c = &layout.parts[2];
    let exact = std::f64::consts::PI * 100.0;
    assert!(
        area(c) < exact && area(c) > exact * (1.0 - 2.0 * 0.01 / 10.0),
        "{}",
        area(c)
    );
    // Quadratic lens: a parabolic segment, 2/3 * base * height (base 40 units = 20 mm,
    // height half the control point's 40 units = 10 mm).
    assert!(
        (area(&layout.parts[3]) - 2.0 / 3.0 * 20.0 * 10.0).abs() < 0.2,
        "{}",
        area(&layout.parts[3])
    );
    // Written and read again: the same parts.
    let back = Layout::read(&layout.write(Format::Svg).unwrap(), Format::Svg, &opts()).unwrap();
    assert_eq!(back.parts.len(), 4);
    for (a, b) in back.parts.iter().zip(&layout.parts) {
        assert_eq!(
            (a.id.as_str(), a.layer.as_str(), a.holes.len()),
            (b.id.as_str(), b.layer.as_str(), b.holes.len())
        );
        assert!(a
            .outer
            .iter()
            .zip(&b.outer)
            .all(|(p, q)| close(*p, *q, 1e-9)));
    }
}

#[test]
fn svg_open_paths_are_refused_with_their_place() {
    let svg = b"<svg xmlns=\"http://www.w3.org/2000/svg\">\n<path id=\"cuff\" d=\"M0 0 L10 0 L10 10\"/></svg>";
    let e = Layout::read(svg, Format::Svg, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 2") && e.contains("cuff") && e.contains("open"),
        "{e}"
    );
    let svg = b"<svg xmlns=\"http://www.w3.org/2000/svg\"><polyline points=\"0 0 1 1\"/></svg>";
    assert!(Layout::read(svg, Format::Svg, &opts())
        .unwrap_err()
        .to_string()
        .contains("open"));
    assert!(Layout::read(b"<svg", Format::Svg, &opts()).is_err());
    let svg = b"<svg xmlns=\"http://www.w3.org/2000/svg\"><defs><path id=\"i\" d=\"M0 0 L1 0 L1 1 Z\"/></defs><use href=\"#i\"/></svg>";
    let e = Layout::read(svg, Format::Svg, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("<use>") && e.contains("not read"), "{e}");
}

fn lw(points: &[Point], closed: bool) -> Entity {
    let mut p = LwPolyline::default();
    p.set_is_closed(closed);
    p.vertices = points
        .iter()
        .map(|q| LwPolylineVertex {
            x: q[0],
            y: q[1],
            ..Default::default()
        })
        .collect();
    Entity::new(EntityType::LwPolyline(p))
}

fn line(a: Point, b: Point) -> Entity {
    Entity::new(EntityType::Line(Line::new(
        dxf::Point::new(a[0], a[1], 0.0),
        dxf::Point::new(b[0], b[1], 0.0),
    )))
}

fn save(d: &Drawing) -> Vec<u8> {
    let mut out = Vec::new();
    d.save(&mut out).unwrap();
    out
}

/// A drawing with every kind of contour the reader takes.
fn sample_drawing(units: Units) -> Drawing {
    let mut d = Drawing::new();
    d.header.version = dxf::enums::AcadVersion::R2000;
    d.header.default_drawing_units = units;
    // 1: a closed polyline with a circular hole.
    d.add_entity(lw(
        &[[0.0, 0.0], [100.0, 0.0], [100.0, 50.0], [0.0, 50.0]],
        true,
    ));
    d.add_entity(Entity::new(EntityType::Circle(Circle::new(
        dxf::Point::new(50.0, 25.0, 0.0),
        10.0,
    ))));
    // 2: a loop of lines, one drawn backwards, out of order.
    d.add_entity(line([200.0, 0.0], [240.0, 0.0]));
    d.add_entity(line([240.0, 30.0], [200.0, 30.0]));
    d.add_entity(line([240.0, 30.0], [240.0, 0.0]));
    d.add_entity(line([200.0, 30.0], [200.0, 0.0]));
    // 3: a D shape, a line closed by a half circle (centre (300,20), r 20, -90..90 deg).
    d.add_entity(line([300.0, 40.0], [300.0, 0.0]));
    d.add_entity(Entity::new(EntityType::Arc(Arc::new(
        dxf::Point::new(300.0, 20.0, 0.0),
        20.0,
        -90.0,
        90.0,
    ))));
    // 4: a block (a 10 x 20 rectangle, base point (5, 0), a grain line inside) inserted
    // at (500, 100), scaled 2, turned 90 degrees.
    let mut block = Block {
        name: "sleeve".into(),
        base_point: dxf::Point::new(5.0, 0.0, 0.0),
        ..Default::default()
    };
    block.entities.push(lw(
        &[[0.0, 0.0], [10.0, 0.0], [10.0, 20.0], [0.0, 20.0]],
        true,
    ));
    block.entities.push(line([5.0, 2.0], [5.0, 18.0]));
    d.add_block(block);
    for x in [500.0, 700.0] {
        let ins = Insert {
            name: "sleeve".into(),
            location: dxf::Point::new(x, 100.0, 0.0),
            x_scale_factor: 2.0,
            y_scale_factor: 2.0,
            rotation: 90.0,
            ..Default::default()
        };
        d.add_entity(Entity::new(EntityType::Insert(ins)));
    }
    // 5: a closed cubic B-spline (clamped, its first and last control points equal).
    let mut sp = Spline {
        degree_of_curve: 3,
        ..Default::default()
    };
    sp.control_points = [
        [900.0, 0.0],
        [960.0, 0.0],
        [960.0, 60.0],
        [900.0, 60.0],
        [900.0, 0.0],
    ]
    .iter()
    .map(|p| dxf::Point::new(p[0], p[1], 0.0))
    .collect();
    sp.knot_values = vec![0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0];
    d.add_entity(Entity::new(EntityType::Spline(sp)));
    d
}

/// 20 000 INSERTs of one large block (a circle of 1 m radius, about 700 chords at
/// 0.01 mm): the expansion is estimated from the block flattened once and refused before
/// any copy is made, naming the estimate (the drawing grew to 2.5 GB before); the same
/// block placed a few times is read, each placement its own part.
#[test]
fn a_dxf_whose_inserts_expand_beyond_the_vertex_bound_is_refused_naming_the_estimate() {
    let drawing = |n: usize| {
        let mut d = Drawing::new();
        d.header.version = dxf::enums::AcadVersion::R2000;
        d.header.default_drawing_units = Units::Millimeters;
        let mut block = Block {
            name: "disc".into(),
            ..Default::default()
        };
        block
            .entities
            .push(Entity::new(EntityType::Circle(Circle::new(
                dxf::Point::new(0.0, 0.0, 0.0),
                1000.0,
            ))));
        d.add_block(block);
        for k in 0..n {
            let ins = Insert {
                name: "disc".into(),
                location: dxf::Point::new(2100.0 * k as f64, 0.0, 0.0),
                x_scale_factor: 1.0,
                y_scale_factor: 1.0,
                ..Default::default()
            };
            d.add_entity(Entity::new(EntityType::Insert(ins)));
        }
        save(&d)
    };
    let e = Layout::read(&drawing(20_000), Format::Dxf, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("the drawing's 20000 INSERTs expand to at least")
            && e.contains("vertices (block `disc` of")
            && e.contains("placed 20000 times), more than the 4000000"),
        "{e}"
    );
    let layout = Layout::read(&drawing(3), Format::Dxf, &opts()).unwrap();
    assert_eq!(layout.parts.len(), 3);
    assert!(layout.parts[0].outer.len() > 500);
}

/// An element of 200 000 attributes (minutes in the XML parser's duplicate check) is
/// refused at once naming its place; comments and quoted `=` do not count, and an
/// element with as many as allowed is read.
#[test]
fn an_svg_element_with_too_many_attributes_is_refused_before_parsing() {
    let attrs: String = (0..200_000).map(|i| format!(" a{i}=\"1\"")).collect();
    let svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\">\n<!-- a <b c=1> -->\n  <rect width=\"10\" height=\"10\"{attrs}/></svg>"
    );
    let e = Layout::read(svg.as_bytes(), Format::Svg, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 3, column 3: element <rect> has 200002 attributes, more than the 1000"),
        "{e}"
    );
    let attrs: String = (0..svg_io::MAX_ATTRIBUTES - 2)
        .map(|i| format!(" data-a{i}=\"x=y\""))
        .collect();
    let svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\"><rect width=\"10\" height=\"10\"{attrs}/></svg>"
    );
    let layout = Layout::read(svg.as_bytes(), Format::Svg, &opts()).unwrap();
    assert_eq!(layout.parts.len(), 1);
}

#[test]
fn dxf_reads_polylines_loops_arcs_blocks_and_splines() {
    let bytes = save(&sample_drawing(Units::Millimeters));
    let layout = Layout::read(&bytes, Format::Dxf, &opts()).unwrap();
    assert_eq!(
        layout.parts.len(),
        6,
        "{:?}",
        layout.parts.iter().map(|p| &p.id).collect::<Vec<_>>()
    );
    let by_id = |id: &str| {
        layout
            .parts
            .iter()
            .find(|p| p.id == id)
            .unwrap_or_else(|| panic!("no part {id}"))
    };
    let sleeve = by_id("sleeve");
    // (x - 5, y) * 2 turned 90 deg: x' = -2y, y' = 2(x - 5); placed at (500, 100).
    let b = sleeve.bounds();
    assert!(
        close([b[0], b[1]], [460.0, 90.0], 1e-9) && close([b[2], b[3]], [500.0, 110.0], 1e-9),
        "{b:?}"
    );
    assert!(sleeve.holes.is_empty());
    assert_eq!(by_id("sleeve#2").bounds()[2], 700.0);
    let plate = layout.parts.iter().find(|p| p.holes.len() == 1).unwrap();
    let hole = std::f64::consts::PI * 100.0;
    assert!(
        (area(plate) - (5000.0 - hole)).abs() < 0.05 * 62.9,
        "{}",
        area(plate)
    );
    let rect = layout
        .parts
        .iter()
        .find(|p| p.bounds() == [200.0, 0.0, 240.0, 30.0])
        .unwrap();
    assert_eq!(area(rect), 1200.0);
    let d = layout
        .parts
        .iter()
        .find(|p| p.bounds()[0] == 300.0)
        .unwrap();
    let half = std::f64::consts::PI * 400.0 / 2.0;
    assert!(
        area(d) <= half && area(d) > half - 0.01 * 63.0,
        "{}",
        area(d)
    );
    assert!((d.bounds()[2] - 320.0).abs() < 1e-9);
}

#[test]
fn dxf_units_scale_and_missing_units_are_refused() {
    let inches = Layout::read(&save(&sample_drawing(Units::Inches)), Format::Dxf, &opts()).unwrap();
    let b = inches
        .parts
        .iter()
        .find(|p| p.id == "sleeve")
        .unwrap()
        .bounds();
    assert!(close([b[2], b[3]], [500.0 * 25.4, 110.0 * 25.4], 1e-6));
    let e = Layout::read(
        &save(&sample_drawing(Units::Unitless)),
        Format::Dxf,
        &opts(),
    )
    .unwrap_err();
    assert_eq!(e, LayoutError::MissingUnits);
    let e = Layout::read(&save(&sample_drawing(Units::Miles)), Format::Dxf, &opts()).unwrap_err();
    assert!(matches!(e, LayoutError::UnsupportedUnits(_)));
}

#[test]
fn dxf_open_contour_names_the_handles() {
    let mut d = Drawing::new();
    d.header.version = dxf::enums::AcadVersion::R2000;
    d.header.default_drawing_units = Units::Millimeters;
    d.add_entity(line([0.0, 0.0], [10.0, 0.0]));
    d.add_entity(line([10.0, 0.0], [10.0, 10.0]));
    let h: Vec<String> = d.entities().map(|e| e.common.handle.as_string()).collect();
    let e = Layout::read(&save(&d), Format::Dxf, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!("LINE (handle {})", h[0])) && e.contains(&format!("handle {}", h[1])),
        "{e}"
    );
    assert!(e.contains("open contour"), "{e}");
    // A self-intersecting polyline is named by its handle.
    let mut d = Drawing::new();
    d.header.version = dxf::enums::AcadVersion::R2000;
    d.header.default_drawing_units = Units::Millimeters;
    d.add_entity(lw(
        &[[0.0, 0.0], [10.0, 10.0], [10.0, 0.0], [0.0, 10.0]],
        true,
    ));
    let h = d.entities().next().unwrap().common.handle.as_string();
    let e = Layout::read(&save(&d), Format::Dxf, &opts())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!("part `{h}`")) && e.contains("self-intersection"),
        "{e}"
    );
    assert!(Layout::read(
        b"0\nSECTION\n2\nENTITIES\n0\nLINE\n10\nabc\n",
        Format::Dxf,
        &opts()
    )
    .is_err());
}

#[test]
fn dxf_written_back_moves_only_the_parts() {
    let layout = Layout::read(
        &save(&sample_drawing(Units::Centimeters)),
        Format::Dxf,
        &opts(),
    )
    .unwrap();
    let offsets: Vec<Point> = (0..layout.parts.len())
        .map(|i| [10.0 * i as f64, -3.0])
        .collect();
    let moved = layout.translated(&offsets).unwrap();
    let back = Layout::read(&moved.write(Format::Dxf).unwrap(), Format::Dxf, &opts()).unwrap();
    assert_eq!(back.parts.len(), layout.parts.len());
    for ((a, b), d) in back.parts.iter().zip(&layout.parts).zip(&offsets) {
        assert_eq!(a.id, b.id);
        let (ba, bb) = (a.bounds(), b.bounds());
        assert!(
            close([ba[0], ba[1]], [bb[0] + d[0], bb[1] + d[1]], 1e-6),
            "{} {ba:?} {bb:?}",
            a.id
        );
    }
    // Parts from JSON written as DXF come back with their ids (one block per part).
    let json = Layout::from_parts(
        vec![square("a", 0.0, 0.0, 10.0), square("b", 20.0, 0.0, 5.0)],
        None,
    )
    .unwrap();
    let back = Layout::read(&json.write(Format::Dxf).unwrap(), Format::Dxf, &opts()).unwrap();
    assert_eq!(
        back.parts.iter().map(|p| p.id.as_str()).collect::<Vec<_>>(),
        ["a", "b"]
    );
    assert_eq!(back.parts[1].bounds(), [20.0, 0.0, 25.0, 5.0]);
}

#[test]
fn format_from_extension() {
    assert_eq!(Format::from_path("out/x.DXF"), Some(Format::Dxf));
    assert_eq!(Format::from_path("a.svg"), Some(Format::Svg));
    assert_eq!(Format::from_path("a.json"), Some(Format::Json));
    assert_eq!(Format::from_path("a.txt"), None);
}

/// The handles (codes 5 and 105) of a DXF text, the BLOCK_RECORD names, `$HANDSEED`.
fn dxf_handles(bytes: &[u8]) -> (Vec<u64>, Vec<String>, u64) {
    let text = String::from_utf8_lossy(bytes);
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    let pairs: Vec<(&str, &str)> = lines.chunks(2).map(|c| (c[0], c[1])).collect();
    let mut handles = Vec::new();
    let mut records = Vec::new();
    let mut seed = 0;
    for (i, (c, v)) in pairs.iter().enumerate() {
        if (*c == "5" || *c == "105") && (i == 0 || pairs[i - 1] != ("9", "$HANDSEED")) {
            handles.push(u64::from_str_radix(v, 16).unwrap());
        }
        if *c == "0" && *v == "BLOCK_RECORD" {
            let name = pairs[i + 1..].iter().find(|p| p.0 == "2").unwrap().1;
            records.push(name.to_ascii_uppercase());
        }
        if *c == "9" && *v == "$HANDSEED" {
            seed = u64::from_str_radix(pairs[i + 1].1, 16).unwrap();
        }
    }
    (handles, records, seed)
}

fn assert_tidy(bytes: &[u8], what: &str) {
    let (handles, records, seed) = dxf_handles(bytes);
    let unique: std::collections::HashSet<u64> = handles.iter().copied().collect();
    assert_eq!(unique.len(), handles.len(), "{what}: a handle repeats");
    let names: std::collections::HashSet<&String> = records.iter().collect();
    assert_eq!(
        names.len(),
        records.len(),
        "{what}: block records {records:?}"
    );
    assert!(records.contains(&"*MODEL_SPACE".to_string()), "{what}");
    assert!(
        handles.iter().all(|&h| h < seed),
        "{what}: $HANDSEED {seed:X}"
    );
}

/// Written DXF has one handle per object (a BLOCK and its ENDBLK had one between them)
/// and one block record per block, also when a drawing is read and written back twice
/// (each write added the blocks' records again); the header's unit and version stay.
#[test]
fn written_dxf_has_unique_handles_and_one_block_record_each() {
    let json = Layout::from_parts(
        vec![square("a", 0.0, 0.0, 10.0), square("b", 20.0, 0.0, 5.0)],
        None,
    )
    .unwrap();
    let fresh = json.write(Format::Dxf).unwrap();
    assert_tidy(&fresh, "parts written as DXF");
    let mut bytes = save(&sample_drawing(Units::Centimeters));
    for round in 0..2 {
        let l = Layout::read(&bytes, Format::Dxf, &opts()).unwrap();
        let n = l.parts.len();
        bytes = l
            .translated(&vec![[1.0, 2.0]; n])
            .unwrap()
            .write(Format::Dxf)
            .unwrap();
        assert_tidy(&bytes, &format!("read and written back, round {round}"));
        let d = Drawing::load(&mut std::io::Cursor::new(&bytes)).unwrap();
        assert_eq!(d.header.default_drawing_units, Units::Centimeters);
        assert_eq!(d.header.version, dxf::enums::AcadVersion::R2000);
    }
    let back = Layout::read(&fresh, Format::Dxf, &opts()).unwrap();
    assert_eq!(back.parts[1].bounds(), [20.0, 0.0, 25.0, 5.0]);
}

#[test]
fn an_unreadable_scale_or_material_width_is_refused_not_guessed() {
    let svg = |w: &str, vb: &str| {
        format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="100mm" viewBox="{vb}">
  <rect id="r" x="10" y="10" width="20" height="20"/>
</svg>"#
        )
    };
    for (w, vb, bad) in [
        ("200mm", "NaN 0 200 100", "viewBox `NaN 0 200 100`"),
        ("200mm", "0 0 0 100", "viewBox `0 0 0 100`"),
        ("200mm", "0 0 200", "viewBox `0 0 200`"),
        ("inf mm", "0 0 200 100", "width `inf mm`"),
        ("-5mm", "0 0 200 100", "width `-5mm`"),
    ] {
        let e = Layout::read(svg(w, vb).as_bytes(), Format::Svg, &opts())
            .unwrap_err()
            .to_string();
        assert!(e.contains(bad) && e.contains("line 1"), "{e}");
    }
    // Half a millimetre a unit, read as such.
    let half = Layout::read(svg("100mm", "0 0 200 100").as_bytes(), Format::Svg, &opts()).unwrap();
    let b = half.parts[0].bounds();
    assert!((b[2] - b[0] - 10.0).abs() < 1e-9, "{b:?}");
    for w in ["1e308", "0", "-3", "2e6"] {
        let json = format!(r#"{{"units":"mm","width_mm":{w},"parts":[]}}"#);
        let e = Layout::read(json.as_bytes(), Format::Json, &opts())
            .unwrap_err()
            .to_string();
        assert!(e.contains("width_mm"), "{w}: {e}");
    }
}

#[test]
fn a_second_json_layout_after_the_first_is_refused() {
    let one = br#"{"units":"mm","parts":[{"id":"a","contours":[[[0,0],[10,0],[10,10]]]}]}"#;
    assert!(Layout::read(one, Format::Json, &opts()).is_ok());
    let two = [&one[..], b"\n", &one[..]].concat();
    let e = Layout::read(&two, Format::Json, &opts())
        .unwrap_err()
        .to_string();
    assert!(e.contains("after the layout"), "{e}");
}
