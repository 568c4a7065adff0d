//! Reader and writer of g2o 2-D pose graphs (`VERTEX_SE2`, `EDGE_SE2`, `FIX`).
//!
//! `VERTEX_SE2 id x y yaw` gives `world_from_id`; `EDGE_SE2 i j x y yaw I11 I12 I13 I22 I23 I33` gives the
//! measurement `i_from_j` and the upper triangle of its information matrix (order x, y, yaw). Blank lines
//! and `#` comments are skipped; any other tag is an error (a foreign file must not half-load). Vertex
//! indices follow ascending g2o ids. The fixed vertex is the `FIX` one, else the smallest id. An edge
//! between consecutive ids (`|j − i| = 1`) is classed as odometry, any other as a loop closure, which
//! is the convention of the standard benchmarks (some write closures backward, `j < i`). Files without
//! `VERTEX_SE2` lines (the KITTI graphs) get their initial poses by dead reckoning along the odometry.
use crate::error::{MapError, Result};
use crate::files::write_replacing;
use crate::graph::{Edge, EdgeKind, PoseGraph};
use crate::se2::Pose2;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

fn parse_error(line: usize, message: impl Into<String>) -> MapError {
    MapError::G2oParse {
        line,
        message: message.into(),
    }
}

fn parse_id(token: Option<&str>, line: usize) -> Result<u64> {
    let token = token.ok_or_else(|| parse_error(line, "missing vertex id"))?;
    token.parse::<u64>().map_err(|_| {
        parse_error(
            line,
            format!("vertex id {token:?} is not a non-negative integer"),
        )
    })
}

fn parse_numbers<const N: usize>(tokens: &[&str], line: usize, tag: &str) -> Result<[f64; N]> {
    if tokens.len() != N {
        return Err(parse_error(
            line,
            format!(
                "{tag} needs {N} numbers after the ids, found {}",
                tokens.len()
            ),
        ));
    }
    let mut out = [0.0; N];
    for (slot, token) in out.iter_mut().zip(tokens) {
        let value = token
            .parse::<f64>()
            .map_err(|_| parse_error(line, format!("{token:?} is not a number")))?;
        if !value.is_finite() {
            return Err(parse_error(line, format!("{token:?} is not finite")));
        }
        *slot = value;
    }
    Ok(out)
}

type RawEdge = (u64, u64, Pose2, [[f64; 3]; 3], usize);

/// Parse g2o text into a pose graph.
pub fn parse_g2o(text: &str) -> Result<PoseGraph> {
    let mut vertices: BTreeMap<u64, Pose2> = BTreeMap::new();
    // (from id, to id, measurement, information, line number)
    let mut raw_edges: Vec<RawEdge> = Vec::new();
    let mut fixed_id: Option<(u64, usize)> = None; // (vertex id, line)
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let tokens: Vec<&str> = content.split_whitespace().collect();
        match tokens[0] {
            "VERTEX_SE2" => {
                let id = parse_id(tokens.get(1).copied(), line)?;
                let [x, y, yaw] =
                    parse_numbers::<3>(&tokens[2.min(tokens.len())..], line, "VERTEX_SE2")?;
                let pose = Pose2::new(x, y, yaw);
                // As `add_vertex` and a map file do: a pose of 1e300 m is a unit error, not a place.
                crate::graph::check_pose("VERTEX_SE2 pose", &pose)
                    .map_err(|e| parse_error(line, e.to_string()))?;
                if vertices.insert(id, pose).is_some() {
                    return Err(parse_error(line, format!("vertex {id} is declared twice")));
                }
            }
            "EDGE_SE2" => {
                let from = parse_id(tokens.get(1).copied(), line)?;
                let to = parse_id(tokens.get(2).copied(), line)?;
                let v = parse_numbers::<9>(&tokens[3.min(tokens.len())..], line, "EDGE_SE2")?;
                let information = [[v[3], v[4], v[5]], [v[4], v[6], v[7]], [v[5], v[7], v[8]]];
                raw_edges.push((from, to, Pose2::new(v[0], v[1], v[2]), information, line));
            }
            "FIX" => {
                fixed_id = Some((parse_id(tokens.get(1).copied(), line)?, line));
            }
            other => {
                return Err(parse_error(
                    line,
                    format!(
                        "unsupported element {other:?}; only VERTEX_SE2, EDGE_SE2 and FIX are read"
                    ),
                ))
            }
        }
    }
    let all_declared = raw_edges
        .iter()
        .all(|(a, b, ..)| vertices.contains_key(a) && vertices.contains_key(b));
    // Some vertices declared and some not is a broken file, not a KITTI graph without vertices: dead reckoning
    // would silently replace every declared pose.
    if !vertices.is_empty() && !all_declared {
        if let Some((a, b, .., line)) = raw_edges
            .iter()
            .find(|(a, b, ..)| !vertices.contains_key(a) || !vertices.contains_key(b))
        {
            let missing = if vertices.contains_key(a) { b } else { a };
            return Err(parse_error(
                *line,
                format!(
                    "EDGE_SE2 joins vertex {missing}, which has no VERTEX_SE2 line while other vertices do; \
                     declare it (or declare none, and the poses come from dead reckoning along the odometry)"
                ),
            ));
        }
    }
    let mut ids: BTreeMap<u64, Pose2> = vertices.clone();
    for (a, b, ..) in &raw_edges {
        ids.entry(*a).or_insert(Pose2::IDENTITY);
        ids.entry(*b).or_insert(Pose2::IDENTITY);
    }
    if ids.is_empty() {
        return Err(MapError::EmptyGraph);
    }
    let index_of: BTreeMap<u64, usize> = ids.keys().enumerate().map(|(i, id)| (*id, i)).collect();
    let mut graph = PoseGraph {
        ids: ids.keys().copied().collect(),
        poses: ids.values().copied().collect(),
        edges: Vec::with_capacity(raw_edges.len()),
        fixed: 0,
    };
    if let Some((id, line)) = fixed_id {
        graph.fixed = *index_of.get(&id).ok_or_else(|| {
            parse_error(
                line,
                format!("FIX names vertex {id}, which has no vertex or edge"),
            )
        })?;
    }
    for (from_id, to_id, from_to, information, line) in raw_edges {
        let kind = if from_id.abs_diff(to_id) == 1 {
            EdgeKind::Odometry
        } else {
            EdgeKind::Loop
        };
        let edge = Edge {
            from: index_of[&from_id],
            to: index_of[&to_id],
            from_from_to: from_to,
            information,
            kind,
        };
        graph
            .add_edge(edge)
            .map_err(|e| parse_error(line, e.to_string()))?;
    }
    if !all_declared {
        graph.initialize_from_odometry()?;
    }
    Ok(graph)
}

/// Read a g2o file.
pub fn read_g2o(path: &Path) -> Result<PoseGraph> {
    let text = std::fs::read_to_string(path).map_err(|source| MapError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_g2o(&text)
}

/// g2o text of a graph: vertices, edges (upper-triangular information), and the fixed vertex.
/// Numbers use Rust's shortest round-trip formatting, so writing then reading is lossless.
pub fn format_g2o(graph: &PoseGraph) -> String {
    let mut out = String::new();
    for (id, p) in graph.ids.iter().zip(&graph.poses) {
        let _ = writeln!(out, "VERTEX_SE2 {id} {} {} {}", p.x, p.y, p.yaw);
    }
    for e in &graph.edges {
        let m = &e.information;
        let z = &e.from_from_to;
        let _ = writeln!(
            out,
            "EDGE_SE2 {} {} {} {} {} {} {} {} {} {} {}",
            graph.ids[e.from],
            graph.ids[e.to],
            z.x,
            z.y,
            z.yaw,
            m[0][0],
            m[0][1],
            m[0][2],
            m[1][1],
            m[1][2],
            m[2][2]
        );
    }
    if let Some(id) = graph.ids.get(graph.fixed) {
        let _ = writeln!(out, "FIX {id}");
    }
    out
}

/// Write a g2o file, whole or not at all: a temporary file renamed over `path`, so a link at `path` is
/// replaced rather than written through (see `files`).
pub fn write_g2o(graph: &PoseGraph, path: &Path) -> Result<()> {
    write_replacing(path, format_g2o(graph).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n\nVERTEX_SE2 2 1 1 1.5\n\
EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 0 1 1.5 1 0 0 1 0 1\nEDGE_SE2 2 0 0.1 -1 -1.5 1 0 0 1 0 1\n";

    #[test]
    fn reads_vertices_edges_and_classifies_closures() {
        let g = parse_g2o(SMALL).unwrap();
        assert_eq!(g.len(), 3);
        assert_eq!(g.edges.len(), 3);
        assert_eq!(g.edge_counts(), (2, 1));
        assert_eq!(g.fixed, 0);
        assert_eq!(g.poses[2], Pose2::new(1.0, 1.0, 1.5));
    }

    #[test]
    fn write_then_read_is_lossless() {
        let mut g = parse_g2o(SMALL).unwrap();
        g.poses[1].x = 0.1 + 0.2; // a value without a short decimal form
        let back = parse_g2o(&format_g2o(&g)).unwrap();
        assert_eq!(back, g);
    }

    #[test]
    fn edges_only_files_start_from_dead_reckoning() {
        let g = parse_g2o("EDGE_SE2 0 1 2 0 0.5 1 0 0 1 0 1\nEDGE_SE2 1 2 2 0 0 1 0 0 1 0 1\n")
            .unwrap();
        let p = g.poses[2];
        assert!((p.x - (2.0 + 2.0 * 0.5f64.cos())).abs() < 1e-12);
        assert!((p.y - 2.0 * 0.5f64.sin()).abs() < 1e-12);
    }

    #[test]
    fn an_edge_to_an_undeclared_vertex_is_an_error_when_others_are_declared() {
        let err = parse_g2o(
            "VERTEX_SE2 0 5 5 0\nVERTEX_SE2 1 6 5 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 7 1 0 0 1 0 0 1 0 1\n",
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("line 4") && err.to_string().contains("vertex 7"),
            "{err}"
        );
        // No vertex declared at all (the KITTI graphs): dead reckoning, as before.
        let graph = parse_g2o("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n").unwrap();
        assert_eq!(graph.len(), 2);
    }

    #[test]
    fn malformed_lines_name_the_line() {
        let err = parse_g2o("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0\n").unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
        let err = parse_g2o("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n").unwrap_err();
        assert!(err.to_string().contains("unsupported"), "{err}");
        let err =
            parse_g2o("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 1 0 0 -1 0 0 1 0 1\n")
                .unwrap_err();
        assert!(err.to_string().contains("positive definite"), "{err}");
        // A vertex beyond any map (a unit error) is refused as `add_vertex` refuses it: relaxed, such a
        // graph pulled every vertex onto it and called itself converged.
        let err = parse_g2o(
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1e300 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n",
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("line 2") && err.to_string().contains("1e9"),
            "{err}"
        );
        let err = parse_g2o(
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nFIX 9\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("line 4"), "{err}");
    }

    /// A link at the g2o file's name is replaced by the file; what it pointed to is untouched. A write
    /// into a folder that is not there fails naming the file and leaves nothing behind.
    #[cfg(unix)]
    #[test]
    fn writing_replaces_a_link_at_the_target_and_fails_cleanly() {
        use crate::files::test_support::Scratch;
        let dir = Scratch::new("g2o_link");
        let victim = dir.0.join("victim");
        std::fs::write(&victim, b"precious").unwrap();
        let target = dir.0.join("map.g2o");
        std::os::unix::fs::symlink(&victim, &target).unwrap();
        let graph = parse_g2o(SMALL).unwrap();
        write_g2o(&graph, &target).unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        assert!(std::fs::symlink_metadata(&target).unwrap().is_file());
        assert_eq!(read_g2o(&target).unwrap(), graph);

        let missing = dir.0.join("missing").join("map.g2o");
        let err = write_g2o(&graph, &missing).unwrap_err();
        assert!(
            err.to_string().contains(&missing.display().to_string()),
            "{err}"
        );
        assert_eq!(dir.names(), ["map.g2o", "victim"]);
    }
}
