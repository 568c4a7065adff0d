//! The experience map driven frame by frame: the map reproduces its odometry, never jumps, closes
//! loops (measured and RatSLAM-style), rejects closures outside the gate or against the map,
//! ambiguity, relocalisation, save/load.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use hippo_map::{from_bytes, to_bytes};
use hippo_map::{
    isotropic_information, AmbiguityPolicy, ClosureMode, ClosureRejection, Corrector, EdgeKind,
    ExperienceMap, FrameInput, LoopMeasurement, MapParams, OnlineCorrection, Pose2,
    RelaxationParams,
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
            loop_closure: None,
        });
        pose = pose.compose(&true_step);
    }
    frames
}

fn ratslam() -> MapParams {
    MapParams {
        closure: ClosureMode::RatSlam,
        online_correction: OnlineCorrection::None,
        ..MapParams::default()
    }
}

#[test]
fn ratslam_first_lap_creates_vertices_and_second_lap_closes_the_loop() {
    let mut map = ExperienceMap::new(ratslam()).unwrap();
    let frames = square_circuit(2, 0.003);
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
    // The drifted map disagrees with the closures until corrected. Relaxation (which ignores the links'
    // uncertainties) shrinks the closures' disagreement; least squares lowers χ² and beats relaxation.
    let loop_error_m = |m: &ExperienceMap| -> f64 {
        m.links()
            .iter()
            .filter(|l| l.kind == EdgeKind::Loop)
            .map(|l| {
                let a = m.vertices()[l.from].world_from_vertex;
                let b = m.vertices()[l.to].world_from_vertex;
                let r = l.from_from_to.between(&a.between(&b));
                r.x.hypot(r.y)
            })
            .sum()
    };
    let before = map.pose_graph().chi2();
    let before_loop_m = loop_error_m(&map);
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
    assert!(
        loop_error_m(&relaxed) < 0.5 * before_loop_m,
        "relaxation {r:?}: loop error {} m -> {} m",
        before_loop_m,
        loop_error_m(&relaxed)
    );
    assert!(ls.final_chi2 < before, "{ls:?}");
    assert!(ls.final_chi2 <= r.final_chi2 && ls.converged, "{ls:?}");
}

#[test]
fn ratslam_staying_put_keeps_the_vertex_and_a_new_view_creates_one() {
    let mut map = ExperienceMap::new(ratslam()).unwrap();
    let still = FrameInput {
        view_cell_id: 3,
        place_code_rad: [0.0, 0.0],
        heading_code_rad: 0.0,
        odometry_step: Pose2::IDENTITY,
        elapsed_s: 0.1,
        loop_closure: None,
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
    // Codes wrap: 2π − 0.01 is 0.01 away from 0, so this matches vertex 0's codes; but vertex 0 was
    // made no distance ago, so this is not a place seen again: no jump back onto it, a new vertex.
    let wrapped = FrameInput {
        place_code_rad: [2.0 * PI - 0.01, 0.0],
        ..still
    };
    let back = map.on_frame(&wrapped).unwrap();
    assert_eq!((back.vertex, back.created), (Some(2), true));
    assert_eq!(back.loop_closure, None);
    assert_eq!(back.rejected_closure, Some(ClosureRejection::TooRecent));
}

#[test]
fn ambiguous_candidates_are_reported_and_resolved_by_policy() {
    use hippo_map::{Link, Vertex};
    for policy in [
        AmbiguityPolicy::NearestPose,
        AmbiguityPolicy::NearestCode,
        AmbiguityPolicy::CreateVertex,
    ] {
        let mut map = ExperienceMap::new(MapParams {
            ambiguity: policy,
            min_loop_separation_m: 0.0,
            loop_gate_m: 100.0,
            ..ratslam()
        })
        .unwrap();
        // Vertices 1 and 2 share view cell 9 and nearly the same place code (the code repeats every torus
        // period) but lie 40 m apart; vertex 3 is 5 m short of vertex 2.
        let vertex = |view: u64, code: f64, x: f64| Vertex {
            view_cell_id: view,
            place_code_rad: [code, 0.0],
            heading_code_rad: 0.0,
            world_from_vertex: Pose2::new(x, 0.0, 0.0),
            odometer_m: 0.0,
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
                information: isotropic_information(0.1, 0.01),
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
            loop_closure: None,
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
    let mut map = ExperienceMap::new(ratslam()).unwrap();
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
            .replacen("HIPPO_NAV_MAP 2", "HIPPO_NAV_MAP 3", 1);
    assert!(message(newer.as_bytes()).contains("version 3"));
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
            "HIPPO_NAV_MAP 2\nlength {} fnv1a64 {:016x}\n{p}",
            p.len(),
            fnv(p.as_bytes())
        )
    };
    assert!(message(header_for(&broken).as_bytes()).contains("does not exist"));
    // A link from a vertex to itself, which `add_link` refuses, is refused in a file too.
    let first_link = payload.find("\"from\":0,\"to\":1,").expect("a link 0 -> 1");
    let self_linked = format!(
        "{}\"from\":0,\"to\":0,{}",
        &payload[..first_link],
        &payload[first_link + "\"from\":0,\"to\":1,".len()..]
    );
    assert!(message(header_for(&self_linked).as_bytes()).contains("self-links"));
    // A link that took negative time.
    let elapsed = payload
        .find("\"elapsed_s\":")
        .expect("a link's elapsed time")
        + "\"elapsed_s\":".len();
    let backwards = format!("{}-{}", &payload[..elapsed], &payload[elapsed..]);
    assert!(message(header_for(&backwards).as_bytes()).contains("elapsed_s"));
}

fn fnv(bytes: &[u8]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    hash
}

/// Deterministic pseudo-random numbers in [-1, 1) (no dependency needed for a test).
fn noise(k: u64) -> f64 {
    let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

#[test]
fn without_closures_the_map_reproduces_its_odometry_exactly() {
    for closure in [ClosureMode::Geometric, ClosureMode::RatSlam] {
        let mut map = ExperienceMap::new(MapParams {
            closure,
            ..MapParams::default()
        })
        .unwrap();
        let mut odometry = Pose2::IDENTITY;
        for k in 0..600u64 {
            let step = if k == 0 {
                Pose2::IDENTITY
            } else {
                Pose2::new(
                    1.0 + 0.5 * noise(3 * k),
                    0.05 * noise(3 * k + 1),
                    0.1 * noise(3 * k + 2),
                )
            };
            odometry = odometry.compose(&step);
            // Codes jitter and sometimes come back near earlier values (a car turning on the spot, a
            // view seen again a few frames later): none of it may move the agent.
            let out = map
                .on_frame(&FrameInput {
                    view_cell_id: k % 7,
                    place_code_rad: [0.3 * noise(5 * k), 0.3 * noise(5 * k + 1)],
                    heading_code_rad: 0.5 * noise(5 * k + 2),
                    odometry_step: step,
                    elapsed_s: 0.1,
                    loop_closure: None,
                })
                .unwrap();
            let agent = out.world_from_agent.unwrap();
            assert!(
                (agent.x - odometry.x).abs() < 1e-9
                    && (agent.y - odometry.y).abs() < 1e-9
                    && wrap(agent.yaw - odometry.yaw).abs() < 1e-9,
                "{closure:?} frame {k}: map {agent:?} odometry {odometry:?}"
            );
            // The agent's offset from its vertex is the odometry since that vertex.
            let vertex = map.vertices()[out.vertex.unwrap()].world_from_vertex;
            let offset = vertex.between(&agent);
            let reported = out.vertex_from_agent.unwrap();
            assert!((offset.x - reported.x).abs() < 1e-9 && (offset.y - reported.y).abs() < 1e-9);
        }
        assert_eq!(map.loop_link_count(), 0, "{closure:?}");
        assert!(map.links().iter().all(|l| l.kind == EdgeKind::Odometry));
    }
}

fn wrap(a: f64) -> f64 {
    hippo_map::wrap_angle(a)
}

/// An out-and-back drive: 60 m east along y = 0, a U-turn, 60 m back west 2.5 m further left. The
/// odometry over-reads distance by 2 % and turns 0.05° per frame too far left.
fn out_and_back() -> (Vec<Pose2>, Vec<Pose2>) {
    let mut truth = vec![Pose2::IDENTITY];
    for k in 1..140 {
        let step = if (60..80).contains(&k) {
            // The U-turn: 20 frames of 9° on a 1.3 m radius.
            Pose2::new(0.2, 0.0, PI / 20.0)
        } else {
            Pose2::new(1.0, 0.0, 0.0)
        };
        truth.push(truth[k - 1].compose(&step));
    }
    let mut odometry = vec![Pose2::IDENTITY];
    for k in 1..truth.len() {
        let step = truth[k - 1].between(&truth[k]);
        let drifted = Pose2::new(
            1.02 * step.x,
            1.02 * step.y,
            step.yaw + 0.05f64.to_radians(),
        );
        odometry.push(odometry[k - 1].compose(&drifted));
    }
    (truth, odometry)
}

fn frame_of(k: usize, truth: &[Pose2], odometry: &[Pose2]) -> FrameInput {
    FrameInput {
        view_cell_id: k as u64,
        place_code_rad: [truth[k].x * 2.0 * PI / 100.0, truth[k].y * 2.0 * PI / 100.0],
        heading_code_rad: truth[k].yaw,
        odometry_step: if k == 0 {
            Pose2::IDENTITY
        } else {
            odometry[k - 1].between(&odometry[k])
        },
        elapsed_s: 0.1,
        loop_closure: None,
    }
}

#[test]
fn a_measured_closure_recovers_its_offset_and_corrects_the_map() {
    let (truth, odometry) = out_and_back();
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    let mut frame_of_vertex: Vec<usize> = Vec::new();
    let mut closures = Vec::new();
    for k in 0..truth.len() {
        let mut input = frame_of(k, &truth, &odometry);
        // Back past the U-turn (more than min_loop_separation_m on), every 3 frames measure the pose of
        // the outbound vertex nearest in truth.
        if k >= 105 && k % 3 == 0 {
            let (target, _) = frame_of_vertex
                .iter()
                .enumerate()
                .filter(|&(_, &f)| f < 50)
                .map(|(v, &f)| {
                    let d: Pose2 = truth[f].between(&truth[k]);
                    (v, d.x.hypot(d.y))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            let agent_from_target = truth[k].between(&truth[frame_of_vertex[target]]);
            input.loop_closure = Some(LoopMeasurement {
                target,
                agent_from_target,
                information: isotropic_information(0.05, 0.005),
            });
        }
        let out = map.on_frame(&input).unwrap();
        if out.created {
            frame_of_vertex.push(k);
        }
        if let Some(c) = out.loop_closure {
            closures.push((k, c));
        }
        assert_eq!(out.rejected_closure, None, "frame {k}");
    }
    assert!(closures.len() >= 8, "{closures:?}");
    // Every closure link holds its measurement in the corrected map (the offset is recovered) …
    for &(k, (from, to)) in &closures {
        let a = map.vertices()[from].world_from_vertex;
        let b = map.vertices()[to].world_from_vertex;
        let measured = truth[k].between(&truth[frame_of_vertex[to]]);
        let mapped = a.between(&b);
        assert!(
            (mapped.x - measured.x).abs() < 0.1 && (mapped.y - measured.y).abs() < 0.1,
            "frame {k}: map says {mapped:?}, measured {measured:?}"
        );
    }
    // … and the map's vertices sit closer to the truth than the odometry's (closures fix how the legs lie
    // relative to each other, not the outbound leg's own 2 % scale error).
    let error = |poses: &dyn Fn(usize) -> Pose2| -> f64 {
        let n = frame_of_vertex.len();
        let sum: f64 = (0..n)
            .map(|v| {
                let p = poses(v);
                let t = truth[frame_of_vertex[v]];
                (p.x - t.x).hypot(p.y - t.y).powi(2)
            })
            .sum();
        (sum / n as f64).sqrt()
    };
    let map_error = error(&|v| map.vertices()[v].world_from_vertex);
    let odometry_error = error(&|v| odometry[frame_of_vertex[v]]);
    assert!(
        map_error < 0.5 * odometry_error,
        "map {map_error} m vs odometry {odometry_error} m"
    );
}

#[test]
fn closures_outside_the_gate_or_against_the_map_are_rejected() {
    let (truth, odometry) = out_and_back();
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    let mut frame_of_vertex: Vec<usize> = Vec::new();
    for k in 0..100 {
        let out = map.on_frame(&frame_of(k, &truth, &odometry)).unwrap();
        if out.created {
            frame_of_vertex.push(k);
        }
    }
    let vertices = map.vertices().len();
    let poses: Vec<Pose2> = map.vertices().iter().map(|v| v.world_from_vertex).collect();
    // A look-alike place 80 m away from where the odometry puts the agent: outside the gate.
    let far = FrameInput {
        loop_closure: Some(LoopMeasurement {
            target: 1,
            agent_from_target: Pose2::new(80.0, 0.0, 0.0),
            information: isotropic_information(0.05, 0.005),
        }),
        ..frame_of(100, &truth, &odometry)
    };
    let out = map.on_frame(&far).unwrap();
    assert_eq!(out.rejected_closure, Some(ClosureRejection::OutsideGate));
    assert_eq!((out.loop_closure, map.loop_link_count()), (None, 0));
    // A vertex made a few metres back is not a place seen again.
    let recent = FrameInput {
        loop_closure: Some(LoopMeasurement {
            target: map.vertices().len() - 1,
            agent_from_target: Pose2::new(-2.0, 0.0, 0.0),
            information: isotropic_information(0.05, 0.005),
        }),
        ..frame_of(101, &truth, &odometry)
    };
    assert_eq!(
        map.on_frame(&recent).unwrap().rejected_closure,
        Some(ClosureRejection::TooRecent)
    );
    // A true closure, then one a few frames later that contradicts it by 6 m: inside the gate, but
    // the short odometry between them cannot absorb 6 m, so the corrected map refuses the second.
    let true_closure = |k: usize, target: usize, bias: Pose2| FrameInput {
        loop_closure: Some(LoopMeasurement {
            target,
            agent_from_target: truth[k]
                .between(&truth[frame_of_vertex[target]])
                .compose(&bias),
            information: isotropic_information(0.05, 0.005),
        }),
        ..frame_of(k, &truth, &odometry)
    };
    let first = map
        .on_frame(&true_closure(102, 4, Pose2::IDENTITY))
        .unwrap();
    assert!(first.loop_closure.is_some(), "{first:?}");
    let before: Vec<Pose2> = map.vertices().iter().map(|v| v.world_from_vertex).collect();
    let links = map.links().len();
    let wrong = map
        .on_frame(&true_closure(104, 3, Pose2::new(0.0, 6.0, 0.0)))
        .unwrap();
    assert_eq!(wrong.rejected_closure, Some(ClosureRejection::Inconsistent));
    assert_eq!(map.loop_link_count(), 1);
    assert_eq!(
        map.links().len(),
        links + 1,
        "only the odometry link to the new vertex stays"
    );
    for (v, p) in before.iter().enumerate() {
        assert_eq!(
            map.vertices()[v].world_from_vertex,
            *p,
            "vertex {v} restored"
        );
    }
    assert_eq!(vertices, poses.len());
}

/// The out-and-back drive as two sessions: the first drives the outbound leg and is saved; the second
/// starts (as a new map session, not knowing where) on the way back, grows a part of its own, and is
/// joined to the first by one measured closure, which places the whole second session in the first's
/// frame.
#[test]
fn a_second_session_grows_unjoined_until_a_closure_joins_it_to_the_first() {
    let (truth, odometry) = out_and_back();
    let mut first = ExperienceMap::new(MapParams::default()).unwrap();
    let mut frame_of_vertex: Vec<usize> = Vec::new();
    for k in 0..60 {
        if first
            .on_frame(&frame_of(k, &truth, &odometry))
            .unwrap()
            .created
        {
            frame_of_vertex.push(k);
        }
    }
    let mut map = from_bytes(&to_bytes(&first).unwrap()).unwrap();
    let earlier = map.vertices().len();
    map.start_session();
    assert_eq!(map.unjoined_from(), Some(earlier));
    // The second session starts at frame 85 (after the U-turn, heading back west) with odometry of its own.
    let start = 85;
    let mut joined_at = None;
    for k in start..140 {
        let mut input = frame_of(k, &truth, &odometry);
        if k == start {
            input.odometry_step = Pose2::IDENTITY;
        }
        if map.unjoined_from().is_some() {
            assert!(map
                .loop_candidates(&[0, 1, 2], &Pose2::IDENTITY)
                .unwrap()
                .is_empty());
            assert!(matches!(
                map.correct(&Corrector::Relaxation(RelaxationParams::default())),
                Err(hippo_map::MapError::Unjoined { first }) if first == earlier
            ));
        }
        if k == 95 {
            // A closure between two vertices of the unjoined session waits for the join.
            input.loop_closure = Some(LoopMeasurement {
                target: earlier,
                agent_from_target: Pose2::new(-10.0, 0.0, 0.0),
                information: isotropic_information(0.05, 0.005),
            });
            let out = map.on_frame(&input).unwrap();
            assert_eq!(out.rejected_closure, Some(ClosureRejection::Unjoined));
            assert!(!out.relocalized);
            continue;
        }
        if k == 110 {
            // Truth: the outbound vertex nearest to the agent, 2.5 m to the side, seen the other way.
            let (target, _) = frame_of_vertex
                .iter()
                .enumerate()
                .map(|(v, &f)| (v, (truth[f].x - truth[k].x).hypot(truth[f].y - truth[k].y)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            input.loop_closure = Some(LoopMeasurement {
                target,
                agent_from_target: truth[k].between(&truth[frame_of_vertex[target]]),
                information: isotropic_information(0.05, 0.005),
            });
            let out = map.on_frame(&input).unwrap();
            assert!(out.relocalized, "{out:?}");
            assert_eq!(out.loop_closure.map(|(_, to)| to), Some(target));
            joined_at = Some(k);
            // The agent now stands where the closure puts it on the first session's map (one link joins the
            // two parts, so the correction leaves it exact), which is where the truth puts it up to the first
            // session's odometry drift.
            let agent = out.world_from_agent.unwrap();
            let measured = input.loop_closure.unwrap();
            let expected = map.vertices()[target]
                .world_from_vertex
                .compose(&measured.agent_from_target.inverse());
            assert!(
                (agent.x - expected.x).hypot(agent.y - expected.y) < 0.01,
                "{agent:?} vs {expected:?}"
            );
            let truth_here = truth[0].between(&truth[k]);
            assert!(
                (agent.x - truth_here.x).hypot(agent.y - truth_here.y) < 1.0,
                "{agent:?} vs {truth_here:?}"
            );
            assert!(wrap(agent.yaw - expected.yaw).abs() < 1e-3);
            continue;
        }
        let out = map.on_frame(&input).unwrap();
        assert!(!out.relocalized);
    }
    assert_eq!(joined_at, Some(110));
    assert_eq!(map.unjoined_from(), None);
    // One graph again: it corrects, and the first session's vertices did not move at the join.
    map.correct(&Corrector::Relaxation(RelaxationParams::default()))
        .unwrap();
    for v in 0..earlier {
        let a = first.vertices()[v].world_from_vertex;
        let b = map.vertices()[v].world_from_vertex;
        assert!(
            (a.x - b.x).hypot(a.y - b.y) < 0.5,
            "vertex {v}: {a:?} → {b:?}"
        );
    }
    // The session's vertices made before the join were moved with it: near the return leg, in the
    // first session's frame (2.5 m north of the outbound leg, within the odometry's drift).
    let session = &map.vertices()[earlier];
    assert!(
        (session.world_from_vertex.y - 2.5).abs() < 1.0,
        "{session:?}"
    );
}

#[test]
fn an_unjoined_session_survives_save_and_load() {
    let (truth, odometry) = out_and_back();
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    for k in 0..30 {
        map.on_frame(&frame_of(k, &truth, &odometry)).unwrap();
    }
    let odometer = map.odometer_m();
    map.start_session();
    assert!(map.odometer_m() >= odometer + MapParams::default().min_loop_separation_m);
    for k in 30..40 {
        map.on_frame(&frame_of(k, &truth, &odometry)).unwrap();
    }
    let loaded = from_bytes(&to_bytes(&map).unwrap()).unwrap();
    assert_eq!(loaded, map);
    assert!(loaded.unjoined_from().is_some());
    // A session started on an empty map is a plain start.
    let mut empty = ExperienceMap::new(MapParams::default()).unwrap();
    empty.start_session();
    assert_eq!(empty.unjoined_from(), None);
}

#[test]
fn a_step_beyond_any_map_is_refused_and_leaves_the_map_as_it_was() {
    // A step of 1e200 m (odometry in the wrong units, an overflow) used to be taken: the map added a vertex
    // with no link, moved the agent there, and every later frame failed.
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    let frames = square_circuit(1, 0.0);
    for input in &frames[..4] {
        map.on_frame(input).unwrap();
    }
    let (vertices, links, odometer) = (map.vertices().len(), map.links().len(), map.odometer_m());
    let agent = map.world_from_agent().unwrap();
    let mut absurd = frames[4];
    absurd.odometry_step = Pose2::new(1e200, 0.0, 0.0);
    let err = map.on_frame(&absurd).unwrap_err().to_string();
    assert!(
        err.contains("beyond any map") && err.contains("units"),
        "{err}"
    );
    assert_eq!(
        (map.vertices().len(), map.links().len(), map.odometer_m()),
        (vertices, links, odometer)
    );
    assert_eq!(map.world_from_agent().unwrap(), agent);
    map.on_frame(&frames[4]).unwrap(); // the next good frame goes on
                                       // The same bound on a vertex added directly and on a pose graph's vertices.
    let mut graph = hippo_map::PoseGraph::new();
    assert!(graph.add_vertex(Pose2::new(0.0, 2e9, 0.0)).is_err());
}

#[test]
fn steps_that_add_up_beyond_any_map_are_refused_before_anything_changes() {
    // Each step is within the bound; their sum is not. The frame that would cross it is refused whole
    // (it used to advance the odometer and the agent, then fail making its vertex, and every later frame failed).
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    let frames = square_circuit(1, 0.0);
    map.on_frame(&frames[0]).unwrap();
    let mut far = frames[1];
    far.odometry_step = Pose2::new(6e8, 0.0, 0.0);
    map.on_frame(&far).unwrap();
    let (vertices, links, odometer, count) = (
        map.vertices().len(),
        map.links().len(),
        map.odometer_m(),
        map.frames(),
    );
    let agent = map.world_from_agent().unwrap();
    let err = map.on_frame(&far).unwrap_err().to_string();
    assert!(err.contains("beyond any map"), "{err}");
    assert_eq!(
        (
            map.vertices().len(),
            map.links().len(),
            map.odometer_m(),
            map.frames()
        ),
        (vertices, links, odometer, count)
    );
    assert_eq!(map.world_from_agent().unwrap(), agent);
    map.on_frame(&frames[2]).unwrap(); // a plausible step still goes on
}
