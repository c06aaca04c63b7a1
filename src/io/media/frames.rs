//! Frames of a camera: a folder of image files (PNG, JPEG, TIFF, sorted by file name) or one video
//! file (MP4, MOV, AVI, MKV); the cameras of an image layout (`DIR/<camera>/`) and the check that
//! synchronized cameras have as many frames each; frame selections (`START:STOP:STEP`).
//!
//! Videos are decoded by the `ffmpeg` command-line tool, run as a child process whose raw frames
//! (`-f rawvideo -pix_fmt gray|rgb24`) are read from its standard output one at a time: a video is
//! never held whole in memory and no temporary file is written. The tool and not a crate:
//! `ffmpeg-next` needs the libav* development libraries at build time and tracks their versions,
//! while the tool decodes every codec FFmpeg knows and is one `apt-get install ffmpeg`. The frame
//! count comes from `ffprobe -count_packets` (the container is read, nothing decoded); a frame
//! that does not decode stops the decoding with an error naming the video and how many frames
//! were read (a frame left out would shift every later one against the other cameras'), and so
//! does a video that decodes to fewer frames than it has packets. FFmpeg 5.1 or newer is needed
//! (`-fps_mode passthrough`: every decoded frame once, none duplicated or dropped to a constant
//! rate; the older `-vsync` is gone from FFmpeg 9).

use std::ffi::OsString;
use std::io::Read;
use std::iter::StepBy;
use std::marker::PhantomData;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::str::FromStr;
use std::thread::JoinHandle;

use image::{DynamicImage, GrayImage, ImageBuffer, Luma, Pixel, Rgb, RgbImage};

use super::image::read_image;
use crate::io::IoError;

/// File name extensions (any case) read as images.
pub const IMAGE_EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "tif", "tiff"];
/// File name extensions (any case) read as videos.
pub const VIDEO_EXTENSIONS: [&str; 4] = ["mp4", "mov", "avi", "mkv"];
/// How to install the tools that decode videos, for error messages.
pub const INSTALL_FFMPEG: &str = "install FFmpeg 5.1 or newer (Debian/Ubuntu: `apt-get install ffmpeg`; macOS: `brew install ffmpeg`) so that `ffmpeg` and `ffprobe` are on PATH";

/// Bytes of ffmpeg's standard error kept for an error message (its end: the cause comes last).
const STDERR_TAIL_BYTES: usize = 4096;
/// Lines of ffmpeg's standard error quoted in an error message.
const STDERR_TAIL_LINES: usize = 8;

/// The frames of one camera: the image files of a folder in file-name order, or one video file.
///
/// Opening reads the folder and every image's header, or asks `ffprobe` for a video's size and
/// frame count; frames are decoded only when [`FrameSource::frames`] or [`FrameSource::frame`]
/// asks for them.
#[derive(Debug, Clone)]
pub struct FrameSource {
    folder: PathBuf,
    kind: SourceKind,
    width: u32,
    height: u32,
}

#[derive(Debug, Clone)]
enum SourceKind {
    /// The image files, sorted by file name.
    Images(Vec<PathBuf>),
    /// One video file and its frame count.
    Video { path: PathBuf, frames: usize },
}

/// The kind of a file in a camera's folder, by its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FileKind {
    Image,
    Video,
}

fn file_kind(path: &Path) -> Option<FileKind> {
    let extension = path.extension()?.to_str()?.to_ascii_lowercase();
    if IMAGE_EXTENSIONS.contains(&extension.as_str()) {
        Some(FileKind::Image)
    } else if VIDEO_EXTENSIONS.contains(&extension.as_str()) {
        Some(FileKind::Video)
    } else {
        None
    }
}

/// Whether a folder entry is hidden (`.name`): macOS leaves `._IMG_0001.png` resource files beside
/// the images, which are no images.
fn is_hidden(path: &Path) -> bool {
    path.file_name()
        .is_some_and(|name| name.as_encoded_bytes().starts_with(b"."))
}

fn invalid(path: &Path, reason: String) -> IoError {
    IoError::Invalid {
        path: path.to_path_buf(),
        field: String::new(),
        reason,
    }
}

/// The entries of a folder (hidden ones left out), sorted by file name.
fn sorted_entries(folder: &Path) -> Result<Vec<PathBuf>, IoError> {
    let read = |source| IoError::Read {
        path: folder.to_path_buf(),
        source,
    };
    let mut entries = Vec::new();
    for entry in std::fs::read_dir(folder).map_err(read)? {
        let path = entry.map_err(read)?.path();
        if !is_hidden(&path) {
            entries.push(path);
        }
    }
    entries.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(entries)
}

impl FrameSource {
    /// Opens the frames in `folder`: its image files (PNG, JPEG, TIFF by extension, any case),
    /// sorted by file name, or its one video file (MP4, MOV, AVI, MKV). Other files, hidden files
    /// (`.name`) and sub-folders are left out.
    ///
    /// Errors naming the path: a folder that cannot be read or holds no frames, images and a video
    /// together, two or more videos, an image that does not decode or whose size differs from the
    /// first image's, a video that `ffprobe` cannot read or that has no video stream or no frames
    /// ([`IoError::Invalid`], with the end of ffprobe's messages), and `ffprobe` not installed
    /// ([`IoError::MissingProgram`]).
    pub fn open(folder: &Path) -> Result<Self, IoError> {
        if !folder.is_dir() {
            return Err(invalid(
                folder,
                "not a folder (a camera's frames are a folder of images or of one video file)"
                    .into(),
            ));
        }
        let mut images = Vec::new();
        let mut videos = Vec::new();
        for path in sorted_entries(folder)? {
            match file_kind(&path) {
                Some(FileKind::Image) if path.is_file() => images.push(path),
                Some(FileKind::Video) if path.is_file() => videos.push(path),
                _ => {}
            }
        }
        let names = |paths: &[PathBuf]| {
            paths
                .iter()
                .map(|p| format!("'{}'", file_name(p)))
                .collect::<Vec<_>>()
                .join(", ")
        };
        match (images.is_empty(), videos.len()) {
            (true, 0) => Err(invalid(
                folder,
                format!(
                    "no frames: the folder holds no image ({}) and no video ({})",
                    upper(&IMAGE_EXTENSIONS),
                    upper(&VIDEO_EXTENSIONS)
                ),
            )),
            (false, n) if n > 0 => Err(invalid(
                folder,
                format!(
                    "holds {} image(s) and the video(s) {}: a camera's folder holds images or one video, not both",
                    images.len(),
                    names(&videos)
                ),
            )),
            (true, n) if n > 1 => Err(invalid(
                folder,
                format!(
                    "holds {n} videos ({}): a camera's folder holds one video (or images)",
                    names(&videos)
                ),
            )),
            (true, _) => Self::open_video(folder, videos.remove(0)),
            (false, _) => Self::open_images(folder, images),
        }
    }

    fn open_images(folder: &Path, files: Vec<PathBuf>) -> Result<Self, IoError> {
        let (width, height) = super::image::image_size(&files[0])?;
        for file in &files[1..] {
            let size = super::image::image_size(file)?;
            if size != (width, height) {
                return Err(invalid(
                    file,
                    format!(
                        "is {}x{} but {} is {width}x{height}: a camera's images have one size",
                        size.0,
                        size.1,
                        file_name(&files[0])
                    ),
                ));
            }
        }
        Ok(Self {
            folder: folder.to_path_buf(),
            kind: SourceKind::Images(files),
            width,
            height,
        })
    }

    fn open_video(folder: &Path, path: PathBuf) -> Result<Self, IoError> {
        let probe = probe_video(&path)?;
        Ok(Self {
            folder: folder.to_path_buf(),
            kind: SourceKind::Video {
                path,
                frames: probe.frames,
            },
            width: probe.width,
            height: probe.height,
        })
    }

    /// The folder the frames were found in.
    pub fn folder(&self) -> &Path {
        &self.folder
    }

    /// The video file, when the frames are a video's.
    pub fn video(&self) -> Option<&Path> {
        match &self.kind {
            SourceKind::Video { path, .. } => Some(path),
            SourceKind::Images(_) => None,
        }
    }

    /// The image files in frame order, when the frames are images.
    pub fn images(&self) -> Option<&[PathBuf]> {
        match &self.kind {
            SourceKind::Images(files) => Some(files),
            SourceKind::Video { .. } => None,
        }
    }

    /// The number of frames.
    pub fn len(&self) -> usize {
        match &self.kind {
            SourceKind::Images(files) => files.len(),
            SourceKind::Video { frames, .. } => *frames,
        }
    }

    /// Whether there are no frames (never, for an opened source).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The frames' size in pixels, (width, height) (a video's as coded: a rotation in its
    /// metadata is not applied, so the frames are the sensor's).
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The frames in words: `34 PNG images, 1280x1024` or `video clip.mp4, 300 frames, 1280x1024`.
    pub fn describe(&self) -> String {
        let (w, h) = (self.width, self.height);
        match &self.kind {
            SourceKind::Images(files) => {
                let mut formats: Vec<String> = files
                    .iter()
                    .map(|f| image_format_name(f).to_string())
                    .collect();
                formats.sort();
                formats.dedup();
                let formats = formats.join("/");
                let plural = if files.len() == 1 { "" } else { "s" };
                format!("{} {formats} image{plural}, {w}x{h}", files.len())
            }
            SourceKind::Video { path, frames } => {
                format!("video {}, {frames} frames, {w}x{h}", file_name(path))
            }
        }
    }

    /// Frame `index` in words, for messages: the image's file name, or `clip.mp4 frame 17`.
    pub fn frame_name(&self, index: usize) -> String {
        match &self.kind {
            SourceKind::Images(files) => files
                .get(index)
                .map_or_else(|| format!("frame {index}"), |f| file_name(f)),
            SourceKind::Video { path, .. } => format!("{} frame {index}", file_name(path)),
        }
    }

    /// The frames of `selection` in 8-bit grey, in order, each with its index; decoded one at a
    /// time as the iterator is advanced (a video sequentially from its start, the frames not
    /// selected decoded and dropped). Colour becomes luma (images: Rec. 709 weights, the `image`
    /// crate's; videos: the video's own luma, ffmpeg's conversion); 16-bit values are scaled to 8.
    ///
    /// Errors: a selection that starts beyond the last frame or selects none
    /// ([`IoError::Invalid`] naming the folder or video: `--frames 40: the video has 30 frames`).
    /// The iterator yields an error naming the file for an image that does not decode, a video
    /// that ends early or that ffmpeg fails on (with the end of ffmpeg's messages), and
    /// [`IoError::MissingProgram`] when `ffmpeg` is not installed; after an error it ends.
    pub fn frames(&self, selection: &FrameSelection) -> Result<Frames<'_, Luma<u8>>, IoError> {
        Frames::new(self, selection)
    }

    /// The frames of `selection` as 8-bit RGB (grey repeated for grey images); as
    /// [`FrameSource::frames`] otherwise.
    pub fn frames_rgb(&self, selection: &FrameSelection) -> Result<Frames<'_, Rgb<u8>>, IoError> {
        Frames::new(self, selection)
    }

    /// Frame `index` in 8-bit grey (a video is decoded from its start up to it).
    ///
    /// Errors as [`FrameSource::frames`].
    pub fn frame(&self, index: usize) -> Result<GrayImage, IoError> {
        self.frames(&FrameSelection::single(index))?
            .next()
            .map(|frame| frame.map(|(_, image)| image))
            .unwrap_or_else(|| Err(invalid(&self.folder, format!("no frame {index}"))))
    }

    /// Frame `index` as 8-bit RGB; as [`FrameSource::frame`].
    pub fn frame_rgb(&self, index: usize) -> Result<RgbImage, IoError> {
        self.frames_rgb(&FrameSelection::single(index))?
            .next()
            .map(|frame| frame.map(|(_, image)| image))
            .unwrap_or_else(|| Err(invalid(&self.folder, format!("no frame {index}"))))
    }

    /// The path that errors about the frames as a whole name: the video, else the folder.
    fn path(&self) -> &Path {
        self.video().unwrap_or(&self.folder)
    }
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn upper(extensions: &[&str]) -> String {
    extensions
        .iter()
        .map(|e| e.to_ascii_uppercase())
        .collect::<Vec<_>>()
        .join(", ")
}

/// `PNG`, `JPEG` or `TIFF` by the file's extension.
fn image_format_name(path: &Path) -> &'static str {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => "PNG",
        Some("jpg" | "jpeg") => "JPEG",
        _ => "TIFF",
    }
}

/// The cameras of an image layout: every sub-folder of `dir` (hidden ones left out), sorted by
/// name, as (camera name = folder name, its frames).
///
/// Errors: `dir` not a folder or without sub-folders (naming it), a folder name that is not
/// UTF-8, and every error of [`FrameSource::open`] for each camera.
pub fn open_cameras(dir: &Path) -> Result<Vec<(String, FrameSource)>, IoError> {
    if !dir.is_dir() {
        return Err(invalid(
            dir,
            "not a folder (it should hold one sub-folder of frames per camera)".into(),
        ));
    }
    let entries = sorted_entries(dir)?;
    let mut cameras = Vec::new();
    for path in entries.iter().filter(|p| p.is_dir()) {
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .ok_or_else(|| {
                invalid(
                    path,
                    "the folder's name is not UTF-8 text; it names a camera".into(),
                )
            })?
            .to_string();
        cameras.push((name, FrameSource::open(path)?));
    }
    if cameras.is_empty() {
        let loose = entries.iter().filter(|p| file_kind(p).is_some()).count();
        return Err(invalid(
            dir,
            if loose > 0 {
                format!(
                    "holds {loose} image or video file(s) but no camera folder: put each camera's frames in a sub-folder named after the camera ({}/<camera>/)",
                    dir.display()
                )
            } else {
                "no camera folder: it should hold one sub-folder of frames per camera".into()
            },
        ));
    }
    Ok(cameras)
}

/// The frame count of synchronized cameras (the n-th frame of every camera is the same instant):
/// every camera of `cameras` (read from `dir`, which errors name) must have as many frames.
///
/// Errors: counts that differ ([`IoError::Invalid`] naming every camera and its count).
pub fn check_synchronized(dir: &Path, cameras: &[(String, FrameSource)]) -> Result<usize, IoError> {
    let Some((_, first)) = cameras.first() else {
        return Err(invalid(dir, "no camera".into()));
    };
    let count = first.len();
    if cameras.iter().any(|(_, source)| source.len() != count) {
        let counts = cameras
            .iter()
            .map(|(name, source)| format!("{name} {}", source.len()))
            .collect::<Vec<_>>()
            .join(", ");
        return Err(invalid(
            dir,
            format!(
                "the cameras' frame counts differ ({counts}): these cameras are synchronized (the n-th frame of each is the same instant), so each needs the same number of frames"
            ),
        ));
    }
    Ok(count)
}

/// Synchronized grey frames of a rig's cameras ([`read_camera_frames`]).
#[derive(Debug, Clone)]
pub struct CameraFrames {
    /// One entry per selected frame: one image per camera, in the order the names were given,
    /// grey 0 … 1.
    pub frames: Vec<Vec<crate::base::GreyImage>>,
    /// The selected frames' indices.
    pub indices: Vec<usize>,
    /// The footage's frame count (every camera's).
    pub count: usize,
    /// The selection used (the one given, or the default spread).
    pub selection: FrameSelection,
    /// Sub-folders of the layout that name no camera (not read).
    pub unused: Vec<String>,
}

/// The frames of the cameras `names` (in that order) from `dir`, a folder per camera named as
/// the camera (images sorted by name, or one video), as `flatport stereo` and `calibrate
/// --targetless` read them: the frames `selection` picks, or without one at most
/// `default_frames` spread evenly over the footage (every ⌈count / default_frames⌉-th).
///
/// Errors: [`open_cameras`]' and [`check_synchronized`]'s, a camera without a folder (naming it
/// and the folders found), a selection outside the footage, a frame that does not decode.
pub fn read_camera_frames(
    dir: &Path,
    names: &[&str],
    selection: Option<FrameSelection>,
    default_frames: usize,
) -> Result<CameraFrames, IoError> {
    let mut found = open_cameras(dir)?;
    let mut ordered = Vec::with_capacity(names.len());
    for name in names {
        let Some(i) = found.iter().position(|(n, _)| n == name) else {
            return Err(invalid(
                dir,
                format!(
                    "no folder for camera '{name}' (one folder per rig camera, named as in the rig; found: {})",
                    found
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        };
        ordered.push(found.swap_remove(i));
    }
    let count = check_synchronized(dir, &ordered)?;
    let selection = selection.unwrap_or(FrameSelection {
        start: 0,
        stop: None,
        step: count.div_ceil(default_frames.max(1)).max(1),
    });
    let indices: Vec<usize> = selection
        .indices(count)
        .map_err(|e| invalid(dir, e.to_string()))?
        .collect();
    let mut frames: Vec<Vec<crate::base::GreyImage>> =
        vec![Vec::with_capacity(ordered.len()); indices.len()];
    for (_, source) in &ordered {
        for (slot, item) in frames.iter_mut().zip(source.frames(&selection)?) {
            let (_, image) = item?;
            slot.push(crate::base::GreyImage {
                width: image.width(),
                height: image.height(),
                pixels: image.pixels().map(|p| f32::from(p.0[0]) / 255.0).collect(),
            });
        }
    }
    let mut unused: Vec<String> = found.into_iter().map(|(n, _)| n).collect();
    unused.sort();
    Ok(CameraFrames {
        frames,
        indices,
        count,
        selection,
        unused,
    })
}

/// Which frames to read, as Python slices them: `START:STOP:STEP`, frames START, START + STEP, …
/// below STOP. Each part may be left empty (START 0, STOP the end, STEP 1); a single number `N`
/// is frame N alone. The default is every frame.
///
/// ```
/// use flatport::io::frames::FrameSelection;
/// let s: FrameSelection = "10::5".parse()?;
/// assert_eq!(s.indices(27)?.collect::<Vec<_>>(), [10, 15, 20, 25]);
/// assert!("::0".parse::<FrameSelection>().is_err());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameSelection {
    /// The first frame (0-based).
    pub start: usize,
    /// The frame before which the selection stops; `None`: the last frame is the last.
    pub stop: Option<usize>,
    /// The distance between selected frames, ≥ 1.
    pub step: usize,
}

impl Default for FrameSelection {
    fn default() -> Self {
        Self::ALL
    }
}

/// A frame selection that cannot be parsed or selects nothing.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameSelectionError {
    /// Text that is not `START:STOP:STEP`.
    #[error("--frames {text}: {reason} (START:STOP:STEP, each part optional: 0:300:10, ::5, 40:)")]
    Syntax {
        /// The text as given.
        text: String,
        /// What is wrong.
        reason: String,
    },
    /// A selection whose start is beyond the last frame.
    #[error("--frames {selection}: there are {count} frames (0 to {})", count.saturating_sub(1))]
    BeyondEnd {
        /// The selection.
        selection: FrameSelection,
        /// The number of frames.
        count: usize,
    },
    /// A selection that stops at or before its start.
    #[error("--frames {selection}: selects no frame (STOP must exceed START)")]
    Empty {
        /// The selection.
        selection: FrameSelection,
    },
}

impl FrameSelection {
    /// Every frame.
    pub const ALL: Self = Self {
        start: 0,
        stop: None,
        step: 1,
    };

    /// Frame `index` alone.
    pub fn single(index: usize) -> Self {
        Self {
            start: index,
            stop: Some(index.saturating_add(1)),
            step: 1,
        }
    }

    /// The selected indices among `count` frames (a STOP beyond the end stops at the end).
    ///
    /// Errors: START at or beyond `count` ([`FrameSelectionError::BeyondEnd`]), STOP at or
    /// before START ([`FrameSelectionError::Empty`]).
    pub fn indices(&self, count: usize) -> Result<StepBy<Range<usize>>, FrameSelectionError> {
        let stop = self.stop.map_or(count, |s| s.min(count));
        if self.stop.is_some_and(|s| s <= self.start) {
            return Err(FrameSelectionError::Empty { selection: *self });
        }
        if self.start >= count {
            return Err(FrameSelectionError::BeyondEnd {
                selection: *self,
                count,
            });
        }
        Ok((self.start..stop).step_by(self.step.max(1)))
    }
}

impl FromStr for FrameSelection {
    type Err = FrameSelectionError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let syntax = |reason: String| FrameSelectionError::Syntax {
            text: text.to_string(),
            reason,
        };
        let number = |part: &str, what: &str| -> Result<Option<usize>, FrameSelectionError> {
            let part = part.trim();
            if part.is_empty() {
                return Ok(None);
            }
            part.parse::<usize>().map(Some).map_err(|_| {
                syntax(format!(
                    "{what} '{part}' is not a frame number (0, 1, 2, …)"
                ))
            })
        };
        let parts: Vec<&str> = text.split(':').collect();
        match parts.as_slice() {
            [single] => match number(single, "the frame")? {
                Some(index) => Ok(Self::single(index)),
                None => Ok(Self::ALL),
            },
            [start, stop] | [start, stop, ""] => Ok(Self {
                start: number(start, "START")?.unwrap_or(0),
                stop: number(stop, "STOP")?,
                step: 1,
            }),
            [start, stop, step] => {
                let step = number(step, "STEP")?.unwrap_or(1);
                if step == 0 {
                    return Err(syntax("STEP must be at least 1".into()));
                }
                Ok(Self {
                    start: number(start, "START")?.unwrap_or(0),
                    stop: number(stop, "STOP")?,
                    step,
                })
            }
            _ => Err(syntax(format!("{} parts", parts.len()))),
        }
    }
}

/// `START:STOP:STEP` with the defaults left out (`:` for every frame, `N` for frame N alone).
impl std::fmt::Display for FrameSelection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.step == 1 && self.stop == Some(self.start.saturating_add(1)) {
            return write!(f, "{}", self.start);
        }
        if self.start > 0 {
            write!(f, "{}", self.start)?;
        }
        write!(f, ":")?;
        if let Some(stop) = self.stop {
            write!(f, "{stop}")?;
        }
        if self.step != 1 {
            write!(f, ":{}", self.step)?;
        }
        Ok(())
    }
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for image::Luma<u8> {}
    impl Sealed for image::Rgb<u8> {}
}

/// The pixel types frames are read as: `Luma<u8>` (8-bit grey) and `Rgb<u8>` (8-bit RGB).
pub trait FramePixel: Pixel<Subpixel = u8> + sealed::Sealed + 'static {
    /// ffmpeg's name of the raw pixel format (`gray`, `rgb24`).
    const FFMPEG_PIXEL_FORMAT: &'static str;
    /// A decoded image in this pixel type.
    fn convert(image: DynamicImage) -> ImageBuffer<Self, Vec<u8>>;
}

impl FramePixel for Luma<u8> {
    const FFMPEG_PIXEL_FORMAT: &'static str = "gray";
    fn convert(image: DynamicImage) -> GrayImage {
        image.to_luma8()
    }
}

impl FramePixel for Rgb<u8> {
    const FFMPEG_PIXEL_FORMAT: &'static str = "rgb24";
    fn convert(image: DynamicImage) -> RgbImage {
        image.to_rgb8()
    }
}

/// The frames of a [`FrameSelection`], decoded one at a time ([`FrameSource::frames`]): each item
/// is (frame index, image). A video's ffmpeg process runs from the first item until the last
/// selected frame is read or the iterator is dropped.
pub struct Frames<'a, P: FramePixel> {
    source: &'a FrameSource,
    wanted: StepBy<Range<usize>>,
    video: Option<VideoDecoder>,
    failed: bool,
    pixel: PhantomData<P>,
}

impl<'a, P: FramePixel> Frames<'a, P> {
    fn new(source: &'a FrameSource, selection: &FrameSelection) -> Result<Self, IoError> {
        let count = source.len();
        let wanted = selection.indices(count).map_err(|e| {
            let what = match &source.kind {
                SourceKind::Video { .. } => format!("the video has {count} frames"),
                SourceKind::Images(_) => format!("the folder has {count} images"),
            };
            match e {
                FrameSelectionError::BeyondEnd { selection, .. } => {
                    invalid(source.path(), format!("--frames {selection}: {what}"))
                }
                e => invalid(source.path(), e.to_string()),
            }
        })?;
        Ok(Self {
            source,
            wanted,
            video: None,
            failed: false,
            pixel: PhantomData,
        })
    }

    fn read(&mut self, index: usize) -> Result<ImageBuffer<P, Vec<u8>>, IoError> {
        let (width, height) = self.source.size();
        match &self.source.kind {
            SourceKind::Images(files) => {
                let file = &files[index];
                let image = read_image(file)?;
                if (image.width(), image.height()) != (width, height) {
                    return Err(invalid(
                        file,
                        format!(
                            "decodes to {}x{} but its header and the first image say {width}x{height}",
                            image.width(),
                            image.height()
                        ),
                    ));
                }
                Ok(P::convert(image))
            }
            SourceKind::Video { path, frames } => {
                if self.video.is_none() {
                    let frame_bytes =
                        width as usize * height as usize * usize::from(P::CHANNEL_COUNT);
                    self.video = Some(VideoDecoder::start(
                        path,
                        P::FFMPEG_PIXEL_FORMAT,
                        frame_bytes,
                        *frames,
                    )?);
                }
                let decoder = self.video.as_mut().expect("started above");
                let pixels = decoder.read_frame(index)?;
                ImageBuffer::from_raw(width, height, pixels)
                    .ok_or_else(|| invalid(path, "a frame of the wrong size".into()))
            }
        }
    }
}

impl<P: FramePixel> Iterator for Frames<'_, P> {
    type Item = Result<(usize, ImageBuffer<P, Vec<u8>>), IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let index = self.wanted.next()?;
        let result = self.read(index);
        if result.is_err() {
            self.failed = true;
        }
        if result.is_err() || self.wanted.len() == 0 {
            // Nothing more to read: stop ffmpeg now rather than when the iterator is dropped.
            self.video = None;
        }
        Some(result.map(|image| (index, image)))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        if self.failed {
            (0, Some(0))
        } else {
            (0, Some(self.wanted.len()))
        }
    }
}

/// A video's size and frame count, from `ffprobe`.
struct Probe {
    width: u32,
    height: u32,
    frames: usize,
}

/// `file:PATH`: the path as ffmpeg's file protocol, so that no file name reads as an option or
/// another protocol (`-x.mp4`, `a:b.mp4`).
fn ffmpeg_input(path: &Path) -> OsString {
    let mut input = OsString::from("file:");
    input.push(path.as_os_str());
    input
}

fn missing(path: &Path, program: &str, source: std::io::Error) -> IoError {
    IoError::MissingProgram {
        path: path.to_path_buf(),
        program: program.into(),
        install: INSTALL_FFMPEG.into(),
        source,
    }
}

/// The last lines of a program's standard error, on one line (` | ` between lines).
fn stderr_tail(stderr: &[u8]) -> String {
    let text = String::from_utf8_lossy(stderr);
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    let tail = &lines[lines.len().saturating_sub(STDERR_TAIL_LINES)..];
    if tail.is_empty() {
        "no message".into()
    } else {
        tail.join(" | ")
    }
}

/// Asks `ffprobe` for the first video stream's size and packet count (one packet per frame; the
/// container is read, nothing decoded).
fn probe_video(path: &Path) -> Result<Probe, IoError> {
    let output = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_packets"])
        .args(["-show_entries", "stream=width,height,nb_read_packets"])
        .args(["-of", "default=noprint_wrappers=1"])
        .arg(ffmpeg_input(path))
        .stdin(Stdio::null())
        .output()
        .map_err(|e| missing(path, "ffprobe", e))?;
    if !output.status.success() {
        return Err(invalid(
            path,
            format!(
                "cannot read the video (ffprobe: {}): {}",
                output.status,
                stderr_tail(&output.stderr)
            ),
        ));
    }
    let text = String::from_utf8_lossy(&output.stdout);
    let value = |key: &str| {
        text.lines()
            .find_map(|line| line.trim().strip_prefix(key)?.strip_prefix('='))
            .and_then(|v| v.trim().parse::<u64>().ok())
    };
    let (Some(width), Some(height)) = (value("width"), value("height")) else {
        return Err(invalid(
            path,
            format!(
                "no video stream (ffprobe found none with a size){}",
                if output.stderr.is_empty() {
                    String::new()
                } else {
                    format!(": {}", stderr_tail(&output.stderr))
                }
            ),
        ));
    };
    let frames = value("nb_read_packets").unwrap_or(0);
    let (Ok(width), Ok(height), Ok(frames)) = (
        u32::try_from(width),
        u32::try_from(height),
        usize::try_from(frames),
    ) else {
        return Err(invalid(path, "a video size beyond 32 bits".into()));
    };
    if width == 0 || height == 0 {
        return Err(invalid(path, format!("a video of {width}x{height} pixels")));
    }
    if frames == 0 {
        return Err(invalid(path, "the video has no frames".into()));
    }
    Ok(Probe {
        width,
        height,
        frames,
    })
}

/// An `ffmpeg` process writing a video's frames, raw, to its standard output; its standard error
/// drained by a thread that keeps the end (ffmpeg would stop once a full pipe blocks it).
struct VideoDecoder {
    path: PathBuf,
    child: Child,
    stdout: ChildStdout,
    stderr: Option<JoinHandle<Vec<u8>>>,
    frame_bytes: usize,
    /// The index of the next frame ffmpeg writes.
    next: usize,
    /// The frame count ffprobe gave.
    expected: usize,
}

impl VideoDecoder {
    fn start(
        path: &Path,
        pixel_format: &str,
        frame_bytes: usize,
        expected: usize,
    ) -> Result<Self, IoError> {
        let mut child = Command::new("ffmpeg")
            // -xerror: a frame that does not decode stops ffmpeg (and is an error here) rather
            // than being left out, which would shift every later frame against the other cameras'.
            .args(["-nostdin", "-hide_banner", "-v", "error", "-xerror"])
            .args(["-noautorotate", "-i"])
            .arg(ffmpeg_input(path))
            .args([
                "-map",
                "0:v:0",
                "-fps_mode",
                "passthrough",
                "-f",
                "rawvideo",
            ])
            .args(["-pix_fmt", pixel_format, "pipe:1"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| missing(path, "ffmpeg", e))?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let mut stderr = child.stderr.take().expect("stderr is piped");
        let stderr = std::thread::spawn(move || {
            let mut tail = Vec::new();
            let mut chunk = [0u8; 4096];
            while let Ok(n) = stderr.read(&mut chunk) {
                if n == 0 {
                    break;
                }
                tail.extend_from_slice(&chunk[..n]);
                if tail.len() > 2 * STDERR_TAIL_BYTES {
                    tail.drain(..tail.len() - STDERR_TAIL_BYTES);
                }
            }
            tail
        });
        Ok(Self {
            path: path.to_path_buf(),
            child,
            stdout,
            stderr: Some(stderr),
            frame_bytes,
            next: 0,
            expected,
        })
    }

    /// Frame `index` (≥ the next one): the frames before it are read and dropped.
    fn read_frame(&mut self, index: usize) -> Result<Vec<u8>, IoError> {
        let mut pixels = vec![0u8; self.frame_bytes];
        while self.next <= index {
            let read =
                read_full(&mut self.stdout, &mut pixels).map_err(|source| IoError::Read {
                    path: self.path.clone(),
                    source,
                })?;
            if read < self.frame_bytes {
                return Err(self.ended_early(read));
            }
            self.next += 1;
        }
        Ok(pixels)
    }

    /// The error of a stream that ended before frame `self.next` was whole.
    fn ended_early(&mut self, partial_bytes: usize) -> IoError {
        let status = self.child.wait();
        let stderr = self
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        let mut tail = stderr_tail(&stderr);
        if tail.contains("fps_mode") {
            tail.push_str(&format!(" ({INSTALL_FFMPEG})"));
        }
        let status = match status {
            Ok(s) if s.success() => "ffmpeg ended".to_string(),
            Ok(s) => format!("ffmpeg failed ({s})"),
            Err(e) => format!("ffmpeg failed ({e})"),
        };
        let partial = if partial_bytes > 0 {
            format!(" and {partial_bytes} bytes of the next")
        } else {
            String::new()
        };
        invalid(
            &self.path,
            format!(
                "cannot decode the video: {status} after {} of its {} frames{partial}: {tail}",
                self.next, self.expected
            ),
        )
    }
}

impl Drop for VideoDecoder {
    fn drop(&mut self) {
        // Stop ffmpeg (this child alone, by its handle) and reap it; errors here change nothing.
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        if let Some(thread) = self.stderr.take() {
            let _ = thread.join();
        }
    }
}

/// Reads until `buf` is full or the stream ends; the number of bytes read.
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}
