//! Behaviour of view-cell matching: differences, shifts, headings, exactness of the pruned search, errors.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use approx::assert_abs_diff_eq;
use hippo_views::{ViewCellParams, ViewCells, ViewError, ViewStatus};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn params() -> ViewCellParams {
    ViewCellParams::default()
}

fn random_template(rng: &mut ChaCha8Rng, p: &ViewCellParams) -> Vec<f32> {
    (0..p.template_len())
        .map(|_| rng.random_range(-1.7f32..1.7))
        .collect()
}

/// `t` moved `shift` columns to the right (content entering on the left is fresh noise).
fn shifted(t: &[f32], p: &ViewCellParams, shift: isize, rng: &mut ChaCha8Rng) -> Vec<f32> {
    let w = p.width_px as isize;
    (0..t.len())
        .map(|i| {
            let (r, x) = ((i / p.width_px) as isize, (i % p.width_px) as isize);
            let src = x - shift;
            if (0..w).contains(&src) {
                t[(r * w + src) as usize]
            } else {
                rng.random_range(-1.7f32..1.7)
            }
        })
        .collect()
}

fn cells_with(n: usize, seed: u64) -> (ViewCells, ChaCha8Rng) {
    let p = params();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut cells = ViewCells::new(p.clone()).unwrap();
    for _ in 0..n {
        cells.add(&random_template(&mut rng, &p)).unwrap();
    }
    (cells, rng)
}

#[test]
fn identical_view_has_zero_difference_and_no_shift() {
    let (cells, _) = cells_with(20, 1);
    let t = cells.template(11).unwrap().to_vec();
    let m = cells.best_match(&t).unwrap().unwrap();
    assert_eq!((m.cell_id, m.shift_px), (11, 0));
    assert_abs_diff_eq!(m.difference, 0.0, epsilon = 1e-7);
}

#[test]
fn unrelated_textures_differ_by_about_two_thirds() {
    let p = params();
    let (cells, mut rng) = cells_with(50, 2);
    let q = random_template(&mut rng, &p);
    let d = cells.differences(&q).unwrap();
    let mean = d.iter().map(|x| x.0).sum::<f32>() / d.len() as f32;
    // Uniform noise: E|a−b| / (E|a|+E|b|) = (2/3)/(1) over equal ranges; the shift minimum lowers it a bit.
    assert!(mean > 0.6 && mean < 0.7, "mean unrelated difference {mean}");
    assert!(d.iter().all(|x| (0.0..=1.0).contains(&x.0)));
}

#[test]
fn shift_is_recovered_and_gives_counter_clockwise_heading() {
    let p = params();
    for shift in [-6isize, -2, 3, 7] {
        let (mut cells, mut rng) = cells_with(30, 3);
        let q = shifted(&cells.template(5).unwrap(), &p, shift, &mut rng);
        let obs = cells.observe(&q).unwrap();
        assert_eq!(obs.status, ViewStatus::Familiar);
        assert_eq!(obs.cell_id, Some(5));
        assert_eq!(obs.shift_px as isize, shift);
        assert_abs_diff_eq!(obs.difference, 0.0, epsilon = 1e-6);
        // Content moved right ⇒ camera turned left (counter-clockwise): positive relative heading.
        assert_abs_diff_eq!(
            obs.relative_heading_rad,
            shift as f64 * p.field_of_view_rad / p.width_px as f64
        );
        assert_eq!(cells.len(), 30, "a familiar view must not create a cell");
    }
}

#[test]
fn pruned_search_equals_brute_force() {
    let p = params();
    let (mut cells, mut rng) = cells_with(700, 4);
    // Duplicates: ties must resolve to the lowest id in both searches.
    let dup = cells.template(100).unwrap().to_vec();
    cells.add(&dup).unwrap();
    for k in 0..40 {
        let q = match k % 4 {
            0 => random_template(&mut rng, &p),
            1 => dup.clone(),
            _ => {
                let base = cells.template((k * 37) % 700).unwrap().to_vec();
                let mut q = shifted(&base, &p, (k as isize % 9) - 4, &mut rng);
                for v in &mut q {
                    *v += rng.random_range(-0.6f32..0.6);
                }
                q
            }
        };
        let fast = cells.best_match(&q).unwrap().unwrap();
        let slow = cells.best_match_brute_force(&q).unwrap().unwrap();
        assert_eq!(fast, slow, "query {k}");
    }
    assert_eq!(cells.best_match(&dup).unwrap().unwrap().cell_id, 100);
}

/// Smooth-ish textures (neighbouring values correlated, as in patch-normalised street images) make the
/// coarse bounds tight and near-duplicates common: the hardest case for the pruning to stay exact.
fn smooth_template(rng: &mut ChaCha8Rng, p: &ViewCellParams) -> Vec<f32> {
    let raw = random_template(rng, p);
    let w = p.width_px;
    (0..raw.len())
        .map(|i| {
            let (r, x) = (i / w, i % w);
            let right = raw[r * w + (x + 1) % w];
            let below = raw[((r + 1) % p.height_px) * w + x];
            raw[i] + right + below
        })
        .collect()
}

#[test]
fn pruned_search_equals_brute_force_for_novel_queries() {
    let p = params();
    for (seed, smooth) in [(6u64, false), (7, true)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut cells = ViewCells::new(p.clone()).unwrap();
        for _ in 0..600 {
            let t = if smooth {
                smooth_template(&mut rng, &p)
            } else {
                random_template(&mut rng, &p)
            };
            cells.add(&t).unwrap();
        }
        for k in 0..30 {
            let q = if smooth {
                smooth_template(&mut rng, &p)
            } else {
                random_template(&mut rng, &p)
            };
            let fast = cells.best_match(&q).unwrap().unwrap();
            let slow = cells.best_match_brute_force(&q).unwrap().unwrap();
            assert_eq!(fast, slow, "seed {seed}, query {k}");
            assert!(
                fast.difference > p.novelty_threshold,
                "query {k} is not novel"
            );
        }
    }
    // Tiny stores (fewer cells than seeds) and a single cell.
    for n in [1usize, 2, 5] {
        let (cells, mut rng) = cells_with(n, 8);
        let q = random_template(&mut rng, &p);
        assert_eq!(
            cells.best_match(&q).unwrap(),
            cells.best_match_brute_force(&q).unwrap()
        );
    }
    let empty = ViewCells::new(p.clone()).unwrap();
    assert_eq!(
        empty.best_match(&vec![0.5; p.template_len()]).unwrap(),
        None
    );
}

#[test]
fn observe_creates_cells_for_novel_views_only() {
    let p = params();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut cells = ViewCells::new(p.clone()).unwrap();
    let a = random_template(&mut rng, &p);
    let b = random_template(&mut rng, &p);
    let first = cells.observe(&a).unwrap();
    assert_eq!(
        (first.status, first.cell_id, first.difference),
        (ViewStatus::New, Some(0), 1.0)
    );
    let second = cells.observe(&b).unwrap();
    assert_eq!((second.status, second.cell_id), (ViewStatus::New, Some(1)));
    assert!(second.difference > p.novelty_threshold);
    let again = cells.observe(&a).unwrap();
    assert_eq!(
        (again.status, again.cell_id),
        (ViewStatus::Familiar, Some(0))
    );
}

#[test]
fn blank_views_are_uninformative_and_not_stored() {
    let p = params();
    let mut cells = ViewCells::new(p.clone()).unwrap();
    let obs = cells.observe(&vec![0.0; p.template_len()]).unwrap();
    assert_eq!((obs.status, obs.cell_id), (ViewStatus::Uninformative, None));
    assert!(cells.is_empty());
}

#[test]
fn bad_input_is_rejected_with_a_reason() {
    let p = params();
    let mut cells = ViewCells::new(p.clone()).unwrap();
    let err = cells.observe(&[0.5; 10]).unwrap_err();
    assert!(matches!(err, ViewError::BadTemplateSize { got: 10, .. }));
    assert!(err.to_string().contains("expected 1536"));
    let mut t = vec![0.5; p.template_len()];
    t[p.width_px * 2 + 3] = f32::NAN;
    let err = cells.observe(&t).unwrap_err();
    assert_eq!(
        err.to_string(),
        "template value at row 2, column 3 is not finite (NaN); check the input image"
    );
    assert!(matches!(
        cells.template(3),
        Err(ViewError::UnknownCell { id: 3, count: 0 })
    ));

    let too_wide = ViewCellParams {
        max_shift_px: 32,
        ..p.clone()
    };
    assert!(matches!(
        ViewCells::new(too_wide),
        Err(ViewError::BadParameter {
            name: "max_shift_px",
            ..
        })
    ));
    let bad_threshold = ViewCellParams {
        novelty_threshold: 1.5,
        ..p.clone()
    };
    assert!(ViewCells::new(bad_threshold)
        .unwrap_err()
        .to_string()
        .contains("novelty_threshold"));
    let even_patch = ViewCellParams {
        patch_size_px: 4,
        ..p.clone()
    };
    assert!(ViewCells::new(even_patch).is_err());
    // A template is stored for every cell: one of gigabytes is refused, not allocated per cell.
    let huge = ViewCellParams {
        width_px: 4096,
        height_px: 4096,
        ..p
    };
    assert!(ViewCells::new(huge)
        .unwrap_err()
        .to_string()
        .contains("values at most"));
}

#[test]
fn params_round_trip_through_json() {
    let p = params();
    let s = serde_json::to_string(&p).unwrap();
    let back: ViewCellParams = serde_json::from_str(&s).unwrap();
    assert_eq!(p, back);
    assert!(serde_json::from_str::<ViewCellParams>(r#"{"width_px": 3}"#).is_err());
}

/// Brute force over a subset from the exhaustive differences: lowest difference, ties to the lowest id.
fn brute_force_among(cells: &ViewCells, q: &[f32], ids: &[usize]) -> Option<(usize, f32, i32)> {
    let d = cells.differences(q).unwrap();
    let mut sorted = ids.to_vec();
    sorted.sort_unstable();
    sorted
        .into_iter()
        .map(|id| (id, d[id].0, d[id].1))
        .fold(None, |best, c| match best {
            Some(b) if b.1 <= c.1 => Some(b),
            _ => Some(c),
        })
}

#[test]
fn restricted_search_equals_brute_force_over_the_subset() {
    let p = params();
    let (mut cells, mut rng) = cells_with(600, 11);
    let dup = cells.template(40).unwrap().to_vec();
    cells.add(&dup).unwrap(); // id 600, a tie with 40
    for k in 0..40usize {
        let target = (k * 53) % 600;
        let q = match k % 3 {
            0 => random_template(&mut rng, &p),
            1 => dup.clone(),
            _ => {
                let mut q = shifted(
                    &cells.template(target).unwrap(),
                    &p,
                    (k as isize % 7) - 3,
                    &mut rng,
                );
                for v in &mut q {
                    *v += rng.random_range(-0.5f32..0.5);
                }
                q
            }
        };
        // Random subsets of 1–250 ids with duplicates, sometimes holding the target, sometimes not.
        let size = 1 + (k * 37) % 250;
        let mut ids: Vec<usize> = (0..size)
            .map(|_| rng.random_range(0..cells.len()))
            .collect();
        if k % 2 == 0 {
            ids.push(target);
            ids.push(600);
        }
        ids.extend_from_slice(&ids.clone()[..size / 3]);
        let fast = cells.best_match_among(&q, &ids).unwrap().unwrap();
        let (id, d, s) = brute_force_among(&cells, &q, &ids).unwrap();
        assert_eq!((fast.cell_id, fast.shift_px), (id, s), "query {k}");
        assert_eq!(fast.difference, d, "query {k}");
    }
    // With every id, the restricted search is the full one.
    let q = random_template(&mut rng, &p);
    let all: Vec<usize> = (0..cells.len()).rev().collect();
    assert_eq!(
        cells.best_match_among(&q, &all).unwrap(),
        cells.best_match(&q).unwrap()
    );
    // Ties resolve to the lowest id of the subset, as in the full search.
    assert_eq!(
        cells
            .best_match_among(&dup, &[600, 40])
            .unwrap()
            .unwrap()
            .cell_id,
        40
    );
    assert_eq!(
        cells
            .best_match_among(&dup, &[600])
            .unwrap()
            .unwrap()
            .cell_id,
        600
    );
    assert_eq!(cells.best_match_among(&dup, &[]).unwrap(), None);
}

#[test]
fn restricted_observe_is_familiar_only_within_the_subset() {
    let p = params();
    let (mut cells, mut rng) = cells_with(50, 12);
    let q = shifted(&cells.template(7).unwrap(), &p, 2, &mut rng);
    let obs = cells.observe_among(&q, &[3, 7, 7, 20]).unwrap();
    assert_eq!(
        (obs.status, obs.cell_id, obs.shift_px),
        (ViewStatus::Familiar, Some(7), 2)
    );
    assert_eq!(obs, cells.observe(&q).unwrap());
    assert_eq!(cells.len(), 50);

    // The same view with its cell left out is novel among the rest: a new cell, reporting the best
    // difference among the candidates.
    let others = [3usize, 20, 21];
    let obs = cells.observe_among(&q, &others).unwrap();
    assert_eq!((obs.status, obs.cell_id), (ViewStatus::New, Some(50)));
    let best_other = brute_force_among(&cells, &q, &others).unwrap();
    assert_eq!(obs.difference, best_other.1);
    assert_eq!(cells.template(50).unwrap(), q.as_slice());
    // No candidates at all: always new.
    let obs = cells.observe_among(&q, &[]).unwrap();
    assert_eq!(
        (obs.status, obs.cell_id, obs.difference),
        (ViewStatus::New, Some(51), 1.0)
    );
    // Uninformative templates change nothing, whatever the candidates.
    let blank = vec![0.0; p.template_len()];
    let obs = cells.observe_among(&blank, &[0, 1]).unwrap();
    assert_eq!((obs.status, obs.cell_id), (ViewStatus::Uninformative, None));
    assert_eq!(cells.len(), 52);
}

#[test]
fn unknown_candidates_are_errors_and_store_nothing() {
    let p = params();
    let (mut cells, mut rng) = cells_with(10, 13);
    let q = random_template(&mut rng, &p);
    let err = cells.observe_among(&q, &[1, 2, 10]).unwrap_err();
    assert_eq!(
        err,
        ViewError::UnknownCandidate {
            id: 10,
            position: 2,
            count: 10
        }
    );
    assert!(err.to_string().contains("candidate 2 is view cell 10"));
    assert_eq!(cells.len(), 10);
    assert!(matches!(
        cells.best_match_among(&q, &[usize::MAX]),
        Err(ViewError::UnknownCandidate { id: usize::MAX, .. })
    ));
    let empty = ViewCells::new(p.clone()).unwrap();
    assert!(empty.best_match_among(&q, &[0]).is_err());
    // A bad template is still reported as such.
    assert!(matches!(
        cells.best_match_among(&[0.5; 3], &[0]),
        Err(ViewError::BadTemplateSize { got: 3, .. })
    ));
}
