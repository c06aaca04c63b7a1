//! Images and exact depth maps of a [`TexturedScene`] as a camera sees it through its port.
//!
//! Every sub-sample of every pixel is back-projected exactly through the port by the [`Engine`]
//! (lens distortion included), its water ray meets the nearest surface
//! ([`TexturedScene::trace`]), and the pixel is the mean grey level of its n × n sub-samples
//! (a box filter over the pixel: supersampled anti-aliasing, also across depth edges and the
//! silhouettes of spheres). The depth of a pixel is z, in that camera's frame, of the point its
//! centre's ray hits: z = (R_k·(X − C_k))_z, NaN where that ray hits nothing or has no answer.
//! Blur and noise as for the chessboard ([`RenderOptions`]).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::scene::TexturedScene;
use super::{GreyImage, RenderError, RenderOptions, check_options, finish_image};
use crate::engine::Engine;
use crate::model::RefractiveCamera;

/// Sub-samples per band of the back-projection (bounds memory whatever the image).
const BAND_SAMPLES: usize = 1 << 18;

/// A rendered view: the image and the exact depth of each pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedView {
    /// Grey levels 0 … 1 (after blur and noise).
    pub image: GreyImage,
    /// z of each pixel centre's hit point in the camera's frame, metres, row-major; NaN where
    /// the ray hits nothing.
    pub depth: Vec<f32>,
}

/// Offsets of the n × n sub-samples in a pixel, and the index of the pixel centre among the
/// samples (the middle sub-sample for odd n; an extra sample appended for even n).
fn sample_offsets(n: u32) -> (Vec<[f64; 2]>, usize) {
    let n = n.max(1) as usize;
    let offset = |i: usize| (i as f64 + 0.5) / n as f64 - 0.5;
    let mut offsets: Vec<[f64; 2]> = (0..n)
        .flat_map(|j| (0..n).map(move |i| [offset(i), offset(j)]))
        .collect();
    let centre = if n % 2 == 1 {
        (n / 2) * n + n / 2
    } else {
        offsets.push([0.0, 0.0]);
        n * n
    };
    (offsets, centre)
}

/// Renders `camera`'s image and depth map of `scene` in frame `frame` (the options' supersample
/// counts sub-samples per axis of every pixel; blur, noise and seed as for the chessboard;
/// `border_squares` and `shades` do not apply: the scene's background is the water's grey).
///
/// Errors: [`RenderError::Option`] for options out of range or a frame the scene does not have;
/// [`RenderError::Engine`] when the engine fails.
pub fn render_textured(
    engine: &Engine,
    camera: &RefractiveCamera,
    scene: &TexturedScene,
    frame: usize,
    options: &RenderOptions,
) -> Result<RenderedView, RenderError> {
    check_options(options)?;
    if frame >= scene.frames.len() {
        return Err(RenderError::Option {
            option: "frame",
            reason: format!(
                "frame {frame} asked for, the scene has {}",
                scene.frames.len()
            ),
        });
    }
    let intrinsics = camera.intrinsics();
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    let (offsets, centre) = sample_offsets(options.supersample);
    let per_pixel = offsets.len();
    // The n² sub-samples are averaged; for even n the appended centre only gives the depth.
    let averaged = (options.supersample.max(1) as usize).pow(2);
    let rows_per_band = (BAND_SAMPLES / (w * per_pixel).max(1)).max(1);
    let z_row = camera.cam_from_master().row(2).transpose();
    let camera_centre = *camera.centre();
    let mut pixels = vec![0f32; w * h];
    let mut depth = vec![f32::NAN; w * h];
    let mut samples = Vec::new();
    let mut rays = Vec::new();
    let mut status = Vec::new();
    let mut first = 0;
    while first < h {
        let rows = rows_per_band.min(h - first);
        samples.clear();
        for v in first..first + rows {
            for u in 0..w {
                samples.extend(offsets.iter().map(|o| [u as f64 + o[0], v as f64 + o[1]]));
            }
        }
        rays.resize(samples.len(), [0.0; 6]);
        status.resize(samples.len(), 0);
        engine.backproject(camera, &samples, &mut rays, &mut status)?;
        let band_pixels = &mut pixels[first * w..(first + rows) * w];
        let band_depth = &mut depth[first * w..(first + rows) * w];
        band_pixels
            .par_chunks_mut(w)
            .zip(band_depth.par_chunks_mut(w))
            .enumerate()
            .for_each(|(row, (out, out_depth))| {
                for u in 0..w {
                    let base = (row * w + u) * per_pixel;
                    let mut sum = 0.0;
                    for s in 0..per_pixel {
                        let (r, ok) = (rays[base + s], status[base + s] == 0);
                        let hit = if ok {
                            scene.trace(
                                &Point3::new(r[0], r[1], r[2]),
                                &Vector3::new(r[3], r[4], r[5]),
                                frame,
                            )
                        } else {
                            None
                        };
                        if s < averaged {
                            sum += hit.map_or(scene.background, |h| h.grey);
                        }
                        if s == centre
                            && let Some(hit) = hit
                        {
                            out_depth[u] = z_row.dot(&(hit.point - camera_centre)) as f32;
                        }
                    }
                    out[u] = (sum / averaged as f64) as f32;
                }
            });
        first += rows;
    }
    let image = GreyImage {
        width: w as u32,
        height: h as u32,
        pixels,
    };
    Ok(RenderedView {
        image: finish_image(image, options)?,
        depth,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sub_samples_cover_the_pixel_and_name_its_centre() {
        let (o, c) = sample_offsets(3);
        assert_eq!(o.len(), 9);
        assert_eq!(o[c], [0.0, 0.0]);
        let (o, c) = sample_offsets(2);
        assert_eq!(o.len(), 5);
        assert_eq!(o[c], [0.0, 0.0]);
        assert_eq!(o[0], [-0.25, -0.25]);
        let (o, c) = sample_offsets(1);
        assert_eq!((o, c), (vec![[0.0, 0.0]], 0));
    }
}
