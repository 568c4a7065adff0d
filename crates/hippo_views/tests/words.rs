//! Behaviour of the vocabulary of binary words and of word view cells: training, words, bags, scores,
//! the inverted index against a brute-force search, the file format and its errors.
// A test: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use hippo_views::words::{hamming, BowVector, Descriptor, TrainingParams, Vocabulary, WordCells};
use hippo_views::ViewError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_descriptor(rng: &mut ChaCha8Rng) -> Descriptor {
    let mut d = [0u8; 32];
    rng.fill(&mut d[..]);
    d
}

/// `d` with `bits` of its bits flipped (distinct positions).
fn noisy(d: &Descriptor, bits: usize, rng: &mut ChaCha8Rng) -> Descriptor {
    let mut out = *d;
    let mut flipped = std::collections::HashSet::new();
    while flipped.len() < bits {
        let b: usize = rng.random_range(0..256);
        if flipped.insert(b) {
            out[b / 8] ^= 1 << (b % 8);
        }
    }
    out
}

/// Images made of noisy copies of `prototypes` (like the same corners seen again): image i holds
/// `per_image` descriptors drawn from the prototypes it uses.
fn images(
    seed: u64,
    n_images: usize,
    per_image: usize,
    prototypes: &[Descriptor],
) -> Vec<Vec<Descriptor>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n_images)
        .map(|_| {
            (0..per_image)
                .map(|_| {
                    let p = &prototypes[rng.random_range(0..prototypes.len())];
                    noisy(p, 10, &mut rng)
                })
                .collect()
        })
        .collect()
}

fn prototypes(seed: u64, n: usize) -> Vec<Descriptor> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| random_descriptor(&mut rng)).collect()
}

fn params(levels: usize) -> TrainingParams {
    TrainingParams {
        branching: 8,
        levels,
        seed: 7,
    }
}

#[test]
fn hamming_counts_differing_bits() {
    let a = [0u8; 32];
    let mut b = [0u8; 32];
    assert_eq!(hamming(&a, &b), 0);
    b[0] = 0b1011;
    b[31] = 0x80;
    assert_eq!(hamming(&a, &b), 4);
    assert_eq!(
        hamming(&a, &[0xff; 32]),
        256,
        "all bits differ: 256 fits (no u8 wrap)"
    );
}

#[test]
fn training_is_deterministic_and_independent_of_threads() {
    let protos = prototypes(1, 300);
    let data = images(2, 60, 200, &protos);
    let a = Vocabulary::train(&data, params(3)).unwrap();
    let b = Vocabulary::train(&data, params(3)).unwrap();
    assert_eq!(a.to_bytes(), b.to_bytes());
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let c = one_thread.install(|| Vocabulary::train(&data, params(3)).unwrap());
    assert_eq!(a.to_bytes(), c.to_bytes());
    let other_seed = Vocabulary::train(
        &data,
        TrainingParams {
            seed: 8,
            ..params(3)
        },
    )
    .unwrap();
    assert_ne!(a.to_bytes(), other_seed.to_bytes(), "the seed matters");
    assert!(
        a.len() > 100 && a.len() <= 8usize.pow(3),
        "{} words",
        a.len()
    );
}

#[test]
fn noisy_copies_of_a_corner_share_its_word() {
    // Clusters well apart (random prototypes differ in ~128 bits) with 10-bit noise: a vocabulary with
    // about as many words as prototypes gives every copy of a prototype the same word, mostly.
    let protos = prototypes(3, 60);
    let data = images(4, 40, 150, &protos);
    let vocabulary = Vocabulary::train(&data, params(2)).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut same = 0;
    for p in &protos {
        let w = vocabulary.word(&noisy(p, 10, &mut rng));
        same += usize::from(w == vocabulary.word(&noisy(p, 10, &mut rng)));
    }
    assert!(same >= 57, "{same} of 60 prototypes kept their word");
}

#[test]
fn a_word_in_every_image_weighs_nothing() {
    let protos = prototypes(6, 40);
    let mut data = images(7, 30, 100, &protos[1..]);
    let everywhere = protos[0];
    for image in &mut data {
        image.push(everywhere);
    }
    let vocabulary = Vocabulary::train(&data, params(3)).unwrap();
    let w = vocabulary.word(&everywhere) as usize;
    assert!(vocabulary.idf()[w] < 0.05, "idf {}", vocabulary.idf()[w]);
    let bag = vocabulary.bag(&[everywhere, everywhere]);
    assert!(bag.entries.iter().all(|&(word, _)| word as usize != w));
}

#[test]
fn bags_are_l1_normalised_and_score_like_dbow2() {
    let protos = prototypes(8, 200);
    let data = images(9, 50, 200, &protos);
    let vocabulary = Vocabulary::train(&data, params(3)).unwrap();
    let a = vocabulary.bag(&data[0]);
    let b = vocabulary.bag(&data[1]);
    let total: f32 = a.entries.iter().map(|e| e.1).sum();
    assert!((total - 1.0).abs() < 1e-5);
    assert!(
        a.entries.windows(2).all(|w| w[0].0 < w[1].0),
        "sorted by word"
    );
    assert!((a.score(&a) - 1.0).abs() < 1e-5);
    // 1 − ½‖a − b‖₁ over dense vectors.
    let dense = |v: &BowVector| {
        let mut d = vec![0.0f32; vocabulary.len()];
        for &(w, x) in &v.entries {
            d[w as usize] = x;
        }
        d
    };
    let (da, db) = (dense(&a), dense(&b));
    let l1: f32 = da.iter().zip(&db).map(|(x, y)| (x - y).abs()).sum();
    assert!((a.score(&b) - (1.0 - 0.5 * l1)).abs() < 1e-5);
    assert!((a.score(&b) - b.score(&a)).abs() < 1e-6);
    assert!(vocabulary.bag(&[]).is_empty());
}

#[test]
fn the_inverted_index_ranks_like_brute_force() {
    let protos = prototypes(10, 400);
    let data = images(11, 80, 150, &protos);
    let vocabulary = Vocabulary::train(&data, params(3)).unwrap();
    let mut cells = WordCells::new(vocabulary.clone());
    for image in &data[..60] {
        let keypoints = vec![[1.0f32, 2.0]; image.len()];
        cells.add(keypoints, image.clone()).unwrap();
    }
    for query in &data[60..] {
        let bag = vocabulary.bag(query);
        let mut brute: Vec<(usize, f32)> = (0..60)
            .map(|id| (id, bag.score(&cells.cell(id).unwrap().bag)))
            .filter(|&(_, s)| s > 0.0)
            .collect();
        brute.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let ranked = cells.query(&bag, None, 5).unwrap();
        assert_eq!(ranked.len(), 5);
        for (got, want) in ranked.iter().zip(&brute) {
            assert_eq!(got.0, want.0);
            assert!((got.1 - want.1).abs() < 1e-5);
        }
        // Among a subset (duplicates allowed), only its members are ranked.
        let subset = [3usize, 17, 17, 42, 59];
        let among = cells.query(&bag, Some(&subset), 10).unwrap();
        assert!(among.iter().all(|(id, _)| subset.contains(id)));
        assert_eq!(among.len(), 4);
    }
}

#[test]
fn a_revisit_outranks_other_places() {
    // Place A seen twice (different noise), places B.. once: A's second view ranks A first.
    let protos = prototypes(12, 2000);
    let data = images(13, 40, 300, &protos);
    let vocabulary = Vocabulary::train(&data, params(3)).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let place: Vec<Descriptor> = (0..300).map(|i| protos[(i * 7) % 2000]).collect();
    let seen = |rng: &mut ChaCha8Rng| -> Vec<Descriptor> {
        place.iter().map(|d| noisy(d, 12, rng)).collect()
    };
    let mut cells = WordCells::new(vocabulary.clone());
    for image in &data[..30] {
        cells
            .add(vec![[0.0, 0.0]; image.len()], image.clone())
            .unwrap();
    }
    let first = seen(&mut rng);
    let id = cells.add(vec![[0.0, 0.0]; first.len()], first).unwrap();
    let again = vocabulary.bag(&seen(&mut rng));
    let ranked = cells.query(&again, None, 3).unwrap();
    assert_eq!(ranked[0].0, id, "{ranked:?}");
    assert!(ranked[0].1 > 1.5 * ranked[1].1, "{ranked:?}");
}

#[test]
fn bad_input_is_a_clear_error() {
    assert_eq!(
        Vocabulary::train(&[], params(3)),
        Err(ViewError::NoTrainingData)
    );
    assert!(matches!(
        Vocabulary::train(
            &[vec![[0u8; 32]]],
            TrainingParams {
                branching: 1,
                ..params(3)
            }
        ),
        Err(ViewError::BadParameter {
            name: "branching",
            ..
        })
    ));
    assert!(matches!(
        Vocabulary::train(&[vec![[0u8; 32]]], params(0)),
        Err(ViewError::BadParameter { name: "levels", .. })
    ));
    // A degenerate training set (one repeated descriptor) gives a one-word vocabulary, not a panic.
    let one = Vocabulary::train(&[vec![[5u8; 32]; 50]], params(3)).unwrap();
    assert_eq!(one.len(), 1);

    let vocabulary =
        Vocabulary::train(&images(15, 10, 50, &prototypes(16, 50)), params(2)).unwrap();
    let mut cells = WordCells::new(vocabulary);
    let err = cells.add(vec![[0.0, 0.0]], vec![[0u8; 32]; 2]).unwrap_err();
    assert!(
        err.to_string().contains("one keypoint per descriptor"),
        "{err}"
    );
    let err = cells
        .add(vec![[f32::NAN, 0.0]], vec![[0u8; 32]])
        .unwrap_err();
    assert!(err.to_string().contains("not finite"), "{err}");
    assert!(cells.is_empty(), "nothing stored by a refused add");
    cells.add(vec![[0.0, 0.0]], vec![[0u8; 32]]).unwrap();
    let bag = cells.bag(&[[0.0, 0.0]], &[[0u8; 32]]).unwrap();
    assert!(matches!(
        cells.query(&bag, Some(&[0, 1]), 3),
        Err(ViewError::UnknownCandidate {
            id: 1,
            position: 1,
            count: 1
        })
    ));
    assert!(matches!(
        cells.cell(5),
        Err(ViewError::UnknownCell { id: 5, count: 1 })
    ));
}

#[test]
fn the_file_format_round_trips_and_refuses_damage() {
    let vocabulary =
        Vocabulary::train(&images(17, 30, 100, &prototypes(18, 100)), params(3)).unwrap();
    let bytes = vocabulary.to_bytes();
    assert_eq!(Vocabulary::from_bytes(&bytes).unwrap(), vocabulary);

    let why = |b: &[u8]| match Vocabulary::from_bytes(b) {
        Err(ViewError::BadVocabulary { why }) => why,
        other => panic!("expected BadVocabulary, got {other:?}"),
    };
    assert!(why(&bytes[..bytes.len() - 7]).contains("truncated"));
    let mut corrupted = bytes.clone();
    let last = corrupted.len() - 100;
    corrupted[last] ^= 0x10;
    assert!(why(&corrupted).contains("checksum"));
    assert!(why(b"hippo_nav map 1\nlength 0 fnv1a64 0\n").contains("not a vocabulary"));
    assert!(why(b"").contains("header"));
    // A well-formed file whose tree points outside itself.
    let mut bad = Vocabulary::from_bytes(&bytes).unwrap().to_bytes();
    let header_end = bad
        .iter()
        .enumerate()
        .filter(|(_, &b)| b == b'\n')
        .nth(1)
        .unwrap()
        .0
        + 1;
    // Root node's first_child (after 16 bytes of counts and 32 of centroid) made huge; fix the CRC.
    let at = header_end + 16 + 32;
    bad[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    let payload = bad[header_end..].to_vec();
    let header = format!(
        "hippo_nav vocabulary 1\nlength {} crc32 {:08x}\n",
        payload.len(),
        crc32fast::hash(&payload)
    );
    let mut rebuilt = header.into_bytes();
    rebuilt.extend_from_slice(&payload);
    assert!(why(&rebuilt).contains("outside the node list"));
}
