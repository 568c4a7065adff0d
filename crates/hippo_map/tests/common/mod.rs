//! Shared by the integration tests and the benches: data location and synthetic graphs.
#![allow(dead_code)]
use hippo_map::{isotropic_information, Edge, EdgeKind, Pose2, PoseGraph};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;

/// `$HIPPO_NAV_DATA` or `<repo>/../shared/data`; `None` (and a printed note) when absent.
pub fn shared_data() -> Option<PathBuf> {
    let path = std::env::var_os("HIPPO_NAV_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    if path.is_dir() {
        Some(path)
    } else {
        eprintln!(
            "skipping: real data not found at {} (set HIPPO_NAV_DATA)",
            path.display()
        );
        None
    }
}

/// Standard normal sample by Box–Muller (rand_distr is not a dependency).
pub fn gaussian(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// A noisy measurement of `true_from_to` with the given standard deviations.
pub fn noisy(
    true_from_to: &Pose2,
    sigma_xy_m: f64,
    sigma_yaw_rad: f64,
    rng: &mut impl Rng,
) -> Pose2 {
    Pose2::new(
        true_from_to.x + sigma_xy_m * gaussian(rng),
        true_from_to.y + sigma_xy_m * gaussian(rng),
        true_from_to.yaw + sigma_yaw_rad * gaussian(rng),
    )
}

/// A closed loop: `n` poses on a circle of circumference `n` metres, noisy odometry between neighbours
/// and one closure from the last pose back to the first. Returns (ground truth, graph at dead reckoning).
pub fn circle_loop(
    n: usize,
    sigma_xy_m: f64,
    sigma_yaw_rad: f64,
    seed: u64,
) -> (Vec<Pose2>, PoseGraph) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let step_yaw = 2.0 * std::f64::consts::PI / n as f64;
    let step = Pose2::new(1.0, 0.0, step_yaw);
    let mut truth = vec![Pose2::IDENTITY];
    for i in 1..n {
        truth.push(truth[i - 1].compose(&step));
    }
    let info = isotropic_information(sigma_xy_m, sigma_yaw_rad);
    let mut graph = PoseGraph::new();
    for _ in 0..n {
        graph.add_vertex(Pose2::IDENTITY).unwrap();
    }
    for i in 1..n {
        let z = noisy(
            &truth[i - 1].between(&truth[i]),
            sigma_xy_m,
            sigma_yaw_rad,
            &mut rng,
        );
        graph
            .add_edge(Edge {
                from: i - 1,
                to: i,
                from_from_to: z,
                information: info,
                kind: EdgeKind::Odometry,
            })
            .unwrap();
    }
    let z = noisy(
        &truth[n - 1].between(&truth[0]),
        sigma_xy_m,
        sigma_yaw_rad,
        &mut rng,
    );
    graph
        .add_edge(Edge {
            from: n - 1,
            to: 0,
            from_from_to: z,
            information: info,
            kind: EdgeKind::Loop,
        })
        .unwrap();
    graph.initialize_from_odometry().unwrap();
    (truth, graph)
}

/// A Manhattan-world random walk on a unit grid (like the M3500/City10000 benchmarks): `n` poses, noisy
/// odometry, and a loop closure to every earlier pose within `closure_radius_m` (at most `max_closures`
/// per pose, truth-consistent, with the same noise). Returns (ground truth, graph at dead reckoning).
pub fn manhattan_world(
    n: usize,
    closure_radius_m: f64,
    max_closures: usize,
    seed: u64,
) -> (Vec<Pose2>, PoseGraph) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (sigma_xy, sigma_yaw) = (0.05, 0.01);
    let side = ((n as f64).sqrt() * 0.5).ceil() as i64 + 2;
    let mut truth = vec![Pose2::IDENTITY];
    let mut cell = (0i64, 0i64);
    let mut heading = 0i64; // quarter turns
    let mut occupied: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    occupied.entry(cell).or_default().push(0);
    for i in 1..n {
        let turn: i64 = match rng.random_range(0..10) {
            0 => 1,
            1 => -1,
            _ => 0,
        };
        let mut h = heading + turn;
        let mut next;
        loop {
            let dir = [(1, 0), (0, 1), (-1, 0), (0, -1)][h.rem_euclid(4) as usize];
            next = (cell.0 + dir.0, cell.1 + dir.1);
            if next.0.abs() <= side && next.1.abs() <= side {
                break;
            }
            h += 1;
        }
        heading = h;
        cell = next;
        truth.push(Pose2::new(
            cell.0 as f64,
            cell.1 as f64,
            hippo_map::wrap_angle(heading as f64 * std::f64::consts::FRAC_PI_2),
        ));
        occupied.entry(cell).or_default().push(i);
    }
    let info = isotropic_information(sigma_xy, sigma_yaw);
    let mut graph = PoseGraph::new();
    for _ in 0..n {
        graph.add_vertex(Pose2::IDENTITY).unwrap();
    }
    for i in 1..n {
        let z = noisy(
            &truth[i - 1].between(&truth[i]),
            sigma_xy,
            sigma_yaw,
            &mut rng,
        );
        graph
            .add_edge(Edge {
                from: i - 1,
                to: i,
                from_from_to: z,
                information: info,
                kind: EdgeKind::Odometry,
            })
            .unwrap();
    }
    let r = closure_radius_m.ceil() as i64;
    for i in 0..n {
        let (cx, cy) = (truth[i].x as i64, truth[i].y as i64);
        let mut added = 0;
        'search: for dx in -r..=r {
            for dy in -r..=r {
                if let Some(list) = occupied.get(&(cx + dx, cy + dy)) {
                    for &j in list {
                        if added >= max_closures {
                            break 'search;
                        }
                        if j + 1 < i && ((dx * dx + dy * dy) as f64).sqrt() <= closure_radius_m {
                            let z =
                                noisy(&truth[j].between(&truth[i]), sigma_xy, sigma_yaw, &mut rng);
                            graph
                                .add_edge(Edge {
                                    from: j,
                                    to: i,
                                    from_from_to: z,
                                    information: info,
                                    kind: EdgeKind::Loop,
                                })
                                .unwrap();
                            added += 1;
                        }
                    }
                }
            }
        }
    }
    graph.initialize_from_odometry().unwrap();
    (truth, graph)
}

/// The robust-back-end protocol: `count` false loop closures between random vertex pairs, each
/// claiming a random small transform with the information of the graph's first loop edge.
pub fn add_outliers(graph: &mut PoseGraph, count: usize, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let information = graph
        .edges
        .iter()
        .find(|e| e.kind == EdgeKind::Loop)
        .map(|e| e.information)
        .unwrap_or(graph.edges[0].information);
    let n = graph.len();
    let mut added = 0;
    while added < count {
        let a = rng.random_range(0..n);
        let b = rng.random_range(0..n);
        if a.abs_diff(b) < 2 {
            continue;
        }
        let z = Pose2::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
        );
        graph
            .add_edge(Edge {
                from: a,
                to: b,
                from_from_to: z,
                information,
                kind: EdgeKind::Loop,
            })
            .unwrap();
        added += 1;
    }
}
