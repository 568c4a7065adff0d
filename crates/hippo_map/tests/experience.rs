//! The experience map driven frame by frame: creation rule, loop closure, ambiguity, relocalisation,
//! save/load.
mod common;

use hippo_map::persist::{from_bytes, to_bytes};
use hippo_map::{
    AmbiguityPolicy, Corrector, ExperienceMap, FrameInput, MapParams, Pose2, RelaxationParams,
};
use std::f64::consts::PI;

/// A square circuit of side 20 m driven at 1 m per frame, repeated `laps` times. The view cell and the
/// codes are those of a perfect front end: the view cell is the (rounded) place along the circuit, the
/// place code is position scaled onto a 100 m torus, the heading code is the true heading. Odometry
/// drifts by `yaw_bias_rad` per frame.
fn square_circuit(laps: usize, yaw_bias_rad: f64) -> Vec<FrameInput> {
    let mut frames = Vec::new();
    let mut pose = Pose2::IDENTITY;
    for step in 0..laps * 80 {
        let s = step % 80;
        let turn = s % 20 == 19;
        let true_step = Pose2::new(1.0, 0.0, if turn { PI / 2.0 } else { 0.0 });
        frames.push(FrameInput {
            view_cell_id: (s / 4) as u64,
            place_code_rad: [pose.x * 2.0 * PI / 100.0, pose.y * 2.0 * PI / 100.0],
            heading_code_rad: pose.yaw,
            odometry_step: if step == 0 {
                Pose2::IDENTITY
            } else {
                Pose2::new(1.0, 0.0, true_step.yaw + yaw_bias_rad)
            },
            elapsed_s: 0.1,
        });
        pose = pose.compose(&true_step);
    }
    frames
}

#[test]
fn first_lap_creates_vertices_and_second_lap_closes_the_loop() {
    let mut map = ExperienceMap::new(MapParams {
        online_relaxation_passes: 0,
        ..MapParams::default()
    })
    .unwrap();
    let frames = square_circuit(2, 0.01);
    let mut closures = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        let out = map.on_frame(f).unwrap();
        if let Some(c) = out.loop_closure {
            closures.push((k, c));
        }
        if k < 80 {
            assert!(
                out.loop_closure.is_none(),
                "no closure on the first lap (frame {k})"
            );
        }
    }
    let first_lap_vertices = map.vertices().len();
    assert!(
        first_lap_vertices >= 20,
        "a vertex every few metres: {first_lap_vertices}"
    );
    assert!(
        !closures.is_empty(),
        "the second lap re-enters the first lap's vertices"
    );
    assert!(
        closures[0].0 >= 80 && closures[0].0 <= 84,
        "closure at the start of lap 2: {closures:?}"
    );
    assert_eq!(map.loop_link_count(), closures.len());
    // The drifted map disagrees with the closures until corrected; both correctors reduce χ².
    let before = map.pose_graph().chi2();
    let mut relaxed = map.clone();
    let r = relaxed
        .correct(&Corrector::Relaxation(RelaxationParams {
            gain: 0.5,
            passes: 200,
        }))
        .unwrap();
    let ls = map
        .correct(&Corrector::LeastSquares(
            ExperienceMap::default_least_squares(),
        ))
        .unwrap();
    assert!(r.final_chi2 < 0.5 * before, "relaxation {r:?}");
    assert!(ls.final_chi2 <= r.final_chi2 && ls.converged, "{ls:?}");
}

#[test]
fn staying_put_keeps_the_vertex_and_a_new_view_creates_one() {
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    let still = FrameInput {
        view_cell_id: 3,
        place_code_rad: [0.0, 0.0],
        heading_code_rad: 0.0,
        odometry_step: Pose2::IDENTITY,
        elapsed_s: 0.1,
    };
    assert!(map.on_frame(&still).unwrap().created);
    let again = map.on_frame(&still).unwrap();
    assert_eq!((again.vertex, again.created), (Some(0), false));
    let new_view = map
        .on_frame(&FrameInput {
            view_cell_id: 4,
            ..still
        })
        .unwrap();
    assert_eq!((new_view.vertex, new_view.created), (Some(1), true));
    // Codes wrap: 2π − 0.01 is 0.01 away from 0, so this matches vertex 0's codes.
    let wrapped = FrameInput {
        place_code_rad: [2.0 * PI - 0.01, 0.0],
        ..still
    };
    let back = map.on_frame(&wrapped).unwrap();
    assert_eq!(back.vertex, Some(0));
    assert_eq!(
        back.loop_closure, None,
        "0 and 1 are already linked: a transition, not a closure"
    );
}

#[test]
fn ambiguous_candidates_are_reported_and_resolved_by_policy() {
    use hippo_map::{EdgeKind, Link, Vertex};
    for policy in [
        AmbiguityPolicy::NearestPose,
        AmbiguityPolicy::NearestCode,
        AmbiguityPolicy::CreateVertex,
    ] {
        let mut map = ExperienceMap::new(MapParams {
            ambiguity: policy,
            online_relaxation_passes: 0,
            ..Default::default()
        })
        .unwrap();
        // Vertices 1 and 2 share view cell 9 and nearly the same place code (the code repeats every torus
        // period) but lie 40 m apart; vertex 3 is 5 m short of vertex 2.
        let vertex = |view: u64, code: f64, x: f64| Vertex {
            view_cell_id: view,
            place_code_rad: [code, 0.0],
            heading_code_rad: 0.0,
            world_from_vertex: Pose2::new(x, 0.0, 0.0),
        };
        for v in [
            vertex(1, 1.0, 0.0),
            vertex(9, 0.0, 10.0),
            vertex(9, 0.15, 50.0),
            vertex(3, 2.0, 45.0),
        ] {
            map.add_vertex(v).unwrap();
        }
        for to in 1..4 {
            let from_to = Pose2::new(map.vertices()[to].world_from_vertex.x, 0.0, 0.0);
            map.add_link(Link {
                from: 0,
                to,
                from_from_to: from_to,
                elapsed_s: 1.0,
                kind: EdgeKind::Odometry,
            })
            .unwrap();
        }
        map.start_relocalization();
        let frame = |view: u64, code: f64, dx: f64| FrameInput {
            view_cell_id: view,
            place_code_rad: [code, 0.0],
            heading_code_rad: 0.0,
            odometry_step: Pose2::new(dx, 0.0, 0.0),
            elapsed_s: 0.1,
        };
        assert_eq!(map.on_frame(&frame(3, 2.0, 0.0)).unwrap().vertex, Some(3));
        // 5 m ahead the view is cell 9 with code 0.07: within 0.2 rad of both vertex 1 (0.07 away, the
        // closer code) and vertex 2 (0.08 away, where dead reckoning puts the agent).
        let out = map.on_frame(&frame(9, 0.07, 5.0)).unwrap();
        assert_eq!(out.ambiguous_candidates, vec![1, 2], "{policy:?}: {out:?}");
        match policy {
            AmbiguityPolicy::CreateVertex => {
                assert!(out.created && out.loop_closure.is_none());
                assert_eq!(out.vertex, Some(4));
            }
            AmbiguityPolicy::NearestCode => assert_eq!(out.loop_closure, Some((3, 1))),
            AmbiguityPolicy::NearestPose => assert_eq!(out.loop_closure, Some((3, 2))),
        }
    }
}

#[test]
fn relocalization_resumes_on_a_matching_vertex_without_adding_links() {
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    for f in square_circuit(1, 0.0) {
        map.on_frame(&f).unwrap();
    }
    let (vertices, links) = (map.vertices().len(), map.links().len());
    map.start_relocalization();
    let lost = map
        .on_frame(&FrameInput {
            view_cell_id: 999,
            ..square_circuit(1, 0.0)[10]
        })
        .unwrap();
    assert_eq!(lost.vertex, None);
    let found = map.on_frame(&square_circuit(1, 0.0)[40]).unwrap();
    assert!(found.relocalized);
    let v = found.vertex.unwrap();
    assert_eq!(map.vertices()[v].view_cell_id, 10);
    assert_eq!((map.vertices().len(), map.links().len()), (vertices, links));
}

#[test]
fn save_load_round_trip_is_identical_and_resumes() {
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    let frames = square_circuit(2, 0.01);
    for f in &frames[..120] {
        map.on_frame(f).unwrap();
    }
    let dir = std::env::temp_dir().join(format!("hippo_map_test_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("map.hnm");
    map.save(&path).unwrap();
    let mut loaded = ExperienceMap::load(&path).unwrap();
    assert_eq!(loaded, map);
    // Resuming gives the same result as never stopping.
    for f in &frames[120..] {
        assert_eq!(loaded.on_frame(f).unwrap(), map.on_frame(f).unwrap());
    }
    assert_eq!(loaded, map);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn corrupted_truncated_and_foreign_files_are_rejected_with_a_reason() {
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    for f in &square_circuit(1, 0.0)[..30] {
        map.on_frame(f).unwrap();
    }
    let bytes = to_bytes(&map).unwrap();
    let message = |b: &[u8]| from_bytes(b).unwrap_err().to_string();
    assert!(message(&bytes[..bytes.len() - 10]).contains("truncated"));
    assert!(message(&bytes[..5]).contains("not a hippo_nav map file"));
    assert!(message(b"VERTEX_SE2 0 0 0 0\n").contains("not a hippo_nav map file"));
    assert!(message(&bytes.iter().chain(b"xx").copied().collect::<Vec<_>>()).contains("trailing"));
    let mut flipped = bytes.clone();
    let k = bytes.len() - 40;
    flipped[k] = if flipped[k] == b'1' { b'2' } else { b'1' };
    assert!(message(&flipped).contains("checksum"));
    let newer =
        String::from_utf8(bytes.clone())
            .unwrap()
            .replacen("HIPPO_NAV_MAP 1", "HIPPO_NAV_MAP 2", 1);
    assert!(message(newer.as_bytes()).contains("version 2"));
    // A checksummed payload that is valid JSON but not a consistent map (a link to a missing vertex).
    let text = String::from_utf8(bytes).unwrap();
    let payload = &text[text.find('{').unwrap()..];
    let broken = payload.replacen("\"to\":1,", "\"to\":100000,", 1);
    assert_ne!(broken, payload);
    let mut fake = ExperienceMap::new(MapParams::default()).unwrap();
    fake.on_frame(&square_circuit(1, 0.0)[0]).unwrap();
    let header_for = |p: &str| {
        let good = to_bytes(&fake).unwrap();
        let good = String::from_utf8(good).unwrap();
        let h = good.find('{').unwrap();
        let _ = h;
        format!(
            "HIPPO_NAV_MAP 1\nlength {} fnv1a64 {:016x}\n{p}",
            p.len(),
            fnv(p.as_bytes())
        )
    };
    assert!(message(header_for(&broken).as_bytes()).contains("does not exist"));
}

fn fnv(bytes: &[u8]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    hash
}
