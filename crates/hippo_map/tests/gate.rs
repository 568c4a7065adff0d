//! The loop gate grows with the path through the map's links between the agent and a vertex: a closure
//! narrows it near the place closed onto only, and a vertex passed a short drive ago keeps a narrow gate
//! however far the agent has driven since the last closure.
// A test: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hippo_map::{
    isotropic_information, EdgeKind, ExperienceMap, FrameInput, Link, MapParams, Pose2, Vertex,
};
use std::f64::consts::PI;

fn vertex_at(x: f64, y: f64, yaw: f64) -> Vertex {
    Vertex {
        view_cell_id: 0,
        place_code_rad: [0.0, 0.0],
        heading_code_rad: 0.0,
        world_from_vertex: Pose2::new(x, y, yaw),
        odometer_m: 0.0,
    }
}

fn link(map: &ExperienceMap, from: usize, to: usize, kind: EdgeKind) -> Link {
    let v = map.vertices();
    Link {
        from,
        to,
        from_from_to: v[from].world_from_vertex.between(&v[to].world_from_vertex),
        elapsed_s: 1.0,
        kind,
        information: isotropic_information(0.5, 0.01),
    }
}

/// Drive `steps` frames of `step` (codes and view cell fixed: the map makes a vertex every 10 m).
fn drive(map: &mut ExperienceMap, steps: usize, step: Pose2) {
    for _ in 0..steps {
        let input = FrameInput {
            view_cell_id: 0,
            place_code_rad: [0.0, 0.0],
            heading_code_rad: 0.0,
            odometry_step: step,
            elapsed_s: 0.1,
            loop_closure: None,
        };
        map.on_frame(&input).unwrap();
    }
}

#[test]
fn a_place_far_along_the_graph_from_the_last_closure_keeps_a_wide_gate() {
    // The agent (vertex 0, the current one) has just closed onto vertex 1. The old path from vertex 1 runs
    // 2 020 m round a block and ends at vertex `far`, beside the street the agent is about to drive.
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    map.add_vertex(vertex_at(0.0, 0.0, 0.0)).unwrap();
    let corners: [(f64, f64); 5] = [
        (0.0, 0.5),
        (-900.0, 0.5),
        (-900.0, 100.0),
        (60.0, 100.0),
        (60.0, 40.0),
    ];
    let mut previous = None;
    for pair in corners.windows(2) {
        let ((x0, y0), (x1, y1)) = (pair[0], pair[1]);
        let length_m = (x1 - x0).hypot(y1 - y0);
        let steps = (length_m / 10.0).round() as usize;
        for k in 0..steps {
            let t = k as f64 / steps as f64;
            let v = map
                .add_vertex(vertex_at(x0 + t * (x1 - x0), y0 + t * (y1 - y0), 0.0))
                .unwrap();
            if let Some(p) = previous {
                let l = link(&map, p, v, EdgeKind::Odometry);
                map.add_link(l).unwrap();
            }
            previous = Some(v);
        }
    }
    let far = map.add_vertex(vertex_at(60.0, 40.0, 0.0)).unwrap();
    let l = link(&map, previous.unwrap(), far, EdgeKind::Odometry);
    map.add_link(l).unwrap();
    let closure = link(&map, 0, 1, EdgeKind::Loop);
    map.add_link(closure).unwrap();
    // 60 m east: `far` lies 40 m to the left, and only the 2 km round the block relate the two.
    drive(&mut map, 60, Pose2::new(1.0, 0.0, 0.0));
    let candidates = map.loop_candidates(&[1, 2, far], &Pose2::IDENTITY).unwrap();
    let found: Vec<usize> = candidates.iter().map(|c| c.vertex).collect();
    assert_eq!(found, vec![far], "{candidates:?}");
    let c = &candidates[0];
    assert!((c.distance_m - 40.0).abs() < 1e-6);
    // 60 m back to vertex 0, 0.5 m of closure, 2 019.5 m round the block.
    assert!((c.path_m - 2080.0).abs() < 1e-6, "path {} m", c.path_m);
    // The gate a travel-since-closure rule would give (10 m + 10 % of 60 m, plus a vertex spacing) is
    // narrower than the 40 m, and so is the gate of vertex 2 (70 m along the links, 70 m away): refused.
    let params = MapParams::default();
    assert!(params.loop_gate(60.0).0 + params.max_vertex_spacing_m < 40.0);
    assert!(params.loop_gate(c.path_m).0 > 40.0);
}

#[test]
fn a_place_passed_a_short_drive_ago_keeps_a_narrow_gate() {
    // 1 km east without a closure, turn round, 60 m back west.
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    drive(&mut map, 1000, Pose2::new(1.0, 0.0, 0.0));
    drive(&mut map, 1, Pose2::new(0.0, 0.0, PI));
    drive(&mut map, 60, Pose2::new(1.0, 0.0, 0.0));
    let vertices: Vec<usize> = (0..map.vertices().len()).collect();
    let candidates = map.loop_candidates(&vertices, &Pose2::IDENTITY).unwrap();
    let params = MapParams::default();
    for c in &candidates {
        let x = map.vertices()[c.vertex].world_from_vertex.x;
        // The path runs along the road, out to the turn and back, less the last metres before the turn
        // (links keep net displacements: the vertex before the turn and the one after it are 11 m apart).
        let road_m = (1000.0 - x) + 60.0;
        assert!(
            c.path_m <= road_m && c.path_m >= road_m - 20.0,
            "{c:?} at {x}"
        );
        assert!(c.distance_m <= params.loop_gate(c.path_m).0 + params.max_vertex_spacing_m);
    }
    // The agent stands at x = 940. The vertex nearest x = 900 is about 40 m ahead but only about 140 m of
    // links back: a revisit cannot have drifted that far, so it is refused; a gate grown with the 1 060 m
    // since the start would take it (126 m). The one nearest x = 935 is within its gate.
    let at = |x: f64| {
        (0..map.vertices().len())
            .min_by(|&a, &b| {
                let gap = |v: usize| (map.vertices()[v].world_from_vertex.x - x).abs();
                gap(a).total_cmp(&gap(b))
            })
            .unwrap()
    };
    let found: Vec<usize> = candidates.iter().map(|c| c.vertex).collect();
    assert!(!found.contains(&at(900.0)), "{candidates:?}");
    assert!(found.contains(&at(935.0)), "{candidates:?}");
    assert!(params.loop_gate(map.odometer_m()).0 > 100.0);
}
