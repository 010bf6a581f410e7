//! Cutting a partitioned layout on a conveyor cutter: where the conveyor stops, which
//! group each knife head cuts at each stop, and the G-code each head runs.
//!
//! The cutter: a conveyor feeding the material along X and k heads over a cutting area
//! of length L' (the window), head `t` over lane `t`. Frames (mm): the material frame is
//! the shifted layout's; the conveyor's position `c` is the material X under the area's
//! start edge; head `t`'s machine frame starts at that edge and at material Y
//! `origin_y[t]`, so material `(X, Y)` is head machine `(X - c, Y - origin_y[t])`, and
//! must lie within `0..=L'` and `0..=reach[t]`. Worked example (L' = 300, head 1 with
//! origin_y 45, reach 50): with the conveyor at 300, material (320, 55) is head 1's
//! machine (20, 10); material (320, 100) would be Y 55, beyond its reach, and is refused.
//!
//! Stops: every head cuts its groups in window order. A stop puts the conveyor at the
//! smallest X where a head's next group starts; every head cuts its next groups, in
//! order, as long as they lie wholly in the area; the others wait for a later stop. Each
//! stop cuts at least one group (a group is shorter than L'). The conveyor never goes
//! back: each head's groups start further along X window by window, and a partition
//! where they do not (a part moved into an earlier window's group can do it) is refused. Within a group,
//! each part's holes are cut before its outline (the part is still held while its
//! inside is cut), parts in the layout's order.

use crate::Partition;
use layout_io::Part;
use serde::Serialize;

/// The cutter the layout runs on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CutterSpec {
    /// Cutting area length L', mm (normally the partition's window).
    pub window_mm: f64,
    /// Per head: material Y of its machine Y 0, and its Y travel, mm.
    pub heads: Vec<HeadSpec>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HeadSpec {
    pub origin_y_mm: f64,
    pub reach_y_mm: f64,
}

impl CutterSpec {
    /// A cutter built for the partition: the area as long as the window, head `t`
    /// reaching its shifted lane (lane `t` moved by its groups' DY) and every point of
    /// its groups' parts (overlap resolution can move a part into a neighbouring lane's
    /// group, so neighbouring heads' reaches can overlap; heads are taken as points).
    pub fn for_partition(parts: &[Part], partition: &Partition) -> CutterSpec {
        let lane = partition.lane_mm();
        let heads = (0..partition.tools)
            .map(|t| {
                let base = partition.y0_mm + t as f64 * lane;
                let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                for g in partition.groups.iter().filter(|g| g.tool == t) {
                    lo = lo.min(base + g.dy_mm);
                    hi = hi.max(base + lane + g.dy_mm);
                    for q in g.parts.iter().flat_map(|&p| rings(&parts[p]).flatten()) {
                        lo = lo.min(q[1] + g.dy_mm);
                        hi = hi.max(q[1] + g.dy_mm);
                    }
                }
                if !lo.is_finite() {
                    (lo, hi) = (base, base + lane);
                }
                HeadSpec {
                    origin_y_mm: lo,
                    reach_y_mm: hi - lo,
                }
            })
            .collect();
        CutterSpec {
            window_mm: partition.window_mm,
            heads,
        }
    }
}

/// How a head cuts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CutSettings {
    /// Knife feed along the contour, mm/min.
    pub feed_mm_min: f64,
    /// Knife plunge feed, mm/min.
    pub plunge_mm_min: f64,
    /// Knife Z while cutting (below the material's top at 0) and while travelling, mm.
    pub knife_down_mm: f64,
    pub knife_up_mm: f64,
}

impl Default for CutSettings {
    fn default() -> Self {
        Self {
            feed_mm_min: 12_000.0,
            plunge_mm_min: 3_000.0,
            knife_down_mm: -1.0,
            knife_up_mm: 5.0,
        }
    }
}

/// One closed contour a head cuts, in its machine frame (first point repeated last).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Contour {
    /// The part's index in the layout and the ring (0 the outline, 1.. its holes).
    pub part: usize,
    pub ring: usize,
    pub points: Vec<[f64; 2]>,
}

/// A head's work at one stop: one group.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeadJob {
    pub tool: usize,
    /// The group's id (G-1, G-2, ...) and window.
    pub group: usize,
    pub window: usize,
    pub contours: Vec<Contour>,
}

impl HeadJob {
    /// Knife path length (contours only), mm.
    pub fn cut_length_mm(&self) -> f64 {
        self.contours
            .iter()
            .flat_map(|c| c.points.windows(2))
            .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
            .sum()
    }

    /// The head's G-code for this job: absolute mm, the knife lifted to travel, lowered at
    /// each contour's start, the contour at the cutting feed, lifted at its end.
    pub fn program(&self, s: &CutSettings) -> String {
        let mut g = String::from("G21 G90 G94\n");
        g.push_str(&format!("G0 Z{:.3}\n", s.knife_up_mm));
        for c in &self.contours {
            let [x, y] = c.points[0];
            g.push_str(&format!("G0 X{x:.3} Y{y:.3}\n"));
            g.push_str(&format!(
                "G1 Z{:.3} F{:.0}\n",
                s.knife_down_mm, s.plunge_mm_min
            ));
            g.push_str(&format!("F{:.0}\n", s.feed_mm_min));
            for [x, y] in &c.points[1..] {
                g.push_str(&format!("G1 X{x:.3} Y{y:.3}\n"));
            }
            g.push_str(&format!("G0 Z{:.3}\n", s.knife_up_mm));
        }
        g
    }
}

/// One conveyor stop and what the heads cut there.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Stop {
    /// Material X under the area's start edge, mm.
    pub conveyor_mm: f64,
    pub jobs: Vec<HeadJob>,
}

/// Why a partition cannot be cut on a cutter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CutError {
    #[error("the cutter has {heads} heads; the partition has {tools} tools")]
    Heads { heads: usize, tools: usize },
    #[error(
        "group G-{group} (tool {tool}) spans X {from:.3}..{to:.3} mm, {length:.3} mm: longer than the cutting area ({window:.3} mm)"
    )]
    GroupTooLong {
        group: usize,
        tool: usize,
        from: f64,
        to: f64,
        length: f64,
        window: f64,
    },
    #[error(
        "part `{part}` point ({x:.3}, {y:.3}) mm is outside head {tool}'s reach (material Y {lo:.3}..{hi:.3} mm)"
    )]
    OutOfReach {
        part: String,
        x: f64,
        y: f64,
        tool: usize,
        lo: f64,
        hi: f64,
    },
    #[error(
        "group G-{group} (tool {tool}) starts at X {from:.3} mm, behind the conveyor's last stop at {conveyor:.3} mm: the tool's groups are not in feed order, and the conveyor does not go back"
    )]
    Backwards {
        group: usize,
        tool: usize,
        from: f64,
        conveyor: f64,
    },
    #[error("part `{part}` has a point that is not a number")]
    NotANumber { part: String },
}

/// The stops that cut the partition's shifted layout on `cutter` (see the module).
pub fn plan(
    parts: &[Part],
    partition: &Partition,
    cutter: &CutterSpec,
) -> Result<Vec<Stop>, CutError> {
    if cutter.heads.len() != partition.tools {
        return Err(CutError::Heads {
            heads: cutter.heads.len(),
            tools: partition.tools,
        });
    }
    // Each group's shifted X extent; every point checked against its head's reach.
    let mut extent = vec![[f64::INFINITY, f64::NEG_INFINITY]; partition.groups.len()];
    for (gi, g) in partition.groups.iter().enumerate() {
        let head = cutter.heads[g.tool];
        let (lo, hi) = (head.origin_y_mm, head.origin_y_mm + head.reach_y_mm);
        for &p in &g.parts {
            for q in rings(&parts[p]).flatten() {
                let (x, y) = (q[0] + g.dx_mm, q[1] + g.dy_mm);
                if !x.is_finite() || !y.is_finite() {
                    return Err(CutError::NotANumber {
                        part: parts[p].id.clone(),
                    });
                }
                if !(lo..=hi).contains(&y) {
                    return Err(CutError::OutOfReach {
                        part: parts[p].id.clone(),
                        x,
                        y,
                        tool: g.tool,
                        lo,
                        hi,
                    });
                }
                extent[gi] = [extent[gi][0].min(x), extent[gi][1].max(x)];
            }
        }
        let [from, to] = extent[gi];
        if !g.parts.is_empty() && to - from > cutter.window_mm {
            return Err(CutError::GroupTooLong {
                group: g.id,
                tool: g.tool,
                from,
                to,
                length: to - from,
                window: cutter.window_mm,
            });
        }
    }
    // Each tool's groups in window order.
    let mut queues: Vec<std::collections::VecDeque<usize>> = (0..partition.tools)
        .map(|t| {
            let mut q: Vec<usize> = (0..partition.groups.len())
                .filter(|&g| partition.groups[g].tool == t && !partition.groups[g].parts.is_empty())
                .collect();
            q.sort_by_key(|&g| partition.groups[g].window);
            q.into()
        })
        .collect();
    let mut stops: Vec<Stop> = Vec::new();
    loop {
        let next: Vec<(usize, usize)> = queues
            .iter()
            .enumerate()
            .filter_map(|(t, q)| q.front().map(|&g| (t, g)))
            .collect();
        let Some(&(tool, first)) = next
            .iter()
            .min_by(|a, b| extent[a.1][0].total_cmp(&extent[b.1][0]))
        else {
            break;
        };
        let conveyor_mm = extent[first][0];
        if let Some(last) = stops.last() {
            if conveyor_mm < last.conveyor_mm {
                let group = &partition.groups[first];
                return Err(CutError::Backwards {
                    group: group.id,
                    tool,
                    from: conveyor_mm,
                    conveyor: last.conveyor_mm,
                });
            }
        }
        // Each head cuts every next group of its own that lies wholly in the area.
        let mut jobs = Vec::new();
        for (t, queue) in queues.iter_mut().enumerate() {
            while let Some(&g) = queue.front() {
                let [from, to] = extent[g];
                if from < conveyor_mm || to > conveyor_mm + cutter.window_mm {
                    break;
                }
                queue.pop_front();
                jobs.push(head_job(parts, partition, g, conveyor_mm, cutter.heads[t]));
            }
        }
        stops.push(Stop { conveyor_mm, jobs });
    }
    Ok(stops)
}

fn rings(part: &Part) -> impl Iterator<Item = &Vec<[f64; 2]>> {
    std::iter::once(&part.outer).chain(part.holes.iter())
}

fn head_job(
    parts: &[Part],
    partition: &Partition,
    g: usize,
    conveyor_mm: f64,
    head: HeadSpec,
) -> HeadJob {
    let group = &partition.groups[g];
    let mut contours = Vec::new();
    for &p in &group.parts {
        let part = &parts[p];
        let machine = |ring: &Vec<[f64; 2]>| -> Vec<[f64; 2]> {
            ring.iter()
                .chain(ring.first())
                .map(|q| {
                    [
                        q[0] + group.dx_mm - conveyor_mm,
                        q[1] + group.dy_mm - head.origin_y_mm,
                    ]
                })
                .collect()
        };
        // Holes first: the part is still held while its inside is cut.
        for (k, hole) in part.holes.iter().enumerate() {
            contours.push(Contour {
                part: p,
                ring: k + 1,
                points: machine(hole),
            });
        }
        contours.push(Contour {
            part: p,
            ring: 0,
            points: machine(&part.outer),
        });
    }
    HeadJob {
        tool: group.tool,
        group: group.id,
        window: group.window,
        contours,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Group;

    fn square(id: &str, x: f64, y: f64) -> Part {
        Part {
            id: id.into(),
            outer: vec![[x, y], [x + 10.0, y], [x + 10.0, y + 10.0], [x, y + 10.0]],
            holes: vec![],
            layer: String::new(),
            attributes: Default::default(),
        }
    }

    fn group(id: usize, tool: usize, window: usize, dx: f64, dy: f64, parts: Vec<usize>) -> Group {
        Group {
            id,
            tool,
            window,
            dx_mm: dx,
            dy_mm: dy,
            parts,
        }
    }

    fn partition(groups: Vec<Group>, parts: usize) -> Partition {
        let mut group_of = vec![0; parts];
        for (gi, g) in groups.iter().enumerate() {
            for &p in &g.parts {
                group_of[p] = gi;
            }
        }
        Partition {
            groups,
            group_of,
            y0_mm: 0.0,
            width_mm: 100.0,
            gap_mm: 5.0,
            clearance_mm: 5.0,
            window_mm: 300.0,
            windows_mm: vec![0.0, 300.0],
            tools: 2,
        }
    }

    /// Each head reaches its shifted lane, and its parts beyond it (part `b`, moved
    /// into tool 0's group, reaches Y 70 from lane 0's 0..50).
    #[test]
    fn the_cutter_reaches_each_shifted_lane_and_its_parts() {
        let parts = vec![
            square("a", 0.0, 10.0),
            square("b", 20.0, 60.0),
            square("c", 0.0, 60.0),
        ];
        let p = partition(
            vec![
                group(1, 0, 0, 0.0, 0.0, vec![0, 1]),
                group(2, 1, 0, 0.0, 5.0, vec![2]),
            ],
            3,
        );
        let c = CutterSpec::for_partition(&parts, &p);
        let head = |origin_y_mm, reach_y_mm| HeadSpec {
            origin_y_mm,
            reach_y_mm,
        };
        assert_eq!(c.heads, vec![head(0.0, 70.0), head(55.0, 50.0)]);
        assert_eq!(c.window_mm, 300.0);
    }

    /// Stops: each head's next group, the conveyor at the first start, groups wholly in
    /// the area cut there, the others at the next stop; machine frame = material minus the
    /// conveyor and the head's origin.
    #[test]
    fn stops_follow_the_groups_and_convert_to_machine_frames() {
        let parts = vec![
            square("a", 0.0, 10.0),
            square("b", 100.0, 60.0),
            square("c", 320.0, 10.0),
            square("d", 420.0, 60.0),
        ];
        let p = partition(
            vec![
                group(1, 0, 0, 0.0, 0.0, vec![0]),
                group(2, 1, 0, 0.0, 5.0, vec![1]),
                group(3, 0, 1, 5.0, 0.0, vec![2]),
                group(4, 1, 1, 5.0, 5.0, vec![3]),
            ],
            4,
        );
        let cutter = CutterSpec::for_partition(&parts, &p);
        let stops = plan(&parts, &p, &cutter).unwrap();
        let summary: Vec<(f64, Vec<usize>)> = stops
            .iter()
            .map(|s| (s.conveyor_mm, s.jobs.iter().map(|j| j.group).collect()))
            .collect();
        assert_eq!(summary, vec![(0.0, vec![1, 2]), (325.0, vec![3, 4])]);
        // Part d (group 4: shift (5, 5)) at material (425, 65): head 1 (origin 55, its lane
        // 50..100 shifted by 5) machine (100, 10).
        assert_eq!(cutter.heads[1].origin_y_mm, 55.0);
        let d = &stops[1].jobs[1].contours[0];
        assert_eq!(d.points[0], [100.0, 10.0]);
        assert_eq!(d.points.len(), 5);
        assert!((stops[1].jobs[1].cut_length_mm() - 40.0).abs() < 1e-9);
        let g = stops[1].jobs[1].program(&CutSettings::default());
        assert!(
            g.contains("G0 X100.000 Y10.000\nG1 Z-1.000 F3000\nF12000\nG1 X110.000 Y10.000\n"),
            "{g}"
        );
    }

    /// Two small consecutive groups of one head inside the area are cut at one stop, in
    /// window order; groups that start behind an earlier stop are refused.
    #[test]
    fn a_head_cuts_every_next_group_inside_the_area_and_never_goes_back() {
        let parts = vec![
            square("a", 0.0, 10.0),
            square("b", 100.0, 10.0),
            square("c", 400.0, 10.0),
        ];
        let p = partition(
            vec![
                group(1, 0, 0, 0.0, 0.0, vec![0]),
                group(2, 0, 1, 5.0, 0.0, vec![1]),
                group(3, 0, 2, 10.0, 0.0, vec![2]),
            ],
            3,
        );
        let stops = plan(&parts, &p, &CutterSpec::for_partition(&parts, &p)).unwrap();
        let summary: Vec<(f64, Vec<usize>)> = stops
            .iter()
            .map(|s| (s.conveyor_mm, s.jobs.iter().map(|j| j.group).collect()))
            .collect();
        assert_eq!(summary, vec![(0.0, vec![1, 2]), (410.0, vec![3])]);
        // G-3 moved behind G-2 (as a resolution move could leave it).
        let back = vec![
            square("a", 0.0, 10.0),
            square("b", 400.0, 10.0),
            square("c", 350.0, 10.0),
        ];
        let p = partition(
            vec![
                group(1, 0, 0, 0.0, 0.0, vec![0]),
                group(2, 0, 1, 0.0, 0.0, vec![1]),
                group(3, 0, 2, 0.0, 0.0, vec![2]),
            ],
            3,
        );
        let e = plan(&back, &p, &CutterSpec::for_partition(&back, &p)).unwrap_err();
        assert!(matches!(e, CutError::Backwards { group: 3, .. }), "{e}");
    }

    /// A head's next group that does not fit with another head's waits for its own stop.
    #[test]
    fn a_group_beyond_the_area_waits() {
        let parts = vec![square("a", 0.0, 10.0), square("b", 295.0, 60.0)];
        let p = partition(
            vec![
                group(1, 0, 0, 0.0, 0.0, vec![0]),
                group(2, 1, 0, 0.0, 5.0, vec![1]),
            ],
            2,
        );
        let stops = plan(&parts, &p, &CutterSpec::for_partition(&parts, &p)).unwrap();
        assert_eq!(stops.len(), 2);
        assert_eq!(stops[1].conveyor_mm, 295.0);
        assert_eq!(stops[1].jobs[0].group, 2);
    }

    /// The module's worked example and what a cutter cannot do: material (320, 55) with
    /// the conveyor at 300 is head 1's machine (20, 10); (320, 100) is beyond its reach.
    #[test]
    fn refuses_what_the_cutter_cannot_reach() {
        let cutter = CutterSpec {
            window_mm: 300.0,
            heads: vec![
                HeadSpec {
                    origin_y_mm: 0.0,
                    reach_y_mm: 50.0,
                },
                HeadSpec {
                    origin_y_mm: 45.0,
                    reach_y_mm: 50.0,
                },
            ],
        };
        let tool1 = |parts| partition(vec![group(1, 1, 0, 0.0, 0.0, parts)], 1);
        let stops = plan(&[square("a", 320.0, 55.0)], &tool1(vec![0]), &cutter).unwrap();
        assert_eq!(stops[0].conveyor_mm, 320.0);
        let at_300 = head_job(
            &[square("a", 320.0, 55.0)],
            &tool1(vec![0]),
            0,
            300.0,
            cutter.heads[1],
        );
        assert_eq!(at_300.contours[0].points[0], [20.0, 10.0]);
        let e = plan(&[square("a", 320.0, 90.0)], &tool1(vec![0]), &cutter).unwrap_err();
        assert!(
            e.to_string().contains("part `a`") && e.to_string().contains("head 1"),
            "{e}"
        );
        let long = vec![square("a", 0.0, 10.0), square("b", 295.0, 10.0)];
        let p = partition(vec![group(1, 0, 0, 0.0, 0.0, vec![0, 1])], 2);
        let e = plan(&long, &p, &CutterSpec::for_partition(&long, &p)).unwrap_err();
        assert!(e.to_string().contains("G-1"), "{e}");
        let mut one = CutterSpec::for_partition(&long, &p);
        one.heads.pop();
        assert!(matches!(plan(&long, &p, &one), Err(CutError::Heads { .. })));
    }
}
