//! Synchronized frame sequences for stereo: one folder per rig camera holding its images or one
//! video file, frame n of every camera taken at the same instant.
//!
//! The frames are read by [`crate::io::frames`] (the reader of `calibrate --images`: images sorted
//! by file name, videos streamed through the `ffmpeg` tool), checked against the rig (a folder per
//! camera, named as in the rig; as many frames everywhere; images whose file names two cameras
//! share at the same place in both; the rig's image size), and handed out one frame at a time as
//! grey levels and colours ([`ColourImage`]), in the form `flatport stereo` reads single images.
//!
//! ```no_run
//! use flatport::io::frames::FrameSelection;
//! use flatport::runs::sequence::Sequence;
//! # let rig: flatport::model::Rig = unimplemented!();
//! let sequence = Sequence::open(&rig, std::path::Path::new("footage"))?;
//! let wanted = sequence.select(&"0:100:10".parse()?)?;
//! for frame in sequence.reader(&wanted) {
//!     let frame = frame?;
//!     println!("{}: {} images", sequence.frame_name(0, frame.index), frame.images.len());
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use image::{DynamicImage, GrayImage, Rgb, RgbImage};
use thiserror::Error;

use crate::io::IoError;
use crate::io::frames::{
    FrameSelection, FrameSelectionError, FrameSource, Frames, check_synchronized,
};
use crate::io::stereo_files::{ColourImage, read_colour_image};
use crate::model::Rig;

/// Why a sequence cannot be read.
#[derive(Debug, Error)]
pub enum SequenceError {
    /// A rig camera without its folder.
    #[error(
        "{}: missing: the folder of camera '{camera}' (--images needs one sub-folder per rig camera, named as in the rig, holding its images or one video)",
        folder.display()
    )]
    MissingCamera {
        /// The folder looked for.
        folder: PathBuf,
        /// The rig camera.
        camera: String,
    },
    /// Cameras with different frame counts (the error names every camera and its count).
    #[error("frames do not match: {0}")]
    Count(IoError),
    /// Two cameras' image files that share a name at different places in their folders.
    #[error(
        "frames do not match: {} is frame {index} of camera '{camera}' but {} is frame {other_index} of camera '{other_camera}' (an image missing in one camera?)",
        file.display(),
        other_file.display()
    )]
    Names {
        /// The file of `camera`.
        file: PathBuf,
        /// Its place in `camera`'s folder.
        index: usize,
        /// The camera.
        camera: String,
        /// The file of the same name in `other_camera`'s folder.
        other_file: PathBuf,
        /// Its place there.
        other_index: usize,
        /// The camera compared with.
        other_camera: String,
    },
    /// Frames whose size is not the rig camera's.
    #[error(
        "{}: the frames are {width} × {height} pixels, camera '{camera}' of the rig is {expected_width} × {expected_height}",
        path.display()
    )]
    Size {
        /// The video, or the camera's first image.
        path: PathBuf,
        /// The camera.
        camera: String,
        /// The frames' width.
        width: u32,
        /// The frames' height.
        height: u32,
        /// The rig's width.
        expected_width: u32,
        /// The rig's height.
        expected_height: u32,
    },
    /// A frame selection outside the frames, a file that does not decode, a video that ffmpeg
    /// cannot decode or that is not installed (the error names the file).
    #[error(transparent)]
    Io(#[from] IoError),
}

/// The frames of every rig camera, checked to be synchronized ([`Sequence::open`]).
#[derive(Debug, Clone)]
pub struct Sequence {
    dir: PathBuf,
    /// Rig order: (camera name, its frames).
    cameras: Vec<(String, FrameSource)>,
    count: usize,
}

/// One frame of every camera (rig order).
#[derive(Debug, Clone)]
pub struct SequenceFrame {
    /// The frame's index in the sequence (0-based).
    pub index: usize,
    /// Each camera's image: grey levels 0 … 1 and 8-bit colours.
    pub images: Vec<ColourImage>,
}

impl Sequence {
    /// Opens `dir/<camera>/` for every camera of `rig` (other folders are left alone): its images
    /// (PNG, JPEG, TIFF, sorted by file name) or its one video (MP4, MOV, AVI, MKV). Reads the
    /// image headers and asks `ffprobe` for each video's size and frame count; decodes nothing.
    ///
    /// Errors: [`SequenceError::MissingCamera`]; every error of [`FrameSource::open`] (no frames,
    /// images and a video together, an image header that does not read, a video that `ffprobe`
    /// cannot read, `ffprobe` not installed); [`SequenceError::Count`] when the cameras' frame
    /// counts differ; [`SequenceError::Names`] when two image folders hold a file of the same
    /// name at different places; [`SequenceError::Size`] for frames not of the rig's size.
    pub fn open(rig: &Rig, dir: &Path) -> Result<Self, SequenceError> {
        if !dir.is_dir() {
            return Err(IoError::Invalid {
                path: dir.to_path_buf(),
                field: String::new(),
                reason: "not a folder (--images takes a folder with one sub-folder per rig camera)"
                    .into(),
            }
            .into());
        }
        let mut cameras = Vec::with_capacity(rig.cameras().len());
        for camera in rig.cameras() {
            let folder = dir.join(&camera.name);
            if !folder.is_dir() {
                return Err(SequenceError::MissingCamera {
                    folder,
                    camera: camera.name.clone(),
                });
            }
            let source = FrameSource::open(&folder)?;
            cameras.push((camera.name.clone(), source));
        }
        let count = check_synchronized(dir, &cameras).map_err(SequenceError::Count)?;
        check_names(&cameras)?;
        for (camera, (name, source)) in rig.cameras().iter().zip(&cameras) {
            let expected = (camera.intrinsics.width, camera.intrinsics.height);
            let (width, height) = source.size();
            if (width, height) != expected {
                let path = source
                    .video()
                    .map(Path::to_path_buf)
                    .or_else(|| source.images().map(|files| files[0].clone()))
                    .unwrap_or_else(|| source.folder().to_path_buf());
                return Err(SequenceError::Size {
                    path,
                    camera: name.clone(),
                    width,
                    height,
                    expected_width: expected.0,
                    expected_height: expected.1,
                });
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            cameras,
            count,
        })
    }

    /// The folder holding the cameras' folders.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Each camera's name and frames, rig order.
    pub fn cameras(&self) -> &[(String, FrameSource)] {
        &self.cameras
    }

    /// The number of frames (every camera's).
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether there are no frames (never, for an opened sequence).
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Whether any camera's frames are a video.
    pub fn has_video(&self) -> bool {
        self.cameras.iter().any(|(_, s)| s.video().is_some())
    }

    /// The name of frame `index` as camera `camera` (rig index) holds it: its image's file name
    /// without extension, or `frame_NNNNNN` (the index, six digits) for a video.
    pub fn frame_name(&self, camera: usize, index: usize) -> String {
        let file = self
            .cameras
            .get(camera)
            .and_then(|(_, s)| s.images()?.get(index));
        match file.and_then(|f| f.file_stem()) {
            Some(stem) => stem.to_string_lossy().into_owned(),
            None => format!("frame_{index:06}"),
        }
    }

    /// The indices of `selection` among the frames, in order.
    ///
    /// Errors: a selection that starts beyond the last frame or selects none
    /// ([`IoError::Invalid`] naming the first camera's video or folder and its frame count).
    pub fn select(&self, selection: &FrameSelection) -> Result<Vec<usize>, SequenceError> {
        let (name, source) = &self.cameras[0];
        let what = match source.video() {
            Some(video) => (video.to_path_buf(), "the video of camera"),
            None => (source.folder().to_path_buf(), "the folder of camera"),
        };
        let count = self.count;
        let indices = selection.indices(count).map_err(|e| IoError::Invalid {
            path: what.0,
            field: String::new(),
            reason: match e {
                FrameSelectionError::BeyondEnd { .. } => format!(
                    "--frames '{selection}' starts beyond the last frame: {} '{name}' has {count} frames (0 to {})",
                    what.1,
                    count - 1
                ),
                e => e.to_string(),
            },
        })?;
        Ok(indices.collect())
    }

    /// Decodes every image file of the frames `wanted` (videos are decoded as they are read):
    /// for a caller that refuses a broken image before it writes anything.
    ///
    /// Errors: the first image that does not decode or whose size differs from its header's
    /// ([`IoError::Invalid`] naming it).
    pub fn check_images(&self, wanted: &[usize]) -> Result<(), SequenceError> {
        for (_, source) in &self.cameras {
            if let Some(files) = source.images() {
                let size = source.size();
                for &index in wanted {
                    let file = &files[index];
                    let image = read_colour_image(file)?;
                    if (image.grey.width, image.grey.height) != size {
                        return Err(IoError::Invalid {
                            path: file.clone(),
                            field: String::new(),
                            reason: format!(
                                "decodes to {} × {} but its header says {} × {}",
                                image.grey.width, image.grey.height, size.0, size.1
                            ),
                        }
                        .into());
                    }
                }
            }
        }
        Ok(())
    }

    /// The frames `wanted` (increasing indices), one at a time: image files are read when their
    /// frame is asked for, videos are decoded sequentially from the first wanted frame (the
    /// frames between wanted ones are decoded and dropped).
    pub fn reader(&self, wanted: &[usize]) -> SequenceReader<'_> {
        SequenceReader {
            sequence: self,
            wanted: wanted.to_vec(),
            next: 0,
            last: wanted.iter().copied().max(),
            videos: self.cameras.iter().map(|_| None).collect(),
            failed: false,
        }
    }
}

/// The frames of [`Sequence::reader`]; after an error it ends.
pub struct SequenceReader<'a> {
    sequence: &'a Sequence,
    wanted: Vec<usize>,
    /// The place in `wanted` of the next frame.
    next: usize,
    last: Option<usize>,
    /// Each video camera's decoder, started at its first frame.
    videos: Vec<Option<Frames<'a, Rgb<u8>>>>,
    failed: bool,
}

impl SequenceReader<'_> {
    fn read(&mut self, index: usize) -> Result<SequenceFrame, SequenceError> {
        let mut images = Vec::with_capacity(self.sequence.cameras.len());
        for (k, (_, source)) in self.sequence.cameras.iter().enumerate() {
            if let Some(files) = source.images() {
                images.push(read_colour_image(&files[index])?);
                continue;
            }
            if self.videos[k].is_none() {
                let selection = FrameSelection {
                    start: index,
                    stop: self.last.map(|l| l + 1),
                    step: 1,
                };
                self.videos[k] = Some(source.frames_rgb(&selection)?);
            }
            let frames = self.videos[k].as_mut().expect("started above");
            let image = loop {
                match frames.next() {
                    Some(Ok((i, image))) if i == index => break image,
                    Some(Ok(_)) => {}
                    Some(Err(e)) => return Err(e.into()),
                    None => {
                        return Err(IoError::Invalid {
                            path: source.video().unwrap_or(source.folder()).to_path_buf(),
                            field: String::new(),
                            reason: format!("frame {index} was asked for out of order"),
                        }
                        .into());
                    }
                }
            };
            images.push(colour_from_rgb(image));
        }
        Ok(SequenceFrame { index, images })
    }
}

impl Iterator for SequenceReader<'_> {
    type Item = Result<SequenceFrame, SequenceError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let index = *self.wanted.get(self.next)?;
        self.next += 1;
        let frame = self.read(index);
        if frame.is_err() {
            self.failed = true;
        }
        if frame.is_err() || self.next == self.wanted.len() {
            // Stop the decoders now rather than when the reader is dropped.
            self.videos.iter_mut().for_each(|v| *v = None);
        }
        Some(frame)
    }
}

/// A decoded video frame as [`read_colour_image`] reads an image file of the same pixels: a frame
/// whose every pixel is grey (r = g = b: a grey video, which ffmpeg hands out as RGB) is read as
/// an 8-bit grey image, so its grey levels are those of the grey PNG it was encoded from, bit for
/// bit; a colour frame's grey levels are its luma (Rec. 709 weights, as for colour image files).
pub fn colour_from_rgb(rgb: RgbImage) -> ColourImage {
    let colours: Vec<[u8; 3]> = rgb.pixels().map(|p| p.0).collect();
    let grey = colours.iter().all(|[r, g, b]| r == g && g == b);
    let (width, height) = rgb.dimensions();
    let image = if grey {
        let levels: Vec<u8> = colours.iter().map(|c| c[0]).collect();
        DynamicImage::ImageLuma8(
            GrayImage::from_raw(width, height, levels).expect("one level per pixel"),
        )
    } else {
        DynamicImage::ImageRgb8(rgb)
    };
    let luma = image.to_luma32f();
    ColourImage {
        grey: crate::base::GreyImage {
            width,
            height,
            pixels: luma.into_raw(),
        },
        rgb: colours,
    }
}

/// Image folders must agree on file names: a name two cameras share sits at the same place in
/// both (a missing image in one camera shifts every later frame).
fn check_names(cameras: &[(String, FrameSource)]) -> Result<(), SequenceError> {
    let folders: Vec<(&String, &[PathBuf])> = cameras
        .iter()
        .filter_map(|(name, source)| Some((name, source.images()?)))
        .collect();
    let Some(((first, first_files), rest)) = folders.split_first() else {
        return Ok(());
    };
    let positions: HashMap<_, usize> = first_files
        .iter()
        .enumerate()
        .map(|(i, p)| (p.file_stem().map(|s| s.to_os_string()), i))
        .collect();
    for (name, files) in rest {
        for (i, file) in files.iter().enumerate() {
            if let Some(&j) = positions.get(&file.file_stem().map(|s| s.to_os_string()))
                && j != i
            {
                return Err(SequenceError::Names {
                    file: file.clone(),
                    index: i,
                    camera: (*name).clone(),
                    other_file: first_files[j].clone(),
                    other_index: j,
                    other_camera: (*first).clone(),
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grey_frame_decoded_as_rgb_reads_as_its_grey_image_file() {
        // Every grey level, through both routes: a grey PNG as read_colour_image reads it, and
        // the same pixels as a video's RGB frame.
        let levels: Vec<u8> = (0..=255).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grey.png");
        GrayImage::from_raw(16, 16, levels.clone())
            .unwrap()
            .save(&path)
            .unwrap();
        let from_file = read_colour_image(&path).unwrap();
        let rgb: Vec<u8> = levels.iter().flat_map(|&l| [l, l, l]).collect();
        let from_video = colour_from_rgb(RgbImage::from_raw(16, 16, rgb).unwrap());
        assert_eq!(from_file, from_video);
        for (k, &p) in from_video.grey.pixels.iter().enumerate() {
            assert_eq!(p, k as f32 / 255.0, "level {k}");
        }
    }

    #[test]
    fn a_colour_frame_reads_as_its_colour_image_file() {
        let rgb: Vec<u8> = (0..16 * 16 * 3).map(|i| (i * 37 % 256) as u8).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("colour.png");
        RgbImage::from_raw(16, 16, rgb.clone())
            .unwrap()
            .save(&path)
            .unwrap();
        let from_file = read_colour_image(&path).unwrap();
        let from_video = colour_from_rgb(RgbImage::from_raw(16, 16, rgb).unwrap());
        assert_eq!(from_file, from_video);
    }
}
