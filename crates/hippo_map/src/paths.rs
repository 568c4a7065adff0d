//! Shortest paths through the map's links, in metres.
//!
//! The odometry's uncertainty between two places grows with the path of measurements that relates them,
//! not with the time since the last closure: a closure pins the agent to one place, and says little about a
//! place kilometres along the graph from it (KITTI 00 at `strong` with 1 %-drifting odometry: after a
//! closure, the next revisited street lay 20 m from where the odometry put it and drew away at 0.2–0.5 m
//! per metre, docs/map.md "Search by path").
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Length (m) of the shortest path from `source` to each of `vertices` vertices, through `links`
/// (`(from, to, length_m)`, walked both ways); `f64::INFINITY` where no path leads. Dijkstra with a binary
/// heap: `O(links · log vertices)`, about 0.1 ms for a few thousand vertices.
pub(crate) fn path_lengths_m(
    vertices: usize,
    links: impl Iterator<Item = (usize, usize, f64)>,
    source: usize,
) -> Vec<f64> {
    let mut neighbours: Vec<Vec<(usize, f64)>> = vec![Vec::new(); vertices];
    for (from, to, length_m) in links {
        // A link to a vertex that does not exist, or a length that is not a length, carries no path.
        if from < vertices && to < vertices && length_m.is_finite() && length_m >= 0.0 {
            neighbours[from].push((to, length_m));
            neighbours[to].push((from, length_m));
        }
    }
    let mut length_m = vec![f64::INFINITY; vertices];
    if source >= vertices {
        return length_m;
    }
    length_m[source] = 0.0;
    // Non-negative finite f64s order as their bit patterns do, so the heap can hold the bits.
    let mut heap = BinaryHeap::from([Reverse((0.0f64.to_bits(), source))]);
    while let Some(Reverse((bits, v))) = heap.pop() {
        let here_m = f64::from_bits(bits);
        if here_m > length_m[v] {
            continue;
        }
        for &(w, step_m) in &neighbours[v] {
            let there_m = here_m + step_m;
            if there_m < length_m[w] {
                length_m[w] = there_m;
                heap.push(Reverse((there_m.to_bits(), w)));
            }
        }
    }
    length_m
}

#[cfg(test)]
mod tests {
    use super::path_lengths_m;

    #[test]
    fn a_chain_sums_its_links_and_a_shortcut_shortens_it() {
        // 0 - 1 - 2 - 3 - 4, 10 m apart; then a 1 m shortcut from 4 back to 0.
        let chain: Vec<(usize, usize, f64)> = (0..4).map(|i| (i, i + 1, 10.0)).collect();
        assert_eq!(
            path_lengths_m(5, chain.iter().copied(), 4),
            vec![40.0, 30.0, 20.0, 10.0, 0.0]
        );
        let looped = chain.iter().copied().chain([(4, 0, 1.0)]);
        assert_eq!(
            path_lengths_m(5, looped, 4),
            vec![1.0, 11.0, 20.0, 10.0, 0.0]
        );
    }

    #[test]
    fn unreachable_vertices_and_bad_links_have_no_path() {
        let links = [(0, 1, 5.0), (2, 3, 1.0), (1, 9, 1.0), (0, 2, f64::NAN)];
        let length_m = path_lengths_m(4, links.into_iter(), 0);
        assert_eq!(&length_m[..2], &[0.0, 5.0]);
        assert!(length_m[2].is_infinite() && length_m[3].is_infinite());
        assert!(path_lengths_m(2, links.into_iter(), 7)
            .iter()
            .all(|l| l.is_infinite()));
    }
}
