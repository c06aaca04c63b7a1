//! What the GPU test files share: opening an engine on the Vulkan adapter (lavapipe in CI), which
//! fails the run when `CI` is set and there is none, and a small reproducible random source.
#![allow(dead_code)]

use flatport::engine::GpuEngine;
use flatport::gpu::{GpuContext, Precision};
use flatport::model::Rig;

/// The GPU engine at `precision`, or `None` (with a note) when there is no adapter outside CI.
pub fn engine(precision: Precision) -> Option<GpuEngine> {
    engine_with(precision, true)
}

/// As [`engine`]; `map_storage: false` forces the staging copies of discrete GPUs.
pub fn engine_with(precision: Precision, map_storage: bool) -> Option<GpuEngine> {
    match GpuContext::open(None, map_storage) {
        Ok(context) => {
            eprintln!(
                "GPU adapter: {} ({}), {precision}",
                context.adapter().name,
                context.adapter().driver
            );
            Some(
                GpuEngine::new(context, precision)
                    .expect("lavapipe and the GPUs we test have SHADER_F64"),
            )
        }
        Err(e) if std::env::var_os("CI").is_none() => {
            eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead): {e}");
            None
        }
        Err(e) => panic!("CI needs a Vulkan adapter (scripts/test.sh installs lavapipe): {e}"),
    }
}

/// xorshift64*: reproducible random batches without a dependency.
pub struct Random(pub u64);

impl Random {
    pub fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
}

/// Two housings whose ports have different layer stacks, a port per camera (in each camera's
/// frame), lenses with distortion: one camera behind a bare interface, the other behind three
/// layers (the bare one first where `bare_first`). The kernels run their layer loops to the most
/// layers of the pair and each camera to its own count.
pub fn rig_with_layer_stacks(bare_first: bool) -> Rig {
    let port = |normal: [f64; 3], distance: f64, layers: &str| {
        format!(
            r#"{{"normal": {normal:?}, "distance": {distance}, "layers": [{layers}],
                "index_air": 1.0, "index_water": 1.333}}"#
        )
    };
    let bare = port([0.12, 0.0, 1.0], 0.015, "");
    let stack = port(
        [-0.05, 0.07, 1.0],
        0.012,
        r#"{"thickness": 0.008, "index": 1.49}, {"thickness": 0.002, "index": 1.38},
           {"thickness": 0.01, "index": 1.7}"#,
    );
    let camera = |name: &str, pose: &str, interface: &str| {
        format!(
            r#"{{"name": "{name}", "width": 1280, "height": 1024, "fx": 1000.0, "fy": 1000.0,
                "cx": 639.5, "cy": 511.5, "distortion": [-0.1, 0.02, 0.0005, -0.0003, 0.0]{pose},
                "interface": {interface}}}"#
        )
    };
    let right_pose = r#", "rotation": [[0.999390827019, 0.0, 0.034899496703], [0.0, 1.0, 0.0],
        [-0.034899496703, 0.0, 0.999390827019]], "translation": [-0.2, 0.0, 0.008]"#;
    let (first, second) = if bare_first {
        (&bare, &stack)
    } else {
        (&stack, &bare)
    };
    let text = format!(
        r#"{{"cameras": [{}, {}]}}"#,
        camera("left", "", first),
        camera("right", right_pose, second)
    );
    flatport::io::rig_from_json_str(&text, std::path::Path::new("rig_with_layer_stacks"))
        .expect("rig with a port per camera")
}
