//! The nadir camera pose of a GPS pose prior (positions come from [`crate::geo::Projector`]; the pose from
//! [`crate::data::pose_build::nadir_pose`]).

pub use crate::data::pose_build::nadir_pose;
