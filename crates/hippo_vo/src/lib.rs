//! Windowed refinement of stereo visual odometry.
//!
//! A frame-to-frame tracker (the Python `hippo_nav.vo`) gives each keyframe an initial pose and the stereo
//! pixels of the points it tracks, each with a landmark id that stays the same while the point is tracked.
//! [`SlidingWindow`] keeps the last keyframes and the landmarks they share and refines them jointly after
//! every keyframe: a stereo bundle adjustment (left pixel and right-image column of every observation,
//! Huber loss, observations beyond a χ² bound dropped as outliers, the oldest keyframe fixed), solved by
//! Levenberg–Marquardt on the normal equations with the landmarks eliminated by the Schur complement.
//!
//! [`tracks`] refines the tracker's KLT matches with a warped window (a slanted road biases a square one).
//! [`disparity`] fits one frame's stereo disparity offset to its motion (the self-calibration's measurement).
//!
//! Conventions: camera x right, y down, z forward (the left camera of a rectified pair); a pose is
//! `camera_from_world`; pixels of the input resolution; the right camera sits `baseline_m` along +x.
#![warn(missing_docs)]
pub mod bundle;
pub mod camera;
pub mod disparity;
pub mod error;
pub mod tracks;
pub mod window;

pub use camera::StereoCamera;
pub use disparity::{frame_offset, OffsetEstimate, OffsetTracks};
pub use error::{Result, VoError};
pub use tracks::{refine_matches, GrayImage, RefineParams, Sampling, WarpModel};
pub use window::{KeyframeOutcome, Observation, SlidingWindow, WindowParams};
