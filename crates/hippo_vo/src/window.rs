//! The sliding window: the last keyframes, the landmarks they see, and their joint refinement.
//!
//! Landmark management. A landmark is created by the first stereo observation of its id (triangulated with
//! that keyframe's pose) and forgotten when no keyframe of the window sees it any more. An observation
//! whose χ² after the first round of adjustment exceeds the bound (a track that slid, a moving object) is
//! an outlier from then on: it no longer enters the adjustment, and the caller learns which of the
//! newest keyframe's observations are, so that it stops tracking them. A landmark seen by one keyframe
//! only carries no information about the poses; it moves with its keyframe.
//!
//! Keyframes that share too few landmarks with the window (the tracker lost its points and started
//! afresh, after a frame it rejected) start a new window with that keyframe as its fixed anchor: a
//! pose nothing ties to the window cannot be refined, and a wrong link would poison the others.
use crate::bundle::{self, BundleObservation, BundleSettings};
use crate::camera::StereoCamera;
use crate::error::{Result, VoError};
use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, VecDeque};

/// Settings of the window. Its `Default` is the one source of every default: Python reads them
/// (`default_params_json("vo_window")`) and gives the window back the JSON of the config's `vo.window`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WindowParams {
    /// Keyframes refined together (the oldest stays fixed); ≥ 2.
    pub max_keyframes: usize,
    /// Older keyframes kept beyond those, fixed: their observations still place the landmarks they share
    /// with the refined ones (a longer baseline), as the fixed keyframes of ORB-SLAM's local adjustment.
    pub fixed_keyframes: usize,
    /// Standard deviation of a tracked pixel coordinate, px.
    pub pixel_sigma_px: f64,
    /// Standard deviation of a right-image column from the stereo match, px. A stereo match of a slanted
    /// surface is less certain than a temporal track: t_rel 1.03 % on the 05 render at 2 px against 1.25 %
    /// at 1 px (docs/vo.md).
    pub right_sigma_px: f64,
    /// Huber threshold on an observation's normalised residual norm, σ.
    pub huber_sigma: f64,
    /// χ² bound beyond which an observation with a right-image match (3 coordinates) is an outlier
    /// (7.815: the 95 % quantile of χ²₃).
    pub outlier_chi2_stereo: f64,
    /// The same for an observation without one (2 coordinates; 5.991: χ²₂ at 95 %).
    pub outlier_chi2_mono: f64,
    /// Levenberg–Marquardt iterations of each of the two rounds (before and after outlier removal).
    pub iterations: usize,
    /// A keyframe sharing fewer landmarks with the window starts a new window.
    pub min_shared_landmarks: usize,
    /// Smallest disparity a landmark is created from, px (farther points are too uncertain to place).
    pub min_disparity_px: f64,
}

impl Default for WindowParams {
    fn default() -> Self {
        Self {
            max_keyframes: 8,
            fixed_keyframes: 0,
            pixel_sigma_px: 1.0,
            right_sigma_px: 2.0,
            huber_sigma: 7.815_f64.sqrt(),
            outlier_chi2_stereo: 7.815,
            outlier_chi2_mono: 5.991,
            iterations: 6,
            min_shared_landmarks: 20,
            min_disparity_px: 1.0,
        }
    }
}

impl WindowParams {
    fn check(&self) -> Result<()> {
        let bad = |name, value: f64, why: &str| {
            Err(VoError::BadParameter {
                name,
                value: value.to_string(),
                why: why.to_string(),
            })
        };
        if self.max_keyframes < 2 {
            return bad(
                "max_keyframes",
                self.max_keyframes as f64,
                "must be ≥ 2 (one fixed, one refined)",
            );
        }
        for (name, value) in [
            ("pixel_sigma_px", self.pixel_sigma_px),
            ("right_sigma_px", self.right_sigma_px),
            ("huber_sigma", self.huber_sigma),
            ("outlier_chi2_stereo", self.outlier_chi2_stereo),
            ("outlier_chi2_mono", self.outlier_chi2_mono),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return bad(name, value, "must be finite and > 0");
            }
        }
        if !(self.min_disparity_px.is_finite() && self.min_disparity_px >= 0.0) {
            return bad(
                "min_disparity_px",
                self.min_disparity_px,
                "must be finite and ≥ 0",
            );
        }
        Ok(())
    }
}

/// One tracked point seen in a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// The tracker's id of the point: the same while it is tracked, never reused.
    pub landmark: u64,
    /// Left-image pixel (u, v).
    pub left_px: [f64; 2],
    /// Right-image column of the same point (NaN: not matched in the right image).
    pub right_u_px: f64,
}

#[derive(Debug, Clone, Copy)]
struct Stored {
    landmark: u64,
    left_px: [f64; 2],
    right_u_px: Option<f64>,
    outlier: bool,
}

#[derive(Debug, Clone)]
struct Keyframe {
    camera_from_world: Isometry3<f64>,
    observations: Vec<Stored>,
}

#[derive(Debug, Clone, Copy)]
struct Landmark {
    world: Vector3<f64>,
    /// Keyframes of the window that observe it (outliers included).
    seen_by: usize,
}

/// What adding a keyframe did.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeOutcome {
    /// The keyframe's refined pose.
    pub camera_from_world: Isometry3<f64>,
    /// The window was started afresh with this keyframe (too few shared landmarks, or the first one).
    pub reset: bool,
    /// Observations of landmarks the window already held.
    pub shared_landmarks: usize,
    /// Keyframes in the window after this one was added.
    pub keyframes: usize,
    /// Landmarks refined (seen by at least two keyframes).
    pub landmarks_adjusted: usize,
    /// Observations of the window found to be outliers by this refinement.
    pub new_outliers: usize,
    /// Per input observation: its landmark has an outlier observation in the window (stop tracking it).
    pub outlier: Vec<bool>,
    /// Per input observation: its landmark in this keyframe's camera frame after refinement (NaN when
    /// it has none).
    pub point_camera: Vec<[f64; 3]>,
    /// Robust cost of the adjustment before and after (0 when nothing was adjusted).
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
}

/// The last keyframes and their landmarks, refined jointly (see the module doc).
#[derive(Debug, Clone)]
pub struct SlidingWindow {
    camera: StereoCamera,
    params: WindowParams,
    keyframes: VecDeque<Keyframe>,
    landmarks: HashMap<u64, Landmark>,
}

/// A 4×4 rigid transform as an isometry; errors when it is not finite or not rigid.
pub fn isometry_from_matrix(m: &Matrix4<f64>) -> Result<Isometry3<f64>> {
    if let Some(v) = m.iter().find(|v| !v.is_finite()) {
        return Err(VoError::NonFinite {
            what: "the keyframe pose",
            value: *v,
        });
    }
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    let deviation = (r.transpose() * r - nalgebra::Matrix3::identity())
        .abs()
        .max();
    // A chain of float products drifts from orthonormal by about 1e-9 per step: allow that, re-normalise.
    if deviation > 1e-4 || r.determinant() < 0.0 {
        return Err(VoError::NotRigid { deviation });
    }
    let rotation = UnitQuaternion::from_matrix(&r);
    Ok(Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        rotation,
    ))
}

impl SlidingWindow {
    /// An empty window.
    pub fn new(camera: StereoCamera, params: WindowParams) -> Result<Self> {
        params.check()?;
        Ok(Self {
            camera,
            params,
            keyframes: VecDeque::new(),
            landmarks: HashMap::new(),
        })
    }

    /// The settings.
    pub fn params(&self) -> &WindowParams {
        &self.params
    }

    /// Keyframes in the window.
    pub fn len(&self) -> usize {
        self.keyframes.len()
    }

    /// No keyframe yet (or after [`Self::clear`]).
    pub fn is_empty(&self) -> bool {
        self.keyframes.is_empty()
    }

    /// Landmarks held.
    pub fn landmarks(&self) -> usize {
        self.landmarks.len()
    }

    /// Forget every keyframe and landmark.
    pub fn clear(&mut self) {
        self.keyframes.clear();
        self.landmarks.clear();
    }

    /// The poses of the window's keyframes, oldest first.
    pub fn poses(&self) -> Vec<Isometry3<f64>> {
        self.keyframes.iter().map(|k| k.camera_from_world).collect()
    }

    /// Add a keyframe with its initial pose and observations, drop the oldest beyond `max_keyframes`, and
    /// refine the window.
    pub fn add_keyframe(
        &mut self,
        camera_from_world_guess: Isometry3<f64>,
        observations: &[Observation],
    ) -> Result<KeyframeOutcome> {
        let mut seen = std::collections::HashSet::with_capacity(observations.len());
        for obs in observations {
            for value in [obs.left_px[0], obs.left_px[1]] {
                if !value.is_finite() {
                    return Err(VoError::NonFinite {
                        what: "an observed pixel",
                        value,
                    });
                }
            }
            if obs.right_u_px.is_infinite() {
                return Err(VoError::NonFinite {
                    what: "an observed right column",
                    value: obs.right_u_px,
                });
            }
            if !seen.insert(obs.landmark) {
                return Err(VoError::DuplicateLandmark {
                    landmark: obs.landmark,
                });
            }
        }
        let shared = observations
            .iter()
            .filter(|o| self.landmarks.contains_key(&o.landmark))
            .count();
        let reset = self.keyframes.is_empty() || shared < self.params.min_shared_landmarks;
        if reset {
            self.clear();
        }
        // Store the keyframe; create the landmarks first seen here (stereo observations only).
        let mut stored = Vec::with_capacity(observations.len());
        let world_from_camera = camera_from_world_guess.inverse();
        for obs in observations {
            let right = (!obs.right_u_px.is_nan()).then_some(obs.right_u_px);
            if let Some(landmark) = self.landmarks.get_mut(&obs.landmark) {
                landmark.seen_by += 1;
            } else {
                let Some(x) = right.and_then(|r| {
                    self.camera.triangulate(
                        obs.left_px[0],
                        obs.left_px[1],
                        r,
                        self.params.min_disparity_px,
                    )
                }) else {
                    continue;
                };
                let world = (world_from_camera * Point3::from(x)).coords;
                self.landmarks
                    .insert(obs.landmark, Landmark { world, seen_by: 1 });
            }
            stored.push(Stored {
                landmark: obs.landmark,
                left_px: obs.left_px,
                right_u_px: right,
                outlier: false,
            });
        }
        self.keyframes.push_back(Keyframe {
            camera_from_world: camera_from_world_guess,
            observations: stored,
        });
        while self.keyframes.len() > self.params.max_keyframes + self.params.fixed_keyframes {
            if let Some(old) = self.keyframes.pop_front() {
                for obs in &old.observations {
                    if let Some(landmark) = self.landmarks.get_mut(&obs.landmark) {
                        landmark.seen_by -= 1;
                        if landmark.seen_by == 0 {
                            self.landmarks.remove(&obs.landmark);
                        }
                    }
                }
            }
        }
        let (landmarks_adjusted, new_outliers, initial_cost, final_cost) = self.refine();
        let newest = self
            .keyframes
            .back()
            .map_or(camera_from_world_guess, |k| k.camera_from_world);
        let mut outlier = Vec::with_capacity(observations.len());
        let mut point_camera = Vec::with_capacity(observations.len());
        // A landmark with an outlier observation anywhere in the window is not trusted any more (a moving
        // object, or a track that slid): the tracker should let it go.
        let outliers: std::collections::HashSet<u64> = self
            .keyframes
            .iter()
            .flat_map(|k| {
                k.observations
                    .iter()
                    .filter(|o| o.outlier)
                    .map(|o| o.landmark)
            })
            .collect();
        for obs in observations {
            let bad = outliers.contains(&obs.landmark);
            outlier.push(bad);
            match self.landmarks.get(&obs.landmark) {
                Some(landmark) if !bad => {
                    let x = newest * Point3::from(landmark.world);
                    point_camera.push([x.x, x.y, x.z]);
                }
                _ => point_camera.push([f64::NAN; 3]),
            }
        }
        Ok(KeyframeOutcome {
            camera_from_world: newest,
            reset,
            shared_landmarks: if reset { 0 } else { shared },
            keyframes: self.keyframes.len(),
            landmarks_adjusted,
            new_outliers,
            outlier,
            point_camera,
            initial_cost,
            final_cost,
        })
    }

    /// Two rounds of adjustment with outlier removal between them; (landmarks adjusted, new outliers,
    /// initial cost, final cost).
    fn refine(&mut self) -> (usize, usize, f64, f64) {
        if self.keyframes.len() < 2 {
            return (0, 0, 0.0, 0.0);
        }
        let settings = BundleSettings {
            pixel_sigma_px: self.params.pixel_sigma_px,
            right_sigma_px: self.params.right_sigma_px,
            huber_sigma: self.params.huber_sigma,
            max_iterations: self.params.iterations,
        };
        // Landmarks seen (as inliers) by at least two keyframes take part; the others move with their
        // only keyframe afterwards.
        let mut count: HashMap<u64, usize> = HashMap::new();
        for keyframe in &self.keyframes {
            for obs in keyframe.observations.iter().filter(|o| !o.outlier) {
                *count.entry(obs.landmark).or_default() += 1;
            }
        }
        // In id order: the sums of the normal equations, and so the result, must not depend on a hash
        // map's iteration order (the same frames give the same trajectory).
        let mut ids: Vec<u64> = count
            .iter()
            .filter(|(_, &n)| n >= 2)
            .map(|(&id, _)| id)
            .collect();
        ids.retain(|id| self.landmarks.contains_key(id));
        ids.sort_unstable();
        let index: HashMap<u64, usize> = ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
        let points: Vec<Vector3<f64>> = ids
            .iter()
            .filter_map(|id| self.landmarks.get(id))
            .map(|l| l.world)
            .collect();
        let single_before: Vec<(u64, usize, Vector3<f64>)> =
            self.single_landmarks_in_camera(&index);
        let mut points = points;
        let mut poses = self.poses();
        // (keyframe, position in its list) of each bundle observation, to flag outliers.
        let mut origin = Vec::new();
        let mut observations = Vec::new();
        for (k, keyframe) in self.keyframes.iter().enumerate() {
            for (i, obs) in keyframe.observations.iter().enumerate() {
                if let (false, Some(&point)) = (obs.outlier, index.get(&obs.landmark)) {
                    observations.push(BundleObservation {
                        pose: k,
                        point,
                        left_px: obs.left_px,
                        right_u_px: obs.right_u_px,
                    });
                    origin.push((k, i));
                }
            }
        }
        // The oldest keyframe, and those kept beyond `max_keyframes`, stay fixed.
        let fixed = (self.keyframes.len() + 1)
            .saturating_sub(self.params.max_keyframes)
            .max(1);
        let first = bundle::adjust(
            &self.camera,
            &mut poses,
            fixed,
            &mut points,
            &observations,
            &settings,
        );
        let chi2 = bundle::chi2(&self.camera, &poses, &points, &observations, &settings);
        let mut kept = Vec::with_capacity(observations.len());
        let mut new_outliers = 0;
        for ((obs, &(k, i)), &c) in observations.iter().zip(&origin).zip(&chi2) {
            let bound = if obs.right_u_px.is_some() {
                self.params.outlier_chi2_stereo
            } else {
                self.params.outlier_chi2_mono
            };
            if c > bound {
                self.keyframes[k].observations[i].outlier = true;
                new_outliers += 1;
            } else {
                kept.push(*obs);
            }
        }
        let mut final_cost = first.final_cost;
        if new_outliers > 0 {
            final_cost = bundle::adjust(
                &self.camera,
                &mut poses,
                fixed,
                &mut points,
                &kept,
                &settings,
            )
            .final_cost;
        }
        for (keyframe, pose) in self.keyframes.iter_mut().zip(&poses) {
            keyframe.camera_from_world = *pose;
        }
        for (id, point) in ids.iter().zip(&points) {
            if let Some(landmark) = self.landmarks.get_mut(id) {
                landmark.world = *point;
            }
        }
        for (id, k, x) in single_before {
            if let Some(landmark) = self.landmarks.get_mut(&id) {
                landmark.world =
                    (self.keyframes[k].camera_from_world.inverse() * Point3::from(x)).coords;
            }
        }
        (ids.len(), new_outliers, first.initial_cost, final_cost)
    }

    /// (id, keyframe, point in that keyframe's camera) of the landmarks not adjusted: each is placed by the
    /// one keyframe that created it, whose pose the adjustment is about to move.
    fn single_landmarks_in_camera(
        &self,
        adjusted: &HashMap<u64, usize>,
    ) -> Vec<(u64, usize, Vector3<f64>)> {
        let mut out = Vec::new();
        let mut done = std::collections::HashSet::new();
        for (k, keyframe) in self.keyframes.iter().enumerate() {
            for obs in &keyframe.observations {
                if adjusted.contains_key(&obs.landmark) || !done.insert(obs.landmark) {
                    continue;
                }
                if let Some(landmark) = self.landmarks.get(&obs.landmark) {
                    let x = keyframe.camera_from_world * Point3::from(landmark.world);
                    out.push((obs.landmark, k, x.coords));
                }
            }
        }
        out
    }
}
