//! The GPU engine and toolkit: every kernel of every catalogue validated by naga (no GPU
//! needed), host/WGSL layouts in sync, and GPU-vs-CPU parity on random batches on lavapipe, f32 and f64, including the rows with no
//! answer. With `CI` set, a missing Vulkan adapter fails the run: GPU tests are never skipped
//! silently there.
//!
//! Tolerances (issue #3): f32 pixels within 1e-3 px and directions within 2e-6; f64 within 1e-9
//! relative (|Δ| ≤ 1e-9 · max(1, |cpu|)). Other f32 outputs get bounds derived from those.

mod common;
mod gpu_harness;

use common::*;
use flatport::calib::backends::gpu::kernels as calibration_kernels;
use flatport::engine::CpuEngine;
use flatport::engine::GpuEngine;
use flatport::engine::gpu::kernels;
use flatport::gpu::{CPU_BOUNDS, CpuBounds, KernelSource, Precision, Rows, source};
use flatport::model::{NoSolution, RefractiveCamera, Rig};
use gpu_harness::{Random, engine, engine_with};
use nalgebra::{Point2, Vector3};

// The build's validation, as build.rs compiles it (it names `super::CpuBounds`).
#[path = "../build/wgsl.rs"]
mod wgsl;

/// The capabilities a kernel composed at `precision` needs (as build.rs asks).
fn capabilities(precision: Precision) -> naga::valid::Capabilities {
    wgsl::capabilities(precision == Precision::F64)
}

/// build.rs composes with a copy of the CPU's stopping rules: the same as the engine's.
#[test]
fn the_build_validates_the_texts_the_engine_compiles() {
    assert_eq!(
        wgsl::CPU_BOUNDS_COPY,
        CPU_BOUNDS,
        "update CPU_BOUNDS_COPY in build/wgsl.rs"
    );
}

/// Every kernel of every catalogue: the relation kernels and the calibration kernels.
fn every_kernel() -> impl Iterator<Item = &'static KernelSource> {
    kernels::ALL.into_iter().chain(calibration_kernels::ALL)
}

/// The texts the pipeline cache compiles: every kernel of every catalogue in f32 and f64 with
/// both view-row bindings, through the build's validation with no more capabilities than each
/// kernel needs.
#[test]
fn every_shader_parses_and_validates() {
    for kernel in every_kernel() {
        for precision in [Precision::F32, Precision::F64] {
            for rows in Rows::ALL {
                let precision = kernel.precision(precision);
                let name = format!("{} {precision}", kernel.label(rows));
                wgsl::check(
                    &name,
                    &source(kernel, precision, rows),
                    capabilities(precision),
                )
                .unwrap_or_else(|e| panic!("{e}"));
            }
        }
    }
}

/// Every kernel's composed text is the same every time, holds each of its parts once, in order,
/// after the shared files, and the view-row binding exactly where the kernel reads view rows;
/// the names are unique across the catalogues (the pipeline cache's key).
#[test]
fn every_kernel_composes_deterministically_from_its_parts() {
    let mut names = std::collections::HashSet::new();
    for kernel in every_kernel() {
        assert!(names.insert(kernel.name), "{} twice", kernel.name);
        assert!(!kernel.parts.is_empty(), "{}", kernel.name);
        for precision in [Precision::F32, Precision::F64] {
            for rows in Rows::ALL {
                let text = source(kernel, precision, rows);
                assert_eq!(text, source(kernel, precision, rows), "{}", kernel.name);
                let mut from = text
                    .find("override RIG_LAYERS")
                    .expect("shaders/common.wgsl first");
                for part in kernel.parts {
                    let at = text[from..].find(part).unwrap_or_else(|| {
                        panic!("{}: a part missing or out of order", kernel.name)
                    });
                    from += at + part.len();
                }
                // The binding of view rows (the others declare `input: array<real>` themselves).
                let view_rows = text.contains("@group(0) @binding(1) var<uniform> input")
                    || text.contains("@binding(1) var<storage, read> input: array<vec4r>;");
                assert_eq!(
                    view_rows, kernel.reads_view_rows,
                    "{} {rows:?}",
                    kernel.name
                );
            }
        }
    }
    assert_eq!(names.len(), 23);
}

/// The build's validation fails a broken kernel with naga's message naming the kernel: syntax and
/// an undeclared name (front end), a type error and a capability the kernel was not granted (f64
/// arithmetic) (validator).
#[test]
fn broken_wgsl_is_an_error_naming_the_kernel() {
    let project = source(&kernels::PROJECT, Precision::F32, Rows::Storage);
    let cases = [
        (
            "project f32 (missing semicolon)",
            project.replace("return;", "return"),
            "parse error",
        ),
        (
            "project f32 (u32 + f32)",
            project.replace(
                "let i = 2u * item_index(gid, groups);",
                "let i = 2u * item_index(gid, groups) + 1.0;",
            ),
            "validation error",
        ),
        (
            "project f32 (undeclared)",
            format!("{project}\nfn broken() -> real {{ return no_such_value; }}\n"),
            "parse error",
        ),
        (
            "project f64 (without FLOAT64)",
            source(&kernels::PROJECT, Precision::F64, Rows::Storage),
            "validation error",
        ),
    ];
    for (name, text, kind) in cases {
        assert_ne!(text, project, "{name}: the case changes the kernel");
        let error = wgsl::check(name, &text, wgsl::capabilities(false))
            .err()
            .unwrap_or_else(|| panic!("{name} validated"));
        assert!(
            error.starts_with(&format!("{name}: WGSL {kind}")),
            "{name}: {error}"
        );
    }
    let fine = wgsl::check("project f32", &project, wgsl::capabilities(false));
    assert!(fine.is_ok(), "{:?}", fine.err());
}

/// The offset of `field` in naga's layout of struct `name`.
fn member_offset(module: &naga::Module, name: &str, field: &str) -> usize {
    let (_, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("struct {name}"));
    let naga::TypeInner::Struct { members, .. } = &ty.inner else {
        panic!("{name} is a struct")
    };
    members
        .iter()
        .find(|m| m.name.as_deref() == Some(field))
        .unwrap_or_else(|| panic!("{name}.{field}"))
        .offset as usize
}

/// The host mirrors have naga's sizes and field offsets (WGSL's layout rules) in both precisions.
#[test]
fn host_mirrors_have_the_wgsl_layout() {
    use flatport::gpu::layout::{CameraF32, CameraF64, ParamsF32, ParamsF64};
    use std::mem::{offset_of, size_of};
    macro_rules! offsets {
        ($ty:ty: $($field:ident),*) => { [$((stringify!($field), offset_of!($ty, $field))),*] };
    }
    for precision in [Precision::F32, Precision::F64] {
        let text = source(&kernels::PROJECT, precision, Rows::Storage);
        let module = wgsl::check("project", &text, capabilities(precision))
            .unwrap_or_else(|e| panic!("{e}"));
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).unwrap();
        let size = |name: &str| {
            let (handle, _) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("struct {name}"));
            layouter[handle].size as usize
        };
        let (camera_size, params_size, camera, params) = match precision {
            Precision::F32 => (
                size_of::<CameraF32>(),
                size_of::<ParamsF32>(),
                offsets!(CameraF32: intrinsics, distortion, extra, master_from_cam0, master_from_cam1, master_from_cam2, centre, normal, layers, counts),
                offsets!(ParamsF32: cams, info),
            ),
            Precision::F64 => (
                size_of::<CameraF64>(),
                size_of::<ParamsF64>(),
                offsets!(CameraF64: intrinsics, distortion, extra, master_from_cam0, master_from_cam1, master_from_cam2, centre, normal, layers, counts),
                offsets!(ParamsF64: cams, info),
            ),
        };
        assert_eq!(camera_size, size("Camera"), "{precision} Camera size");
        assert_eq!(params_size, size("Params"), "{precision} Params size");
        for (field, offset) in camera {
            assert_eq!(
                offset,
                member_offset(&module, "Camera", field),
                "{precision} Camera.{field}"
            );
        }
        for (field, offset) in params {
            assert_eq!(
                offset,
                member_offset(&module, "Params", field),
                "{precision} Params.{field}"
            );
        }
        // Every WGSL member is mirrored, in order (the mirrors add only `end_padding`).
        for name in ["Camera", "Params"] {
            let (_, ty) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap();
            let naga::TypeInner::Struct { members, .. } = &ty.inner else {
                unreachable!()
            };
            let wgsl: Vec<&str> = members.iter().filter_map(|m| m.name.as_deref()).collect();
            let host: Vec<&str> = if name == "Camera" {
                camera.iter().map(|(f, _)| *f).collect()
            } else {
                params.iter().map(|(f, _)| *f).collect()
            };
            assert_eq!(wgsl, host, "{precision} {name} members");
        }
        let (_, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some("Params"))
            .unwrap();
        let naga::TypeInner::Struct { members, .. } = &ty.inner else {
            unreachable!()
        };
        let naga::TypeInner::Array { stride, .. } = module.types[members[0].ty].inner else {
            panic!("Params.cams is an array")
        };
        assert_eq!(
            stride as usize, camera_size,
            "{precision} Params.cams stride"
        );
    }
}

/// Random raw pixels over the image and a margin around it (some beyond the lens fold).
fn random_pixels(random: &mut Random, n: usize) -> Vec<[f64; 2]> {
    (0..n)
        .map(|_| [random.range(-300.0, 1580.0), random.range(-300.0, 1324.0)])
        .collect()
}

/// Random points: mostly in the water in view of `camera`, some in the air or behind it.
fn random_points(random: &mut Random, camera: &RefractiveCamera, n: usize) -> Vec<[f64; 3]> {
    (0..n)
        .map(|k| {
            let pixel = Point2::new(random.range(0.0, 1280.0), random.range(0.0, 1024.0));
            match camera.backproject(&pixel) {
                Ok(ray) if k % 10 != 0 => ray.point_at(random.range(1e-3, 6.0)).coords.into(),
                _ => [
                    random.range(-2.0, 2.0),
                    random.range(-2.0, 2.0),
                    random.range(-0.5, 4.0),
                ],
            }
        })
        .collect()
}

/// Largest |gpu − cpu| and largest |gpu − cpu| / max(1, |cpu|) over columns `cols` of rows both
/// answered; panics on a status disagreement beyond `allowed` rows.
fn compare<const M: usize>(
    what: &str,
    cpu: (&[[f64; M]], &[u32]),
    gpu: (&[[f64; M]], &[u32]),
    cols: std::ops::Range<usize>,
    allowed: usize,
) -> (f64, f64) {
    let (mut abs, mut rel, mut disagreements) = (0.0f64, 0.0f64, 0);
    let mut codes = std::collections::BTreeSet::new();
    for ((c, cs), (g, gs)) in cpu.0.iter().zip(cpu.1).zip(gpu.0.iter().zip(gpu.1)) {
        codes.insert(*cs);
        if cs != gs {
            disagreements += 1;
            continue;
        }
        if *cs != 0 {
            assert!(
                g.iter().all(|v| v.is_nan()),
                "{what}: rows without an answer are NaN"
            );
            continue;
        }
        for k in cols.clone() {
            let d = (g[k] - c[k]).abs();
            abs = abs.max(d);
            rel = rel.max(d / c[k].abs().max(1.0));
        }
    }
    assert!(
        disagreements <= allowed,
        "{what}: {disagreements} statuses differ (allowed {allowed})"
    );
    assert!(codes.contains(&0), "{what}: the batch must have answers");
    (abs, rel)
}

/// Allowed status disagreements: none in f64, rounding at boundaries in f32 (0.2 %).
fn allowed(precision: Precision, n: usize) -> usize {
    match precision {
        Precision::F64 => 0,
        Precision::F32 => n / 500,
    }
}

fn each_camera(mut f: impl FnMut(&str, &Rig, usize)) {
    for (name, rig) in configurations() {
        for k in 0..2 {
            f(name, &rig, k);
        }
    }
}

const N: usize = 5000;

#[test]
fn backproject_matches_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0x9E37_79B9_7F4A_7C15);
        each_camera(|name, rig, k| {
            let camera = rig.refractive_camera(k);
            let pixels = random_pixels(&mut random, N);
            let (mut c, mut cs) = (vec![[0.0; 6]; N], vec![0; N]);
            let (mut g, mut gs) = (vec![[0.0; 6]; N], vec![0; N]);
            cpu.backproject(&camera, &pixels, &mut c, &mut cs);
            gpu.backproject(&camera, &pixels, &mut g, &mut gs).unwrap();
            let what = format!("backproject {precision} {name} camera {k}");
            let (dir_abs, dir_rel) =
                compare(&what, (&c, &cs), (&g, &gs), 3..6, allowed(precision, N));
            let (origin_abs, origin_rel) =
                compare(&what, (&c, &cs), (&g, &gs), 0..3, allowed(precision, N));
            println!("{what:60} |Δdir| {dir_abs:.1e}  |Δorigin| {origin_abs:.1e} m");
            match precision {
                Precision::F32 => assert!(dir_abs < 2e-6 && origin_abs < 2e-6, "{what}"),
                Precision::F64 => assert!(dir_rel < 1e-9 && origin_rel < 1e-9, "{what}"),
            }
        });
    }
}

/// Pixels out to 10⁷ px from the image centre through a lens whose distortion grows without
/// a fold (k1 < 0, k2 > 0): inverting it takes Newton up to the stopping rule's 30 steps,
/// from the inverse radial series and, where that run fails (it overflows far out), again from
/// the distorted point. In f64 the kernel must stop where the CPU does, pixel for pixel: a run
/// that converges at its last step, a second run, a start other than the CPU's, each changes
/// statuses on this ring of pixels. f32 stops at a looser tolerance, a step or two sooner, so it
/// may answer where f64 runs out of steps (3.4–4.6·10⁶ px here), and nowhere else differs; the
/// directions both answer agree.
#[test]
fn undistortion_far_outside_the_image_matches_the_cpu() {
    let cpu = CpuEngine::new(None);
    let rig = gpu_harness::rig_with_layer_stacks(true);
    let camera = rig.refractive_camera(0);
    let n = 6000;
    // Radii geometric from 10 to 10⁷ px, at angles of the golden ratio's turns.
    let radius = |i: usize| 10f64.powf(1.0 + 6.0 * i as f64 / (n - 1) as f64);
    let pixels: Vec<[f64; 2]> = (0..n)
        .map(|i| {
            let angle = i as f64 * 2.399_963_229_728_653;
            [
                639.5 + radius(i) * angle.cos(),
                511.5 + radius(i) * angle.sin(),
            ]
        })
        .collect();
    let (mut c, mut cs) = (vec![[0.0; 6]; n], vec![0; n]);
    cpu.backproject(&camera, &pixels, &mut c, &mut cs);
    let answered = cs.iter().filter(|&&s| s == 0).count();
    let outside_lens = NoSolution::OutsideLens.code();
    let outside = cs.iter().filter(|&&s| s == outside_lens).count();
    assert!(
        answered > n / 2 && outside > n / 20,
        "{answered} answered, {outside} outside the lens"
    );
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let (mut g, mut gs) = (vec![[0.0; 6]; n], vec![0; n]);
        gpu.backproject(&camera, &pixels, &mut g, &mut gs).unwrap();
        let what = format!("undistortion {precision}, out to 1e7 px");
        let f32_sooner =
            |i: usize| precision == Precision::F32 && cs[i] == outside_lens && radius(i) > 1e6;
        let differ: Vec<usize> = (0..n).filter(|&i| cs[i] != gs[i]).collect();
        let unexplained: Vec<String> = differ
            .iter()
            .filter(|&&i| !f32_sooner(i))
            .map(|&i| format!("{:.3e} px: CPU {}, GPU {}", radius(i), cs[i], gs[i]))
            .collect();
        assert!(
            unexplained.is_empty(),
            "{what}: statuses differ at {unexplained:?}"
        );
        let (dir_abs, _) = compare(&what, (&c, &cs), (&g, &gs), 3..6, differ.len());
        println!(
            "{what:60} |Δdir| {dir_abs:.1e}, {answered} answered, {outside} outside the lens, \
             {} statuses differ",
            differ.len()
        );
        match precision {
            Precision::F32 => assert!(dir_abs < 2e-6, "{what}"),
            Precision::F64 => assert!(dir_abs < 1e-9, "{what}"),
        }
    }
}

#[test]
fn project_matches_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0xD1B5_4A32_D192_ED03);
        each_camera(|name, rig, k| {
            let camera = rig.refractive_camera(k);
            let points = random_points(&mut random, &camera, N);
            let (mut c, mut cs) = (vec![[0.0; 2]; N], vec![0; N]);
            let (mut g, mut gs) = (vec![[0.0; 2]; N], vec![0; N]);
            cpu.project(&camera, &points, &mut c, &mut cs);
            gpu.project(&camera, &points, &mut g, &mut gs).unwrap();
            let what = format!("project {precision} {name} camera {k}");
            let (_, rel) = compare(&what, (&c, &cs), (&g, &gs), 0..2, allowed(precision, N));
            // Absolute pixel error over the image (1280 × 1024). Points seen at steeper angles
            // project far outside it, where the ill-conditioning of the refraction amplifies the
            // rounding of f32 inputs (about 2e-4 px at 65° incidence from the inputs alone).
            let near_image =
                |p: &[f64; 2]| p[0] > 0.0 && p[0] < 1280.0 && p[1] > 0.0 && p[1] < 1024.0;
            let in_view: Vec<usize> = (0..N)
                .filter(|&i| cs[i] == 0 && gs[i] == 0 && near_image(&c[i]))
                .collect();
            assert!(in_view.len() > N / 2, "{what}: most points in view");
            let abs = in_view
                .iter()
                .map(|&i| (c[i][0] - g[i][0]).abs().max((c[i][1] - g[i][1]).abs()))
                .fold(0.0, f64::max);
            println!("{what:60} |Δpixel| {abs:.1e} px in the image (relative {rel:.1e} anywhere)");
            assert!(
                cs.iter().any(|&s| s == NoSolution::NotInWater.code()),
                "{what}: batch has points out of the water"
            );
            match precision {
                Precision::F32 => assert!(abs < 1e-3, "{what}"),
                Precision::F64 => assert!(rel < 1e-9, "{what}"),
            }
        });
    }
}

/// The forward-projection kernel takes two rows per invocation (`KernelSource::rows_per_invocation`),
/// paired by their place in the chunk: batches and chunks of odd length, down to one row, must
/// give every row the pixel and status it gets in one whole batch (which must match the CPU), bit
/// for bit, whichever row it is paired with. A row skipped, written twice or swapped with its
/// partner fails here.
#[test]
fn project_answers_every_row_of_odd_batches_and_chunks() {
    let cpu = CpuEngine::new(None);
    let configurations = configurations();
    let camera = configurations[0].1.refractive_camera(0);
    for precision in [Precision::F32, Precision::F64] {
        let Some(mut gpu) = engine(precision) else {
            return;
        };
        let mut random = Random(0x2545_F491_4F6C_DD1D);
        let points = random_points(&mut random, &camera, 2001);
        let (mut c, mut cs) = (vec![[0.0; 2]; points.len()], vec![0; points.len()]);
        let (mut whole, mut whole_status) = (c.clone(), cs.clone());
        cpu.project(&camera, &points, &mut c, &mut cs);
        gpu.project(&camera, &points, &mut whole, &mut whole_status)
            .unwrap();
        let what = format!("project {precision}, one batch of {}", points.len());
        compare(
            &what,
            (&c, &cs),
            (&whole, &whole_status),
            0..2,
            allowed(precision, points.len()),
        );
        assert!(
            whole_status.iter().any(|&s| s != 0),
            "{what}: rows without an answer"
        );
        // The points in reverse first, so that a row the kernel leaves alone keeps another
        // row's answer in the buffers (kept across calls), not its own from the last call. 129
        // rows: 64 pairs fill a workgroup, the 129th needs a second one.
        let reversed: Vec<[f64; 3]> = points.iter().rev().copied().collect();
        for chunk in [usize::MAX, 129, 7, 2, 1] {
            gpu.set_stream_chunk_rows(chunk);
            for n in [1, 2, 3, 10, 129, 2001] {
                let (mut g, mut gs) = (vec![[0.0; 2]; n], vec![u32::MAX; n]);
                gpu.project(&camera, &reversed[..n], &mut g, &mut gs)
                    .unwrap();
                gpu.project(&camera, &points[..n], &mut g, &mut gs).unwrap();
                for i in 0..n {
                    let (expected, got) = ((whole_status[i], whole[i]), (gs[i], g[i]));
                    let same = expected.0 == got.0
                        && (0..2).all(|k| expected.1[k].to_bits() == got.1[k].to_bits());
                    assert!(
                        same,
                        "project {precision}, {n} rows in chunks of {chunk}: row {i} gets \
                         {got:?}, {expected:?} in one batch"
                    );
                }
            }
        }
    }
}

#[test]
fn vop_matches_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0x94D0_49BB_1331_11EB);
        each_camera(|name, rig, k| {
            let camera = rig.refractive_camera(k);
            let points = random_points(&mut random, &camera, N);
            let (mut c, mut cs) = (vec![[0.0; 6]; N], vec![0; N]);
            let (mut g, mut gs) = (vec![[0.0; 6]; N], vec![0; N]);
            cpu.vop(&camera, &points, &mut c, &mut cs);
            gpu.vop(&camera, &points, &mut g, &mut gs).unwrap();
            let what = format!("vop {precision} {name} camera {k}");
            let (abs, rel) = compare(&what, (&c, &cs), (&g, &gs), 0..6, allowed(precision, N));
            println!("{what:60} max |Δ| {abs:.1e} (relative {rel:.1e})");
            match precision {
                // f32 carries ~7 digits of metre-scale values (6 m deep points).
                Precision::F32 => assert!(rel < 5e-6, "{what}"),
                Precision::F64 => assert!(rel < 1e-9, "{what}"),
            }
        });
    }
}

/// Matches: the projections of random points in both cameras, with `noise` px added.
fn random_matches(
    random: &mut Random,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    n: usize,
    noise: f64,
) -> Vec<[f64; 4]> {
    let mut matches = Vec::with_capacity(n);
    while matches.len() < n {
        let p = random_points(random, a, 1)[0];
        let point = nalgebra::Point3::from(p);
        if let (Ok(pa), Ok(pb)) = (a.project(&point), b.project(&point)) {
            matches.push([
                pa.x + noise * random.range(-1.0, 1.0),
                pa.y,
                pb.x + noise * random.range(-1.0, 1.0),
                pb.y,
            ]);
        } else if matches.len() % 50 == 0 {
            matches.push([
                random.range(-500.0, 1800.0),
                random.range(-500.0, 1500.0),
                600.0,
                500.0,
            ]);
        }
    }
    matches
}

/// The largest f32 triangulation error over its bound, over rows both answered: direction
/// errors δ ≤ 2e-6 and origin errors ≤ 2e-6 m move each ray by δ·range + δo at the point, and the
/// midpoint by that over sin θ, θ the angle between the rays (factor 2: both rays).
fn f32_triangulation_error(
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    matches: &[[f64; 4]],
    cpu: (&[[f64; 4]], &[u32]),
    gpu: (&[[f64; 4]], &[u32]),
) -> f64 {
    let ((c, cs), (g, gs)) = (cpu, gpu);
    let mut worst: f64 = 0.0;
    for i in (0..matches.len()).filter(|&i| cs[i] == 0 && gs[i] == 0) {
        let m = matches[i];
        let ra = a.backproject(&Point2::new(m[0], m[1])).unwrap();
        let rb = b.backproject(&Point2::new(m[2], m[3])).unwrap();
        let p = nalgebra::Point3::new(c[i][0], c[i][1], c[i][2]);
        let sin = ra.dir.cross(&rb.dir).norm();
        let bound =
            2.0 * (2e-6 * ((p - ra.origin).norm() + (p - rb.origin).norm()) + 2.0 * 2e-6) / sin;
        let error = (0..4)
            .map(|k| (g[i][k] - c[i][k]).abs())
            .fold(0.0, f64::max);
        worst = worst.max(error / bound);
    }
    worst
}

/// Two cameras whose ports have different layer stacks (a bare interface and three layers, in
/// both orders): the two-camera kernels run their layer loops to the pair's most layers, each
/// camera to its own count. A camera that takes the other's later layers, or a missing layer that
/// is not masked off, moves its rays (or totally reflects them) and fails the comparison.
#[test]
fn triangulate_with_different_layer_stacks_matches_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0x2545_F491_4F6C_DD1D);
        for bare_first in [true, false] {
            let rig = gpu_harness::rig_with_layer_stacks(bare_first);
            let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
            // Pixels within an image size of the image: a point far off both axes projects
            // millions of pixels out through this lens (k2 > 0), where inverting it takes about
            // the stopping rule's 30 Newton steps, and f32's looser tolerance stops a step or two
            // sooner than f64: a status that differs by the bound, not by the layers
            // (`undistortion_far_outside_the_image_matches_the_cpu` tests those pixels).
            let near = |m: &[f64; 4]| {
                let inside = |x: f64, y: f64| {
                    (-1280.0..2560.0).contains(&x) && (-1024.0..2048.0).contains(&y)
                };
                inside(m[0], m[1]) && inside(m[2], m[3])
            };
            let matches: Vec<[f64; 4]> = random_matches(&mut random, &a, &b, 2 * N, 0.3)
                .into_iter()
                .filter(near)
                .take(N)
                .collect();
            assert_eq!(matches.len(), N, "matches near the images");
            let (mut c, mut cs) = (vec![[0.0; 4]; N], vec![0; N]);
            let (mut g, mut gs) = (vec![[0.0; 4]; N], vec![0; N]);
            cpu.triangulate(&a, &b, &matches, &mut c, &mut cs);
            gpu.triangulate(&a, &b, &matches, &mut g, &mut gs).unwrap();
            let layers = [a.layers().len(), b.layers().len()];
            let what = format!("triangulate {precision}, layers {layers:?}");
            let answered = cs.iter().filter(|&&s| s == 0).count();
            assert!(answered > N / 2, "{what}: {answered} of {N} answered");
            let (abs, rel) = compare(&what, (&c, &cs), (&g, &gs), 0..4, allowed(precision, N));
            println!("{what:60} max |Δ| {abs:.1e} m (relative {rel:.1e})");
            match precision {
                Precision::F32 => {
                    let worst = f32_triangulation_error(&a, &b, &matches, (&c, &cs), (&g, &gs));
                    assert!(worst < 1.0, "{what}: |Δ| / bound {worst:.2}");
                }
                Precision::F64 => assert!(rel < 1e-9, "{what}"),
            }
        }
    }
}

#[test]
fn triangulate_and_binocular_vop_match_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0xBF58_476D_1CE4_E5B9);
        for (name, rig) in configurations() {
            let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
            let matches = random_matches(&mut random, &a, &b, N, 0.3);
            let (mut c, mut cs) = (vec![[0.0; 4]; N], vec![0; N]);
            let (mut g, mut gs) = (vec![[0.0; 4]; N], vec![0; N]);
            cpu.triangulate(&a, &b, &matches, &mut c, &mut cs);
            gpu.triangulate(&a, &b, &matches, &mut g, &mut gs).unwrap();
            let what = format!("triangulate {precision} {name}");
            let (abs, rel) = compare(&what, (&c, &cs), (&g, &gs), 0..4, allowed(precision, N));
            println!("{what:60} max |Δ| {abs:.1e} m (relative {rel:.1e})");
            match precision {
                Precision::F32 => {
                    let worst = f32_triangulation_error(&a, &b, &matches, (&c, &cs), (&g, &gs));
                    println!("{what:60} max |Δ| / bound {worst:.2}");
                    assert!(worst < 1.0, "{what}");
                }
                Precision::F64 => assert!(rel < 1e-9, "{what}"),
            }

            let (mut c, mut cs) = (vec![[0.0; 8]; N], vec![0; N]);
            let (mut g, mut gs) = (vec![[0.0; 8]; N], vec![0; N]);
            cpu.binocular_vop(&a, &b, &matches, &mut c, &mut cs);
            gpu.binocular_vop(&a, &b, &matches, &mut g, &mut gs)
                .unwrap();
            let what = format!("binocular vop {precision} {name}");
            match precision {
                Precision::F64 => {
                    let (abs, rel) = compare(&what, (&c, &cs), (&g, &gs), 0..8, 0);
                    println!("{what:60} max |Δ| {abs:.1e} (relative {rel:.1e})");
                    assert!(rel < 1e-9, "{what}");
                }
                Precision::F32 => {
                    // Cramer's rule divides by the conditioning: compare where it is ≥ 0.05, with
                    // the direction error scaled by distance / conditioning.
                    let mut worst: f64 = 0.0;
                    for ((cr, csr), (gr, gsr)) in c.iter().zip(&cs).zip(g.iter().zip(&gs)) {
                        if *csr == 0 && *gsr == 0 && cr[7] >= 0.05 {
                            let scale =
                                2e-6 * (1.0 + cr[0].abs() + cr[1].abs() + cr[2].abs()) / cr[7];
                            for k in 0..7 {
                                worst = worst.max((gr[k] - cr[k]).abs() / scale);
                            }
                        }
                    }
                    println!("{what:60} max |Δ| / bound {worst:.2}");
                    assert!(worst < 1.0, "{what}");
                }
            }
        }
    }
}

#[test]
fn image_grid_backprojection_matches_pixel_buffer() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let (_, rig) = configurations().remove(4);
        let camera = rig.refractive_camera(1);
        let (w, h) = (333u32, 211u32);
        let n = (w * h) as usize;
        let pixels: Vec<[f64; 2]> = (0..h)
            .flat_map(|v| (0..w).map(move |u| [u as f64, v as f64]))
            .collect();
        let (mut c, mut cs) = (vec![[0.0; 6]; n], vec![0; n]);
        let (mut g, mut gs) = (vec![[0.0; 6]; n], vec![0; n]);
        cpu.backproject(&camera, &pixels, &mut c, &mut cs);
        gpu.backproject_grid(&camera, w, h, &mut g, &mut gs)
            .unwrap();
        let what = format!("backproject_grid {precision}");
        let (abs, rel) = compare(&what, (&c, &cs), (&g, &gs), 0..6, allowed(precision, n));
        println!("{what:60} max |Δ| {abs:.1e} (relative {rel:.1e})");
        match precision {
            Precision::F32 => assert!(abs < 2e-6, "{what}"),
            Precision::F64 => assert!(rel < 1e-9, "{what}"),
        }
    }
}

#[test]
fn statuses_match_where_the_cpu_has_no_answer() {
    let cpu = CpuEngine::new(None);
    // Light from a denser "air" (1.333) into a thinner last medium (1.0): steep pixels are totally
    // internally reflected. Far pixels of a strongly distorted image lie beyond the lens fold; a
    // steeply tilted port is missed by the image's far side.
    let cases = [
        stereo_rig(unit(0.0, 0.0, 1.0), 0.02, vec![], 1.333, 1.0, false),
        stereo_rig(unit(0.05, 0.0, 1.0), 0.02, vec![], 1.0, 1.333, true),
        stereo_rig(unit(1.2, 0.0, 1.0), 0.2, vec![], 1.0, 1.333, false),
    ];
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut seen = std::collections::BTreeSet::new();
        for rig in &cases {
            let camera = rig.refractive_camera(0);
            let pixels: Vec<[f64; 2]> = (0..60)
                .flat_map(|i| {
                    (0..50).map(move |j| [-4000.0 + i as f64 * 157.3, -3000.0 + j as f64 * 143.1])
                })
                .collect();
            let n = pixels.len();
            let (mut c, mut cs) = (vec![[0.0; 6]; n], vec![0; n]);
            let (mut g, mut gs) = (vec![[0.0; 6]; n], vec![0; n]);
            cpu.backproject(&camera, &pixels, &mut c, &mut cs);
            gpu.backproject(&camera, &pixels, &mut g, &mut gs).unwrap();
            compare(
                &format!("statuses {precision}"),
                (&c, &cs),
                (&g, &gs),
                0..6,
                allowed(precision, n),
            );
            seen.extend(cs);
        }
        for reason in [
            NoSolution::OutsideLens,
            NoSolution::MissesInterface,
            NoSolution::TotalInternalReflection,
        ] {
            assert!(
                seen.contains(&reason.code()),
                "the cases must exercise {reason}"
            );
        }
    }
}

/// Six million rows in one call: chunked under the binding cap, nothing lost or truncated.
#[test]
fn six_million_rows_go_through() {
    let Some(gpu) = engine(Precision::F32) else {
        return;
    };
    let (_, rig) = configurations().remove(2);
    let camera = rig.refractive_camera(0);
    let n = 6_000_000;
    let pixels: Vec<[f64; 2]> = (0..n)
        .map(|i| [(i % 1280) as f64 + 0.5, ((i / 1280) % 1024) as f64 + 0.25])
        .collect();
    let mut rays = vec![[f64::INFINITY; 6]; n];
    let mut status = vec![u32::MAX; n];
    gpu.backproject(&camera, &pixels, &mut rays, &mut status)
        .unwrap();
    assert!(
        status.iter().all(|&s| s == 0),
        "every pixel of the image sees the water"
    );
    assert!(
        rays.iter().all(|r| r.iter().all(|v| v.is_finite())),
        "every row written"
    );
    for i in (0..n).step_by(9973).chain([n - 1]) {
        let cpu = camera
            .backproject(&Point2::new(pixels[i][0], pixels[i][1]))
            .unwrap();
        let dir = Vector3::new(rays[i][3], rays[i][4], rays[i][5]);
        assert!((dir - cpu.dir.into_inner()).norm() < 2e-6, "row {i}");
    }
}

/// The staging path (discrete GPUs: storage buffers copied to and from host-mapped staging
/// buffers) gives the same results as the directly mapped path lavapipe uses by default, for a
/// row kernel over several chunks and the image grid (the calibration kernels' staging:
/// tests/calib_gpu.rs).
#[test]
fn staged_and_mapped_buffers_agree() {
    for precision in [Precision::F32, Precision::F64] {
        let (Some(mapped), Some(staged)) =
            (engine_with(precision, true), engine_with(precision, false))
        else {
            return;
        };
        assert!(!staged.context().maps_storage());
        let (_, rig) = configurations().remove(3);
        let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
        let mut random = Random(0x6A09_E667_F3BC_C909);
        let n = flatport::gpu::MAX_CHUNK_ITEMS + 777; // two chunks
        let points = random_points(&mut random, &a, n);
        let run = |gpu: &GpuEngine| {
            let (mut pixels, mut status) = (vec![[0.0; 2]; n], vec![0; n]);
            gpu.project(&a, &points, &mut pixels, &mut status).unwrap();
            let (mut rays, mut grid_status) = (vec![[0.0; 6]; 200 * 150], vec![0; 200 * 150]);
            gpu.backproject_grid(&b, 200, 150, &mut rays, &mut grid_status)
                .unwrap();
            (pixels, status, rays, grid_status)
        };
        let (m, s) = (run(&mapped), run(&staged));
        assert_eq!(m.1, s.1, "{precision} project statuses");
        assert_eq!(m.3, s.3, "{precision} grid statuses");
        assert!(
            m.1.contains(&0) && m.1.iter().any(|&c| c != 0),
            "{precision}: answers and rows without"
        );
        let same = |x: &[f64], y: &[f64]| {
            x.iter()
                .zip(y)
                .all(|(p, q)| p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()))
        };
        assert!(
            same(m.0.as_flattened(), s.0.as_flattened()),
            "{precision} project"
        );
        assert!(
            same(m.2.as_flattened(), s.2.as_flattened()),
            "{precision} grid"
        );
    }
}

/// Issue 14 (rows that lie): points from metres to 1e299 m (past 1.3e154, where squares overflow),
/// beyond ±1e300 and beyond f32's range, in view, far to the side and far down the axis. Every row
/// is all numbers or all NaN on both engines; the f64 kernels give the CPU's statuses and values;
/// the f32 kernels reject inputs they cannot represent (beyond ±1e30) as out of range.
#[test]
fn extreme_points_are_every_number_or_none_and_agree() {
    let cpu = CpuEngine::new(None);
    let directions = [
        [0.1, 0.05, 1.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.01],
        [-0.3, 0.2, 1.0],
        [100.0, 0.0, 1.0],
        [0.0, 1e-3, 1e17],
    ];
    let scales = [
        1.0,
        1e3,
        1e10,
        1e20,
        1e40,
        1e100,
        1e154,
        1e155,
        1e200,
        1e299,
        1e301,
        f64::MAX,
    ];
    let points: Vec<[f64; 3]> = scales
        .iter()
        .flat_map(|&s| directions.iter().map(move |d| d.map(|c| c * s)))
        .collect();
    let n = points.len();
    let all_or_none = |row: &[f64], s: u32| {
        if s == 0 {
            row.iter().all(|v| v.is_finite())
        } else {
            row.iter().all(|v| v.is_nan())
        }
    };
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        each_camera(|name, rig, k| {
            let camera = rig.refractive_camera(k);
            let (mut c, mut cs, mut g, mut gs) =
                (vec![[0.0; 6]; n], vec![0; n], vec![[0.0; 6]; n], vec![0; n]);
            cpu.vop(&camera, &points, &mut c, &mut cs);
            gpu.vop(&camera, &points, &mut g, &mut gs).unwrap();
            let (mut pc, mut pcs, mut pg, mut pgs) =
                (vec![[0.0; 2]; n], vec![0; n], vec![[0.0; 2]; n], vec![0; n]);
            cpu.project(&camera, &points, &mut pc, &mut pcs);
            gpu.project(&camera, &points, &mut pg, &mut pgs).unwrap();
            for i in 0..n {
                let what = format!("{precision} {name} camera {k} point {:?}", points[i]);
                assert!(
                    all_or_none(&c[i], cs[i]) && all_or_none(&g[i], gs[i]),
                    "vop {what}: cpu {:?} {} gpu {:?} {}",
                    c[i],
                    cs[i],
                    g[i],
                    gs[i]
                );
                assert!(
                    all_or_none(&pc[i], pcs[i]) && all_or_none(&pg[i], pgs[i]),
                    "project {what}"
                );
                let beyond = |limit: f64| points[i].iter().any(|v| v.abs() > limit);
                if beyond(1e300) {
                    assert_eq!(
                        (cs[i], pcs[i]),
                        (NoSolution::OutOfRange.code(), NoSolution::OutOfRange.code()),
                        "cpu {what}"
                    );
                }
                match precision {
                    Precision::F64 => {
                        assert_eq!((cs[i], pcs[i]), (gs[i], pgs[i]), "statuses {what}");
                        // The VOP's coordinates (O + (x̌ − x)·n) and the depth x are sums at
                        // the point's scale and round there. x̌ = r / tan a − d_k − Σtᵢ does
                        // not: tan a is a well-conditioned root (found in the air's angle near
                        // grazing), and r / tan a is of the size of the port, so x̌ is held to
                        // its own size or a metre, however far the point (a point 1e10 m to the
                        // side once stopped at tan a = 1.4e8: x̌ 66 m on the CPU, 113 m on an
                        // NVIDIA GPU, for 0.0285 m).
                        let scale = points[i].iter().fold(1.0f64, |m, v| m.max(v.abs()));
                        for (j, (a, b)) in c[i].iter().zip(&g[i]).enumerate() {
                            let size = if j == 1 { 1.0 } else { scale };
                            assert!(
                                !a.is_finite() || (a - b).abs() <= 1e-9 * a.abs().max(size),
                                "vop {what} value {j}: cpu {a} gpu {b}"
                            );
                        }
                        for (a, b) in pc[i].iter().zip(&pg[i]).filter(|(a, _)| a.is_finite()) {
                            assert!(
                                (a - b).abs() <= 1e-9 * a.abs().max(1.0),
                                "project {what}: cpu {a} gpu {b}"
                            );
                        }
                    }
                    Precision::F32 if beyond(1e30) => {
                        assert_eq!(
                            (gs[i], pgs[i]),
                            (NoSolution::OutOfRange.code(), NoSolution::OutOfRange.code()),
                            "gpu {what}"
                        );
                    }
                    Precision::F32 => {}
                }
            }
        });
    }
}

/// Bitwise equality of two batches, NaN rows equal.
fn same_bits<const M: usize>(x: &[[f64; M]], y: &[[f64; M]]) -> bool {
    x.as_flattened()
        .iter()
        .zip(y.as_flattened())
        .all(|(p, q)| p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()))
}

/// The row kernels' chunking follows the adapter: on a software adapter (lavapipe, which CI
/// runs) a batch in as few chunks as the bindings allow, on a hardware GPU through the ring of
/// `STREAM_CHUNK_ROWS`-row chunks. The adapter's kind is read from its summary (wgpu's device
/// type as `flatport info` prints it), apart from the flag the engine decides by.
#[test]
fn the_chunking_follows_the_adapter_kind() {
    let Some(gpu) = engine(Precision::F32) else {
        return;
    };
    let adapter = gpu.context().adapter();
    let software = adapter.device_type == "Cpu";
    assert_eq!(gpu.context().is_software(), software, "{}", adapter.name);
    if adapter.name.contains("llvmpipe") {
        assert!(
            software,
            "lavapipe is a software adapter: {}",
            adapter.device_type
        );
    }
    let expected = if software {
        usize::MAX
    } else {
        flatport::gpu::STREAM_CHUNK_ROWS
    };
    assert_eq!(gpu.stream_chunk_rows(), expected, "{}", adapter.name);
}

/// Issue 13: a batch streamed over many chunks (20 chunks of 256 rows through the ring of buffer
/// sets, so several are in flight) gives bit for bit what one chunk gives, on the mapped and the
/// staged path, and matches the CPU within the tolerances of the tests above.
#[test]
fn streamed_chunks_equal_one_chunk_and_the_cpu() {
    let cpu = CpuEngine::new(None);
    const ROWS: usize = 20 * 256 - 17;
    for precision in [Precision::F32, Precision::F64] {
        for map_storage in [true, false] {
            let (Some(one), Some(mut streamed)) = (
                engine_with(precision, map_storage),
                engine_with(precision, map_storage),
            ) else {
                return;
            };
            streamed.set_max_chunk_items(256);
            let (_, rig) = configurations().remove(3);
            let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
            let mut random = Random(0xBB67_AE85_84CA_A73B);
            let what = format!("{precision}, mapped storage {map_storage}");
            // Forward projection.
            let points = random_points(&mut random, &a, ROWS);
            let run = |gpu: &GpuEngine| {
                let (mut pixels, mut status) = (vec![[0.0; 2]; ROWS], vec![0; ROWS]);
                gpu.project(&a, &points, &mut pixels, &mut status).unwrap();
                (pixels, status)
            };
            let ((p1, s1), (ps, ss)) = (run(&one), run(&streamed));
            assert_eq!(s1, ss, "{what}: project statuses");
            assert!(same_bits(&p1, &ps), "{what}: project rows");
            let (mut c, mut cs) = (vec![[0.0; 2]; ROWS], vec![0; ROWS]);
            cpu.project(&a, &points, &mut c, &mut cs);
            let (_, rel) = compare(&what, (&c, &cs), (&ps, &ss), 0..2, allowed(precision, ROWS));
            let in_image =
                |p: &[f64; 2]| p[0] > 0.0 && p[0] < 1280.0 && p[1] > 0.0 && p[1] < 1024.0;
            let abs = (0..ROWS)
                .filter(|&i| cs[i] == 0 && ss[i] == 0 && in_image(&c[i]))
                .map(|i| (c[i][0] - ps[i][0]).abs().max((c[i][1] - ps[i][1]).abs()))
                .fold(0.0, f64::max);
            match precision {
                Precision::F32 => assert!(abs < 1e-3, "{what}: |Δpixel| {abs:.1e}"),
                Precision::F64 => assert!(rel < 1e-9, "{what}: relative {rel:.1e}"),
            }
            assert!(
                ss.iter().any(|&s| s == NoSolution::NotInWater.code()),
                "{what}: rows without an answer in the stream"
            );
            // Triangulation (two cameras, four reals in and out).
            let matches = random_matches(&mut random, &a, &b, ROWS, 0.3);
            let run = |gpu: &GpuEngine| {
                let (mut points, mut status) = (vec![[0.0; 4]; ROWS], vec![0; ROWS]);
                gpu.triangulate(&a, &b, &matches, &mut points, &mut status)
                    .unwrap();
                (points, status)
            };
            let ((t1, s1), (ts, ss)) = (run(&one), run(&streamed));
            assert_eq!(s1, ss, "{what}: triangulate statuses");
            assert!(same_bits(&t1, &ts), "{what}: triangulate rows");
            let (mut c, mut cs) = (vec![[0.0; 4]; ROWS], vec![0; ROWS]);
            cpu.triangulate(&a, &b, &matches, &mut c, &mut cs);
            let (_, rel) = compare(&what, (&c, &cs), (&ts, &ss), 0..4, allowed(precision, ROWS));
            // As triangulate_and_binocular_vop_match_cpu.
            match precision {
                Precision::F32 => {
                    let worst = f32_triangulation_error(&a, &b, &matches, (&c, &cs), (&ts, &ss));
                    assert!(worst < 1.0, "{what}: triangulate |Δ| / bound {worst:.2}");
                }
                Precision::F64 => assert!(rel < 1e-9, "{what}: triangulate relative {rel:.1e}"),
            }
        }
    }
}

/// Issue 13: f32 host slices. With f32 kernels they go to and from the device unconverted and
/// give exactly the f32 rounding of what the f64 host path gives on the same (f32-representable)
/// points; with f64 kernels the f32 rounding of the f64 results. Both match the CPU on those
/// points within 1e-3 px, and rows without an answer are NaN with their status.
#[test]
fn f32_host_slices_match_the_f64_host_path_and_the_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(mut gpu) = engine(precision) else {
            return;
        };
        gpu.set_max_chunk_items(1024); // several chunks in flight
        let (_, rig) = configurations().remove(3);
        let camera = rig.refractive_camera(0);
        let mut random = Random(0x3C6E_F372_FE94_F82B);
        let points32: Vec<[f32; 3]> = random_points(&mut random, &camera, N)
            .iter()
            .map(|p| p.map(|v| v as f32))
            .collect();
        let points64: Vec<[f64; 3]> = points32.iter().map(|p| p.map(f64::from)).collect();
        let (mut g32, mut s32) = (vec![[0.0f32; 2]; N], vec![0; N]);
        gpu.project(&camera, &points32, &mut g32, &mut s32).unwrap();
        let (mut g64, mut s64) = (vec![[0.0f64; 2]; N], vec![0; N]);
        gpu.project(&camera, &points64, &mut g64, &mut s64).unwrap();
        assert_eq!(s32, s64, "{precision}: statuses of both host types");
        for i in 0..N {
            for k in 0..2 {
                let rounded = g64[i][k] as f32;
                assert!(
                    g32[i][k].to_bits() == rounded.to_bits()
                        || (g32[i][k].is_nan() && rounded.is_nan()),
                    "{precision} row {i}: f32 host {} against f64 host {}",
                    g32[i][k],
                    g64[i][k]
                );
            }
        }
        let (mut c, mut cs) = (vec![[0.0; 2]; N], vec![0; N]);
        cpu.project(&camera, &points64, &mut c, &mut cs);
        let widened: Vec<[f64; 2]> = g32.iter().map(|p| p.map(f64::from)).collect();
        let what = format!("project, f32 host, {precision} kernels");
        compare(
            &what,
            (&c, &cs),
            (&widened, &s32),
            0..2,
            allowed(precision, N),
        );
        let in_image = |p: &[f64; 2]| p[0] > 0.0 && p[0] < 1280.0 && p[1] > 0.0 && p[1] < 1024.0;
        let in_view: Vec<usize> = (0..N)
            .filter(|&i| cs[i] == 0 && s32[i] == 0 && in_image(&c[i]))
            .collect();
        assert!(in_view.len() > N / 2, "{what}: most points in view");
        let abs = in_view
            .iter()
            .map(|&i| {
                (c[i][0] - widened[i][0])
                    .abs()
                    .max((c[i][1] - widened[i][1]).abs())
            })
            .fold(0.0, f64::max);
        println!("{what}: |Δpixel| {abs:.1e} px in the image");
        assert!(abs < 1e-3, "{what}: |Δpixel| {abs:.1e}");
        assert!(
            s32.iter().any(|&s| s == NoSolution::NotInWater.code()),
            "{what}: rows without an answer"
        );
    }
}
