//! The frame reader (`flatport::io::frames`): folders of images and videos read back against the
//! pixels written into them (images by the `image` crate's encoders, videos by the ffmpeg tool
//! from raw frames, in lossless codecs: equal; H.264 in 4:2:0: within its range conversion),
//! selections, the cameras of a layout, and every refused folder named in its error. Without
//! ffmpeg on PATH the video tests print a message and return.

#![cfg(feature = "images")]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use flatport::io::IoError;
use flatport::io::frames::{FrameSelection, FrameSource, check_synchronized, open_cameras};
use image::{GrayImage, RgbImage};

const W: u32 = 40;
const H: u32 = 30;

/// Frame `k` of a synthetic sequence: a gradient moving with `k`, and a pseudo-random texture, so
/// that every frame and every pixel differs (the whole 0…255 range is used).
fn grey_frame(k: u32) -> GrayImage {
    GrayImage::from_fn(W, H, |x, y| {
        let hash = (x * 7919 + y * 104_729 + k * 1_299_709).wrapping_mul(2_654_435_761) >> 24;
        image::Luma([((x * 5 + y * 3 + k * 11 + hash) % 256) as u8])
    })
}

fn rgb_frame(k: u32) -> RgbImage {
    RgbImage::from_fn(W, H, |x, y| {
        let g = grey_frame(k).get_pixel(x, y).0[0];
        image::Rgb([g, g.wrapping_mul(3), 255 - g])
    })
}

fn folder(parent: &Path, name: &str) -> PathBuf {
    let dir = parent.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn message(result: Result<impl std::fmt::Debug, IoError>) -> String {
    result.expect_err("an error").to_string()
}

#[test]
fn an_image_folder_is_read_in_file_name_order() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = folder(tmp.path(), "left");
    // Written out of order, in mixed cases and formats; other files and hidden files are left out.
    let names = ["a_000.PNG", "a_001.png", "a_002.tif", "a_003.png"];
    for k in [2, 0, 3, 1] {
        grey_frame(k as u32).save(dir.join(names[k])).unwrap();
    }
    std::fs::write(dir.join("notes.txt"), "not a frame").unwrap();
    std::fs::write(dir.join("._a_000.png"), "a macOS resource file").unwrap();
    folder(&dir, "sub");
    let source = FrameSource::open(&dir).unwrap();
    assert_eq!(source.len(), 4);
    assert_eq!(source.size(), (W, H));
    assert_eq!(source.describe(), "4 PNG/TIFF images, 40x30");
    assert!(source.video().is_none());
    assert_eq!(source.frame_name(2), "a_002.tif");
    let read: Vec<(usize, GrayImage)> = source
        .frames(&FrameSelection::ALL)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(read.len(), 4);
    for (k, (index, image)) in read.iter().enumerate() {
        assert_eq!(*index, k);
        assert!(*image == grey_frame(k as u32), "frame {k}");
    }
    let picked: Vec<usize> = source
        .frames(&"1::2".parse().unwrap())
        .unwrap()
        .map(|f| f.unwrap().0)
        .collect();
    assert_eq!(picked, [1, 3]);
    assert!(source.frame(3).unwrap() == grey_frame(3));
    let m = message(source.frames(&"40".parse().unwrap()).map(|_| ()));
    assert!(
        m.ends_with("left: --frames 40: the folder has 4 images"),
        "{m}"
    );
}

#[test]
fn colour_images_read_as_rgb_and_as_luma() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = folder(tmp.path(), "cam");
    for k in 0..2 {
        rgb_frame(k).save(dir.join(format!("{k}.png"))).unwrap();
    }
    let source = FrameSource::open(&dir).unwrap();
    assert!(source.frame_rgb(1).unwrap() == rgb_frame(1));
    // Rec. 709 luma (the image crate's weights), within a rounding step.
    let grey = source.frame(1).unwrap();
    for (g, c) in grey.pixels().zip(rgb_frame(1).pixels()) {
        let [r, gr, b] = c.0.map(f64::from);
        let luma = 0.2126 * r + 0.7152 * gr + 0.0722 * b;
        assert!(
            (f64::from(g.0[0]) - luma).abs() <= 1.0,
            "{} vs {luma}",
            g.0[0]
        );
    }
}

#[test]
fn refused_folders_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let empty = folder(tmp.path(), "empty");
    std::fs::write(empty.join("readme.md"), "no frames").unwrap();
    let m = message(FrameSource::open(&empty));
    assert!(m.contains("empty") && m.contains("no frames"), "{m}");

    let mixed = folder(tmp.path(), "mixed");
    grey_frame(0).save(mixed.join("0.png")).unwrap();
    std::fs::write(mixed.join("clip.MP4"), "x").unwrap();
    let m = message(FrameSource::open(&mixed));
    assert!(
        m.contains("mixed") && m.contains("'clip.MP4'") && m.contains("not both"),
        "{m}"
    );

    let two = folder(tmp.path(), "two");
    std::fs::write(two.join("a.mkv"), "x").unwrap();
    std::fs::write(two.join("b.avi"), "x").unwrap();
    let m = message(FrameSource::open(&two));
    assert!(
        m.contains("two") && m.contains("2 videos") && m.contains("'a.mkv', 'b.avi'"),
        "{m}"
    );

    let broken = folder(tmp.path(), "broken");
    grey_frame(0).save(broken.join("0.png")).unwrap();
    std::fs::write(broken.join("1.png"), "not a png at all").unwrap();
    let m = message(FrameSource::open(&broken));
    assert!(m.contains("1.png"), "{m}");

    let sizes = folder(tmp.path(), "sizes");
    grey_frame(0).save(sizes.join("0.png")).unwrap();
    GrayImage::new(W + 1, H).save(sizes.join("1.png")).unwrap();
    let m = message(FrameSource::open(&sizes));
    assert!(
        m.contains("1.png") && m.contains("41x30") && m.contains("40x30"),
        "{m}"
    );

    let m = message(FrameSource::open(&tmp.path().join("absent")));
    assert!(m.contains("absent") && m.contains("not a folder"), "{m}");
}

#[test]
fn cameras_are_the_sorted_sub_folders_and_synchronized_counts_are_checked() {
    let tmp = tempfile::tempdir().unwrap();
    let water = folder(tmp.path(), "water");
    for (camera, count) in [("top", 3), ("left", 3), ("right", 2)] {
        let dir = folder(&water, camera);
        for k in 0..count {
            grey_frame(k).save(dir.join(format!("{k:03}.png"))).unwrap();
        }
    }
    folder(&water, ".hidden");
    let cameras = open_cameras(&water).unwrap();
    let names: Vec<&str> = cameras.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["left", "right", "top"]);
    let m = message(check_synchronized(&water, &cameras));
    assert!(
        m.contains("water") && m.contains("left 3, right 2, top 3"),
        "{m}"
    );
    assert_eq!(check_synchronized(&water, &cameras[..1]).unwrap(), 3);

    let loose = folder(tmp.path(), "loose");
    grey_frame(0).save(loose.join("0.png")).unwrap();
    let m = message(open_cameras(&loose));
    assert!(
        m.contains("no camera folder") && m.contains("<camera>"),
        "{m}"
    );

    // A camera's refused folder is named through the layout.
    std::fs::write(water.join("right").join("clip.mkv"), "x").unwrap();
    let m = message(open_cameras(&water));
    assert!(m.contains("right") && m.contains("not both"), "{m}");
}

/// Whether the ffmpeg tool runs; else a message saying the video tests are skipped.
fn have_ffmpeg(test: &str) -> bool {
    let runs = |program: &str| {
        Command::new(program)
            .arg("-version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    let found = runs("ffmpeg") && runs("ffprobe");
    if !found {
        eprintln!("{test}: skipped: ffmpeg/ffprobe not on PATH (apt-get install ffmpeg)");
    }
    found
}

fn has_encoder(name: &str) -> bool {
    Command::new("ffmpeg")
        .args(["-hide_banner", "-encoders"])
        .output()
        .is_ok_and(|o| {
            String::from_utf8_lossy(&o.stdout)
                .split_whitespace()
                .any(|w| w == name)
        })
}

/// Encodes raw frames (`pixel_format`, W×H) into `path` with ffmpeg's `codec_args`.
fn encode(path: &Path, pixel_format: &str, frames: &[Vec<u8>], codec_args: &[&str]) {
    let mut child = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y", "-f", "rawvideo"])
        .args([
            "-pix_fmt",
            pixel_format,
            "-s",
            format!("{W}x{H}").as_str(),
            "-r",
            "10",
        ])
        .args(["-i", "pipe:0"])
        .args(codec_args)
        .arg(path)
        .stdin(Stdio::piped())
        .spawn()
        .expect("ffmpeg runs");
    let mut stdin = child.stdin.take().unwrap();
    for frame in frames {
        stdin.write_all(frame).unwrap();
    }
    drop(stdin);
    assert!(
        child.wait().unwrap().success(),
        "ffmpeg encoded {}",
        path.display()
    );
}

fn grey_frames(count: u32) -> Vec<GrayImage> {
    (0..count).map(grey_frame).collect()
}

#[test]
fn lossless_videos_read_back_every_pixel() {
    if !have_ffmpeg("lossless_videos_read_back_every_pixel") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let frames = grey_frames(7);
    let raw: Vec<Vec<u8>> = frames.iter().map(|f| f.as_raw().clone()).collect();
    for (file, codec) in [
        ("clip.mkv", ["-c:v", "ffv1"]),
        ("clip.MOV", ["-c:v", "png"]),
        ("clip.avi", ["-c:v", "ffv1"]),
    ] {
        let dir = folder(tmp.path(), file);
        let path = dir.join(file);
        encode(&path, "gray", &raw, &codec);
        let source = FrameSource::open(&dir).unwrap();
        assert_eq!(source.len(), 7, "{file}");
        assert_eq!(source.size(), (W, H));
        assert_eq!(source.video(), Some(path.as_path()));
        assert_eq!(source.describe(), format!("video {file}, 7 frames, 40x30"));
        for (k, frame) in source.frames(&FrameSelection::ALL).unwrap().enumerate() {
            let (index, image) = frame.unwrap();
            assert_eq!(index, k);
            assert!(image == frames[k], "{file} frame {k}");
        }
        // Frames skipped while decoding; a stop beyond the end stops at the end.
        let picked: Vec<(usize, GrayImage)> = source
            .frames(&"2:100:3".parse().unwrap())
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(picked.iter().map(|p| p.0).collect::<Vec<_>>(), [2, 5]);
        assert!(picked[0].1 == frames[2] && picked[1].1 == frames[5]);
        assert!(source.frame(6).unwrap() == frames[6]);
        // Grey to RGB repeats the grey level.
        let rgb = source.frame_rgb(4).unwrap();
        assert!(
            rgb.pixels()
                .zip(frames[4].pixels())
                .all(|(c, g)| c.0 == [g.0[0]; 3])
        );
        let m = message(source.frames(&"40".parse().unwrap()).map(|_| ()));
        assert!(
            m.ends_with(&format!("{file}: --frames 40: the video has 7 frames")),
            "{m}"
        );
    }

    // A colour video read as RGB: every pixel.
    let colour: Vec<RgbImage> = (0..3).map(rgb_frame).collect();
    let raw: Vec<Vec<u8>> = colour.iter().map(|f| f.as_raw().clone()).collect();
    let dir = folder(tmp.path(), "colour");
    encode(&dir.join("rgb.mkv"), "rgb24", &raw, &["-c:v", "ffv1"]);
    let source = FrameSource::open(&dir).unwrap();
    for (k, frame) in source.frames_rgb(&FrameSelection::ALL).unwrap().enumerate() {
        assert!(frame.unwrap().1 == colour[k], "rgb frame {k}");
    }
}

#[test]
fn an_h264_mp4_reads_back_within_its_range_conversion() {
    if !have_ffmpeg("an_h264_mp4_reads_back_within_its_range_conversion") {
        return;
    }
    if !has_encoder("libx264") {
        eprintln!("an_h264_mp4_reads_back_within_its_range_conversion: skipped: no libx264");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let frames = grey_frames(5);
    let raw: Vec<Vec<u8>> = frames.iter().map(|f| f.as_raw().clone()).collect();
    // Lossless H.264 of 4:0:0 grey, flagged full range (0…255; unflagged, a decoder takes the
    // video range 16…235 and stretches it): every pixel back.
    let dir = folder(tmp.path(), "grey");
    encode(
        &dir.join("clip.mp4"),
        "gray",
        &raw,
        &[
            "-c:v",
            "libx264",
            "-qp",
            "0",
            "-pix_fmt",
            "gray",
            "-color_range",
            "pc",
        ],
    );
    let source = FrameSource::open(&dir).unwrap();
    assert_eq!(source.len(), 5);
    for (k, frame) in source.frames(&FrameSelection::ALL).unwrap().enumerate() {
        assert!(frame.unwrap().1 == frames[k], "frame {k}");
    }
    // Lossless H.264 in 4:2:0, as cameras record: the grey levels 0…255 go to the video range
    // 16…235 and back, so each comes back within one level (219/255 of a level per step, rounded
    // twice); the chroma of a grey image is constant and takes no part.
    let dir = folder(tmp.path(), "yuv");
    encode(
        &dir.join("clip.mp4"),
        "gray",
        &raw,
        &["-c:v", "libx264", "-qp", "0", "-pix_fmt", "yuv420p"],
    );
    let source = FrameSource::open(&dir).unwrap();
    assert_eq!(source.len(), 5);
    for (k, frame) in source.frames(&FrameSelection::ALL).unwrap().enumerate() {
        let image = frame.unwrap().1;
        let worst = image
            .pixels()
            .zip(frames[k].pixels())
            .map(|(a, b)| a.0[0].abs_diff(b.0[0]))
            .max()
            .unwrap();
        assert!(worst <= 1, "frame {k}: {worst} levels");
    }
}

#[test]
fn a_broken_video_is_named_with_ffmpegs_words() {
    if !have_ffmpeg("a_broken_video_is_named_with_ffmpegs_words") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = folder(tmp.path(), "garbage");
    std::fs::write(
        dir.join("clip.mp4"),
        b"\0\0\0\x18ftypmp42 this is no video".repeat(40),
    )
    .unwrap();
    let m = message(FrameSource::open(&dir));
    assert!(
        m.contains("clip.mp4") && m.contains("cannot read the video"),
        "{m}"
    );

    // An MP4 cut short (its index at the end is lost).
    let raw: Vec<Vec<u8>> = grey_frames(4).iter().map(|f| f.as_raw().clone()).collect();
    let whole = tmp.path().join("whole.mp4");
    let codec: &[&str] = if has_encoder("libx264") {
        &["-c:v", "libx264", "-qp", "0"]
    } else {
        &["-c:v", "mpeg4"]
    };
    encode(&whole, "gray", &raw, codec);
    let bytes = std::fs::read(&whole).unwrap();
    let dir = folder(tmp.path(), "truncated");
    std::fs::write(dir.join("cut.mp4"), &bytes[..bytes.len() / 2]).unwrap();
    let m = message(FrameSource::open(&dir));
    assert!(
        m.contains("cut.mp4") && m.contains("cannot read the video"),
        "{m}"
    );
    assert!(m.contains("moov atom not found"), "ffmpeg's own words: {m}");
}

#[test]
fn a_frame_that_does_not_decode_stops_the_video_with_an_error() {
    if !have_ffmpeg("a_frame_that_does_not_decode_stops_the_video_with_an_error") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let frames = grey_frames(7);
    let raw: Vec<Vec<u8>> = frames.iter().map(|f| f.as_raw().clone()).collect();
    let dir = folder(tmp.path(), "cam");
    let path = dir.join("clip.mkv");
    // FFV1 with a CRC per slice, so that a damaged frame is found.
    encode(&path, "gray", &raw, &["-c:v", "ffv1", "-slicecrc", "1"]);
    // Frame 3's packet, where ffprobe says it lies (size,pos per line), overwritten in its middle.
    let packets = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "packet=size,pos",
        ])
        .args(["-of", "csv=p=0"])
        .arg(&path)
        .output()
        .unwrap();
    let line = String::from_utf8_lossy(&packets.stdout)
        .lines()
        .nth(3)
        .expect("a fourth packet")
        .to_string();
    let (size, pos) = line.split_once(',').unwrap();
    let (size, pos): (usize, usize) = (size.parse().unwrap(), pos.parse().unwrap());
    let mut bytes = std::fs::read(&path).unwrap();
    for (i, b) in bytes[pos + size / 4..pos + 3 * size / 4]
        .iter_mut()
        .enumerate()
    {
        *b = (i * 37 % 251) as u8;
    }
    std::fs::write(&path, bytes).unwrap();
    let source = FrameSource::open(&dir).unwrap();
    assert_eq!(source.len(), 7);
    // The frames before the damage are read, unshifted; then one error quoting the decoder,
    // and the end.
    let read: Vec<_> = source.frames(&FrameSelection::ALL).unwrap().collect();
    let (good, bad): (Vec<_>, Vec<_>) = read.into_iter().partition(|r| r.is_ok());
    assert_eq!(bad.len(), 1);
    assert!(
        good.len() <= 3,
        "{} frames before the damaged one",
        good.len()
    );
    for (k, frame) in good.into_iter().enumerate() {
        assert!(frame.unwrap().1 == frames[k], "frame {k}");
    }
    let m = bad.into_iter().next().unwrap().unwrap_err().to_string();
    assert!(
        m.contains("clip.mkv") && m.contains("of its 7 frames") && m.contains("[ffv1"),
        "{m}"
    );
}

/// Set in the child run of [`a_missing_ffmpeg_says_how_to_install_it`].
const CHILD: &str = "FLATPORT_FRAMES_TEST_WITHOUT_FFMPEG";

#[test]
fn a_missing_ffmpeg_says_how_to_install_it() {
    // This test binary again, alone and with a PATH where no ffmpeg is, running the test below.
    let output = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "opens_a_video_without_ffmpeg", "--nocapture"])
        .env(CHILD, "1")
        .env("PATH", "/nonexistent")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(text.contains("1 passed"), "{text}");
}

#[test]
fn opens_a_video_without_ffmpeg() {
    if std::env::var_os(CHILD).is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = folder(tmp.path(), "cam");
    std::fs::write(dir.join("clip.mov"), "x").unwrap();
    let error = FrameSource::open(&dir).unwrap_err();
    assert!(matches!(error, IoError::MissingProgram { .. }), "{error:?}");
    let m = error.to_string();
    assert!(
        m.contains("clip.mov") && m.contains("ffprobe") && m.contains("apt-get install ffmpeg"),
        "{m}"
    );
}

#[test]
fn selections_parse_as_python_slices() {
    use flatport::io::frames::FrameSelectionError;
    let parse = |t: &str| t.parse::<FrameSelection>();
    let all = |t: &str, count| {
        parse(t)
            .unwrap()
            .indices(count)
            .unwrap()
            .collect::<Vec<_>>()
    };
    assert_eq!(all("", 4), [0, 1, 2, 3]);
    assert_eq!(all(":", 4), [0, 1, 2, 3]);
    assert_eq!(all("::", 4), [0, 1, 2, 3]);
    assert_eq!(all("1:", 4), [1, 2, 3]);
    assert_eq!(all(":2", 4), [0, 1]);
    assert_eq!(all("::2", 5), [0, 2, 4]);
    assert_eq!(all("1:100:3", 8), [1, 4, 7]);
    assert_eq!(all(" 2 ", 8), [2]);
    assert_eq!(all("3", 4), [3]);
    for bad in ["::0", "a", "1:2:3:4", "-1:", "1.5", ":x:"] {
        assert!(
            matches!(parse(bad), Err(FrameSelectionError::Syntax { .. })),
            "{bad}"
        );
    }
    assert_eq!(
        parse("::0").unwrap_err().to_string(),
        "--frames ::0: STEP must be at least 1 (START:STOP:STEP, each part optional: 0:300:10, ::5, 40:)"
    );
    let beyond = parse("40").unwrap().indices(30).unwrap_err();
    assert_eq!(
        beyond.to_string(),
        "--frames 40: there are 30 frames (0 to 29)"
    );
    assert!(parse("30:").unwrap().indices(30).is_err());
    assert!(parse("29:").unwrap().indices(30).is_ok());
    assert!(matches!(
        parse("5:3").unwrap().indices(30),
        Err(FrameSelectionError::Empty { .. })
    ));
    assert!(parse("5:5").unwrap().indices(30).is_err());
}

#[test]
fn selections_print_as_they_parse() {
    for text in [":", "40:", ":7", "::3", "2:9:4", "40", "0"] {
        let selection: FrameSelection = text.parse().unwrap();
        assert_eq!(selection.to_string(), text);
        assert_eq!(
            selection.to_string().parse::<FrameSelection>(),
            Ok(selection)
        );
    }
    assert_eq!(FrameSelection::default(), FrameSelection::ALL);
}
