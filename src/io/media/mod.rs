//! Pixels and arrays: image files, a camera's frames (images or one video), `.npy` arrays, and
//! dense stereo's images, depth maps and point clouds.

#[cfg(feature = "images")]
pub mod frames;
#[cfg(feature = "images")]
pub mod image;
pub mod npy;
#[cfg(feature = "images")]
pub mod stereo_files;
